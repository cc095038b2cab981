"""The caustic region of a scene: the pixels lit by concentrated light from the mirror or glass.

How (docs/experiments.md): ``pm``'s caustic pass shoots ``photons`` photons at the
specular objects' bounding spheres and keeps the light -> specular+ -> diffuse
records (its caustic map), with random numbers of their own
(``STREAM_CAUSTIC_MASK``): for the same seed they are independent of the caustic
photons of every render, so PM+C is never judged on a region drawn from its own
photons (and their noise).  Every record the camera sees is splatted into the pixel
it projects to (``photon_view.splat_records``: occlusion-tested), the splat image is
blurred by a small box (3 x 3 at 512 px, scaled with the image) to average out
photon noise, and the pixels whose caustic power is at least ``threshold`` (default
0.1) times the 99.9th percentile of the non-empty pixels form the mask, dilated by
one pixel.  So the mask is where the caustic is bright, not everywhere a refracted
photon happens to land.  A scene without mirrors or glass gets an empty mask.
"""
from __future__ import annotations

import numpy as np

from ..api import resolve_settings
from ..sampling.rng import STREAM_CAUSTIC_MASK


def _box_blur(img: np.ndarray, r: int) -> np.ndarray:
    if r <= 0:
        return img
    pad = np.pad(img, r, mode="edge")
    c = np.cumsum(np.cumsum(pad, axis=0), axis=1)
    c = np.pad(c, ((1, 0), (1, 0)))
    n = 2 * r + 1
    h, w = img.shape
    s = c[n:n + h, n:n + w] - c[:h, n:n + w] - c[n:n + h, :w] + c[:h, :w]
    return s / (n * n)


def _dilate(mask: np.ndarray, r: int) -> np.ndarray:
    out = mask.copy()
    h, w = mask.shape
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            src = mask[max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)]
            out[max(0, dy):h - max(0, -dy), max(0, dx):w - max(0, -dx)] |= src
    return out


def caustic_density(scene, width: int, height: int, *, photons: int = 200_000, seed: int = 0,
                    threads: int | None = None) -> np.ndarray:
    """Caustic-map power splatted into the camera's pixels (H x W, summed over RGB).

    The photons are ``pm``'s caustic photons (``trace_caustic_photon_pass``) keyed by
    (seed, ``STREAM_CAUSTIC_MASK``, index), never by PM+C's ``STREAM_CAUSTIC_PHOTON``.
    """
    from ..photon_view import splat_records
    from ..photons.records import CAUSTIC, allocate_buffers
    from ..photons.trace import trace_caustic_photon_pass
    scene, _cls, settings = resolve_settings(scene, "pm", res=(width, height), seed=seed, threads=threads,
                                            photons=1, caustic_photons=photons)
    img = np.zeros((height, width, 3), np.float64)
    spheres = scene.specular_bounding_spheres()
    if photons <= 0 or spheres.shape[0] == 0:
        return img.sum(axis=2)
    buf = allocate_buffers(photons, 1)
    trace_caustic_photon_pass(scene, buf, seed, STREAM_CAUSTIC_MASK, photons, spheres=spheres,
                              threads=settings.threads)
    keep = buf.kind == CAUSTIC
    if keep.any():
        splat_records(scene.geometry, scene.materials, scene.camera(width, height),
                      np.ascontiguousarray(buf.position[keep]),
                      np.ascontiguousarray(buf.power[keep]), img)
    return img.sum(axis=2)


def caustic_mask(scene, width: int, height: int, *, photons: int = 200_000, threshold: float = 0.1,
                 seed: int = 0, threads: int | None = None) -> np.ndarray:
    """Boolean H x W mask of the caustic region (see the module's docstring)."""
    dens = caustic_density(scene, width, height, photons=photons, seed=seed, threads=threads)
    r = max(1, min(width, height) // 256)
    smooth = _box_blur(dens, r)
    nz = smooth[smooth > 0]
    if nz.size == 0:
        return np.zeros((height, width), bool)
    level = threshold * np.percentile(nz, 99.9)
    return _dilate(smooth >= level, 1)
