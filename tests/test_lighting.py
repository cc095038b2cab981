"""Direct lighting of the photon methods: stratified shadow rays and the paper's fixed grid (SPEC §2)."""
from __future__ import annotations

import numpy as np
import pytest

import caustica
from caustica.lighting import direct_stratified
from caustica.sampling.rng import STREAM_DIRECT, path_key
from caustica.transport import ShadingPoint

UP = (0.0, 1.0, 0.0)


@pytest.fixture(scope="module")
def pyramid():
    return caustica.load_scene("cornell-pyramid", res=16)


def irradiance(scene, p, key, n, fixed):
    """E at floor point p (its shape: the floor's, in no medium), n x n strata, jittered by ``key``."""
    floor = int(scene.geometry.prim_shape[0])   # any shape: in a scene without media it changes nothing
    return np.array(direct_stratified(scene.tables, ShadingPoint(p, UP, UP, UP, floor, -1), np.uint64(key), 0,
                                      (n, fixed, -1), -1, None))


def test_fixed_grid_is_the_midpoint_rule_and_ignores_the_random_numbers(pyramid):
    p = (-6.0, 0.0, 6.0)  # on the floor, in front of the pyramid, lit by the whole light
    a = irradiance(pyramid, p, path_key(0, STREAM_DIRECT, 1), 5, True)
    b = irradiance(pyramid, p, path_key(7, STREAM_DIRECT, 2), 5, True)
    assert np.array_equal(a, b)
    # the same 25 points, summed here in numpy: L * A / 25 * sum cos_s cos_l / d^2
    lights = pyramid.lights
    c, e1, e2 = lights.corner[0], lights.edge1[0], lights.edge2[0]
    total = 0.0
    for i in range(5):
        for j in range(5):
            q = c + e1 * (i + 0.5) / 5 + e2 * (j + 0.5) / 5
            w = q - np.array(p)
            d2 = w @ w
            wn = w / np.sqrt(d2)
            total += wn[1] * (-(lights.normal[0] @ wn)) / d2
    expected = lights.radiance[0] * lights.area[0] / 25 * total
    np.testing.assert_allclose(a, expected, rtol=1e-12)


def test_jittered_strata_are_unbiased_against_a_fine_grid(pyramid):
    p = (-6.0, 0.0, 6.0)
    reference = irradiance(pyramid, p, 0, 200, True)[0]  # 40,000-point midpoint rule
    samples = np.array([irradiance(pyramid, p, path_key(3, STREAM_DIRECT, i), 5, False)[0] for i in range(400)])
    assert samples.std() > 0  # the jitter is really random
    # The mean of 400 independent stratified estimates is within 4 standard errors.
    assert abs(samples.mean() - reference) < 4 * samples.std(ddof=1) / np.sqrt(len(samples))


def test_fixed_grid_changes_the_rendered_image(pyramid):
    kw = dict(photons=2000, res=16, seed=3)
    jittered = caustica.render(pyramid, "pm", **kw).image
    fixed = caustica.render(pyramid, "pm", fixed_light_grid=True, **kw).image
    again = caustica.render(pyramid, "pm", fixed_light_grid=True, **kw).image
    assert not np.array_equal(jittered, fixed)
    assert np.array_equal(fixed, again)
