#!/usr/bin/env python3
"""Try to load every scene of a Mitsuba 3 corpus with caustica's loader; print, per scene, ok or every blocker.

    python scripts/fetch_mitsuba_scenes.py --dest out/mitsuba-corpus
    python scripts/mitsuba_corpus_report.py out/mitsuba-corpus [--mitsuba] [--markdown out/report.md]

A scene is an XML file whose root is <scene>, outside folders named include/ or fragments/ and not itself
included by another file (those are parts of scenes).  Loading only: nothing is rendered.  The summary
counts, for each kind of blocker, the scenes it blocks (a scene with several blockers counts once for each),
with the date and the pinned commits the corpus came from.  ``--mitsuba`` also loads each scene with
Mitsuba 3 (scalar_rgb), to tell scenes Mitsuba itself cannot load in that variant from caustica's gaps.
"""
from __future__ import annotations

import argparse
import datetime
import re
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

INCLUDE = re.compile(r"""<include\s[^>]*filename\s*=\s*["']([^"']+)["']""")
ROOT = re.compile(r"<(?!\?|!)([A-Za-z_][\w.-]*)")


def find_scenes(root: Path) -> list[Path]:
    xmls = sorted(p for p in root.rglob("*.xml") if ".git" not in p.parts)
    included = set()
    texts = {}
    for p in xmls:
        try:
            texts[p] = p.read_text(errors="replace")
        except OSError:
            continue
        for name in INCLUDE.findall(texts[p]):
            included.add((p.parent / name).resolve())
    scenes = []
    for p, text in texts.items():
        body = re.sub(r"<!--.*?-->", "", text, flags=re.S)
        m = ROOT.search(body)
        if not m or m.group(1) != "scene":
            continue
        if {"include", "fragments"} & set(p.relative_to(root).parts[:-1]) or p.resolve() in included:
            continue
        scenes.append(p)
    return scenes


def blockers_of(message: str) -> list[str]:
    """The problems in a SceneError's text (one, or the lines of the one report)."""
    lines = message.split("\n")
    if len(lines) > 1 and re.search(r": \d+ problems, each with its file and line", lines[0]):
        return [ln.strip() for ln in lines[1:] if ln.strip()]
    return [message]


_ELEMENT = re.compile(r'^.*?:\d+: <([\w.-]+)((?: \w+="[^"]*")*)>: (.*)$')


def kind_of(blocker: str) -> str:
    """A short name for a blocker, to count scenes by (e.g. "emitter envmap", "film pixel_format=...")."""
    m = _ELEMENT.match(blocker)
    if not m:
        return re.sub(r"^\S+?:\d+: ", "", blocker)[:70]
    tag, attrs, what = m.groups()
    attr = dict(re.findall(r'(\w+)="([^"]*)"', attrs))
    if u := re.match(r"reconstruction filter '([^']+)'", what):
        return f"rfilter type {u.group(1)}"
    if u := re.match(r"conductor material=\"([^\"]+)\"", what):
        return f"conductor material={u.group(1)}"
    if u := re.match(r"unknown (\w+) type '([^']+)'", what):
        return f"{u.group(1)} type {u.group(2)}"
    if u := re.match(r"unknown property '([^']+)' of <(\w+)(?: type=\"([^\"]+)\")?", what):
        return f"{u.group(2)} {u.group(3) or ''} property {u.group(1)}".replace("  ", " ")
    if what.startswith("unknown element at the top level"):
        return f"<{tag}> at the top level" + (f" (type {attr['type']})" if "type" in attr else "")
    if u := re.match(r"unexpected element inside <(\w+)(?: type=\"([^\"]+)\")?", what):
        inner = f"<{tag}{' ' + attr['type'] if 'type' in attr else ''}{' name=' + attr['name'] if 'name' in attr else ''}>"
        return f"{inner} inside {u.group(1)} {u.group(2) or ''}".strip()
    if "not found" in what:
        return "a file it names is missing"
    if u := re.match(r"(\w+)='([^']*)' is not supported", what):
        return f"{tag} {u.group(1)}={u.group(2)}"
    if tag in ("float", "integer", "string", "boolean", "rgb", "spectrum", "ref") and "name" in attr:
        return f"{attr['name']}: {re.split(r'[;(]', what)[0].strip()[:50]}"
    return f"<{tag}>: {re.split(r'[;(]', what)[0].strip()[:60]}"


def load_caustica(path: Path) -> tuple[str, list[str]]:
    from caustica.errors import SceneError
    from caustica.scene import load_scene_file
    try:
        load_scene_file(path)
        return "ok", []
    except SceneError as exc:
        return "blocked", blockers_of(str(exc))
    except Exception as exc:   # a loader bug: report it as one, do not stop the survey
        return "crash", [f"{type(exc).__name__}: {exc}"]


def load_mitsuba(path: Path) -> str:
    import mitsuba as mi
    try:
        mi.load_file(str(path))
        return "ok"
    except Exception as exc:
        return "error: " + str(exc).strip().split("\n")[-1][:120]


def pins(root: Path) -> list[str]:
    out = []
    for stamp in sorted(root.glob("*/.caustica-commit")):
        out.append(f"{stamp.parent.name.replace('+', '/')}@{stamp.read_text().strip()[:12]}")
    return out


def caustica_commit() -> str:
    try:
        here = Path(__file__).resolve().parent
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True,
                              text=True, check=True).stdout.strip()
    except Exception:
        return "?"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("corpus", type=Path, help="the folder scripts/fetch_mitsuba_scenes.py filled")
    ap.add_argument("--mitsuba", action="store_true", help="also load each scene with Mitsuba 3 (scalar_rgb)")
    ap.add_argument("--markdown", type=Path, help="also write the summary as a Markdown table here")
    args = ap.parse_args(argv)
    if args.mitsuba:
        import mitsuba as mi
        mi.set_variant("scalar_rgb")
        mi.set_log_level(mi.LogLevel.Error)
    scenes = find_scenes(args.corpus)
    if not scenes:
        print(f"no scenes under {args.corpus}", file=sys.stderr)
        return 1
    counts: Counter = Counter()
    status: Counter = Counter()
    n_blockers = []
    mitsuba_ok = 0
    for path in scenes:
        rel = path.relative_to(args.corpus)
        t0 = time.perf_counter()
        state, blockers = load_caustica(path)
        dt = time.perf_counter() - t0
        status[state] += 1
        extra = ""
        if args.mitsuba:
            mi_state = load_mitsuba(path)
            mitsuba_ok += mi_state == "ok"
            extra = f"   [mitsuba: {mi_state}]"
        if state == "ok":
            print(f"ok       {rel}  ({dt:.2f} s){extra}")
            continue
        n_blockers.append(len(blockers))
        print(f"{state:8} {rel}: {len(blockers)} blocker{'s' if len(blockers) != 1 else ''}{extra}")
        for kind in sorted({kind_of(b) for b in blockers}):
            counts[kind] += 1
        for b in blockers:
            print(f"           {b}")
    n = len(scenes)
    median = sorted(n_blockers)[len(n_blockers) // 2] if n_blockers else 0
    head = [f"date: {datetime.date.today().isoformat()}; caustica {caustica_commit()}; corpus {', '.join(pins(args.corpus))}",
            f"{n} scenes: {status['ok']} load, {status['blocked']} blocked (median {median} blockers), "
            f"{status['crash']} loader crashes" + (f"; Mitsuba 3 scalar_rgb loads {mitsuba_ok}" if args.mitsuba else "")]
    print()
    print("\n".join(head))
    print("\nscenes blocked, by blocker:")
    width = max((len(k) for k in counts), default=10)
    for kind, c in counts.most_common():
        print(f"  {kind:<{width}}  {c}")
    if args.markdown:
        md = ["\n\n".join(head), "", "| blocker | scenes |", "| --- | --- |"]
        md += [f"| {k.replace('|', '/')} | {c} |" for k, c in counts.most_common()]
        args.markdown.parent.mkdir(parents=True, exist_ok=True)
        args.markdown.write_text("\n".join(md) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
