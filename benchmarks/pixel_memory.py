"""Measured memory per pixel of a render against the estimate that refuses a render too large for the machine.

    python benchmarks/pixel_memory.py [--res 96,192] [--threads 2] [--case N ...]

For each case (a method on a scene, with options) this renders twice at each of two sizes (the first to compile)
and takes the peak of the memory NumPy allocates (``tracemalloc``: NumPy's arrays are traced; Numba's own
allocations inside kernels are not) during the second.  The photon buffers do not scale with the pixels, so the
slope between the two sizes is the memory per pixel.  Next to it, the estimate per pixel the checks use:
``bytes_per_pixel`` (api.resolve_settings; a multi-pass render's film added), the camera pass's BSDF rows and medium
segments (the progressive methods' ``camera_pass_bytes``), and in media the one-shot methods' camera pass
(photon_common.check_media_settings).  A measured value above its estimate is marked UNDER.  No asserts.
"""
from __future__ import annotations

import argparse
import tracemalloc
from pathlib import Path

import caustica
from caustica.film import FILM_BYTES_PER_PIXEL, IMAGE_BYTES_PER_PIXEL
from caustica.methods.photon_common import MEDIA_PASS_BYTES
from caustica.photons.visible_points import camera_pass_bytes

PLASTIC = str(Path(__file__).resolve().parents[1] / "tests" / "scenes" / "plastic-caustic.xml")
FOG = "cornell-diacaustic-fog"
#: (method, scene, options): the caustic photons' own statistics on roughplastic keep whole BSDF rows.
CASES = (
    ("sppm", "cornell-diacaustic", dict(photons=2000)),
    ("sppm", PLASTIC, dict(photons=2000, caustic_photons=0)),
    ("sppm", PLASTIC, dict(photons=2000, caustic_photons=2000)),
    ("pspm", PLASTIC, dict(streams=500)),
    ("pspm", PLASTIC, dict(streams=500, caustic_photons=2000)),
    ("sppm", FOG, dict(photons=2000)),
    ("pspm", FOG, dict(streams=500)),
    ("pm", FOG, dict(photons=2000)),
    ("pm", FOG, dict(photons=2000, spp=4)),
    ("spm", FOG, dict(streams=500)),
    ("pm", PLASTIC, dict(photons=2000)),
)


def estimate_per_pixel(method, scene_name, kw) -> float:
    """What the checks count per pixel for this render (see the module's docstring)."""
    cls = caustica.methods.get(method)
    scene, cls, settings = caustica.api.resolve_settings(scene_name, method, multi_pass=cls.progressive,
                                                         **{k: v for k, v in kw.items() if k != "passes"})
    n = settings.width * settings.height
    per = getattr(cls, "bytes_per_pixel", IMAGE_BYTES_PER_PIXEL)
    if cls.progressive:
        per += FILM_BYTES_PER_PIXEL - 24
    if hasattr(cls, "camera_pass_bytes"):
        per += cls.camera_pass_bytes(scene, settings) / n
    elif scene.has_media:
        per += camera_pass_bytes(scene, bool(settings.get("caustic_photons"))) + MEDIA_PASS_BYTES
    return per


def peak_bytes(method, scene_name, kw) -> int:
    caustica.render(scene_name, method, **kw)   # compiles (or loads) the kernels
    tracemalloc.start()
    try:
        caustica.render(scene_name, method, **kw)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", default="96,192", help="two square sizes, comma-separated")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--case", type=int, nargs="*", help="indices into CASES (default: all)")
    a = ap.parse_args()
    sizes = [int(s) for s in a.res.split(",")]
    print(f"{'method':6s} {'scene':26s} {'options':44s} {'measured':>9s} {'estimate':>9s}  (bytes per pixel)")
    for i in a.case if a.case else range(len(CASES)):
        method, scene_name, options = CASES[i]
        kw = dict(options, seed=0, threads=a.threads)
        if caustica.methods.get(method).progressive:
            kw["passes"] = 2
        peaks = [peak_bytes(method, scene_name, dict(kw, res=s)) for s in sizes]
        measured = (peaks[1] - peaks[0]) / (sizes[1] ** 2 - sizes[0] ** 2)
        estimate = estimate_per_pixel(method, scene_name, dict(kw, res=sizes[1]))
        flag = "  UNDER" if measured > estimate else ""
        print(f"{method:6s} {Path(scene_name).name:26s} {str(options):44s} {measured:9.0f} {estimate:9.0f}{flag}",
              flush=True)


if __name__ == "__main__":
    main()
