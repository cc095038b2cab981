"""`pt`'s render time on the Cornell boxes in several source trees, renders interleaved one by one.

    python benchmarks/pt_trees.py OLD/src NEW/src [MORE/src ...] [--renders 40] [--threads 2] [--res 128] [--spp 16]

Each tree runs in its own persistent process (``PYTHONPATH=TREE``), which loads the scene and warms its kernels
up first; then the processes render in turn, one render each, the order rotating, ``--renders`` times per scene
(seeds 0, 1, 2 in turn).  On a shared machine the load drifts by more than the few per cent a change is worth;
renders seconds apart see the same load, so the ratio of each render to the first tree's render of the same
round (a paired ratio) varies far less than the times themselves.

Printed per scene and tree: the median process CPU seconds per render (every thread), the median wall seconds
of the camera pass, and the median and quartiles of the paired CPU ratio to the first tree.  No asserts.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys

SCENES = ("cornell-diacaustic", "cornell-catacaustic")

_CHILD = r"""
import sys, time, caustica
res, spp, threads = (int(v) for v in sys.argv[1:4])
scenes = {}
for line in sys.stdin:
    name, seed = line.split()
    if name not in scenes:
        scenes[name] = caustica.load_scene(name)
        caustica.render(scenes[name], "pt", res=32, spp=1, threads=threads)      # compile or load the kernels
        caustica.render(scenes[name], "pt", res=res, spp=max(1, spp // 4), threads=threads)
    t = time.process_time()
    r = caustica.render(scenes[name], "pt", res=res, spp=spp, seed=int(seed), threads=threads)
    print(time.process_time() - t, r.stats["timings"]["camera_pass_s"], flush=True)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("trees", nargs="+", help="src folders of the trees to compare (the first is the baseline)")
    ap.add_argument("--renders", type=int, default=40, help="renders per tree and scene")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=16)
    args = ap.parse_args()
    if len(args.trees) < 2 or args.renders < 4:
        ap.error("give at least two trees and --renders >= 4")
    for tree in args.trees:
        if not os.path.isdir(os.path.join(tree, "caustica")):
            ap.error(f"{tree}: no caustica package there (give a checkout's src folder)")
    procs = [subprocess.Popen([sys.executable, "-c", _CHILD, str(args.res), str(args.spp), str(args.threads)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
                              env=dict(os.environ, PYTHONPATH=tree)) for tree in args.trees]
    try:
        for scene in SCENES:
            cpu = [[] for _ in procs]
            wall = [[] for _ in procs]
            for i in range(args.renders):
                for k in range(len(procs)):
                    j = (i + k) % len(procs)
                    procs[j].stdin.write(f"{scene} {i % 3}\n")
                    procs[j].stdin.flush()
                    line = procs[j].stdout.readline()
                    if not line:
                        raise SystemExit(f"{args.trees[j]}: the render process ended (see its error above)")
                    c, w = map(float, line.split())
                    cpu[j].append(c)
                    wall[j].append(w)
            for j, tree in enumerate(args.trees):
                ratios = sorted(b / a for a, b in zip(cpu[0], cpu[j]))
                q = len(ratios) // 4
                print(json.dumps({"scene": scene, "tree": tree, "renders": args.renders, "threads": args.threads,
                                  "res": args.res, "spp": args.spp,
                                  "cpu_s_median": round(statistics.median(cpu[j]), 4),
                                  "camera_pass_wall_s_median": round(statistics.median(wall[j]), 4),
                                  "cpu_ratio_to_first": [round(ratios[q], 4), round(statistics.median(ratios), 4),
                                                         round(ratios[-1 - q], 4)]}))
    finally:
        for p in procs:
            p.stdin.close()
            p.wait()


if __name__ == "__main__":
    main()
