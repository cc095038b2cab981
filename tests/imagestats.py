"""Statistics for comparing noisy renders: block means, their standard errors, agreement checks.

Shared by the tests of every Monte Carlo method (tests/test_pt.py explains how the
tolerances were derived and checked).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from caustica.imageio import read_exr

N_SIGMA = 5.0
BLOCK = 4                     # 4x4-pixel blocks: an 8x8 grid of block means at 32x32


def block_means(img, b=BLOCK):
    h, w = img.shape[:2]
    return img.reshape(h // b, b, w // b, b, -1).mean(axis=(1, 3))


def pixel_var_of_mean(images):
    """Per pixel, the variance of the mean of K independent renders: sample variance / K."""
    stack = np.stack(images).astype(np.float64)
    if len(stack) == 1:
        return np.zeros(stack.shape[1:])
    return stack.var(axis=0, ddof=1) / len(stack)


def block_se(images, b=BLOCK):
    """Standard error of the block means of the mean of K independent renders.

    A block mean of n pixels has 1/n² of the sum of its pixels' variances, each estimated
    from the K renders (K - 1 degrees of freedom per pixel, n (K - 1) per block).

    Path-traced caustics make the noise heavy-tailed (rare paths that reach the light through
    glass), so a few renders of one block often agree by luck.  Measured on
    cornell-diacaustic at 32x32 (against the converged reference, which a 16-seed x 1024-spp
    caustica render matches: no bias) the per-block estimate alone let the mean of 2 or 4
    renders sit 9-20 "sigmas" off in some block.  The noise level varies smoothly over the
    image, so the relative variance is also pooled over the 3x3 neighbouring blocks and the
    larger of the two estimates is used: with 4 renders the largest deviation over 192
    block values then stayed within 2.2-3.6 sigmas in 8 independent trials (2 renders: up
    to 6.5, hence 4).
    """
    h, w = images[0].shape[0] // b, images[0].shape[1] // b
    se = np.sqrt(pixel_var_of_mean(images).reshape(h, b, w, b, -1).sum(axis=(1, 3))) / (b * b)
    m = np.abs(block_means(np.mean(np.stack(images).astype(np.float64), axis=0), b))
    rel2 = np.where(m > 0, se ** 2 / np.where(m > 0, m, 1.0) ** 2, 0.0)
    pad = np.pad(rel2, ((1, 1), (1, 1), (0, 0)), mode="edge")
    pooled = sum(pad[i:i + h, j:j + w] for i in range(3) for j in range(3)) / 9.0
    return np.maximum(se, np.sqrt(pooled) * m)


def assert_images_agree(a_images, b_images, extra_se=0.0, label=""):
    """Image mean within 2 %, block means within noise.

    a_images, b_images: independent renders (seeds) of each image; their means are compared.
    Each side's block standard error comes from its own renders (block_se); the difference
    of the two sides' block means has the combined standard error
    sqrt(se_a² + se_b² + extra_se²).  Allowed: 5 of those sigmas plus an absolute floor of
    0.2 % of the image mean (float32, and blocks whose noise happens to be near zero, e.g. the
    green channel of the red wall).
    """
    a = np.mean(np.stack(a_images).astype(np.float64), axis=0)
    b = np.mean(np.stack(b_images).astype(np.float64), axis=0)
    mean_a, mean_b = a.mean(), b.mean()
    assert abs(mean_a - mean_b) <= 0.02 * mean_b, f"{label}: image mean {mean_a:.5f} vs {mean_b:.5f}"
    ba, bb = block_means(a), block_means(b)
    se = np.sqrt(block_se(a_images) ** 2 + block_se(b_images) ** 2 + np.asarray(extra_se) ** 2)
    tol = N_SIGMA * se + 0.002 * mean_b
    z = np.abs(ba - bb) / tol
    worst = np.unravel_index(np.argmax(z), z.shape)
    assert np.all(z <= 1.0), (f"{label}: block {worst[:2]} channel {worst[2]}: {ba[worst]:.5f} vs {bb[worst]:.5f} "
                              f"(tolerance {tol[worst]:.5f}, sigma {se[worst]:.5f}); "
                              f"{int(np.sum(z > 1))} of {z.size} block values outside")


def downsample(img, factor):
    h, w = img.shape[:2]
    return img.reshape(h // factor, factor, w // factor, factor, *img.shape[2:]).mean(axis=(1, 3))


def load_reference(refs_dir, name):
    exr = refs_dir / f"{name}_256.exr"
    if not exr.is_file():
        pytest.skip(f"reference {exr} missing")
    ref = read_exr(exr).astype(np.float64)
    meta = json.loads((refs_dir / f"{name}_256.json").read_text())
    return ref, meta


def mitsuba_path_and_ptracer(mi, path, seeds, files=()):
    """The XML scene at ``path`` rendered by Mitsuba 3 twice per seed: its path integrator (256 spp), which like
    caustica's pt misses the caustics of delta lights (a point, spot or projector seen through a mirror), and its
    ptracer (1024 spp, 32 px), which like the photon methods renders them.  ``files``: names the scene gives
    relative to its folder (the ptracer's copy is loaded from a string).  Returns (path images, ptracer images)."""
    scene = mi.load_file(str(path), spp=256)
    path_images = [np.array(mi.render(scene, spp=256, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    text = path.read_text().replace('<integrator type="path"/>', '<integrator type="ptracer"/>')
    for name in files:
        text = text.replace(f'value="{name}"', f'value="{path.parent / name}"')
    scene = mi.load_string(text.replace('value="$spp"', 'value="1024"').replace('value="$res"', 'value="32"'))
    ptracer_images = [np.array(mi.render(scene, spp=1024, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    return path_images, ptracer_images
