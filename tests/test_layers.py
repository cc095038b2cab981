"""The package's layers: no import cycle, and no module imports from a layer above its own (issue 18).

scene (the description and its loader) → tables (geometry, materials, lights, media, camera, and
the compiled scene that assembles them) → transport (light paths, photon and stream tracing, the
camera passes) → methods → driver (passes, checkpoints, results) → api and cluster → experiments →
the command line.  Below them all, base modules that know nothing of rendering (errors, limits,
memory, the JIT policy and feature-specialised tables, random numbers, vector maths, image files, the film's accumulation).  A module may import its own layer and
the ones below.  Imports are read from the source (``ast``), so the test runs nothing.
"""
from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1] / "src" / "caustica"

LAYERS = (
    ("base", ("caustica.errors", "caustica.limits", "caustica.memory", "caustica.jit", "caustica.sampling",
              "caustica.geometry.vec", "caustica.imageio", "caustica.version", "caustica.film",
              "caustica.interrupts", "caustica.arrays", "caustica.features")),
    ("scene", ("caustica.scene",)),
    ("tables", ("caustica.geometry", "caustica.bsdfs", "caustica.emitters", "caustica.media", "caustica.volumes",
                "caustica.camera", "caustica.tables")),
    ("transport", ("caustica.transport", "caustica.lighting", "caustica.photons")),
    ("methods", ("caustica.methods",)),
    ("driver", ("caustica.driver", "caustica.checkpoint", "caustica.result", "caustica.photon_view")),
    ("api", ("caustica.api", "caustica.cluster", "caustica")),
    ("experiments", ("caustica.experiments",)),
    ("cli", ("caustica.cli", "caustica.__main__")),
)


def modules() -> dict[str, Path]:
    out = {}
    for path in ROOT.rglob("*.py"):
        parts = path.relative_to(ROOT.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        out[name] = path
    return out


def imports(mods: dict[str, Path]) -> dict[str, set[str]]:
    """Module -> the package's modules it imports (``from . import sub`` is an import of ``sub`` alone)."""
    edges = {}
    for name, path in mods.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps = set()
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[:len(package.split(".")) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                else:
                    target = node.module or ""
                subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in mods]
                deps.update(subs)
                if target in mods and len(subs) < len(node.names):
                    deps.add(target)
            elif isinstance(node, ast.Import):
                deps.update(a.name for a in node.names if a.name in mods)
        deps.discard(name)
        edges[name] = deps
    return edges


def layer(name: str) -> int:
    best, level = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for prefix in prefixes:
            if (name == prefix or name.startswith(prefix + ".")) and len(prefix) > best:
                best, level = len(prefix), i
    assert level is not None, f"{name} is in no layer: add it to LAYERS"
    return level


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))
    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle():
    assert cycles(imports(modules())) == []


def test_no_module_imports_from_a_layer_above_its_own():
    upward = [f"{m} ({LAYERS[layer(m)][0]}) imports {d} ({LAYERS[layer(d)][0]})"
              for m, deps in sorted(imports(modules()).items()) for d in sorted(deps) if layer(d) > layer(m)]
    assert upward == []


#: Issue 18's limits on the transport and method layers: a loop a reader can hold in view, kernels that take a few
#: structured arguments (the scene tables, the method's parameters, the pass state) rather than dozens.
MAX_FUNCTION_LINES = 80
MAX_KERNEL_ARGUMENTS = 8


def functions_of(layers: tuple[str, ...]):
    """(module, function node, is a kernel) for every function defined in a module of ``layers``."""
    names = {n for n, _ in LAYERS}
    assert set(layers) <= names, set(layers) - names
    wanted = {i for i, (n, _) in enumerate(LAYERS) if n in layers}
    for name, path in sorted(modules().items()):
        if layer(name) not in wanted:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                kernel = any((d.func if isinstance(d, ast.Call) else d).id == "kernel"
                             for d in node.decorator_list
                             if isinstance(d.func if isinstance(d, ast.Call) else d, ast.Name))
                yield name, node, kernel


def test_transport_and_method_functions_are_at_most_80_lines():
    """Counted from ``def`` to the last line, docstring included."""
    long = [f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines"
            for name, node, _ in functions_of(("transport", "methods"))
            if node.end_lineno - node.lineno + 1 > MAX_FUNCTION_LINES]
    assert not long, f"over {MAX_FUNCTION_LINES} lines (split it into named steps): {long}"


def test_kernels_take_at_most_8_arguments():
    wide = [f"{name}.{node.name}: {len(node.args.args)} arguments"
            for name, node, kernel in functions_of(("tables", "transport", "methods"))
            if kernel and len(node.args.args) > MAX_KERNEL_ARGUMENTS]
    assert not wide, f"kernels over {MAX_KERNEL_ARGUMENTS} arguments (group them in tuples): {wide}"
