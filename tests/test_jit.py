"""The JIT policy (caustica.jit): what kernels are compiled for, and what the compile leaves out."""
from __future__ import annotations

import os
import re
import subprocess
import sys
import time
import types as pytypes
from typing import NamedTuple

import numpy as np
import pytest
from numba import njit, typeof
from numba.core.unsafe.refcount import get_refcount

from caustica.geometry.bvh import _stable_sort
from caustica.jit import BorrowedTuple, borrowed, kernel
from caustica.jit import borrowed as borrow_alias
from caustica.scene import load_scene_description
from caustica.tables import compile_scene


# Which specialisations a kernel gets is only visible when it is compiled in this process: with
# the disk cache warm (a second test run, or CI on a machine that ran the tests before) the outer
# kernel is loaded and its callees are never compiled.  So these checks run in a fresh interpreter
# with caching off (CAUSTICA_NO_CACHE=1, read when caustica.jit is imported).
_SPECIALISATION_CHECKS = """
from caustica.jit import BorrowedTuple, LinkOnlyLibrary, borrowed, kernel
from caustica.scene import load_scene_description
from caustica.tables import compile_scene


@kernel
def _take_dim(x, dim):
    return x + dim


@kernel
def _loop_over_dims(x, n):
    dim = 2  # a constant before a loop that increments it: typed Literal[int](2) at first
    acc = 0.0
    for _ in range(n):
        acc += _take_dim(x, dim)
        dim += 3
    return acc


# a constant argument compiles no literal specialisation
assert _loop_over_dims(1.0, 3) == (1 + 2) + (1 + 5) + (1 + 8)
sigs = [tuple(str(t) for t in s) for s in _take_dim.signatures]
assert sigs == [("float64", "int64")], sigs


@kernel
def _prim_count(geom):
    return geom.prim_kind.shape[0]


@kernel
def _prim_count_borrowed(geom):
    return _prim_count(borrowed(geom))


# a kernel called from kernels has no Python wrapper, and calls from Python still work
scene = compile_scene(load_scene_description("cornell-diacaustic"))
n = scene.geometry.n_prims
assert _prim_count_borrowed(scene.geometry) == n      # Python -> kernel -> kernel
assert _prim_count(scene.geometry) == n               # a kernel called from Python directly
(sig,) = _prim_count.signatures
assert isinstance(sig[0], BorrowedTuple)
cres = _prim_count.overloads[sig]
assert cres.library.get_pointer_to_function(cres.fndesc.llvm_cpython_wrapper_name) == 0
# ... and is kept as IR for its callers to link: no machine code of its own
assert isinstance(cres.library, LinkOnlyLibrary) and "define" in cres.library.get_llvm_str()
twin = _prim_count.from_python
(tsig,) = twin.signatures
tres = twin.overloads[tsig]
assert tres.library.get_pointer_to_function(tres.fndesc.llvm_cpython_wrapper_name) != 0
assert not isinstance(tres.library, LinkOnlyLibrary)
# ... which has no C wrapper: nothing calls a twin from C
assert tres.library.get_pointer_to_function(tres.fndesc.llvm_cfunc_wrapper_name) == 0
print("ok")
"""


def test_specialisations_and_wrappers_of_freshly_compiled_kernels():
    """One int64 specialisation for a constant argument; no Python wrapper on kernel-to-kernel calls, no C wrapper on
    the Python-called twin."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CAUSTICA_NO_CACHE"] = "1"
    proc = subprocess.run([sys.executable, "-c", _SPECIALISATION_CHECKS], env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-3000:]


def _rebind(geom):
    g = geom
    h = g
    return h.prim_kind.shape[0]


def test_binding_a_borrowed_tuple_generates_no_reference_counting(monkeypatch):
    from numba.core import codegen

    generated = []  # Numba's LLVM IR before optimisation (which would hide what was generated)
    add_ir_module = codegen.CPUCodeLibrary.add_ir_module
    monkeypatch.setattr(codegen.CPUCodeLibrary, "add_ir_module",
                        lambda lib, mod: (generated.append(str(mod)), add_ir_module(lib, mod))[1])
    scene = compile_scene(load_scene_description("cornell-diacaustic"))
    plain = typeof(scene.geometry)
    assert BorrowedTuple(plain) != plain
    refops = {}
    for ty in (plain, BorrowedTuple(plain)):
        generated.clear()
        njit(no_cpython_wrapper=True, no_cfunc_wrapper=True)(_rebind).compile((ty,))
        ir = "".join(generated)
        refops[ty] = len(re.findall(r'call void @"?NRT_(?:incref|decref)', ir))
    assert refops[plain] >= 2 * len(scene.geometry)           # every array, at every binding
    assert refops[BorrowedTuple(plain)] <= 4                  # only the one array taken out of it


def _sum_first(a):
    return a[0] + a[1]


def test_a_kernel_does_not_count_references_to_its_arguments(monkeypatch):
    """The caller holds a kernel's arguments for the whole call, so the kernel pipeline
    (``jit.ArgumentsBorrowedLower``) writes no reference counting where a variable is bound to one; Numba's own
    pipeline writes a pair for each array."""
    from numba.core import codegen

    from caustica.jit import KernelCompiler

    generated = []
    add_ir_module = codegen.CPUCodeLibrary.add_ir_module
    monkeypatch.setattr(codegen.CPUCodeLibrary, "add_ir_module",
                        lambda lib, mod: (generated.append(str(mod)), add_ir_module(lib, mod))[1])
    refops = {}
    for name, options in (("numba", {}), ("kernel", {"pipeline_class": KernelCompiler})):
        generated.clear()
        njit(no_cpython_wrapper=True, no_cfunc_wrapper=True, **options)(_sum_first).compile((typeof(np.ones(2)),))
        refops[name] = len(re.findall(r'call void @"?NRT_(?:incref|decref)', "".join(generated)))
    assert refops["numba"] >= 2
    assert refops["kernel"] == 0


@kernel
def _returns_it(a):
    return a


@kernel
def _rebinds_it(a, n):
    if n > 0:
        a = np.zeros(n)
    return a.sum()


@kernel
def _packs_it(a):
    t = (a, a)
    b, _ = t
    return b[0]


@kernel
def _returns_it_packed(a, x):
    return (a, x)


@kernel
def _reference_counts(n):
    """An array's reference count (its meminfo's) before and after kernels read, rebind, repack and return it n
    times each (LLVM's pruning removes only pairs, so a count can never rise or fall by the optimiser alone)."""
    a = np.arange(4.0)
    before = get_refcount(a)
    total = 0.0
    for _ in range(n):
        total += _rebinds_it(a, 0) + _rebinds_it(a, 3) + _packs_it(a) + _returns_it(a)[1]
    return before, get_refcount(a), total


def test_arguments_keep_their_reference_counts():
    """Kernels that read, rebind, repack or return an array argument leave its reference count as it was, plus the
    references they return: a kernel that released a reference it never took (ArgumentsBorrowedLower without its
    delvar) would free an array its caller still holds (with that mutation this test fails).  Counted inside a kernel
    (the array's meminfo), and from Python for calls to the twins."""
    before, after, total = _reference_counts(50)
    assert total == 50 * 7.0 and after == before
    a = np.arange(4.0)
    before = sys.getrefcount(a)
    for _ in range(100):
        assert _rebinds_it(a, 0) == 6.0 and _rebinds_it(a, 3) == 0.0 and _packs_it(a) == 0.0
    assert sys.getrefcount(a) == before
    kept = [_returns_it(a) for _ in range(10)] + [_returns_it_packed(a, 1.0)[0] for _ in range(10)]
    assert all(k is a for k in kept) and sys.getrefcount(a) == before + 20


def _pass_on(geom):
    return _rebind(geom)


def test_a_borrowed_tuple_is_passed_by_reference(monkeypatch):
    """A call passing a borrowed table moves one pointer, not every scalar of its ~27 arrays (which Numba
    passes a struct as: most of the compiled kernels' LLVM IR, and so most of the compile time)."""
    from numba.core import codegen

    generated = []
    add_ir_module = codegen.CPUCodeLibrary.add_ir_module
    monkeypatch.setattr(codegen.CPUCodeLibrary, "add_ir_module",
                        lambda lib, mod: (generated.append(str(mod)), add_ir_module(lib, mod))[1])
    scene = compile_scene(load_scene_description("cornell-diacaustic"))
    plain = typeof(scene.geometry)
    moves = {}
    for ty in (plain, BorrowedTuple(plain)):
        callee = njit(no_cpython_wrapper=True, no_cfunc_wrapper=True)(_rebind)
        caller = pytypes.FunctionType(_pass_on.__code__, {"_rebind": callee})
        generated.clear()
        njit(no_cpython_wrapper=True, no_cfunc_wrapper=True)(caller).compile((ty,))
        ir = generated[-1]   # the caller's own module (the callee was compiled while typing it)
        moves[ty] = len(re.findall(r"= (?:extractvalue|insertvalue) ", ir))
    assert moves[plain] >= 6 * len(scene.geometry)        # each array's fields out and back in
    assert moves[BorrowedTuple(plain)] == 0


class _Pair(NamedTuple):
    a: np.ndarray
    b: np.ndarray


@kernel
def _read_borrowed(geom, tables, pair):
    """Fields of borrowed tuples, read every way kernels read them: by name, by index, unpacked, passed on."""
    g = borrowed(geom)
    t_geom, t_mats, _, _ = borrowed(tables)
    a, b = borrowed(pair)
    return (g.prim_kind.shape[0], g[0].shape[0], g[-1].shape[0], _rebind_kernel(g),
            t_geom.prim_kind.shape[0], t_mats.kind.shape[0], a[1] + b[2])


@kernel
def _rebind_kernel(geom):
    return geom.prim_kind.shape[0]


@kernel
def _borrow_and_return(geom):
    return borrowed(geom)


@kernel
def _use_returned(geom):
    return _borrow_and_return(geom).prim_kind.shape[0]


@kernel
def _borrow_and_return_optional(geom, flag):
    g = borrowed(geom)
    return g if flag else None


@kernel
def _use_optional(geom):
    g = _borrow_and_return_optional(geom, True)
    return 0 if g is None else g.prim_kind.shape[0]


@kernel
def _borrow_and_return_in_list(geom):
    return [borrowed(geom)]


@kernel
def _use_list(geom):
    return _borrow_and_return_in_list(geom)[0].prim_kind.shape[0]


@kernel
def _borrow_by_alias_and_return(geom):
    return borrow_alias(geom)


@kernel
def _use_alias(geom):
    return _borrow_by_alias_and_return(geom).prim_kind.shape[0]


@kernel
def _borrow_in_a_loop(pair, other):
    first = borrowed(pair)
    for i in range(2):
        b = borrowed(pair if i == 0 else other)   # the second iteration would overwrite the first's slot
        if i == 0:
            first = b
    return first.a[0]


def test_borrowed_tuples_read_the_same_values_and_are_never_returned():
    scene = compile_scene(load_scene_description("cornell-diacaustic"))
    geom, mats = scene.geometry, scene.tables[1]
    n = geom.prim_kind.shape[0]
    pair = _Pair(np.arange(3.0), np.arange(10.0, 13.0))
    assert _read_borrowed(geom, scene.tables, pair) == (n, geom[0].shape[0], geom[-1].shape[0], n, n,
                                                        mats.kind.shape[0], 1.0 + 12.0)
    for use in (_use_returned, _use_optional, _use_list, _use_alias,   # in an optional, a list, by an alias too
                _borrow_and_return):                                  # and called from Python (its twin)
        with pytest.raises(Exception, match="borrows and returns a borrowed tuple"):
            use(geom)
    with pytest.raises(Exception, match=r"borrowed\(\) inside a loop"):
        _borrow_in_a_loop(pair, _Pair(np.full(3, 99.0), np.full(3, 77.0)))


class _Mixed(NamedTuple):
    """A named tuple of arrays and numbers, as the camera's parameters are."""
    origin: np.ndarray
    scale: float
    count: int
    flag: bool
    basis: np.ndarray


@kernel
def _mixed_fields(m):
    return m.scale * m.origin[1] + m.count + (100.0 if m.flag else 0.0) + m.basis[1, 0]


@kernel
def _read_borrowed_mixed(m):
    """A borrowed tuple of arrays and numbers, read by name, by index, unpacked and passed on."""
    b = borrowed(m)
    origin, scale, count, flag, basis = b
    return (_mixed_fields(b), b[1], b[2], b[3], b[-1][0, 1], origin[2] * scale + count, flag, basis.shape[0])


class _Numbers(NamedTuple):
    scale: float
    count: int


class _Nested(NamedTuple):
    origin: np.ndarray
    pair: tuple


@kernel
def _borrow_any(t):
    return borrowed(t)[0]


def _rebind_mixed(m):
    g = m
    h = g
    return h.origin.shape[0] + h.count


def test_a_named_tuple_of_arrays_and_numbers_is_borrowed_too(monkeypatch):
    """The camera's parameters (arrays beside numbers) are borrowed as the tables are: the same values, and no
    reference counting where a kernel binds or passes them (each camera ray had three atomic pairs before)."""
    m = _Mixed(np.array([1.0, 2.0, 3.0]), 0.5, 7, True, np.arange(9.0).reshape(3, 3))
    assert _read_borrowed_mixed(m) == (0.5 * 2.0 + 7 + 100.0 + 3.0, 0.5, 7, True, 1.0, 3.0 * 0.5 + 7, True, 3)
    assert _read_borrowed_mixed(m._replace(flag=False))[0] == 0.5 * 2.0 + 7 + 3.0
    for refused in (_Numbers(0.5, 7), _Nested(np.zeros(3), (1.0, 2.0))):   # nothing to detach; not flat
        with pytest.raises(Exception, match="borrowed"):
            _borrow_any(refused)
    from numba.core import codegen

    generated = []
    add_ir_module = codegen.CPUCodeLibrary.add_ir_module
    monkeypatch.setattr(codegen.CPUCodeLibrary, "add_ir_module",
                        lambda lib, mod: (generated.append(str(mod)), add_ir_module(lib, mod))[1])
    plain = typeof(m)
    refops = {}
    for ty in (plain, BorrowedTuple(plain)):
        generated.clear()
        njit(no_cpython_wrapper=True, no_cfunc_wrapper=True)(_rebind_mixed).compile((ty,))
        refops[ty] = len(re.findall(r'call void @"?NRT_(?:incref|decref)', "".join(generated)))
    assert refops[plain] >= 4        # both arrays, at every binding
    assert refops[BorrowedTuple(plain)] <= 2   # only the one array taken out of it


def test_stable_sort_matches_numpy_mergesort_argsort():
    rng = np.random.default_rng(1)
    for trial in range(200):
        n = int(rng.integers(1, 120))
        keys = rng.integers(0, 6, n).astype(np.float64)  # many ties: stability matters
        if trial % 4 == 0:
            keys[rng.integers(0, n, 3)] = np.nan
        order = rng.permutation(n).astype(np.int32)
        lo = int(rng.integers(0, n))
        hi = int(rng.integers(lo, n + 1))
        perm = np.argsort(keys[lo:hi], kind="mergesort")
        want = order.copy()
        want[lo:hi] = order[lo:hi][perm]
        k, o = keys.copy(), order.copy()
        _stable_sort(k, o, lo, hi, np.empty(n), np.empty(n, np.int32))
        assert np.array_equal(o, want)
        assert np.array_equal(k[lo:hi], keys[lo:hi][perm], equal_nan=True)
        assert np.array_equal(o[:lo], order[:lo]) and np.array_equal(o[hi:], order[hi:])


_KERNEL_ARGUMENT_MODULE = '''
from caustica.jit import kernel

@kernel(inline=True)
def twice(x):
    return 2.0 * x

@kernel
def apply(f, x):
    return f(x)

@kernel
def first(x):
    return apply(twice, x)

@kernel
def second(x):
    return apply(twice, x) + 1.0

@kernel
def via_first(x):
    return first(x)

@kernel
def via_first_again(x):
    return first(x) + 2.0
'''


def _path_with(folder) -> str:
    """A subprocess's PYTHONPATH: ``folder`` (a test's module) before this interpreter's path (the tree under test)."""
    return os.pathsep.join([str(folder)] + [p for p in sys.path if p])


def _outputs_of_two_processes(tmp_path, script: str, names: tuple[str, str]) -> list[list[str]]:
    """Run ``script`` with each of ``names`` in its own fresh process, both sharing one kernel cache in ``tmp_path``,
    with the kernels of ``_KERNEL_ARGUMENT_MODULE`` importable: the words each printed."""
    (tmp_path / "kernel_argument_module.py").write_text(_KERNEL_ARGUMENT_MODULE)
    env = dict(os.environ, CAUSTICA_CACHE_DIR=str(tmp_path / "cache"), CAUSTICA_NO_CACHE="0",
               PYTHONPATH=_path_with(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)
    runs = [subprocess.run([sys.executable, "-c", script, name], env=env, capture_output=True, text=True,
                           timeout=300) for name in names]
    for run in runs:
        assert run.returncode == 0, run.stderr
    return [run.stdout.split() for run in runs]


def test_a_kernel_taking_a_kernel_is_read_back_from_the_disk_cache(tmp_path):
    """A kernel passed to a kernel is part of the callee's signature, which Numba's cache index pickles: another
    process compiling a new caller must read that index back (kernels pickle by reference) and load the callee from
    it, not crash (as it did when a kernel pickled as a new dispatcher) or compile it again."""
    script = ("import pickle, sys, kernel_argument_module as m\n"
              "from caustica.jit import LinkOnlyLibrary\n"
              "assert pickle.loads(pickle.dumps(m.twice)) is m.twice\n"
              "print(getattr(m, sys.argv[1])(3.0), sum(m.apply.stats.cache_hits.values()),"
              " sum(m.apply.stats.cache_misses.values()),"
              " all(isinstance(c.library, LinkOnlyLibrary) for c in m.apply.overloads.values()))")
    runs = _outputs_of_two_processes(tmp_path, script, ("first", "second"))
    assert runs[0] == ["6.0", "0", "1", "True"]   # compiled and written to the cache
    assert runs[1] == ["7.0", "1", "0", "True"]   # read back (as IR to link) for a new caller


def test_a_kernel_passing_a_kernel_is_cached_too(tmp_path):
    """``first`` passes the kernel ``twice`` as a value.  Its IR is kept unoptimised for its callers to link
    (:class:`~caustica.jit.LinkOnlyLibrary`), so the value's lowering stays in it: as Numba lowers a dispatcher (the
    address of its Python object, different in each process) Numba refused to cache ``first`` and every kernel
    linking it.  A kernel's value is a null pointer (:class:`~caustica.jit.KernelType`): ``first`` is written once
    and read back for a new caller."""
    script = ("import sys, warnings, kernel_argument_module as m\n"
              "warnings.simplefilter('error')\n"
              "print(getattr(m, sys.argv[1])(3.0), sum(m.first.stats.cache_hits.values()),"
              " sum(m.first.stats.cache_misses.values()))")
    runs = _outputs_of_two_processes(tmp_path, script, ("via_first", "via_first_again"))
    assert runs[0] == ["6.0", "0", "1"]
    assert runs[1] == ["8.0", "1", "0"]


_SAVE_AT_ONCE_SCRIPT = """
import os, sys, time
from numba.core import caching
import kernel_argument_module as m

name, folder, index_delay, code_delay = sys.argv[1], sys.argv[2], float(sys.argv[3]), float(sys.argv[4])
save_index, save_code = caching.IndexDataCacheFile._save_index, caching.IndexDataCacheFile._save_data


def slow_save_index(self, overloads):  # after reading the index, before writing it back
    time.sleep(index_delay)
    save_index(self, overloads)


def slow_save_code(self, name, code):  # after writing the index, before writing the code
    time.sleep(code_delay)
    save_code(self, name, code)


caching.IndexDataCacheFile._save_index = slow_save_index
caching.IndexDataCacheFile._save_data = slow_save_code
open(os.path.join(folder, "ready-" + name), "w").close()
while not os.path.exists(os.path.join(folder, "go")):
    time.sleep(0.01)
print(m.twice(3) if name == "integer" else m.twice(3.5))
"""


@pytest.mark.parametrize("delays", [
    # both read the index before either writes it: unlocked, the real entry's write drops the integer one
    {"integer": (1.0, 0.0), "real": (1.0, 0.0)},
    # as above, and the integer code is written last, to the one file name both chose: unlocked, the index pairs
    # the real key with the integer code, and a third process's twice(3.5) returned 6.0
    {"integer": (0.5, 2.0), "real": (1.0, 0.0)}], ids=["entry-lost", "code-swapped"])
def test_processes_saving_to_the_cache_at_once_keep_every_entry(tmp_path, delays):
    """Two processes compile different specialisations of one kernel at once and save them to one cache.  Each reads
    the kernel's index, adds its entry, writes the index back, then the code, to a file named by the first number
    free in the index it read (slowed here to force the interleavings Numba alone leaves to chance).  Saving holds
    the cache's lock (:func:`~caustica.jit._cache_lock`), so a third process loads both, right, from the cache."""
    (tmp_path / "kernel_argument_module.py").write_text(_KERNEL_ARGUMENT_MODULE)
    env = dict(os.environ, CAUSTICA_CACHE_DIR=str(tmp_path / "cache"), CAUSTICA_NO_CACHE="0",
               PYTHONPATH=_path_with(tmp_path))
    env.pop("NUMBA_CACHE_DIR", None)
    children = {name: subprocess.Popen([sys.executable, "-c", _SAVE_AT_ONCE_SCRIPT, name, str(tmp_path),
                                        *map(str, delay)], env=env, stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True)
                for name, delay in delays.items()}
    deadline = time.monotonic() + 120
    while not all((tmp_path / f"ready-{name}").exists() for name in children) and time.monotonic() < deadline:
        time.sleep(0.05)
    (tmp_path / "go").touch()
    outputs = {name: child.communicate(timeout=300) for name, child in children.items()}
    for name, child in children.items():
        assert child.returncode == 0, outputs[name][1]
    assert (outputs["integer"][0].split(), outputs["real"][0].split()) == (["6.0"], ["7.0"])
    check = subprocess.run([sys.executable, "-c", "import kernel_argument_module as m\n"
                            "print(m.twice(3.5), m.twice(3), sum(m.twice.from_python.stats.cache_hits.values()),"
                            " sum(m.twice.from_python.stats.cache_misses.values()))"],
                           env=env, capture_output=True, text=True, timeout=300)
    assert check.returncode == 0, check.stderr
    assert check.stdout.split() == ["7.0", "6.0", "2", "0"]   # both read back, none compiled again

def test_a_thread_holding_the_cache_lock_can_save_under_it(tmp_path):
    """A save nested in a load (reading an index imports modules; one that compiled as it was imported would save)
    goes on under the shared lock its thread holds, where a second flock of the file would wait on itself; another
    process's exclusive lock still waits for it."""
    from caustica.jit import _cache_lock
    index = str(tmp_path / "f.nbi")
    done = []

    def nested():
        with _cache_lock(index, exclusive=False):
            with _cache_lock(index, exclusive=True):
                done.append("saved")
            other = subprocess.run([sys.executable, "-c", "import fcntl, os, sys\n"
                                    "fd = os.open(sys.argv[1], os.O_RDWR)\n"
                                    "try:\n    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
                                    "except BlockingIOError:\n    print('waits')", str(tmp_path / ".lock")],
                                   capture_output=True, text=True, timeout=60)
            done.append(other.stdout.strip())

    import threading
    thread = threading.Thread(target=nested, daemon=True)
    thread.start()
    thread.join(60)
    assert not thread.is_alive() and done == ["saved", "waits"]


@kernel
def _double(x):
    return 2.0 * x


@kernel
def _the_kernel(x):
    return _double


def test_a_kernel_returned_to_python_is_the_kernel():
    assert _the_kernel(1.0) is _double


def test_a_kernel_not_found_by_name_is_returned_to_python_too():
    """A kernel defined in a function is not found by its module and name: it keeps Numba's lowering (its object's
    address; such a caller is not cached)."""
    @kernel
    def local(x):
        return x

    @kernel
    def give(x):
        return local

    from numba.core.errors import NumbaWarning
    with pytest.warns(NumbaWarning, match="Cannot cache compiled function \"give_from_python\""):
        assert give(1.0) is local


_PYTHON_OBJECTS_MODULE = '''
import numba
from caustica.jit import kernel


@kernel
def leaf_raise(x):
    if x < 0:
        raise ValueError("negative value", x, 7)   # arguments known only at run time
    return 2.0 * x


@kernel
def raise_through(x):
    return leaf_raise(x) + 1.0


@kernel
def leaf_print(x):
    print("leaf", x)
    return x


@kernel
def print_through(x):
    return leaf_print(x) + 1.0


def _plus_100(x):
    return x + 100.0


@kernel
def leaf_objmode(x):
    with numba.objmode(y="float64"):
        y = _plus_100(x)
    return y


@kernel
def objmode_through(x):
    return leaf_objmode(x) + 1.0


@kernel
def is_even(n):
    return True if n == 0 else is_odd(n - 1)


@kernel
def is_odd(n):
    return False if n == 0 else is_even(n - 1)


@kernel
def even_through(n):
    return is_even(n)
'''

_PYTHON_OBJECTS_SCRIPT = """
import faulthandler, sys
faulthandler.dump_traceback_later(240, exit=True)
import python_objects_module as m
try:
    m.raise_through(-1.0)
except ValueError as e:
    print("raised", e.args)
print("printed", m.print_through(2.0))
print("objmode", m.objmode_through(1.0))
print("even", m.even_through(7), m.even_through(10))
"""


def test_kernels_linked_into_callers_reach_python_objects_and_each_other(tmp_path):
    """A kernel linked into its caller (jit.LinkOnlyLibrary: no machine code of its own) still reaches Python
    objects through its environment -- an exception with run-time arguments, print, object mode -- and kernels
    that call each other still resolve (the review of 2026-12-06 found each broken, fresh compiles only)."""
    (tmp_path / "python_objects_module.py").write_text(_PYTHON_OBJECTS_MODULE)
    env = dict(os.environ, CAUSTICA_NO_CACHE="1",
               PYTHONPATH=_path_with(tmp_path))
    run = subprocess.run([sys.executable, "-c", _PYTHON_OBJECTS_SCRIPT], env=env, capture_output=True, text=True,
                         timeout=300)
    assert run.returncode == 0, run.stderr[-3000:]
    assert run.stdout.splitlines() == ["raised ('negative value', -1.0, 7)", "leaf 2.0", "printed 3.0",
                                       "objmode 102.0", "even False True"], run.stdout
