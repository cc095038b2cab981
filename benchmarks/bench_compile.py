"""Where the first render's time goes: Numba compile time per kernel, and the cold-start total.

    python benchmarks/bench_compile.py [--method spm] [--scene cornell-diacaustic] [--top 25]

(a) Per kernel.  A fresh interpreter with ``CAUSTICA_NO_CACHE=1`` (every kernel
    compiled) renders the scene small (32x32, 1 thread) while a listener on Numba's
    ``numba:compile`` event records every compilation: the dispatcher, its
    signature, and the wall and CPU time (``time.thread_time``: compilation runs in
    the calling thread, under Numba's lock) spent in it.  Compilations nest (typing
    a caller compiles its callees), so each row shows the *self* time (less the
    nested compilations) and the inclusive time; self times add up to the total.
    Rows are grouped by kernel: ``specs`` counts its specialisations (one per
    distinct argument types).  The last columns split the self time into typing
    (Numba's type inference, less nested compiles) and lowering (Numba's code
    generation plus LLVM's optimisation and machine code).  A line below the table
    gives LLVM's own CPU time over the whole run (its function and module passes,
    its machine code, parsing Numba's IR), the rest being Numba's, in Python.
(b) Cold start: the README's command ``caustica render SCENE --method METHOD`` (the
    scene's own 512x512 film) in a subprocess, first with an empty kernel cache
    (a fresh install: every kernel compiled and written to the cache), then again
    (kernels loaded from the cache).  Wall time, and CPU time (user + sys of the
    child) -- on a shared machine the CPU time is the number that travels.

No asserts.  The machine's load changes wall times; compare CPU times across runs.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

_CHILD = r"""
import json, sys, time
from numba.core import event

records, stack = [], []


class Listener(event.Listener):
    def on_start(self, ev):
        stack.append([time.perf_counter(), time.thread_time(), 0.0, 0.0])

    def on_end(self, ev):
        t0, c0, nested_w, nested_c = stack.pop()
        wall, cpu = time.perf_counter() - t0, time.thread_time() - c0
        disp = ev.data["dispatcher"]
        cres = disp.overloads.get(tuple(ev.data["args"]))
        typing = lowering = 0.0
        if cres is not None:
            for times in cres.metadata.get("pipeline_times", {}).values():
                for name, t in times.items():
                    if name.endswith("nopython_type_inference"):
                        typing += t.init + t.run + t.finalize
                    elif name.endswith("native_lowering"):
                        lowering += t.init + t.run + t.finalize
        fn = disp.py_func
        records.append({"kernel": fn.__module__ + "." + fn.__qualname__, "args": str(ev.data["args"]),
                        "wall": wall, "self_wall": wall - nested_w, "self_cpu": cpu - nested_c,
                        "typing_self": typing - nested_w, "lowering": lowering})
        if stack:
            stack[-1][2] += wall
            stack[-1][3] += cpu


event.register("numba:compile", Listener())

# LLVM's own share (the rest of a kernel's compile is Numba's, in Python): its pass managers, the machine code, and
# parsing Numba's textual IR, CPU seconds of the calling thread
from llvmlite import binding as ll
from llvmlite.binding import newpassmanagers
from numba.core import codegen
llvm = {"function passes": 0.0, "module passes": 0.0, "machine code": 0.0, "parsing IR": 0.0}


def _llvm_timed(f, key):
    def timed(*args, **kwargs):
        c = time.thread_time()
        try:
            return f(*args, **kwargs)
        finally:
            llvm[key] += time.thread_time() - c
    return timed


newpassmanagers.FunctionPassManager.run = _llvm_timed(newpassmanagers.FunctionPassManager.run, "function passes")
newpassmanagers.ModulePassManager.run = _llvm_timed(newpassmanagers.ModulePassManager.run, "module passes")
codegen.JitEngine.finalize_object = _llvm_timed(codegen.JitEngine.finalize_object, "machine code")
ll.parse_assembly = _llvm_timed(ll.parse_assembly, "parsing IR")   # (Numba calls it as ll.parse_assembly)
t0, c0 = time.perf_counter(), time.process_time()
import caustica
scene = caustica.load_scene(sys.argv[1])
r = caustica.render(scene, sys.argv[2], res=32, threads=1)
print(json.dumps({"records": records, "wall": time.perf_counter() - t0, "cpu": time.process_time() - c0,
                  "timings": r.stats["timings"], "llvm": llvm}))
"""


def _env(**extra):
    env = {k: v for k, v in os.environ.items() if k not in ("CAUSTICA_NO_CACHE", "NUMBA_CACHE_DIR")}
    env.update(extra)
    return env


def per_kernel(scene, method, top):
    proc = subprocess.run([sys.executable, "-c", _CHILD, scene, method], capture_output=True, text=True,
                          env=_env(CAUSTICA_NO_CACHE="1"))
    if proc.returncode != 0:
        raise SystemExit(f"child failed:\n{proc.stderr}")
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    groups = {}
    for r in out["records"]:
        g = groups.setdefault(r["kernel"], {"specs": 0, "self_wall": 0.0, "self_cpu": 0.0, "wall": 0.0,
                                            "typing": 0.0, "lowering": 0.0})
        g["specs"] += 1
        g["self_wall"] += r["self_wall"]
        g["self_cpu"] += r["self_cpu"]
        g["wall"] += r["wall"]
        g["typing"] += max(0.0, r["typing_self"])
        g["lowering"] += r["lowering"]
    rows = sorted(groups.items(), key=lambda kv: -kv[1]["self_cpu"])
    total_cpu = sum(g["self_cpu"] for g in groups.values())
    total_wall = sum(g["self_wall"] for g in groups.values())
    print(f"## (a) Compile time per kernel: `{method}` on {scene} (CAUSTICA_NO_CACHE=1, 32x32, 1 thread)\n")
    print(f"{len(out['records'])} compilations of {len(groups)} kernels; compile CPU {total_cpu:.2f} s "
          f"(wall {total_wall:.2f} s) of the process's {out['cpu']:.2f} s CPU ({out['wall']:.2f} s wall, "
          f"import included).\n")
    print("| kernel | specs | self CPU (s) | self wall (s) | typing (s) | lowering + LLVM (s) | inclusive wall (s) |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    rest = rows[top:]
    for name, g in rows[:top]:
        print(f"| {name.removeprefix('caustica.')} | {g['specs']} | {g['self_cpu']:.3f} | {g['self_wall']:.3f} | "
              f"{g['typing']:.3f} | {g['lowering']:.3f} | {g['wall']:.3f} |")
    if rest:
        print(f"| ({len(rest)} more kernels) | {sum(g['specs'] for _, g in rest)} | "
              f"{sum(g['self_cpu'] for _, g in rest):.3f} | {sum(g['self_wall'] for _, g in rest):.3f} | "
              f"{sum(g['typing'] for _, g in rest):.3f} | {sum(g['lowering'] for _, g in rest):.3f} | |")
    print(f"| **total** | {len(out['records'])} | **{total_cpu:.2f}** | {total_wall:.2f} | | | |\n")
    llvm = out["llvm"]
    print(f"Of the compile CPU, LLVM's own {sum(llvm.values()):.2f} s ("
          + ", ".join(f"{k} {v:.2f}" for k, v in llvm.items())
          + f"); the other {total_cpu - sum(llvm.values()):.2f} s is Numba's, in Python (typing, lowering to IR, "
          "linking).\n")
    return total_cpu


def _timed(cmd, env):
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{proc.stderr}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def cold_start(scene, method):
    exe = Path(sys.executable).with_name("caustica")
    base = [str(exe)] if exe.exists() else [sys.executable, "-m", "caustica"]
    print(f"## (b) Cold start: `caustica render {scene} --method {method}` (the scene's film)\n")
    print("| kernel cache | wall (s) | CPU user + sys (s) | compile_s (s) | total_s (s) |")
    print("|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        env = _env(CAUSTICA_CACHE_DIR=os.path.join(tmp, "cache"))
        for label in ("empty (fresh install)", "warm (second run)"):
            out = os.path.join(tmp, "out.exr")
            wall, cpu = _timed(base + ["render", scene, "--method", method, "-o", out, "--quiet"], env)
            t = json.loads(Path(tmp, "out.json").read_text())["timings"]
            print(f"| {label} | {wall:.2f} | {cpu:.2f} | {t['compile_s']:.2f} | {t['total_s']:.2f} |")
    print("\n(compile_s: the first work item of each kernel, run alone, which compiles or loads it; "
          "the scene load, which builds the BVH, is in total_s.)\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--method", default="spm", help="method of the main job (default: spm, as `make render`)")
    ap.add_argument("--scene", default="cornell-diacaustic")
    ap.add_argument("--top", type=int, default=25, help="kernels listed one by one (default 25)")
    ap.add_argument("--no-cold-start", action="store_true", help="only the per-kernel table")
    args = ap.parse_args()
    print(f"# caustica compile-time benchmark ({time.strftime('%Y-%m-%d')})\n")
    print(f"Python {platform.python_version()}, {platform.machine()}, {os.cpu_count()} CPUs, "
          f"load average {os.getloadavg()[0]:.2f}\n")
    per_kernel(args.scene, args.method, args.top)
    if not args.no_cold_start:
        cold_start(args.scene, args.method)


if __name__ == "__main__":
    main()
