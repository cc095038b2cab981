#!/usr/bin/env bash
# Before/after: benchmarks/bench_core.py on two source trees, interleaved (old, new, old, new), in one run.
#   benchmarks/before_after.sh OLD_SRC NEW_SRC [ROUNDS] [-- bench_core options]
# OLD_SRC / NEW_SRC: the src/ folders of two checkouts (e.g. a `git worktree` of the old commit).
# Results: one JSON line per run in out/before_after.jsonl, and printed.
set -euo pipefail
old=$1; new=$2; rounds=${3:-2}; shift 3 || shift $#
[ "${1:-}" = "--" ] && shift
here="$(cd "$(dirname "$0")" && pwd)"
py="${PYTHON:-$here/../.venv/bin/python}"
mkdir -p "$here/../out"
for r in $(seq "$rounds"); do
  for src in "$old" "$new"; do
    PYTHONPATH="$src" "$py" "$here/bench_core.py" --label "$src" --json "$here/../out/before_after.jsonl" "$@"
  done
done
