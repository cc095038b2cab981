"""Reference-count calls left in the kernels a render calls from Python, after LLVM's optimisation.

    python benchmarks/refcount_audit.py [--scene cornell-diacaustic] [--method sppm] [--top 15]

Numba increments and decrements an array's reference count (an atomic operation on a counter
every thread shares) wherever a variable holding it is bound, and LLVM removes the pairs only
where nothing it cannot see through lies between them.  Left inside a per-pixel or per-photon
loop they cost tens of nanoseconds each and make threads contend (sppm's gather paid 10 pairs a
pixel until 2026-12-06: 0.75-0.78x the gather time without them).  This renders the scene small
in a fresh interpreter with every kernel compiled (``CAUSTICA_NO_CACHE=1``: a kernel loaded from
the cache has no IR to read) and prints, per Python-called kernel, the calls to ``NRT_incref``
and ``NRT_decref`` in its own function (not the Python wrapper's unboxing).  A count is a place
to look, not a verdict: calls at the kernel's entry and exit run once a chunk.  The cure is
:func:`caustica.jit.borrowed` (tuples) or :func:`caustica.geometry.primitives.borrow` (one array)
on the kernel's arguments, or allocating scratch arrays outside the loop.  No asserts.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

_CHILD = r"""
import gc, json, re, sys
import caustica
from numba.core.registry import CPUDispatcher
from caustica.jit import Kernel
scene, method = sys.argv[1], sys.argv[2]
caustica.render(caustica.load_scene(scene), method, res=16, threads=1)
rows = []
for d in gc.get_objects():
    if (isinstance(d, CPUDispatcher) and not isinstance(d, Kernel) and d.signatures   # a Kernel's code is linked
            and d.py_func.__module__.startswith("caustica.")):                         # into these
        for text in d.inspect_llvm().values():
            parts = re.split(r"\ndefine ", text)
            own = parts[1] if len(parts) > 1 else ""
            rows.append([len(re.findall(r"call void @NRT_(?:incref|decref)", own)),
                         d.py_func.__module__ + "." + d.py_func.__qualname__])
print(json.dumps(rows))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scene", default="cornell-diacaustic")
    ap.add_argument("--method", default="sppm")
    ap.add_argument("--top", type=int, default=15)
    args = ap.parse_args()
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["CAUSTICA_NO_CACHE"] = "1"
    proc = subprocess.run([sys.executable, "-c", _CHILD, args.scene, args.method], capture_output=True, text=True,
                          env=env)
    if proc.returncode != 0:
        raise SystemExit(f"the render failed:\n{proc.stderr[-3000:]}")
    rows = sorted(json.loads(proc.stdout.strip().splitlines()[-1]), reverse=True)
    print(f"# reference-count calls per Python-called kernel: {args.method} on {args.scene}\n")
    print("| calls | kernel |\n| ---: | --- |")
    for count, name in rows[:args.top]:
        print(f"| {count} | `{name}` |")


if __name__ == "__main__":
    main()
