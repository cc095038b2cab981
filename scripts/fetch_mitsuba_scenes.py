#!/usr/bin/env python3
"""Fetch a corpus of published Mitsuba 3 scenes (pinned commits) for scripts/mitsuba_corpus_report.py.

    python scripts/fetch_mitsuba_scenes.py                  # into out/mitsuba-corpus (git over https)
    python scripts/fetch_mitsuba_scenes.py --dest DIR
    python scripts/fetch_mitsuba_scenes.py --mirror-root /work/.mirror   # from local clones, offline
    python scripts/fetch_mitsuba_scenes.py --independent     # other repositories' scenes, into out/mitsuba-independent

Each source is a public GitHub repository at a pinned commit, of which only the folders listed below are
checked out (git's partial clone and sparse checkout: no history, no other blobs).  Nothing is committed
to caustica: the scenes, meshes and textures stay in the destination folder, next to the licence files the
repositories ship and a SOURCES.md saying where each folder came from and under which terms.  A source
already fetched at its pinned commit is left as it is.

``--mirror-root DIR`` copies from ``DIR/<owner>+<name>/repo`` (a git directory holding the pinned commit)
instead of fetching https://github.com/<owner>/<name>, for machines without network access; files whose
contents that copy lacks are skipped and listed in SOURCES.md.

Needs git >= 2.27 (sparse checkout without cone mode, partial clone).  Standard library only.
"""
from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Source:
    repo: str            # owner/name on GitHub
    commit: str          # the pinned commit
    paths: tuple         # folders and files to check out
    licence: str         # what the repository says about its terms (checked by hand; see also its LICENSE files)


SOURCES = (
    Source("mitsuba-renderer/mitsuba-data", "01100fa9b0b154492061a92404f26dcd7b784dbb",
           ("docs/scenes", "tests/scenes", "tests/obj", "tests/ply", "tests/serialized", "scenes", "common", "ior",
            "README.md"),
           "Mitsuba 3's own data repository (its resources/data submodule: documentation, test and example "
           "scenes). It states no licence of its own; Mitsuba 3, which ships it, is BSD-3-Clause "
           "(https://github.com/mitsuba-renderer/mitsuba3/blob/master/LICENSE)."),
    Source("mitsuba-renderer/mitsuba-tutorials", "a8dbee7e81b1039a983770ce1042f2d78688d0ae",
           ("scenes", "README.md"),
           "Mitsuba 3's tutorials. No licence file at the repository's root; scenes/lego/LICENSE.txt: the LEGO "
           "scene is by BlendSwap user Heinzelnisse under CC-BY-NC (https://www.blendswap.com/blend/11490)."),
)


#: Complete Mitsuba 3 scenes from repositories other than Mitsuba's own, which the loader was not built on
#: (docs/scenes.md, "Scenes the loader was not built on"): ``--independent`` fetches these instead, into
#: out/mitsuba-independent.  Only the scenes and the folders of files they read; folders of files over 4 MiB that a
#: stored copy may lack are named so that their absence is listed, not hidden.
INDEPENDENT = (
    Source("PearCoding/Ignis", "c209e5b75a7095fd8fc27003cb066911db8159e3",
           ("LICENSE.txt", "scenes/evaluation/meshes", "scenes/evaluation/mitsuba/point.xml"),
           "MIT (LICENSE.txt)."),
    Source("sapo17/BachelorThesis", "dee59d57befeff77f30127bea4eacbd3e3a748ec",
           ("blender/cbox-multiple-lights.xml", "blender/meshes", "blender/textures",
            "scenes/cbox-sch-modified/cbox-custom-light.xml", "scenes/cbox-sch-modified/cbox-multiple-lights-2.xml",
            "scenes/cbox-sch-modified/simple-light.xml", "scenes/cbox-sch-modified/meshes",
            *[f"scenes/material-preview/{d}/{f}" for d, files in (
                ("blendbsdf", ("scene-test.xml", "envmap.exr", "matpreview.serialized")),
                ("translucent-participating-media", ("scene-homogeneuous.xml", "envmap.exr", "matpreview.serialized")),
                ("translucent-textured-principled-bsdf", ("scene.xml", "envmap.exr", "floor_tiles_bumpmap.png",
                                                          "gradient.jpg", "matpreview.serialized"))) for f in files],
            *[f"scenes/texture-scanner/{d}/{f}" for d in ("samples-231122/blueish-circular-obj",
                                                          "simple-plane-homogeneous", "simple-plane-principled")
              for f in ("scene-first-rgb.xml" if d.startswith("samples") else "scene.xml", "meshes")]),
           "No licence file at the repository's root (checked 2026-12-06): fetched to test with, not to share."),
    Source("ReaganCardoza/Physics-Based-Ray-Tracing", "e09569d7753c51fb8f704953758908168db98434",
           ("scenes/cbox_pol.xml", "scenes/polarizers.xml", "scenes/shadow_art.xml", "scenes/simple.xml",
            "scenes/meshes", "scenes/textures"),
           "No licence file (checked 2026-12-06): fetched to test with, not to share."),
    Source("lolgameboy/langevin-mc-rendering", "3ce6cdb494fd96aad6aff1d9b73c175e431a2c3f",
           ("scenes/scene_all_emitters.xml", "scenes/scene_directional.xml", "scenes/veach-bidir"),
           "No licence file at the root; scenes/veach-bidir is Benedikt Bitterli's scene, CC0 (its LICENSE.txt)."),
    Source("niklassanden/ReSTIR_GI_DR", "4e71bd940e50f0e0f408206f1ea368cd9dfb6325",
           ("LICENSE", "scenes/cornell_box_picture", "scenes/staircase2"),
           "A Mitsuba 3 fork (BSD-3-Clause-style LICENSE); the scenes are Bitterli's: cornell_box_picture CC0, "
           "staircase2 CC-BY (their LICENSE.txt files)."),
    Source("takkasila/practical_path_guiding_lab", "c4b6605b3c78dccaa5721275d96ef6cd30c0630c",
           ("LICENSE", "scenes/cornell-box/scene.xml", "scenes/cornell-box/LICENSE.txt", "scenes/torus/scene.xml",
            "scenes/torus/meshes.serialized", "scenes/veach-mis/scene.xml", "scenes/veach-mis/LICENSE.txt"),
           "GPL-3.0 (LICENSE); cornell-box and veach-mis are Bitterli's scenes, CC0 (their LICENSE.txt)."),
    # Added 2026-12-07 (docs/scenes.md): seven more repositories, found by a search for complete scenes that
    # Mitsuba 3.9.1 loads (a helper's search; each loaded from a clean copy of just these paths).
    Source("colour-science/colour-mitsuba", "693379cc0e8f935cd39b4bc01038277fde8baac5",
           ("LICENSE", "colour_mitsuba/cornell_box.xml", "colour_mitsuba/cornell_box/include",
            "colour_mitsuba/cornell_box/geometry", "colour_mitsuba/include/integrator.xml"),
           "BSD-3-Clause (LICENSE)."),
    Source("NVlabs/sionna", "3ec2138ba269405e737e5823ecebef1663832115",
           ("LICENSE", "sionna/rt/scenes/simple_street_canyon_with_cars", "sionna/rt/scenes/etoile"),
           "Apache-2.0 (LICENSE); release v0.19.2, the last with sionna/rt/scenes."),
    Source("SojeongKim-42/denoising-nerf", "8d2557c28b1096e9f13a7e7b609d591aebe8cb24",
           ("scenes/banner_01/scene.xml", "scenes/banner_01/meshes"),
           "No licence file (checked 2026-12-07): fetched to test with, not to share. The scene may derive from "
           "one of the Mitsuba team's banner scenes."),
    Source("gmf128/mitsuba-quickstart", "c9c680f562fa9ab1e92a2684df433bd6f147ed4b",
           ("scenes/shader_ball/scene.xml", "scenes/shader_ball/envmap.exr",
            "scenes/shader_ball/matpreview.serialized"),
           "No licence file (checked 2026-12-07): fetched to test with, not to share. Its mesh is Mitsuba's material "
           "preview (matpreview.serialized), its scene file the author's."),
    Source("pani-vishal/reconstruction", "29426bc5a677e0ce0e3aabd899e6478a28c8b3c1",
           ("scenes/cbox.xml", "scenes/textures/charuco.png",
            *[f"scenes/meshes/{m}" for m in ("cbox_luminaire.obj", "cbox_floor.obj", "cbox_ceiling.obj",
                                             "cbox_back.obj", "cbox_greenwall.obj", "cbox_redwall.obj",
                                             "tex_plane.obj", "tex_plane.mtl")]),
           "No licence file (checked 2026-12-07): fetched to test with, not to share. A Cornell box after Mitsuba's "
           "tutorial one, with a textured plane of the author's."),
    Source("danielwujecki/mitsuba3-acoustic-experiments", "65c6ec914837d41956c4adcb65a1db55805a19ba",
           ("LICENSE", "data/scenes/rgb_debug.xml"),
           "BSD-3-Clause (LICENSE)."),
    Source("s1752729916/mitsuba-synthetic-polar", "b8032f33cfd70d46b12bd4644f989dc2d73d5727",
           ("untitled.xml", "meshes/Cube.ply"),
           "No licence file (checked 2026-12-07): fetched to test with, not to share."),
)


def run(*args: str, cwd: Path | None = None) -> str:
    out = subprocess.run(args, cwd=cwd, check=True, capture_output=True, text=True)
    return out.stdout


def copy_from_mirror(src: Source, git_dir: Path, target: Path) -> list[str]:
    """Write src's paths at its commit from a local git directory into target; the files whose blobs the
    local copy lacks (a mirror may leave its largest files out) are skipped and returned."""
    listing = run("git", f"--git-dir={git_dir}", "ls-tree", "-r", "-z", src.commit, "--", *src.paths)
    entries = []
    for item in listing.split("\0"):
        if not item:
            continue
        meta, name = item.split("\t", 1)
        mode, kind, sha = meta.split()
        if kind == "blob":
            entries.append((name, sha))
    batch = subprocess.run(["git", f"--git-dir={git_dir}", "cat-file", "--batch"], check=True, capture_output=True,
                           input="".join(f"{sha}\n" for _, sha in entries).encode())
    data, pos, absent = batch.stdout, 0, []
    for name, sha in entries:
        end = data.index(b"\n", pos)
        header = data[pos:end].decode().split()
        pos = end + 1
        if header[-1] == "missing":
            absent.append(name)
            continue
        size = int(header[2])
        out = target / name
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(data[pos:pos + size])
        pos += size + 1
    return absent


def fetch(src: Source, dest: Path, mirror_root: Path | None) -> Path:
    """Check out src's paths at its pinned commit into dest/<owner>+<name>; the folder."""
    target = dest / src.repo.replace("/", "+")
    stamp = target / ".caustica-commit"
    if stamp.is_file() and stamp.read_text().strip() == src.commit:
        print(f"{src.repo}: already at {src.commit[:12]} in {target}")
        return target
    if target.exists():
        shutil.rmtree(target)
    target.mkdir(parents=True)
    if mirror_root is not None:
        git_dir = mirror_root / src.repo.replace("/", "+") / "repo"
        print(f"{src.repo}: copying {src.commit[:12]} from {git_dir} ({', '.join(src.paths)})", flush=True)
        absent = copy_from_mirror(src, git_dir, target)
        (target / ".caustica-absent").write_text("".join(f"{a}\n" for a in absent))
        if absent:
            print(f"{src.repo}: {len(absent)} files absent from the local copy: {', '.join(absent)}")
        stamp.write_text(src.commit + "\n")
        return target
    url = f"https://github.com/{src.repo}.git"
    print(f"{src.repo}: fetching {src.commit[:12]} from {url} ({', '.join(src.paths)})", flush=True)
    run("git", "init", "-q", cwd=target)
    run("git", "remote", "add", "origin", url, cwd=target)
    run("git", "config", "extensions.partialClone", "origin", cwd=target)
    run("git", "fetch", "-q", "--depth", "1", "--filter=blob:none", "origin", src.commit, cwd=target)
    run("git", "sparse-checkout", "set", "--no-cone", *[f"/{p}" for p in src.paths], cwd=target)
    run("git", "checkout", "-q", src.commit, cwd=target)
    got = run("git", "rev-parse", "HEAD", cwd=target).strip()
    if got != src.commit:
        raise SystemExit(f"fetch_mitsuba_scenes: {src.repo}: checked out {got}, expected {src.commit}")
    stamp.write_text(src.commit + "\n")
    return target


def licence_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*") if p.is_file() and p.name.upper().startswith(("LICENSE", "LICENCE",
                                                                                            "COPYING"))
                  and ".git" not in p.parts)


def write_sources(dest: Path, fetched: dict[Source, Path]) -> None:
    lines = ["# Where these scenes come from", "",
             "Fetched by caustica's scripts/fetch_mitsuba_scenes.py; not part of caustica. Each folder is a public "
             "repository at a pinned commit (only the listed paths are checked out).", ""]
    for src, folder in fetched.items():
        lines += [f"## {src.repo}", "", f"- commit: {src.commit}",
                  f"- https://github.com/{src.repo}/tree/{src.commit}",
                  f"- paths: {', '.join(src.paths)}", f"- folder: {folder.name}", f"- terms: {src.licence}"]
        for lic in licence_files(folder):
            lines.append(f"- licence file in the fetched paths: {lic.relative_to(dest)}")
        absent = folder / ".caustica-absent"
        if absent.is_file() and absent.read_text().strip():
            lines.append(f"- absent (the local copy it came from lacked them): "
                         f"{', '.join(absent.read_text().split())}")
        lines.append("")
    (dest / "SOURCES.md").write_text("\n".join(lines))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dest", type=Path, default=None,
                    help="where to put the scenes (out/mitsuba-corpus; with --independent out/mitsuba-independent)")
    ap.add_argument("--independent", action="store_true",
                    help="the scenes of other repositories, which the loader was not built on (INDEPENDENT)")
    ap.add_argument("--mirror-root", type=Path, default=None,
                    help="take <DIR>/<owner>+<name>/repo instead of github.com (offline)")
    args = ap.parse_args(argv)
    if args.dest is None:
        args.dest = Path("out/mitsuba-independent" if args.independent else "out/mitsuba-corpus")
    args.dest.mkdir(parents=True, exist_ok=True)
    fetched = {}
    for src in INDEPENDENT if args.independent else SOURCES:
        try:
            fetched[src] = fetch(src, args.dest, args.mirror_root)
        except subprocess.CalledProcessError as exc:
            print(f"fetch_mitsuba_scenes: {src.repo}: {' '.join(exc.cmd)} failed: {exc.stderr.strip()}",
                  file=sys.stderr)
            return 1
    write_sources(args.dest, fetched)
    print(f"done: {args.dest}/SOURCES.md lists the sources and their terms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
