"""The one place that decides how caustica's kernels are compiled and run in parallel.

Every Numba kernel in the package is decorated with :func:`kernel`: compiled
with ``nogil=True`` and cached on disk, without Python wrappers when kernels call
it, with one when Python does (:class:`Kernel`).  Work is spread over cores by
:func:`parallel_for`, which runs a *range kernel* (a kernel whose last two
arguments are the first and one-past-last work item) on chunks of the work from a
pool of Python threads; the kernels release the GIL, so the threads run truly in
parallel.  Each work item (pixel, photon, stream) draws its random numbers from
its own index, so the result is the same for any thread count and any chunking.

Interrupts: the calling thread only waits (but for item 0 of a kernel already compiled
for the call's argument types: one work item), so Ctrl-C (KeyboardInterrupt) reaches
it at once, at any thread count.  It then hands out no more chunks and returns
without waiting for the ones running: a running chunk (a compiled kernel cannot
be stopped) finishes on its daemon thread, which a process that exits does not
wait for.  Chunks are sized to take about :data:`CHUNK_SECONDS` each, so an
interrupted render in a longer-lived process (a notebook) stops using the cores
soon after.

Why threads over chunks rather than ``parallel=True`` / ``prange``: measured on
this project's 2-core machine, a ``prange`` kernel costs 2.7 s of compilation in
*every* process even when it only calls a cached serial kernel (Numba re-optimises
the linked callee module; a trivial ``prange`` loop alone costs 0.44 s), and
caching ``parallel=True`` kernels has crashed other projects (numba #7518,
#8578).  A cached ``nogil`` range kernel starts in milliseconds.
:func:`parallel_kernel` remains for code that wants ``prange`` explicitly (tests
check that the kd-tree search is safe to call from one).

Caching policy
--------------
* Serial kernels are cached on disk (``cache=True``) unless the environment
  variable ``CAUSTICA_NO_CACHE=1`` is set: they are the bulk of the compile time.
  A :class:`Kernel` is cached as the LLVM bitcode its callers link (it has no machine
  code), its Python twin as Numba caches any function (machine code and bitcode).
* Numba invalidates a cached function only when *its own* file changes, not when
  a kernel it calls changes in another file (numba #1833): a stale cache would
  silently run old code.  So the cache lives in a folder named after a hash of
  the package's source files (all but the CLI and the experiments, which no
  kernel imports) (``~/.cache/caustica/numba/<hash>``, or under
  ``$CAUSTICA_CACHE_DIR``): any edit, upgrade or checkout starts a fresh cache.
  A ``NUMBA_CACHE_DIR`` set by the user is respected as it is.
* Processes share the cache safely (:func:`_cache_lock`): Dask workers on one
  machine, renders of a sweep, test workers.  Numba itself does not lock it, and two
  processes saving specialisations of one function at once each rewrite its index
  from the copy they read: one entry is lost, or paired with the other's code.
* Parallel kernels are never cached: caching ``parallel=True`` functions has
  crashed other projects (numba issues #7518 and #8578) and they compile
  quickly once their serial callees are cached.
* ``fastmath`` is off: photon-map estimates and Fresnel terms must not depend on
  reassociation, and NaN checks must keep working.

``CAUSTICA_NO_CACHE=1`` turns caching off (useful when measuring cold compile time).

Compile time
------------
A fresh install compiles every kernel of its first render (``make render``: about
260, see ``benchmarks/bench_compile.py`` for the table per kernel).  What keeps
that short: kernels called from kernels get no Python wrappers (:class:`Kernel`) and no
machine code of their own, only the IR their callers link (:class:`LinkOnlyLibrary`);
calls are typed with plain, never literal, argument types (one specialisation per
kernel); scene tables reach per-ray code *borrowed* (:func:`borrowed`): held by reference, with no
reference counts, so binding or passing one generates one pointer, not the ~600 scalars Numba passes
a struct of arrays as (-29 % compile time, 2026-12-05, ``docs/results.md``); helpers are inlined by LLVM
(``inline``), never by Numba's IR inlining, which compiles the helper again at every call site; and
the code of the kinds a scene lacks is dropped before typing (:class:`FoldFeatureTests`), so the callees
only it calls are never compiled.
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib
import os
import queue
import threading
import time
import types as pytypes
from pathlib import Path

import llvmlite.ir as llvm_ir
import numba
from llvmlite import binding as ll
from numba import _dynfunc, njit, types
from numba.core import caching, cgutils, debuginfo, errors, ir
from numba.core.analysis import compute_cfg_from_blocks
from numba.core.boxing import unbox_unsupported
from numba.core.callconv import CPUCallConv
from numba.core.codegen import CPUCodeLibrary, JITCodeLibrary, RuntimeLinker
from numba.core.compiler import CompileResult, Compiler, DefaultPassBuilder
from numba.core.compiler_machinery import AnalysisPass, FunctionPass, register_pass
from numba.core.cpu import CPUContext
from numba.core.datamodel.models import OpaqueModel, PrimitiveModel
from numba.core.environment import lookup_environment
from numba.core.imputils import lower_builtin, lower_constant, lower_getattr_generic
from numba.core.ir_utils import GuardException, find_const, get_definition
from numba.core.lowering import Lower
from numba.core.registry import CPUDispatcher
from numba.core.typed_passes import NativeLowering, NopythonTypeInference
from numba.core.untyped_passes import WithLifting
from numba.extending import box, intrinsic, register_model, unbox

from .features import features_of, has

CACHE_SERIAL = os.environ.get("CAUSTICA_NO_CACHE", "0") != "1"


def source_hash() -> str:
    """A short hash of the package's sources that kernels can depend on: the cache's version.

    Kernels read code and constants from every module they import, so every file
    counts except those no kernel imports: the command line and the experiments
    (editing them keeps the compiled cache).
    """
    h = hashlib.sha1()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] in ("experiments", "cli.py", "__main__.py"):
            continue
        h.update(str(rel).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _configure_cache_dir() -> None:
    if not CACHE_SERIAL or os.environ.get("NUMBA_CACHE_DIR"):
        return
    base = os.environ.get("CAUSTICA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "caustica", "numba")
    numba.config.CACHE_DIR = os.path.join(base, source_hash())


_configure_cache_dir()

try:
    import fcntl
except ImportError:  # Windows: no advisory locks here, the cache is unlocked as in Numba
    fcntl = None


#: Per thread, the cache folders whose lock it holds, and how deep.
_held_locks = threading.local()


@contextlib.contextmanager
def _cache_lock(index_path: str, exclusive: bool):
    """Hold the lock of the cache folder holding ``index_path`` (the file ``.lock`` in it).

    Saving a specialisation reads a function's index, adds the entry and writes the
    index and the code: done exclusively, or processes saving at once lose entries or
    pair one's key with the other's code.  Loading (index, then code) shares the lock.
    A folder that does not exist yet (nothing to load) or cannot be written is not locked.
    A thread that holds it already goes on under the lock it holds: reading an index imports
    the modules of the kernels its keys name, and a module that compiled a kernel as it was
    imported would otherwise wait on its own thread's shared lock to save.
    """
    folder = os.path.dirname(index_path)
    held = _held_locks.__dict__.setdefault("folders", {})
    if held.get(folder, 0) > 0:
        held[folder] += 1
        try:
            yield
        finally:
            held[folder] -= 1
        return
    try:
        fd = os.open(os.path.join(folder, ".lock"), os.O_RDWR | os.O_CREAT, 0o644)
    except OSError:
        fd = None
    try:
        if fd is not None and fcntl is not None:
            fcntl.flock(fd, fcntl.LOCK_EX if exclusive else fcntl.LOCK_SH)
        held[folder] = 1
        yield
    finally:
        held[folder] = 0
        if fd is not None:
            os.close(fd)  # releases the lock


def _locked(method, exclusive: bool):
    def locked(self, *args):
        with _cache_lock(self._index_path, exclusive):
            return method(self, *args)
    locked.__doc__ = method.__doc__
    return locked


caching.IndexDataCacheFile.save = _locked(caching.IndexDataCacheFile.save, exclusive=True)
caching.IndexDataCacheFile.load = _locked(caching.IndexDataCacheFile.load, exclusive=False)


def _static_type(func_ir, arg_types, var, depth=0):
    """The Numba type of ``var`` where the untyped IR says it: an argument, or an item or field of one (``tables[1]``,
    ``geom, mats, lights, media = tables``, ``scene.lights``); None otherwise (a variable assigned twice, a call)."""
    try:
        d = get_definition(func_ir, var)
    except GuardException:
        return None
    if isinstance(d, ir.Arg):
        return arg_types[d.index] if d.index < len(arg_types) else None
    if not isinstance(d, ir.Expr) or depth > 8:
        return None
    if d.op == "exhaust_iter":
        return _static_type(func_ir, arg_types, d.value, depth + 1)
    of = _static_type(func_ir, arg_types, d.value, depth + 1) if d.op in ("static_getitem", "getitem",
                                                                           "getattr") else None
    index = d.index if d.op == "static_getitem" else None
    if d.op == "getitem":   # tables[1] before Numba's rewrites make it a static_getitem
        try:
            index = find_const(func_ir, d.index)
        except GuardException:
            return None
    if index is not None and isinstance(of, types.BaseTuple) and isinstance(index, int) and 0 <= index < len(of.types):
        return of.types[index]
    if d.op == "getattr" and isinstance(of, types.BaseNamedTuple) and d.attr in of.fields:
        return of.types[of.fields.index(d.attr)]
    return None


@register_pass(mutates_CFG=False, analysis_only=False)
class FoldFeatureTests(FunctionPass):
    """``has(table, CODE)`` (:mod:`caustica.features`) replaced by its constant before typing, wherever the table's
    type follows from the arguments, so that Numba's dead-branch pruning (the pass after it) drops the code it
    guards before type inference.  Typing a call compiles the callee: without this, a scene without plastic still
    compiled plastic's BSDF (and every missing kind's) once, for LLVM to drop from the caller afterwards.  A call
    whose table is not found this way stays as it was (``has`` is a constant at code generation anyway).  A call to a
    kernel marked :func:`caustica.features.guarded_by` whose table (its first argument) holds none of the features
    it names is folded to False the same way."""
    _name = "caustica_fold_feature_tests"

    def __init__(self):
        FunctionPass.__init__(self)

    def run_pass(self, state):
        func_ir = state.func_ir
        changed = False
        for block in func_ir.blocks.values():
            for stmt in block.body:
                if not (isinstance(stmt, ir.Assign) and isinstance(stmt.value, ir.Expr) and stmt.value.op == "call"
                        and stmt.value.args and not stmt.value.kws):
                    continue
                try:
                    fn = get_definition(func_ir, stmt.value.func)
                except GuardException:
                    continue
                if not isinstance(fn, (ir.Global, ir.FreeVar)):
                    continue
                if fn.value is has:
                    if len(stmt.value.args) != 2:
                        continue
                    try:
                        code = find_const(func_ir, stmt.value.args[1])
                    except GuardException:
                        continue
                    if not isinstance(code, int):
                        continue
                    mask = 1 << code
                else:   # a kernel marked by features.guarded_by: False where its table holds none of its features
                    mask = getattr(fn.value, "feature_guard", None)
                    if mask is None:
                        continue
                table = _static_type(func_ir, state.args, stmt.value.args[0])
                if table is None or not hasattr(table, "instance_class"):
                    continue
                present = features_of(table.instance_class) & mask != 0
                if fn.value is not has and present:
                    continue   # the guarded kernel's value is known at run time only
                value = ir.Const(present, stmt.loc)
                defs = func_ir._definitions[stmt.target.name]   # the call's own entry only: the name (a user's
                defs[defs.index(stmt.value)] = value            # variable) may have other assignments
                stmt.value = value
                changed = True
        return changed


@register_pass(mutates_CFG=False, analysis_only=True)
class BorrowOutsideLoops(FunctionPass):
    """Refuses a :func:`borrowed` call inside a loop: its tuple is stored in one slot of the kernel's frame, which
    each iteration would overwrite while an earlier iteration's result may still be in use."""
    _name = "caustica_borrow_outside_loops"

    def __init__(self):
        FunctionPass.__init__(self)

    def run_pass(self, state):
        func_ir = state.func_ir
        in_loops = set()
        for loop in compute_cfg_from_blocks(func_ir.blocks).loops().values():
            in_loops |= loop.body
        for label in in_loops:
            for stmt in func_ir.blocks[label].body:
                if not (isinstance(stmt, ir.Assign) and isinstance(stmt.value, ir.Expr) and stmt.value.op == "call"):
                    continue
                try:
                    fn = get_definition(func_ir, stmt.value.func)
                except GuardException:
                    continue
                if isinstance(fn, (ir.Global, ir.FreeVar)) and fn.value is borrowed:
                    raise errors.UnsupportedError(
                        f"{func_ir.func_id.func_qualname}: borrowed() inside a loop; borrow once, before the loop "
                        "(its tuple has one slot in the kernel's frame, which each iteration would overwrite)",
                        stmt.loc)
        return False


class LinkOnlyLibrary(JITCodeLibrary):
    """The code library of a :class:`Kernel` (not of its twin): kept as LLVM IR, never made machine code, and
    optimised function by function only.

    A kernel has no wrapper to be called by (:class:`Kernel`): its code runs only where other kernels link its IR
    into theirs, which they optimise and compile as their own.  Numba still compiled every library to machine
    code on its own, and cached that: 6.8 of the 50 CPU s of ``make render``'s cold start (2026-12-05), for code
    nothing ever ran.  This library skips the execution engine and is cached as the bitcode its callers link.
    Nor does it run Numba's module passes (two O3 pipelines over the kernel and every kernel it linked): the
    Python-called twin that finally links it runs them once over the whole call tree (when every library ran them,
    each level of the tree was optimised again at every level above it).  Skipping them took 8-22 % off the
    compile time of ``spm``'s kernels, with the same speed and the same bits (docs/results.md, 2026-12-06).
    One that calls a kernel still being compiled (mutual recursion: a ``.numba.unresolved$`` symbol, which only
    the engine resolves) is optimised, finalised and cached as Numba does any library (``link_only`` False).
    """

    link_only = True

    def _optimize_final_module(self):
        if any(gv.name.startswith(RuntimeLinker.PREFIX) for gv in self._final_module.global_variables):
            self.link_only = False
        if not self.link_only:
            return super()._optimize_final_module()

    def _finalize_final_module(self):
        if not self.link_only:
            return super()._finalize_final_module()
        self._finalize_dynamic_globals()
        self._verify_declare_only_symbols()
        self._finalized = True

    def get_pointer_to_function(self, name):
        self._ensure_finalized()
        if not self.link_only:
            return super().get_pointer_to_function(name)
        return 0   # nothing of it is in the execution engine (a Kernel's own entry point was 0 before too: no wrapper)

    def serialize_using_object_code(self):
        self._ensure_finalized()
        if not self.link_only:
            return super().serialize_using_object_code()
        return self.name, _LINK_ONLY, self._get_module_for_linking().as_bitcode()


def _link_only(library) -> bool:
    return isinstance(library, LinkOnlyLibrary) and library.link_only


#: The kind of a cached :class:`LinkOnlyLibrary` (beside Numba's ``object`` and ``bitcode``).
_LINK_ONLY = "caustica-link-only"
_unserialize_library = CPUCodeLibrary._unserialize.__func__


def _unserialize(cls, codegen, state):
    name, kind, data = state
    if kind != _LINK_ONLY:
        return _unserialize_library(cls, codegen, state)
    library = LinkOnlyLibrary(codegen, name)
    library._final_module = library._shared_module = ll.parse_bitcode(data)
    library._finalized = True
    return library


CPUCodeLibrary._unserialize = classmethod(_unserialize)
_get_executable = CPUContext.get_executable
_find_referenced_environments = CompileResult._find_referenced_environments


def _executable(self, library, fndesc, env):
    """Numba's entry point and environment for a compiled function.

    A :class:`LinkOnlyLibrary` gets an entry point of 0 (as Numba gives a function without a Python wrapper) and
    no environment: its code never runs on its own.  Any other library also gets the environments of the kernels
    it linked set in its own copies of them: a kernel's code reaches Python objects through its environment
    (``print``, an exception with arguments known only at run time, object mode), and where Numba's linked copy
    used to resolve to the kernel's own, in the engine, a link-only kernel has none there.  (Numba sets them so
    when it loads a function from its cache.)"""
    if _link_only(library):
        return _dynfunc.make_function(fndesc.lookup_module(), fndesc.qualname.split(".")[-1],
                                      f"kernel {fndesc.qualname} (linked into its callers)", 0, env, (library,))
    cfunc = _get_executable(self, library, fndesc, env)
    for gv in library._final_module.global_variables:
        if gv.name.startswith("_ZN08NumbaEnv") and gv.name != fndesc.env_name and not gv.is_declaration:
            linked = lookup_environment(gv.name)
            if linked is not None:
                library.codegen.set_env(gv.name, linked)
    return cfunc


def _referenced_environments(self):
    return [] if _link_only(self.library) else _find_referenced_environments(self)


CPUContext.get_executable = _executable
CompileResult._find_referenced_environments = _referenced_environments


@register_pass(mutates_CFG=False, analysis_only=True)
class KernelLibrary(AnalysisPass):
    """Gives a :class:`Kernel`'s compilation (no Python or C wrapper) a :class:`LinkOnlyLibrary` to lower into."""
    _name = "caustica_kernel_library"

    def __init__(self):
        AnalysisPass.__init__(self)

    def run_pass(self, state):
        if state.library is None and state.flags.no_cpython_wrapper and state.flags.no_cfunc_wrapper:
            state.library = LinkOnlyLibrary(state.targetctx.codegen(), state.func_id.func_qualname)
            state.library.enable_object_caching()   # (serialised as Numba's own if it has to be: link_only False)
        return False


@register_pass(mutates_CFG=False, analysis_only=True)
class RefuseReturnedBorrow(AnalysisPass):
    """Refuses a kernel that borrows and returns a borrowed tuple (in any container): the tuple lives in that kernel's
    frame (:func:`borrowed`), which has ended when the caller reads it.  Passing on a borrowed tuple it was given is
    fine.  Checked after typing, for kernels and their Python-called twins alike."""
    _name = "caustica_refuse_returned_borrow"

    def __init__(self):
        AnalysisPass.__init__(self)

    def run_pass(self, state):
        if _borrows(state.func_id.func) and holds_borrowed(state.return_type):
            raise TypeError(f"kernel {state.func_id.func_qualname} borrows and returns a borrowed tuple "
                            f"({state.return_type}), which would point into its own frame: borrow in the caller")
        return False


class ArgumentsBorrowedLower(Lower):
    """Numba's lowering, but a function's arguments are not reference-counted: a variable bound to one is neither
    incremented where it is bound nor decremented where it dies.

    The caller holds every argument until the call returns (a kernel's caller, or the Python wrapper of a twin), so
    the pair Numba writes is redundant; LLVM removed most of them again, but only after Numba had written, for every
    array a tuple argument holds (the scene tables: 92), the field extractions down to its counter.  That was 12 %
    of the IR lowered for ``make render``'s scene (157,500 -> 139,200 instructions).  Numba's counting stays for an
    omitted argument (a constant), in a generator, and for a variable with more than one definition (which Numba's
    SSA form never leaves an argument's: each later assignment gets a name of its own)."""

    def pre_lower(self):
        super().pre_lower()
        self._borrowed_args = set()

    def lower_assign(self, ty, inst):
        value = inst.value
        if isinstance(value, ir.Arg) and self.generator_info is None and \
                len(self.func_ir._definitions.get(inst.target.name, ())) == 1:
            argty = self.typeof("arg." + value.name)
            if not isinstance(argty, types.Omitted):
                self._borrowed_args.add(inst.target.name)
                with debuginfo.suspend_emission(self.builder):   # as Numba's: the argument's repacking has no line
                    return self.context.cast(self.builder, self.fnargs[value.index], argty, ty)
        return super().lower_assign(ty, inst)

    def delvar(self, name):
        if name not in self._borrowed_args:
            super().delvar(name)


@register_pass(mutates_CFG=True, analysis_only=False)
class KernelLowering(NativeLowering):
    """Numba's lowering pass with :class:`ArgumentsBorrowedLower`."""
    _name = "caustica_native_lowering"

    @property
    def lowering_class(self):
        return ArgumentsBorrowedLower


class KernelCompiler(Compiler):
    """Numba's nopython pipeline with :class:`FoldFeatureTests` before its dead-branch pruning,
    :class:`BorrowOutsideLoops`, :class:`RefuseReturnedBorrow` after typing, :class:`KernelLibrary` before
    lowering, and :class:`KernelLowering` for Numba's lowering."""

    def define_pipelines(self):
        pm = DefaultPassBuilder.define_nopython_pipeline(self.state)
        pm.add_pass_after(FoldFeatureTests, WithLifting)
        pm.add_pass_after(BorrowOutsideLoops, FoldFeatureTests)
        pm.add_pass_after(RefuseReturnedBorrow, NopythonTypeInference)
        order = [cls for cls, _ in pm.passes]
        pm.add_pass_after(KernelLibrary, order[order.index(NativeLowering) - 1])
        pm.passes = [(KernelLowering if cls is NativeLowering else cls, desc) for cls, desc in pm.passes]
        pm.finalize()
        return [pm]


_OPTIONS = dict(nogil=True, fastmath=False, error_model="numpy")
_TWIN_LOCK = threading.Lock()
_NO_COMPILE = threading.local()   # .on: this thread calls a twin only if it needs no compiling (parallel_for's item 0)


class _WouldCompile(Exception):
    """A twin was called, with :data:`_NO_COMPILE` on, with argument types it has no compiled code for."""


class _Twin(CPUDispatcher):
    """A kernel's Python-called twin (:attr:`Kernel.from_python`): compiles (or loads) a specialisation unless the
    calling thread said it must not (:data:`_NO_COMPILE`)."""

    def _compile_for_args(self, *args, **kws):
        if getattr(_NO_COMPILE, "on", False):
            raise _WouldCompile
        return super()._compile_for_args(*args, **kws)


class Kernel(CPUDispatcher):
    """A kernel as other kernels call it: compiled without the code that calls it from Python.

    Numba compiles every function it is asked for with two wrappers, one that
    unboxes Python arguments (for ~27 arrays of the Geometry that is thousands of
    lines of LLVM IR) and one with a C calling convention, and optimises and
    compiles them to machine code with the function.  Called from other kernels,
    as almost every kernel only is, neither wrapper is ever used; building them
    was about half the compile time of a small kernel.  So a kernel is compiled
    without them, and a call from Python goes to :attr:`from_python`, a twin
    compiled (and cached) separately with its wrapper: only the kernels Python
    actually calls (range kernels, builders, tests) pay for one.  Nothing calls a
    twin from C, so it has no C wrapper either: for a twin that takes the scene
    tables (92 arrays for the diacaustic) that wrapper was 1,089 lines of IR, and
    dropping it took 0.7 s off ``spm``'s compile (docs/results.md, 2026-12-07).

    Calls from kernels are typed with plain argument types, never literal ones:
    while Numba infers a caller's types it may resolve a call with a constant's
    literal type (``Literal[int](2)`` for a ``dim = 2`` that a loop later
    increments) and compile that specialisation before the ``int64`` one it keeps,
    which doubled the compile time of the kernels called that way.
    """

    def __init__(self, py_func, inline):
        options = dict(_OPTIONS, inline="never", forceinline=inline, no_cpython_wrapper=True,
                       no_cfunc_wrapper=True)
        super().__init__(py_func=py_func, locals={}, targetoptions=options, pipeline_class=KernelCompiler)
        if CACHE_SERIAL:
            self.enable_caching()
        self._from_python = None

    @property
    def from_python(self):
        """The same kernel with its Python wrapper and no C one (compiled on the first call from Python)."""
        with _TWIN_LOCK:
            if self._from_python is None:
                f = self.py_func
                twin = pytypes.FunctionType(f.__code__, f.__globals__, f.__name__, f.__defaults__,
                                            f.__closure__)
                twin.__qualname__ = f.__qualname__ + "_from_python"  # its own cache entry
                twin.__doc__ = f.__doc__
                twin.__module__ = f.__module__
                self._from_python = _Twin(py_func=twin, locals={}, targetoptions=dict(_OPTIONS, nopython=True,
                                                                                no_cfunc_wrapper=True),
                                          pipeline_class=KernelCompiler)
                if CACHE_SERIAL:
                    self._from_python.enable_caching()
        return self._from_python

    def __call__(self, *args, **kwargs):
        return self.from_python(*args, **kwargs)

    def __reduce__(self):
        """Pickled by reference (its module and name), as a function is.  Numba's cache index pickles the types of a
        kernel's arguments; where a kernel is an argument (``roughplastic.two_lobe_sample``), every process must find
        the same kernel object there, or the index cannot be read back (and would never match)."""
        return _kernel_named, (self.py_func.__module__, self.py_func.__qualname__)

    @property
    def _numba_type_(self):
        return KernelType(self)

    def compiled_for_python(self) -> bool:
        """Whether a call from Python has compiled (or loaded) this kernel in this process."""
        return self._from_python is not None and len(self._from_python.signatures) > 0

    def get_call_template(self, args, kws):
        return super().get_call_template(tuple(types.unliteral(a) for a in args),
                                         {k: types.unliteral(v) for k, v in kws.items()})


class KernelType(types.Dispatcher):
    """Numba's type of a :class:`Kernel`.  A kernel passed to another as an argument (``local_eval`` in
    ``roughplastic.two_lobe_sample``) is a value of this type, and a call through it is resolved from the type, at
    compile time, without reading the value.  Numba lowers a dispatcher's value as the address of its Python object,
    a global that differs in each process; left in a kernel's unoptimised IR (:class:`LinkOnlyLibrary`), it would
    stop Numba caching that kernel and every kernel that links it.  A kernel found by its module and name (as it
    pickles) lowers to a null pointer instead, and boxes (returned to Python) as the kernel found by its name; any
    other keeps Numba's lowering.  (The value would also be read where two kernels meet as one first-class
    function value, which would then fail; a tuple of two kernels indexed at run time does not type in Numba, with
    or without this type, and other such joins were not tried.)"""


def _found_by_name(k: Kernel) -> bool:
    try:
        return _kernel_named(k.py_func.__module__, k.py_func.__qualname__) is k
    except (ImportError, AttributeError):
        return False


register_model(KernelType)(OpaqueModel)


@lower_constant(KernelType)
def _kernel_value(context, builder, ty, pyval):
    if _found_by_name(pyval):
        return context.get_constant_null(ty)
    return context.add_dynamic_addr(builder, id(pyval), info=type(pyval).__name__)


@box(KernelType)
def _box_kernel(typ, val, c):
    if _found_by_name(typ.dispatcher):
        return c.pyapi.unserialize(c.pyapi.serialize_object(typ.dispatcher))
    c.pyapi.incref(val)
    return val


def _kernel_named(module: str, qualname: str) -> Kernel:
    obj = importlib.import_module(module)
    for part in qualname.split("."):
        obj = getattr(obj, part)
    return obj


def kernel(fn=None, *, inline: bool = False):
    """Compile a serial kernel or device function (nogil; cached per CACHE_SERIAL; see :class:`Kernel`).

    ``inline``: compiled once (per argument types), and LLVM always inlines its machine-level code into its
    callers.  For small helpers and for per-ray helpers that take the scene tables: Numba passes a tuple argument
    as all of its fields, so a call that is not inlined copies some 300 values (a Geometry and a LightTable) --
    on the path tracer's next-event estimate and BVH traversal that was a third of the render time.

    Not Numba's own ``inline="always"``, which inlines the function's IR into each caller before typing: it
    translates, types and lowers the function again at every call site, recursively, and was most of the
    compile time (the photon, stream and camera loops took 14-31 s each, 1.8-3.1 s inlined by LLVM; the whole
    of ``benchmarks/bench_compile.py``'s spm render 114 s -> 59 s, 2026-12-04).
    """
    def wrap(f):
        if numba.config.DISABLE_JIT:
            return f
        return Kernel(f, inline)
    return wrap(fn) if fn is not None else wrap


def parallel_kernel(fn=None):
    """Compile a kernel whose outer loop is a ``prange`` (never cached, see module doc)."""
    def wrap(f):
        return njit(parallel=True, cache=False, fastmath=False, error_model="numpy")(f)
    return wrap(fn) if fn is not None else wrap


def default_threads() -> int:
    """Worker threads: the cores this process may run on."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return max(1, os.cpu_count() or 1)


#: The duration one chunk of work aims at: long enough that calling a kernel costs
#: nothing in comparison, short enough that progress moves and an interrupted
#: render frees its threads soon after.
CHUNK_SECONDS = 0.05
#: The smallest chunk's duration (but the last one's), once a kernel's time per item is known: a chunk costs its
#: thread some 40 µs of Python, with the interpreter's lock held (the kernel call's arguments, the queue); SPPM at
#: 96², whose calls take a few milliseconds, made 100 passes in 1.87-2.03 s on two threads, 1.67-1.70 s with this.
CHUNK_FLOOR_SECONDS = 0.002
#: Seconds per item of each range kernel's last call (see :func:`parallel_for`).
_ITEM_SECONDS: dict = {}


class _Chunks:
    """Hands out ranges [i0, i1) of the work items [start, stop) to worker threads, until cancelled."""

    def __init__(self, start: int, stop: int, threads: int, fixed: int | None, floor: int = 1):
        self.next = start
        self.stop = stop
        self.threads = threads
        self.fixed = fixed
        self.floor = floor   # the smallest chunk handed out before the last (items worth CHUNK_FLOOR_SECONDS)
        self.cancelled = False
        self.lock = threading.Lock()

    def take(self, size: int):
        with self.lock:
            if self.cancelled or self.next >= self.stop:
                return None
            if self.fixed:
                size = self.fixed
            else:   # leave work for the other threads near the end, so they finish together
                size = max(self.floor, min(size, -(-(self.stop - self.next) // (2 * self.threads))))
            i0 = self.next
            self.next = min(self.stop, i0 + size)
            return i0, self.next

    def cancel(self):
        with self.lock:
            self.cancelled = True


class _WorkerThreads:
    """Daemon threads started once and kept, each running one task at a time from a shared queue.

    Starting threads for each parallel call cost about 0.5 ms a call (three starts with two threads: the item that
    compiles, then the workers); kept threads 0.1-0.2 ms.  An sppm pass at 96 x 96 makes four calls: 300 passes on
    the glossy scene took 3.20 s against 3.56 s (medians of five runs, 2026-12-05, docs/results.md).  A task is
    handed out only to a thread reserved for it, an idle one or one started for it, so every call gets its threads
    at once, however many calls run side by side (a Dask worker's tasks, a notebook whose interrupted chunks are
    still finishing).
    """

    def __init__(self):
        self.tasks: queue.SimpleQueue = queue.SimpleQueue()
        self.lock = threading.Lock()
        self.idle = 0      # threads waiting for a task and not reserved for one
        self.started = 0

    def run(self, task, n: int) -> None:
        """Start ``task`` on ``n`` threads (it reports back by its own means)."""
        with self.lock:
            reserved = min(n, self.idle)
            self.idle -= reserved
            for _ in range(n - reserved):
                self.started += 1
                threading.Thread(target=self._serve, name=f"caustica-worker-{self.started}", daemon=True).start()
        for _ in range(n):
            self.tasks.put(task)

    def _serve(self) -> None:
        while True:
            task = self.tasks.get()
            try:
                task()
            except BaseException:   # a task reports its own errors; the thread serves on
                pass
            # an idle thread holds no task: its closure's arguments (a pass's visible points, say) are freed now,
            # not when this thread's next task replaces them
            task = None
            with self.lock:
                self.idle += 1


_WORKERS = _WorkerThreads()


def _run_chunks(range_kernel, args, start: int, stop: int, threads: int, chunk, progress,
                item_s: float | None = None) -> None:
    """Run [start, stop) on ``threads`` daemon threads (:class:`_WorkerThreads`); this thread waits and reports
    progress.  ``item_s``: the seconds one item took in this kernel's last call, if any, which sizes the first
    chunks and the smallest."""
    # the floor, but never so high that there are fewer than two chunks a thread (a call of a few milliseconds, as
    # SPPM's at 96 x 96, would otherwise run in one or three chunks: one thread idle, or one doing two); rounded
    # down, as rounding up left 3 chunks for 2 threads at 9 items
    floor = max(1, min(int(CHUNK_FLOOR_SECONDS / item_s), (stop - start) // (2 * threads))) if item_s else 1
    chunks = _Chunks(start, stop, threads, chunk, floor)
    done: queue.SimpleQueue = queue.SimpleQueue()

    def worker():
        # grows (or shrinks) towards CHUNK_SECONDS of work per chunk, from a quarter of that at the last call's rate
        size = max(1, int(CHUNK_SECONDS / 4 / item_s)) if item_s else 1
        try:
            while (r := chunks.take(size)) is not None:
                t0 = time.perf_counter()
                range_kernel(*args, r[0], r[1])
                dt = time.perf_counter() - t0
                n = r[1] - r[0]
                done.put((n, None))
                size = min(4 * n, max(1, int(n * CHUNK_SECONDS / dt))) if dt > 0 else 4 * n
        except BaseException as exc:   # handed to the waiting thread, which raises it
            chunks.cancel()
            done.put((0, exc))
        finally:
            done.put(None)

    _WORKERS.run(worker, threads)
    running = threads
    try:
        while running:
            msg = done.get()
            if msg is None:
                running -= 1
            elif msg[1] is not None:
                raise msg[1]
            elif progress is not None:
                progress.update(msg[0])
    except BaseException:
        chunks.cancel()   # KeyboardInterrupt included: no more chunks, and no waiting for running ones
        raise


def _item_0_here(range_kernel, args) -> bool:
    """Run item 0 on this thread if that compiles nothing (the kernel has code for these argument types): True."""
    _NO_COMPILE.on = True
    try:
        range_kernel(*args, 0, 1)
    except _WouldCompile:
        return False
    finally:
        _NO_COMPILE.on = False
    return True


def parallel_for(range_kernel, n_items: int, args: tuple, *, threads: int | None = None,
                 chunk: int | None = None, progress=None) -> float:
    """Run ``range_kernel(*args, i0, i1)`` over [0, n_items) in chunks on ``threads`` threads.

    The first single item runs alone, so Numba compiles (or loads from the cache)
    before the threads start; its duration is returned as the compile time in
    seconds (it includes one work item, which is negligible).  It runs here when the
    kernel has completed a call of more than one item in this process and has code for
    these argument types (handing one item to a thread and back cost some 0.2 ms a
    call, 7 % of SPPM's passes at 96 x 96); otherwise (the first call, or new argument
    types: a new specialisation, as long to compile as the first) on a worker thread,
    like the rest, so Ctrl-C reaches this thread at once during the compile.  ``chunk`` fixes the
    number of items per chunk (default: sized to take about CHUNK_SECONDS each, starting and ending, once the
    kernel has run here before, from its last call's time per item: see CHUNK_FLOOR_SECONDS).
    ``progress`` is a tqdm-like bar advanced by the number of items as chunks
    finish.  All but that item 0 run on worker threads even when ``threads`` is 1, so the
    calling thread receives Ctrl-C at once (see the module's docstring).
    """
    threads = threads or default_threads()
    if n_items <= 0:
        return 0.0
    t0 = time.perf_counter()
    if range_kernel in _ITEM_SECONDS and _item_0_here(range_kernel, args):
        if progress is not None:
            progress.update(1)
    else:   # first call, or new argument types: item 0 (and the compile) on a worker, Ctrl-C reaches us at once
        _run_chunks(range_kernel, args, 0, 1, 1, 1, progress)
    compile_s = time.perf_counter() - t0
    if n_items > 1:
        workers = min(threads, n_items - 1)
        item_s = _ITEM_SECONDS.get(range_kernel)
        if item_s is not None and compile_s > 1e-3 + 100.0 * item_s:
            item_s = None   # item 0 took far longer than the last call's items: size the chunks afresh
        t1 = time.perf_counter()
        _run_chunks(range_kernel, args, 1, n_items, workers, chunk, progress, item_s)
        _ITEM_SECONDS[range_kernel] = (time.perf_counter() - t1) * workers / (n_items - 1)
    return compile_s


class BorrowedTuple(types.NamedTuple):
    """The Numba type of a named tuple of arrays (and numbers, booleans) whose reference counts are detached, held by
    reference.

    Its value is a pointer to the tuple, stored once in the frame of the kernel that
    made it (:func:`borrowed`): binding or passing one generates no reference-count
    code, no unboxing code and no copy of its ~27 arrays, and reading a field loads that
    field alone.  Numba passes a struct argument as all of its scalars, one LLVM argument
    each: the four scene tables by value were some 600 arguments, taken apart at every call
    site and put together again in every callee (a 20-line helper taking them compiled to
    0.8 MB of LLVM IR, 3,000 of its instructions moving them), most of the compile time.
    A named tuple is immutable, so the pointer means the same as the value while the frame
    that holds it lives: see :func:`borrowed` for the rules.  What kernels do with one: read a
    field by name or literal index, unpack it, take its ``len``, pass it on.  Slicing it,
    ``literal_unroll`` over it, ``f(*t)`` and printing it do not compile.
    """

    def __init__(self, tup):
        super().__init__(tuple(tup), tup.instance_class)
        self.name = f"borrowed {tup.name}"

    @property
    def key(self):
        return "borrowed", self.instance_class, self.types


@register_model(BorrowedTuple)
class _BorrowedTupleModel(PrimitiveModel):
    """A pointer to the tuple's struct (each field's data model, in order: an array's struct, a number as it is, a
    boolean as a byte): nothing to reference-count."""

    def __init__(self, dmm, fe_type):
        struct = llvm_ir.LiteralStructType([dmm.lookup(t).get_data_type() for t in fe_type])
        super().__init__(dmm, fe_type, struct.as_pointer())


unbox(BorrowedTuple)(unbox_unsupported)


def _borrowed_pointer_types(context, ty, out):
    """The LLVM types of the BorrowedTuple pointers inside a value of type ``ty``."""
    if isinstance(ty, BorrowedTuple):
        out.add(context.get_value_type(ty))
    elif isinstance(ty, types.BaseTuple):
        for t in ty:
            _borrowed_pointer_types(context, t, out)
    return out


def _mentions(llvm_type, pointer_types):
    """Whether ``llvm_type`` is or holds one of ``pointer_types`` (at any depth of structs and arrays)."""
    if llvm_type in pointer_types:
        return True
    members = getattr(llvm_type, "elements", None)
    if members is None and isinstance(llvm_type, llvm_ir.ArrayType):
        members = (llvm_type.element,)
    return members is not None and any(_mentions(t, pointer_types) for t in members)


_decorate_function = CPUCallConv.decorate_function
#: LLVM's "keeps no copy of this pointer" attribute, as the LLVM of this llvmlite spells it.
_NO_CAPTURE = "captures(none)" if "captures(none)" in llvm_ir.values.ArgumentAttributes._known else "nocapture"


def _decorate_borrowed(self, fn, args, fe_argtypes, noalias=False):
    """Numba's argument attributes, and on each borrowed tuple's pointer what is true of it: nothing writes the
    tuple (noalias, readonly), it is the whole tuple (dereferenceable), and a callee keeps no copy of the pointer
    unless it returns it (captures(none)): so LLVM may load its fields once, out of loops and across calls."""
    _decorate_function(self, fn, args, fe_argtypes, noalias)
    pointer_types = set()
    for ty in fe_argtypes:
        _borrowed_pointer_types(self.context, ty, pointer_types)
    if not pointer_types:
        return
    returned = _mentions(self._get_return_argument(fn).type.pointee, pointer_types)
    for arg in self.get_arguments(fn):
        if arg.type in pointer_types:
            set.add(arg.attributes, "noalias")
            set.add(arg.attributes, "readonly")
            set.add(arg.attributes, "nonnull")
            arg.attributes.dereferenceable = self.context.get_abi_sizeof(arg.type.pointee)
            if not returned:
                set.add(arg.attributes, _NO_CAPTURE)


CPUCallConv.decorate_function = _decorate_borrowed


def _borrowed_field(context, builder, tup_ty, ptr, index):
    """Field ``index`` of a :class:`BorrowedTuple`, loaded from the tuple's storage: a number as it is, an array with
    its meminfo and parent the constant null they are there (so that LLVM drops the reference counting of the array
    wherever it is used, as it does where the tuple was borrowed)."""
    field_ty = tup_ty[index]
    field = context.data_model_manager[field_ty].from_data(
        builder, builder.load(cgutils.gep_inbounds(builder, ptr, 0, index)))
    return _unowned(context, builder, field_ty, field) if isinstance(field_ty, types.Array) else field


@lower_getattr_generic(BorrowedTuple)
def _borrowed_getattr(context, builder, typ, value, attr):
    return _borrowed_field(context, builder, typ, value, typ.fields.index(attr))


@lower_builtin("static_getitem", BorrowedTuple, types.IntegerLiteral)
def _borrowed_static_getitem(context, builder, sig, args):
    tup_ty, index = sig.args[0], sig.args[1].literal_value
    if index < 0:
        index += len(tup_ty)
    if not 0 <= index < len(tup_ty):
        raise IndexError(f"tuple index {sig.args[1].literal_value} out of range for {tup_ty}")
    return _borrowed_field(context, builder, tup_ty, args[0], index)


@intrinsic
def borrowed(typingctx, tup):
    """The same named tuple (of arrays, with numbers and booleans beside them, as the camera's parameters) with every
    array's reference count detached, held by reference (:class:`BorrowedTuple`); of a plain tuple of arrays, the
    same tuple with detached views; of a plain tuple of named tuples (the scene tables), each borrowed.  A named
    tuple of numbers alone, or one holding tuples, is refused (there is nothing to detach, or it is not flat).

    Numba increments and decrements the reference count of every array in a tuple
    each time the tuple is bound to a variable or a function's argument: with the
    Geometry's ~27 arrays that is ~80 calls per binding in the generated code (most
    of the compile time of the kernels that take it) and ~400 ns per call at run time,
    with threads contending on shared counters.  Range kernels call this once on the
    scene tuples they receive; everything below them gets a :class:`BorrowedTuple`,
    whose bindings cost nothing.

    The tuple is stored in the frame of the kernel that calls this, once per call site, and
    the result points there.  So: only for tuples whose owners outlive that kernel's call;
    never return or store the result (a kernel that borrows and returns one, in any container, is
    refused when it compiles); and never borrow inside a loop (refused too: :class:`BorrowOutsideLoops`).
    (See also :func:`caustica.geometry.primitives.borrow`, the same for one array.)
    """
    out = _borrowed_type(tup)
    if out is None:
        return None

    def codegen(context, builder, signature, args):
        return _borrow(context, builder, tup, args[0])

    return out(tup), codegen


def _borrowed_type(ty):
    """What :func:`borrowed` makes of a value of type ``ty`` (None: not a tuple it takes)."""
    if isinstance(ty, BorrowedTuple):
        return ty
    if not isinstance(ty, types.BaseTuple) or len(ty) == 0:
        return None
    if isinstance(ty, types.BaseNamedTuple):
        plain = all(isinstance(t, (types.Array, types.Number, types.Boolean)) for t in ty)
        return BorrowedTuple(ty) if plain and any(isinstance(t, types.Array) for t in ty) else None
    if all(isinstance(t, types.Array) for t in ty):
        return ty
    inner = [_borrowed_type(t) for t in ty]
    return None if any(t is None for t in inner) else types.Tuple(inner)


def _borrow(context, builder, ty, value):
    out = _borrowed_type(ty)
    if isinstance(ty, BorrowedTuple):
        return value
    if isinstance(out, BorrowedTuple) or all(isinstance(t, types.Array) for t in ty):
        value = _detached(context, builder, ty, value)
        if not isinstance(out, BorrowedTuple):
            return value
        storage = cgutils.alloca_once(builder, context.get_value_type(out).pointee)
        for i, field_ty in enumerate(ty):
            builder.store(context.data_model_manager[field_ty].as_data(builder, builder.extract_value(value, i)),
                          cgutils.gep_inbounds(builder, storage, 0, i))
        return storage
    # A plain tuple of tuples (the scene tables): each borrowed.
    items = [_borrow(context, builder, t, builder.extract_value(value, i)) for i, t in enumerate(ty)]
    return context.make_tuple(builder, out, items)


def holds_borrowed(ty) -> bool:
    """Whether a value of type ``ty`` is or contains a :class:`BorrowedTuple` (which must not be returned): in a
    tuple, an optional, a list, any container."""
    if isinstance(ty, BorrowedTuple):
        return True
    if isinstance(ty, types.BaseTuple):
        return any(holds_borrowed(t) for t in ty)
    return "borrowed " in str(ty)   # BorrowedTuple's name, inside another type's


def _borrows(py_func) -> bool:
    """Whether ``py_func`` calls :func:`borrowed` (by that name, an alias, or as ``jit.borrowed``)."""
    names = py_func.__code__.co_names
    return "borrowed" in names or any(py_func.__globals__.get(n) is borrowed for n in names)


def _detached(context, builder, tup_ty, value):
    """The tuple ``value`` with every array's meminfo and parent cleared (no reference counts); numbers as they are."""
    result = cgutils.get_null_value(context.get_value_type(tup_ty))
    for i, field_ty in enumerate(tup_ty):
        field = builder.extract_value(value, i)
        if isinstance(field_ty, types.Array):
            field = _unowned(context, builder, field_ty, field)
        result = builder.insert_value(result, field, i)
    return result


def _unowned(context, builder, arr_ty, value):
    """The array ``value`` with its meminfo and parent the constant null: no reference counting where it is used."""
    arr = cgutils.create_struct_proxy(arr_ty)(context, builder, value=value)
    arr.meminfo = cgutils.get_null_value(arr.meminfo.type)
    arr.parent = cgutils.get_null_value(arr.parent.type)
    return arr._getvalue()
