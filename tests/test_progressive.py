"""Progressive rendering: the pass driver, the film, checkpoints, sppm and pspm (SPEC §7).

1. Pieces: the grid's fixed-radius query against brute force; the film's pass order.
2. Migration: a one-pass render is the one-shot render, bit for bit; passes of pt average.
3. Analytic answers: a point light over a plane (direct light only: no photon is stored)
   and a white furnace inside a sphere, where the fixed-radius density estimate of a
   uniform photon density is exact for any radius (a sphere's cap within chord distance
   R has area π R²), so SPPM's only error there is noise.
4. Agreement with the converged Mitsuba reference on the diacaustic scene after many passes.
5. Determinism: the same bits for any thread count; N passes == a passes, checkpoint,
   resume for N - a.
6. Bad input and interrupts.

Tolerances come from the spread of independent renders (seeds), as in tests/test_pt.py.
"""
from __future__ import annotations

import math
import types

import numpy as np
import pytest

import caustica
from caustica import driver
from caustica.errors import ParameterError
from caustica.film import Film
from caustica.photons.density_filters import FILTERS
from caustica.photons.grid import build_grid, grid_range_sum
from caustica.photons.kdtree import FACING_COS
from caustica.photons.visible_points import camera_pass
from caustica.sampling.rng import KRONECKER_ALPHA, kronecker, sobol02
from caustica.scene import builtin_scene_path
from imagestats import N_SIGMA, assert_images_agree, downsample, load_reference
from test_pt import FURNACE_LE, FURNACE_RHO, PLANE_RHO, AH, AW, CAM_H, FOV_X, LIGHT_H, furnace_scene, \
    pixel_footprints, plane_scene

PROGRESSIVE = ("sppm", "pspm")


@pytest.fixture(scope="module")
def diacaustic():
    return caustica.load_scene(builtin_scene_path("cornell-diacaustic"))


# --------------------------------------------------------------------------- 1. pieces

@pytest.mark.parametrize("n", [5000, 3, 0])
def test_grid_range_sum_matches_brute_force(n):
    """Also where many cells share a bucket (cell 0.05: 10^6 cells, 2^14 buckets for 5000 events)
    and where a column is longer than the buckets (a few events: a few buckets).  With a visible point's BSDF (a
    diffuse one, f = rho / pi towards the side of its normal, 0 below) each event's power is weighted by f at the
    event's direction, which the grid keeps then."""
    from caustica.bsdfs import build_material_table
    from caustica.geometry.scene_geometry import NO_UV
    from caustica.scene.description import DIFFUSE, Material
    rho = np.array([0.5, 0.4, 0.3])
    mats = build_material_table(types.SimpleNamespace(materials=[Material(DIFFUSE, tuple(rho))]))
    rng = np.random.default_rng(1)
    pos = rng.uniform(-2, 3, (n, 3)).astype(np.float32)
    nrm = rng.normal(size=(n, 3))
    nrm = (nrm / np.linalg.norm(nrm, axis=1, keepdims=True)).astype(np.float32)
    direction = rng.normal(size=(n, 3))
    direction = (direction / np.linalg.norm(direction, axis=1, keepdims=True)).astype(np.float32)
    power = rng.uniform(0, 1, (n, 3)).astype(np.float32)
    valid = (rng.uniform(size=n) < 0.8).astype(np.int8)
    box = np.array([-2.0, -2.0, -2.0, 3.0, 3.0, 3.0])
    for cell in (0.05, 0.3, 2.0):
        grid, _ = build_grid(pos, power, nrm, valid, box, cell)
        weighted, _ = build_grid(pos, power, nrm, valid, box, cell, direction)
        assert grid.count == valid.sum() and grid.direction.shape == (0, 3)
        for _ in range(40):
            q = rng.uniform(-2.5, 3.5, 3)
            qn = rng.normal(size=3)
            qn /= np.linalg.norm(qn)
            r = float(rng.uniform(0.01, 1.5))
            d2 = ((pos.astype(np.float64) - q) ** 2).sum(axis=1)
            take = (valid == 1) & (d2 <= r * r) & (nrm.astype(np.float64) @ qn > FACING_COS)
            n_q = (qn[0], qn[1], qn[2])
            count, s = grid_range_sum(grid, (q[0], q[1], q[2]), n_q, r, None, None)
            assert count == take.sum()
            np.testing.assert_allclose(s, power[take].astype(np.float64).sum(axis=0), rtol=1e-9, atol=1e-9)
            d = (-qn[0], -qn[1], -qn[2])   # the camera path arriving straight down the normal
            count, s = grid_range_sum(weighted, (q[0], q[1], q[2]), n_q, r, (mats, 0, d, n_q, n_q, NO_UV), None)
            lit = take & (direction.astype(np.float64) @ qn < 0.0)   # arriving from the normal's side
            assert count == take.sum()
            np.testing.assert_allclose(s, power[lit].astype(np.float64).sum(axis=0) * rho / math.pi, rtol=1e-6,
                                       atol=1e-9)
            # a filter weighs each event by its shape at d (mean 1 over the disc); the count stays the events'
            for name, shape in FILTER_SHAPES.items():
                w = shape(np.minimum(d2 / (r * r), 1.0))[:, None]
                count, s = grid_range_sum(grid, (q[0], q[1], q[2]), n_q, r, None, None, FILTERS[name])
                assert count == take.sum()
                np.testing.assert_allclose(s, (power[take] * w[take]).sum(axis=0), rtol=1e-6, atol=1e-9)
                count, s = grid_range_sum(weighted, (q[0], q[1], q[2]), n_q, r, (mats, 0, d, n_q, n_q, NO_UV), None,
                                          FILTERS[name])
                assert count == take.sum()
                np.testing.assert_allclose(s, (power[lit] * w[lit]).sum(axis=0) * rho / math.pi, rtol=1e-6,
                                           atol=1e-9)


#: Each filter's shape π r² W(d, r) as a function of s = d² / r², written out here apart from the kernels
#: (caustica.photons.density_filters); the Gaussian's normalisation α makes it integrate to π r².
_GB = 1.953
_GA = 1.0 / (1.0 - (1.0 - (2.0 / _GB) * (1.0 - math.exp(-_GB / 2.0))) / (1.0 - math.exp(-_GB)))
FILTER_SHAPES = {"none": lambda s: np.ones_like(s), "cone": lambda s: 3.0 * (1.0 - np.sqrt(s)),
                 "epanechnikov": lambda s: 2.0 * (1.0 - s),
                 "gaussian": lambda s: _GA * (1.0 - (1.0 - np.exp(-_GB * s / 2.0)) / (1.0 - math.exp(-_GB)))}


def test_filtered_grid_sums_are_unbiased_for_a_uniform_density():
    """Photons of a Poisson process on a plane, density λ, power φ: within a fixed r every filter's Σ shape(d) φ is
    unbiased for λ φ π r² (Campbell's theorem, the shape's mean over the disc being 1), with variance
    λ φ² ∫ shape² dA.  60 discs apart from each other: the mean of their standardised errors within 5 / sqrt(60), a
    band of about 2 % of the sum (a filter's normalisation off by more would show)."""
    rng = np.random.default_rng(5)
    lam, r = 200_000.0, 0.05                                     # ≈ 1,571 photons a disc
    n = rng.poisson(lam * 4.0)
    pos = np.zeros((n, 3), np.float32)
    pos[:, :2] = rng.uniform(-1.0, 1.0, (n, 2))
    nrm = np.tile(np.float32([0.0, 0.0, 1.0]), (n, 1))
    power = np.ones((n, 3), np.float32)
    grid, _ = build_grid(pos, power, nrm, np.ones(n, np.int8), np.array([-1.0, -1.0, -1.0, 1.0, 1.0, 1.0]), 0.1)
    queries = [(x, y) for x in np.linspace(-0.85, 0.85, 10) for y in np.linspace(-0.8, 0.8, 6)]
    s_mid = (np.arange(20_000) + 0.5) / 20_000                        # midpoints in s = d² / r²
    for name, shape in FILTER_SHAPES.items():
        second = float(np.mean(shape(s_mid) ** 2))                    # ∫ shape² dA / (π r²), dA = π r² ds
        sigma = math.sqrt(lam * math.pi * r * r * second)
        z = [(grid_range_sum(grid, (x, y, 0.0), (0.0, 0.0, 1.0), r, None, None, FILTERS[name])[1][0]
              - lam * math.pi * r * r) / sigma for x, y in queries]
        assert max(abs(v) for v in z) < 5.0, (name, z)
        assert abs(np.mean(z)) < 5.0 / math.sqrt(len(z)), (name, np.mean(z))


@pytest.mark.parametrize("key", [0, 1, 0x9E3779B97F4A7C15, 2**64 - 1])
def test_sobol02_prefixes_are_nets_whatever_the_shift(key):
    """The first 2^m points of the shifted Sobol' (0, 2)-sequence put one point in each elementary
    box of every shape 2^-a x 2^-(m-a): the digital shift keeps the net property."""
    pts = np.array([sobol02(i, np.uint64(key)) for i in range(256)])
    assert np.all((pts >= 0) & (pts < 1))
    for m in range(9):
        for a in range(m + 1):
            cx = np.floor(pts[:2 ** m, 0] * 2 ** a).astype(int)
            cy = np.floor(pts[:2 ** m, 1] * 2 ** (m - a)).astype(int)
            assert len(set(zip(cx, cy))) == 2 ** m, (m, a)


def camera_settings(width, height, seed, light_samples=1, max_specular_depth=64):
    """sppm's settings with these values, the rest defaults (what camera_pass reads of a render's)."""
    from caustica.methods.params import COMMON_PARAMS, resolve
    return resolve("sppm", tuple(caustica.methods.get("sppm").params) + COMMON_PARAMS,
                   {"width": width, "height": height, "seed": seed, "threads": 1, "light_samples": light_samples,
                    "fixed_light_grid": False, "max_specular_depth": max_specular_depth})


def test_sobol02_and_kronecker_points_are_uniform_over_shifts():
    """Each single point is uniform over the random shifts: a pass alone is an unbiased sample."""
    keys = np.arange(4000, dtype=np.uint64) * np.uint64(0x2545F4914F6CDD1D)
    rng = np.random.default_rng(5)
    for index in (0, 1, 7, 1000):
        u = np.array([sobol02(index, k) for k in keys])
        v = np.array([kronecker(index, KRONECKER_ALPHA[0], s) for s in rng.uniform(size=4000)])
        for x in (u[:, 0], u[:, 1], v):
            counts = np.histogram(x, bins=8, range=(0, 1))[0]
            chi2 = float(((counts - 500.0) ** 2 / 500.0).sum())
            assert chi2 < 30.0, (index, counts)   # 7 degrees of freedom: p < 1e-4


def test_kronecker_points_over_passes_are_evenly_spread():
    """frac(s + k alpha) for k < n: the share below any F is within 10/n of F (independent
    numbers stray by about sqrt(F (1 - F) / n), 1/32 at n = 256), for every generator and shift."""
    rng = np.random.default_rng(2)
    f = np.linspace(0, 1, 65)
    for alpha in KRONECKER_ALPHA:
        for shift in rng.uniform(size=20):
            for n in (16, 64, 256):
                x = np.array([kronecker(k, alpha, shift) for k in range(n)])
                assert np.max(np.abs((x[None, :] < f[:, None]).mean(axis=1) - f)) <= 10.0 / n


def test_film_adds_passes_in_its_tree():
    rng = np.random.default_rng(0)
    a, b, c = (rng.uniform(size=(2, 3, 3)).astype(np.float32) for _ in range(3))
    film = Film.empty(3, 2).add(0, a)
    assert film.image().tobytes() == a.tobytes()     # one pass: that pass's own bits
    with pytest.raises(ValueError, match="out of order"):
        film.add(2, b)
    film = film.add(1, b).add(2, c)
    # pairwise: (a + b) is the block of passes [0, 2), then pass 2 is added to it
    np.testing.assert_array_equal(film.image(), (((a.astype(np.float64) + b) + c) / 3).astype(np.float32))
    again = Film.from_arrays(film.to_arrays())
    assert again.passes == 3 and again.image().tobytes() == film.image().tobytes()


@pytest.mark.parametrize("seed", range(4))
def test_film_parts_merge_to_the_bits_of_passes_added_one_by_one(seed):
    """Any split of [0, P) into consecutive parts, as a cluster's tasks make, gives the same bits."""
    from caustica.film import TRUNK_PASSES
    rng = np.random.default_rng(seed)
    P = 2 * TRUNK_PASSES + 37                        # through the trunk and past it
    images = [(rng.uniform(size=(2, 3, 3)) * 10.0 ** rng.uniform(-6, 6)).astype(np.float32) for _ in range(P)]
    whole = Film.empty(3, 2)
    for p, im in enumerate(images):
        whole = whole.add(p, im)
    assert whole.trunk is not None and len(whole.blocks) == bin(37).count("1")
    merged, at = Film.empty(3, 2), 0
    while at < P:
        part = Film.part(3, 2, at)
        for p in range(at, min(P, at + int(rng.integers(1, 90)))):
            part = part.add(p, images[p])
        merged, at = merged.merge(part), part.end
    assert merged.image().tobytes() == whole.image().tobytes()
    assert Film.from_arrays(merged.to_arrays()).image().tobytes() == whole.image().tobytes()
    with pytest.raises(ValueError, match="out of order"):
        merged.merge(Film.part(3, 2, P + 1))


def test_film_refuses_a_damaged_structure():
    film = Film.empty(1, 1)
    for p in range(5):
        film = film.add(p, np.ones((1, 1, 3), np.float32))
    arrays = film.to_arrays()
    arrays["film_blocks"] = np.asarray([[0, 2], [2, 2], [4, 1]])    # [0, 4) must be one block
    arrays["film_block_2"] = arrays["film_block_1"]
    arrays["film_block_1"] = arrays["film_block_0"]
    with pytest.raises(ValueError, match="tree"):
        Film.from_arrays(arrays)


# --------------------------------------------------------------------------- 2. migration

def test_one_pass_of_pt_is_the_one_shot_render(diacaustic):
    one_shot = caustica.render(diacaustic, "pt", spp=4, res=16, seed=3).image
    one_pass = caustica.render(diacaustic, "pt", spp=4, res=16, seed=3, passes=1).image
    assert one_shot.tobytes() == one_pass.tobytes()


def test_pt_passes_are_new_samples_and_average(diacaustic):
    r = caustica.render(diacaustic, "pt", res=16, seed=3, passes=3, spp=2)
    assert r.stats["passes"] == 3 and r.stats["samples_per_pixel"] == 6
    first = caustica.render(diacaustic, "pt", spp=2, res=16, seed=3).image
    assert first.tobytes() != r.image.tobytes()
    # pass 0 of the multi-pass render is the one-shot render; the mean of three passes is smoother
    assert np.mean(np.abs(r.image - first)) > 0
    assert r.stats["camera_rays"] == 3 * 2 * 16 * 16


# --------------------------------------------------------------------------- 3. analytic answers

@pytest.mark.parametrize("method, params", [("sppm", {}), ("pspm", {}), ("sppm", {"schedule": "global"})])
def test_point_light_over_plane(method, params):
    """Direct light only: photons never scatter, so nothing is stored and every pass's
    visible point adds ρ/π I cos θ / d²; the only randomness is the sub-pixel jitter."""
    intensity = np.array([10.0, 20.0, 30.0])
    passes = 64
    scene = plane_scene(f"""<emitter type="point"><point name="position" x="0" y="0" z="{LIGHT_H}"/>
        <rgb name="intensity" value="{', '.join(map(str, intensity))}"/></emitter>""")
    r = caustica.render(scene, method, seed=3, passes=passes, **params)
    assert r.stats["events_stored"] == 0
    x, y = pixel_footprints(AW, AH, FOV_X, CAM_H)
    f = LIGHT_H / (x * x + y * y + LIGHT_H ** 2) ** 1.5
    scale = intensity * np.asarray(PLANE_RHO) / math.pi
    expected = f.mean(axis=2)[..., None] * scale
    tol = (N_SIGMA * f.std(axis=2) / math.sqrt(passes))[..., None] * scale + 1e-4 * expected
    img = r.image.astype(np.float64)
    assert np.all(np.abs(img - expected) <= tol), np.max(np.abs(img - expected) / tol)


def test_camera_pass_stratifies_each_pixel_over_the_passes():
    """Over 16 passes a pixel's visible points on a plane facing the camera fall one in each of the
    4 x 4 (and 2 x 8, 8 x 2, 1 x 16) sub-pixel cells: the jitter is a (0, 4, 2)-net over the passes."""
    scene = plane_scene(f"""<emitter type="point"><point name="position" x="0" y="0" z="{LIGHT_H}"/>
        <rgb name="intensity" value="1, 1, 1"/></emitter>""")
    n = AW * AH
    tan_x = math.tan(math.radians(FOV_X) / 2)
    tan_y = tan_x * AH / AW
    offsets = []
    for p in range(16):
        pos, nrm, w, found, direct = camera_pass(scene, camera_settings(AW, AH, 11), p)[0][:5]
        assert found.all()
        # film coordinates of the visible point (the inverse of tests/test_pt.py's pixel_footprints)
        fx = (1 - pos[:, 0] / (CAM_H * tan_x)) / 2 * AW
        fy = (1 - pos[:, 1] / (CAM_H * tan_y)) / 2 * AH
        col = np.arange(n) % AW
        row = np.arange(n) // AW
        # the camera's handedness may mirror x or y: fold the film coordinate into the pixel
        ux = np.where(np.abs(fx - col - 0.5) <= 0.5, fx - col, (AW - fx) - col)
        uy = np.where(np.abs(fy - row - 0.5) <= 0.5, fy - row, (AH - fy) - row)
        assert np.all((ux > -1e-9) & (ux < 1 + 1e-9) & (uy > -1e-9) & (uy < 1 + 1e-9))
        offsets.append(np.stack([ux, uy], axis=1))
    offsets = np.clip(np.array(offsets), 0, 1 - 1e-12)    # (pass, pixel, 2)
    for a in range(5):
        cells = np.floor(offsets[..., 0] * 2 ** a) * 2 ** (4 - a) + np.floor(offsets[..., 1] * 2 ** (4 - a))
        for i in range(n):
            assert len(set(cells[:, i].tolist())) == 16, (a, i)


def test_stratified_passes_beat_independent_jitter_on_smooth_light():
    """Direct light from a point light is smooth over a pixel: with the jitter stratified over the
    passes, 64 passes leave an error far below the independent-jitter standard error."""
    intensity = np.array([10.0, 20.0, 30.0])
    passes = 64
    scene = plane_scene(f"""<emitter type="point"><point name="position" x="0" y="0" z="{LIGHT_H}"/>
        <rgb name="intensity" value="{', '.join(map(str, intensity))}"/></emitter>""")
    r = caustica.render(scene, "sppm", seed=4, passes=passes)
    x, y = pixel_footprints(AW, AH, FOV_X, CAM_H)
    f = LIGHT_H / (x * x + y * y + LIGHT_H ** 2) ** 1.5
    scale = intensity * np.asarray(PLANE_RHO) / math.pi
    expected = f.mean(axis=2)[..., None] * scale
    independent_se = (f.std(axis=2) / math.sqrt(passes))[..., None] * scale
    err = r.image.astype(np.float64) - expected
    assert np.sqrt(np.mean(err ** 2)) <= 0.25 * np.sqrt(np.mean(independent_se ** 2))


def test_camera_pass_adds_a_light_seen_in_glass_with_its_fresnel_weight():
    """A camera ray meets glass at 45 degrees and its reflection meets an area light: every pass adds
    F Le (the light's expected share), instead of Le in a fraction F of the passes and 0 in the rest."""
    from test_pt import scene_from_xml, sensor_xml
    from caustica.bsdfs.optics import fresnel_dielectric
    le = np.array([2.0, 3.0, 4.0])
    scene = scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0, -2, 2), (0, 0, 0), (0, 0, 1), 0.01, 1, 1)}
        <shape type="rectangle">
            <transform name="to_world"><scale value="5"/></transform>
            <bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1"/></bsdf>
        </shape>
        <shape type="rectangle">
            <transform name="to_world"><scale value="3"/><rotate x="1" angle="135"/><translate y="3" z="3"/></transform>
            <emitter type="area"><rgb name="radiance" value="{', '.join(map(str, le))}"/></emitter>
        </shape>
    </scene>""")
    F, _ = fresnel_dielectric(math.cos(math.pi / 4), 1.5)
    assert 0.05 < F < 0.2
    for p in range(24):
        out, _, _ = camera_pass(scene, camera_settings(1, 1, 7), p)
        # (the refracted ray escapes; the reflected one, when chosen, ends on the light's own diffuse
        # surface, which the light does not light: either way the light's share is all there is)
        np.testing.assert_allclose(out[4][0], F * le, rtol=1e-3)   # the 0.01 degree pixel moves F a little


FURNACE_CASES = [("sppm", {}), ("pspm", {}), ("pspm", {"estimator": "photons"}), ("pspm", {"specular": "split"}),
                 ("sppm", {"schedule": "global"}), ("pspm", {"schedule": "global"})]


@pytest.mark.parametrize("termination", ["cap", "roulette"])
@pytest.mark.parametrize("method, params", FURNACE_CASES)
def test_white_furnace_in_a_sphere(method, params, termination):
    """Every pixel sees Le, direct light ρ Le and photons stored after 1 .. mr bounces:
    L = Le Σ_{k=0}^{mr+1} ρ^k with the paper's cap (mr = 4), and Le / (1 - ρ) with roulette
    and mr = 64 (ρ^65 < 1e-6).  The estimate of a uniform density within R on the sphere is
    exact, so the error is noise, measured over 6 seeds (pixels share photons, so the seeds,
    not the pixels, are the independent samples)."""
    scene = furnace_scene("sphere")
    mr = 4 if termination == "cap" else 64
    count = dict(photons=2000) if method == "sppm" else dict(streams=400, assoc=4, stream_radius=0.5)
    means = np.array([caustica.render(scene, method, res=8, seed=s, passes=6, termination=termination,
                                      max_bounces=mr, radius=0.3, **count, **params).image.reshape(-1, 3).mean(0)
                      for s in range(6)], dtype=np.float64)
    expected = FURNACE_LE * (1 - FURNACE_RHO ** (mr + 2)) / (1 - FURNACE_RHO)
    se = means.std(axis=0, ddof=1) / math.sqrt(len(means))
    got = means.mean(axis=0)
    assert np.all(se > 0)
    assert np.all(np.abs(got - expected) <= N_SIGMA * se + 1e-4 * expected), (got, expected, se)


@pytest.mark.parametrize("statistics, caustic_filter", [("separate", "none"), ("shared", "none"),
                                                         ("separate", "epanechnikov"), ("separate", "cone")])
def test_sppm_caustic_photons_keep_the_image_unbiased(diacaustic, statistics, caustic_filter):
    """Aimed caustic photons replace the global photons' light -> specular -> diffuse paths, with
    the aiming pdf in their power: the image mean stays PM's (5 sigma of the seeds' spread), whether
    they are gathered into statistics of their own or into the others', and whatever filter weighs them."""
    kw = dict(res=16, passes=4, photons=4000, radius=1.0)
    plain = np.array([caustica.render(diacaustic, "sppm", seed=s, **kw).image.mean() for s in range(6)])
    aimed = np.array([caustica.render(diacaustic, "sppm", seed=s, caustic_photons=4000, caustic_filter=caustic_filter,
                                      caustic_statistics=statistics, **kw).image.mean() for s in range(6)])
    se = math.sqrt(plain.var(ddof=1) / 6 + aimed.var(ddof=1) / 6)
    assert abs(plain.mean() - aimed.mean()) <= N_SIGMA * se, (plain.mean(), aimed.mean(), se)


def test_pspm_caustic_photons_keep_the_image_unbiased(diacaustic):
    """pspm --caustic-photons: the streams leave their light -> specular -> diffuse records out and
    the aimed photons carry them: the image mean stays plain pspm's (5 sigma of the seeds' spread)."""
    kw = dict(res=16, passes=4, streams=800, radius=1.0)
    plain = np.array([caustica.render(diacaustic, "pspm", seed=s, **kw).image.mean() for s in range(6)])
    aimed = np.array([caustica.render(diacaustic, "pspm", seed=s, caustic_photons=4000, **kw).image.mean()
                      for s in range(6)])
    se = math.sqrt(plain.var(ddof=1) / 6 + aimed.var(ddof=1) / 6)
    assert abs(plain.mean() - aimed.mean()) <= N_SIGMA * se, (plain.mean(), aimed.mean(), se)


def test_the_stream_records_pspm_leaves_out_carry_the_caustic_photons_flux(diacaustic):
    """The records marked 2 (light -> specular+ -> diffuse, which --caustic-photons leaves to the aimed
    photons) and the aimed photons' events estimate the same caustic flux: totals agree within 5 sigma
    (per-path spreads), and no other record of a stream is left out."""
    from caustica.photons.records import CAUSTIC, allocate_buffers
    from caustica.photons.streams import StreamBuffers, trace_stream_pass
    from caustica.photons.trace import TERMINATION_CAP, trace_caustic_photon_pass
    s, n, mr = diacaustic, 40_000, 4
    buf = StreamBuffers(n, 10, mr)
    trace_stream_pass(s, buf, 3, 11, n, 10, 5.0, mr, TERMINATION_CAP)
    energy, valid = buf.rec[5].astype(np.float64), buf.rec[7]
    per_stream = np.where((valid == 2)[:, None], energy, 0.0).reshape(n, mr + 1, 3).sum(axis=(1, 2))
    cb = allocate_buffers(n, 1)
    trace_caustic_photon_pass(s, cb, 3, 12, n)
    per_photon = np.where((cb.kind == CAUSTIC)[:, None], cb.power.astype(np.float64), 0.0).sum(axis=1)
    a, b = per_stream.sum(), per_photon.sum()
    se = math.sqrt(n * per_stream.var() + n * per_photon.var())
    assert a > 0 and abs(a - b) <= N_SIGMA * se, (a, b, se)
    kept = buf.events("stream", leave_caustics=True)[0].shape[0]
    assert kept == int((valid == 1).sum()) and kept + int((valid == 2).sum()) == buf.events("stream")[0].shape[0]


def test_separate_caustic_statistics_split_the_shared_ones(diacaustic):
    """One pass from the same initial radius: the separate caustic statistics hold exactly the
    caustic photons' events and the others the rest, so N_global + N_caustic is the shared N,
    and the global radius shrinks only where non-caustic events were gathered (the uniform disc; the caustic filter
    reweighs tau_c alone: the counts, radii and the other statistics stay as they are)."""
    from caustica.api import resolve_settings
    kw = dict(res=24, seed=3, multi_pass=True, photons=3000, caustic_photons=3000, radius=0.8)
    states = {}
    for mode, filt in (("shared", "none"), ("separate", "none"), ("separate", "epanechnikov")):
        scene, cls, settings = resolve_settings(diacaustic, "sppm", caustic_statistics=mode, caustic_radius=0.8,
                                                caustic_filter=filt, **kw)
        states[mode, filt], _ = cls.run_pass(scene, settings, cls.new_state(scene, settings), lambda **k: _NoBar())
    shared, sep, filtered = states["shared", "none"], states["separate", "none"], states["separate", "epanechnikov"]
    for name in ("n_photons", "radius", "tau", "n_caustic", "radius_caustic", "gathered"):
        assert np.array_equal(getattr(filtered, name), getattr(sep, name)), name
    assert not np.array_equal(filtered.tau_caustic, sep.tau_caustic)
    assert np.array_equal(filtered.tau_caustic == 0, sep.tau_caustic == 0)
    assert np.all(shared.n_caustic == 0) and np.all(shared.radius_caustic == 0.8)
    assert sep.n_caustic.sum() > 0 and sep.n_photons.sum() > 0
    np.testing.assert_allclose(sep.n_photons + sep.n_caustic, shared.n_photons, rtol=1e-12)
    np.testing.assert_allclose(sep.tau + sep.tau_caustic, shared.tau, rtol=1e-6, atol=1e-12)
    assert np.all(sep.radius >= shared.radius) and np.all(sep.radius_caustic >= shared.radius)
    assert np.all((sep.radius < 0.8) == (sep.n_photons > 0))
    assert np.all((sep.radius_caustic < 0.8) == (sep.n_caustic > 0))
    assert shared.gathered.tolist() == sep.gathered.tolist()


def test_separate_caustic_statistics_radius_and_sidecar(diacaustic):
    r = caustica.render(diacaustic, "sppm", res=16, passes=3, photons=2000, caustic_photons=2000)
    assert r.stats["caustic_statistics"] == "separate"
    assert r.stats["initial_caustic_radius"] == pytest.approx(0.6 * r.stats["initial_radius"])
    assert r.stats["radius_caustic_final"]["min"] < r.stats["initial_caustic_radius"]
    r = caustica.render(diacaustic, "sppm", res=16, passes=3, photons=2000, caustic_photons=2000, caustic_radius=0.1)
    assert r.stats["initial_caustic_radius"] == 0.1 and r.stats["radius_caustic_final"]["max"] <= 0.1
    # without aimed photons, or with shared statistics, nothing is kept apart
    for kw in ({}, {"caustic_statistics": "shared"}):
        plain = caustica.render(diacaustic, "sppm", res=16, passes=2, photons=2000,
                                caustic_photons=2000 if kw else 0, **kw)
        assert "caustic_statistics" not in plain.stats


def test_sppm_default_photons_are_split_where_there_is_a_mirror_or_glass(diacaustic):
    """Defaults in a scene with glass: one photon per pixel, half of them aimed (separate statistics);
    --caustic-photons 0, or --photons alone, keep every photon unaimed; no mirror or glass, no aiming."""
    from caustica.methods.sppm import photon_counts
    from caustica.api import resolve_settings
    def counts(scene, **kw):
        sc, _, settings = resolve_settings(scene, "sppm", res=16, multi_pass=True, **kw)
        return photon_counts(sc, settings)
    assert counts(diacaustic) == (128, 128)
    assert counts(diacaustic, caustic_photons=0) == (256, 0)
    assert counts(diacaustic, photons=1000) == (1000, 0)
    assert counts(diacaustic, caustic_photons=50) == (256, 50)
    assert counts(diacaustic, photons=1000, caustic_photons=50) == (1000, 50)
    plane = plane_scene("""<emitter type="point"><point name="position" x="0" y="0" z="2"/>
        <rgb name="intensity" value="1, 1, 1"/></emitter>""")
    assert counts(plane) == (256, 0) and counts(plane, caustic_photons=50) == (256, 0)
    r = caustica.render(diacaustic, "sppm", res=16, passes=2)
    assert r.stats["emitted_all_passes"] == 2 * 256 and r.stats["caustic_statistics"] == "separate"


class _NoBar:
    def update(self, n=1):
        pass

    def close(self):
        pass


# --------------------------------------------------------------------------- 4. the Mitsuba reference

@pytest.mark.slow
@pytest.mark.parametrize("method, params", [("sppm", {}), ("pspm", {"specular": "split", "stream_radius": 1.0})])
def test_many_passes_match_the_reference(diacaustic, refs_dir, method, params):
    """After 48 passes at 32x32 (roulette and mr = 64: no depth truncation) the image agrees with Mitsuba's
    converged reference: image mean within 2 %, 4x4 block means within 5 sigmas of the
    seeds' spread plus the reference's noise — what is left of SPPM's blur is below that."""
    ref, meta = load_reference(refs_dir, "cornell-diacaustic")
    factor = ref.shape[0] // 32
    ref_small = downsample(ref, factor)
    rel = meta["noise"]["est_rel_rmse_of_full"]
    from imagestats import BLOCK, block_means
    ref_se = rel * block_means(ref_small) / (BLOCK * factor)
    count = {"photons": 20_000} if method == "sppm" else {"streams": 2000}
    images = [caustica.render(diacaustic, method, res=32, seed=s, passes=48, termination="roulette", max_bounces=64,
                              **count, **params).image for s in range(4)]
    assert_images_agree(images, [ref_small], extra_se=ref_se, label=f"{method} vs reference")


# --------------------------------------------------------------------------- 5. determinism, checkpoints

@pytest.mark.parametrize("method, params", [("sppm", {}), ("pspm", {}), ("pspm", {"specular": "split"}),
                                            ("sppm", {"schedule": "global"}), ("sppm", {"caustic_photons": 500}),
                                            ("pspm", {"caustic_photons": 500})])
def test_same_bits_for_any_thread_count(diacaustic, method, params):
    kw = dict(res=16, seed=5, passes=3, **params)
    one = caustica.render(diacaustic, method, threads=1, **kw).image
    two = caustica.render(diacaustic, method, threads=2, **kw).image
    other = caustica.render(diacaustic, method, res=16, seed=6, passes=3, threads=2, **params).image
    assert one.tobytes() == two.tobytes()
    assert one.tobytes() != other.tobytes()


@pytest.mark.parametrize("method, params", [("pt", {}), ("sppm", {}), ("pspm", {}), ("sppm", {"schedule": "global"}),
                                            ("sppm", {"caustic_photons": 500}), ("pspm", {"caustic_photons": 500})])
def test_checkpoint_resume_gives_the_same_bits(diacaustic, method, params, tmp_path):
    kw = dict(res=12, seed=2, **params)
    whole = caustica.render(diacaustic, method, passes=5, **kw)
    ck = tmp_path / "state.npz"
    part = caustica.render(diacaustic, method, passes=2, checkpoint=ck, threads=1, **kw)
    assert part.stats["passes"] == 2 and ck.is_file()
    rest = caustica.render(diacaustic, method, passes=5, checkpoint=ck, threads=2, **kw)
    assert rest.stats["resumed_from_pass"] == 2 and rest.stats["passes_this_run"] == 3
    assert rest.image.tobytes() == whole.image.tobytes()
    # a checkpoint is never continued with other settings
    with pytest.raises(ParameterError, match="seed"):
        caustica.render(diacaustic, method, passes=6, checkpoint=ck, res=12, seed=3, **params)


def test_checkpoint_of_another_build_or_beyond_passes_is_refused(diacaustic, tmp_path, monkeypatch):
    ck = tmp_path / "state.npz"
    caustica.render(diacaustic, "sppm", res=8, seed=2, passes=3, checkpoint=ck)
    with pytest.raises(ParameterError, match="holds 3 passes, more than --passes 2"):
        caustica.render(diacaustic, "sppm", res=8, seed=2, passes=2, checkpoint=ck)
    from caustica import checkpoint
    monkeypatch.setattr(checkpoint, "source_hash", lambda: "0123456789abcdef")
    with pytest.raises(ParameterError, match="another build"):
        caustica.render(diacaustic, "sppm", res=8, seed=2, passes=4, checkpoint=ck)
    ck.write_bytes(b"not a checkpoint")
    with pytest.raises(ParameterError, match="not a caustica checkpoint"):
        caustica.render(diacaustic, "sppm", res=8, seed=2, passes=4, checkpoint=ck)


def test_global_schedule_radius_is_knaus_zwicker_s_product():
    from caustica.methods.progressive import global_radius
    r2, alpha = 4.0, 0.7
    for p in range(1, 200):
        r2 *= (p + alpha) / (p + 1)
        assert global_radius(2.0, alpha, p) == pytest.approx(math.sqrt(r2), rel=1e-12)
    assert global_radius(2.0, alpha, 0) == 2.0
    # R_p² falls as p^(α - 1): the ratio over a factor 1000 in passes
    ratio = (global_radius(1.0, alpha, 10**9) / global_radius(1.0, alpha, 10**6)) ** 2
    assert ratio == pytest.approx(1000.0 ** (alpha - 1), rel=1e-3)


def test_global_schedule_sidecar_and_aovs(diacaustic):
    r = caustica.render(diacaustic, "sppm", res=8, seed=1, passes=3, schedule="global", aov=("radius", "count"))
    from caustica.methods.progressive import global_radius
    r3 = global_radius(r.stats["initial_radius"], 2 / 3, 3)
    assert r.stats["schedule"] == "global" and r.stats["radius_final"]["median"] == pytest.approx(r3)
    assert np.all(r.aovs["radius"] == np.float32(r3))
    assert r.aovs["count"].sum() == r.stats["events_gathered"]


def test_pspm_stream_radius_shrinks_with_the_gather_radii(diacaustic):
    r = caustica.render(diacaustic, "pspm", res=16, seed=1, passes=6, streams=2000, stream_radius=2.0,
                        aov=("radius",))
    r0 = r.stats["initial_radius"]
    rad = r.aovs["radius"].astype(np.float64)
    gathered = rad[rad < np.float32(r0)]
    assert 0 < gathered.size < rad.size      # some pixels (the light) never gather
    assert r.stats["stream_radius_next_pass"] == pytest.approx(2.0 * np.median(gathered) / r0, rel=1e-6)


def test_pspm_stream_radius_follows_only_the_pixels_that_gather(diacaustic):
    """Pixels that never gather keep R_0; the median of every pixel followed them (S4: r_s stayed at
    0.5 of its start while the gathering pixels were at 0.225).  Six pixels in ten never gathered here."""
    from caustica.methods.pspm import stream_radius
    from caustica.methods.params import Settings
    from caustica.methods.progressive import initial_radius

    settings = Settings("pspm", {"stream_radius": 5.0, "radius": None, "width": 64, "height": 64})
    r0 = initial_radius(diacaustic, settings)
    radius = np.concatenate([np.full(60, r0), np.full(40, 0.2 * r0)])
    assert stream_radius(diacaustic, settings, radius) == pytest.approx(5.0 * 0.2)
    assert stream_radius(diacaustic, settings, np.full(10, r0)) == 5.0    # the first pass


def _framed_plane(tmp_path, camera: str, extra: str = "") -> caustica.Scene:
    """A plane of 20 x 20 at z = 0 seen square on from z = 5 by ``camera``, a light above it to the side; ``extra``
    more shapes."""
    path = tmp_path / "framed.xml"
    path.write_text(f"""<scene version="3.0.0">
  {camera}
  <shape type="rectangle"><transform name="to_world"><scale value="10"/></transform><bsdf type="diffuse"/></shape>
  <shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/>
    <translate x="3" z="4"/></transform><emitter type="area"><rgb name="radiance" value="5"/></emitter></shape>
  {extra}
</scene>""")
    return caustica.load_scene(path)


PINHOLE = ('<sensor type="perspective"><float name="fov" value="{fov}"/><transform name="to_world"><lookat '
           'origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>')


def test_the_default_radius_is_at_most_four_pixels_where_the_camera_meets_the_scene(tmp_path):
    """R_0 defaults to 0.01 of the scene's diagonal, at most FOOTPRINT_PIXELS pixel widths where the camera meets the
    scene (the median over a grid of the film): a camera framing a small part of a scene blurred it over tens of
    pixels (docs/progressive.md: a held-out scene at 20.6).  The footprint is depth times a pixel's width at unit
    depth, through a glass ball and a null surface (straight on), and a pixel's width for an orthographic camera."""
    from caustica.methods.progressive import FOOTPRINT_PIXELS
    wide = _framed_plane(tmp_path, PINHOLE.format(fov=90))
    diag = 0.01 * float(np.linalg.norm(wide.geometry.scene_box[3:] - wide.geometry.scene_box[:3]))
    assert wide.pixel_footprint(64, 64) == pytest.approx(5.0 * 2.0 / 64, rel=1e-6)
    assert caustica.render(wide, "sppm", res=64, passes=1).stats["initial_radius"] == pytest.approx(diag)   # 20 px
    narrow = _framed_plane(tmp_path, PINHOLE.format(fov=2), '<shape type="sphere"><point name="center" x="0" y="0" '
                           'z="2"/><float name="radius" value="0.5"/><bsdf type="dielectric"/></shape><shape '
                           'type="rectangle"><transform name="to_world"><translate z="3"/></transform><bsdf '
                           'type="null"/></shape>')
    fp = 5.0 * 2.0 * math.tan(math.radians(1.0)) / 32
    assert narrow.pixel_footprint(32, 32) == pytest.approx(fp, rel=1e-6)
    for method in ("sppm", "pspm"):
        assert caustica.render(narrow, method, res=32, passes=1).stats["initial_radius"] == \
            pytest.approx(FOOTPRINT_PIXELS * fp)
    assert caustica.render(narrow, "sppm", res=32, passes=1, radius=0.5).stats["initial_radius"] == 0.5  # given
    ortho = _framed_plane(tmp_path, '<sensor type="orthographic"><transform name="to_world"><lookat origin="0, 0, 5" '
                                    'target="0, 0, 0" up="0, 1, 0"/><scale value="0.2"/></transform></sensor>')
    assert ortho.pixel_footprint(16, 16) == pytest.approx(2 * 0.2 / 16, rel=1e-6)
    empty = _framed_plane(tmp_path, PINHOLE.replace("0, 0, 0", "0, 0, 10").format(fov=10))   # looks away
    assert empty.pixel_footprint(8, 8) == math.inf


def test_time_budget_stops_between_passes(diacaustic):
    caustica.render(diacaustic, "sppm", res=16, passes=1)   # compiled: the budget then measures passes
    r = caustica.render(diacaustic, "sppm", res=16, time_s=1.0)
    assert r.stats["passes"] >= 2
    assert sum(r.stats["pass_seconds"]) <= 1.0 + max(r.stats["pass_seconds"])
    assert r.stats["time_budget_s"] == 1.0 and not r.stats["interrupted"]


def test_the_first_pass_always_runs_whatever_the_budget(diacaustic):
    """A budget over before the first pass is sent still renders it (then stops): never an image of no passes."""
    r = caustica.render(diacaustic, "sppm", res=8, seed=1, time_s=1e-9)
    assert r.stats["passes"] == 1 and len(r.stats["pass_seconds"]) == 1
    assert r.image.tobytes() == caustica.render(diacaustic, "sppm", res=8, seed=1, passes=1).image.tobytes()


def test_radius_shrinks_and_aovs(diacaustic):
    # plain SPPM: one set of statistics (with separate caustic statistics, radius is the other photons'
    # radius and count every event gathered)
    r = caustica.render(diacaustic, "sppm", res=16, seed=1, passes=8, caustic_photons=0, aov=("radius", "count"))
    r0 = r.stats["initial_radius"]
    rad, cnt = r.aovs["radius"], r.aovs["count"]
    assert rad.shape == cnt.shape == (16, 16)
    assert np.all(rad <= r0 * (1 + 1e-12)) and rad.min() < r0
    # pixels that gathered photons shrank, the others kept R_0
    assert np.all((cnt > 0) == (rad < r0 * (1 - 1e-12)))
    assert r.stats["radius_final"]["max"] <= r0 * (1 + 1e-12)


def test_interrupt_returns_the_finished_passes(diacaustic, monkeypatch):
    cls = caustica.methods.get("sppm")
    real = cls.run_pass.__func__
    calls = []

    def run_pass(klass, scene, settings, state, progress):
        calls.append(state.passes)
        if state.passes == 2:
            raise KeyboardInterrupt
        return real(klass, scene, settings, state, progress)

    monkeypatch.setattr(cls, "run_pass", classmethod(run_pass))
    r = caustica.render(diacaustic, "sppm", res=8, seed=1, passes=10)
    assert r.stats["interrupted"] and r.stats["passes"] == 2
    monkeypatch.undo()
    two = caustica.render(diacaustic, "sppm", res=8, seed=1, passes=2)
    assert two.image.tobytes() == r.image.tobytes()


# --------------------------------------------------------------------------- 6. bad input

@pytest.mark.parametrize("kw, match", [
    (dict(passes=0), "--passes"), (dict(passes=-3), "--passes"), (dict(time_s=-1.0), "--time"),
    (dict(time_s=float("nan")), "--time"), (dict(time_s=float("inf")), "--time"),
    (dict(alpha=1.0, passes=2), "--alpha"), (dict(alpha=0.0, passes=2), "--alpha"),
    (dict(radius=0.0, passes=2), "--radius"), (dict(radius=-1.0, passes=2), "--radius"),
    (dict(spp=4, passes=2), "--spp"), (dict(aov="depth", passes=2), "--aov"),
])
def test_bad_progressive_parameters(diacaustic, kw, match):
    with pytest.raises(ParameterError, match=match):
        caustica.render(diacaustic, "sppm", res=8, **kw)


def test_pspm_caustic_photons_need_the_merge(diacaustic):
    with pytest.raises(ParameterError, match="--caustic-photons: .*--specular merge"):
        caustica.render(diacaustic, "pspm", res=8, passes=2, caustic_photons=100, specular="split")


def test_one_shot_methods_refuse_passes(diacaustic):
    with pytest.raises(ParameterError, match="one shot"):
        caustica.render(diacaustic, "pm", res=8, passes=3)
    with pytest.raises(ParameterError, match="needs --passes or --time"):
        driver.check_plan(caustica.methods.get("sppm"), checkpoint="x.npz")


# --------------------------------------------------------------------------- 7. the command line

def test_cli_progressive_render_writes_aovs_and_pass_stats(cli, tmp_path):
    import json
    out = tmp_path / "r.exr"
    code, _, err = cli("render", "cornell-diacaustic", "--method", "sppm", "--res", "12", "--passes", "3",
                       "--aov", "radius,count", "-o", out, "-q")
    assert code == 0, err
    for name in ("r.exr", "r.png", "r.json", "r.radius.exr", "r.count.exr"):
        assert (tmp_path / name).is_file(), name
    meta = json.loads((tmp_path / "r.json").read_text())
    assert meta["passes"] == 3 and len(meta["pass_seconds"]) == 3 and not meta["interrupted"]
    assert meta["outputs"]["aov_radius"] == "r.radius.exr"
    assert set(meta["radius_final"]) == {"min", "median", "max"}


@pytest.mark.parametrize("args, words", [
    (("--passes", "0"), "--passes"), (("--time", "-1"), "--time"), (("--time", "nan"), "--time"),
    (("--alpha", "1.5", "--passes", "2"), "--alpha"), (("--radius", "0", "--passes", "2"), "--radius"),
    (("--aov", "depth", "--passes", "2"), "--aov"),
])
def test_cli_bad_progressive_input_is_one_line_exit_2_nothing_written(cli, tmp_path, args, words):
    code, out, err = cli("render", "cornell-diacaustic", "--method", "sppm", "--res", "8", "-o",
                         tmp_path / "x.exr", *args)
    assert code == 2
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("caustica: error:") and words in lines[0], err
    assert list(tmp_path.iterdir()) == []


def test_cli_checkpoint_may_not_be_an_output(cli, tmp_path):
    code, _, err = cli("render", "cornell-diacaustic", "--method", "sppm", "--res", "8", "--passes", "2",
                       "-o", tmp_path / "x.exr", "--checkpoint", tmp_path / "x.json")
    assert code == 2 and "--checkpoint" in err
    assert list(tmp_path.iterdir()) == []


def test_cli_interrupted_progressive_render_writes_the_finished_passes(cli, tmp_path, interrupt_at_pass):
    import json
    interrupt_at_pass("sppm", 2)
    code, _, err = cli("render", "cornell-diacaustic", "--method", "sppm", "--res", "8", "--passes", "9",
                       "-o", tmp_path / "x.exr", "-q")
    assert code == 130 and "2 passes" in err
    meta = json.loads((tmp_path / "x.json").read_text())
    assert meta["interrupted"] and meta["passes"] == 2
