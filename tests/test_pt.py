"""Correctness of the path tracer (method ``pt``).

1. Analytic direct lighting: a point light and a small square area light over a large
   diffuse plane, seen by a camera looking straight down (max_depth=2: direct light only).
   The expected pixel values integrate the closed-form radiance over each pixel's footprint.
2. White furnace: a closed diffuse enclosure whose whole inside emits Le: L = Le Σ ρ^k,
   truncated by max_depth with Mitsuba's depth convention, or the full series with
   Russian roulette.
3. Comparison with Mitsuba 3 (same XML) and with the shared Mitsuba reference images.
4. Determinism over thread counts and seeds.
5. Depth semantics: max_depth=1 shows emitters only.

Every statistical tolerance is derived from noise measured in the test itself (several
seeds, or pixels that share one expected value); each place says how.  Renders are small
and cached per module so the file runs in well under three minutes on two cores.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import caustica
from caustica.imageio import read_png_mask
from caustica.scene import builtin_scene_path, parse_scene_string
from caustica.tables import compile_scene
from imagestats import BLOCK, N_SIGMA, assert_images_agree, block_means, downsample, load_reference, \
    pixel_var_of_mean


def scene_from_xml(text: str):
    return compile_scene(parse_scene_string(text))


def sensor_xml(origin, target, up, fov, width, height, fov_axis="x") -> str:
    o, t, u = (", ".join(str(float(c)) for c in v) for v in (origin, target, up))
    return f"""
    <sensor type="perspective">
        <string name="fov_axis" value="{fov_axis}"/>
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{o}" target="{t}" up="{u}"/></transform>
        <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/>
            <rfilter type="box"/></film>
    </sensor>"""


def pixel_footprints(width, height, fov_x_deg, cam_height, n_sub=32):
    """Points where sub-pixel rays of a camera at (0, 0, cam_height) looking down -z meet z = 0.

    Returns x, y arrays of shape (height, width, n_sub * n_sub): a midpoint grid over each
    pixel in film coordinates, which is exactly what the box filter averages (the films of
    :func:`sensor_xml` say ``<rfilter type="box"/>``: without it a film is Mitsuba's gaussian).
    Written from Mitsuba's pinhole model: film point (sx, sy) in [0, 1]^2 maps to the camera-space
    direction (tan_x (1 - 2 sx), tan_y (1 - 2 sy), 1).  The test scenes are symmetric under
    x -> -x and y -> -y, so the camera's handedness does not matter here.
    """
    tan_x = math.tan(math.radians(fov_x_deg) / 2)
    tan_y = tan_x * height / width
    sub = (np.arange(n_sub) + 0.5) / n_sub
    su, sv = np.meshgrid(sub, sub, indexing="xy")
    px = np.arange(width)[None, :, None] + su.ravel()[None, None, :]
    py = np.arange(height)[:, None, None] + sv.ravel()[None, None, :]
    x = cam_height * tan_x * (1 - 2 * px / width)
    y = cam_height * tan_y * (1 - 2 * py / height)
    return np.broadcast_to(x, (height, width, n_sub * n_sub)), np.broadcast_to(y, (height, width, n_sub * n_sub))


# --------------------------------------------------------------------------- 1. analytic direct light

PLANE_RHO = (0.8, 0.5, 0.2)
CAM_H = 1.0          # camera height above the plane z = 0
LIGHT_H = 2.0        # light height (above the camera: the camera sees only the plane)
FOV_X = 90.0
AW, AH = 9, 7        # odd sizes: the centre pixel lies right under the light


def plane_scene(light_xml: str):
    return scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0, 0, CAM_H), (0, 0, 0), (0, 1, 0), FOV_X, AW, AH)}
        <shape type="rectangle">
            <transform name="to_world"><scale value="50"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="{', '.join(map(str, PLANE_RHO))}"/></bsdf>
        </shape>
        {light_xml}
    </scene>""")


def square_irradiance_factor(x, y, half, h):
    """∫∫ cos θ cos θ' / r² dA over the square [-half, half]^2 at height h, seen from (x, y, 0).

    Closed form of the differential-area-to-parallel-rectangle configuration factor (times π):
    for a rectangle [0, X] x [0, Y] with a corner above the point,
    G(X, Y) = ½ [X/√(X²+h²) atan(Y/√(X²+h²)) + Y/√(Y²+h²) atan(X/√(Y²+h²))], odd in X and Y,
    combined over the four corners.
    """
    def g(X, Y):
        ax = np.sqrt(X * X + h * h)
        ay = np.sqrt(Y * Y + h * h)
        return 0.5 * (X / ax * np.arctan(Y / ax) + Y / ay * np.arctan(X / ay))

    x1, x2 = -half - x, half - x
    y1, y2 = -half - y, half - y
    return g(x2, y2) - g(x1, y2) - g(x2, y1) + g(x1, y1)


def test_square_irradiance_closed_form_matches_quadrature():
    # Check the reference formula itself against brute-force midpoint quadrature.
    half, h = 0.5, 2.0
    n = 800
    u = (np.arange(n) + 0.5) / n * 2 * half - half
    uu, vv = np.meshgrid(u, u)
    for x, y in [(0.0, 0.0), (0.7, -0.3), (2.0, 1.5)]:
        r2 = (uu - x) ** 2 + (vv - y) ** 2 + h * h
        brute = np.sum(h * h / r2 ** 2) * (2 * half / n) ** 2
        assert square_irradiance_factor(x, y, half, h) == pytest.approx(brute, rel=1e-5)


def test_point_light_over_plane_is_exact():
    intensity = np.array([10.0, 20.0, 30.0])
    spp = 256
    scene = plane_scene(f"""<emitter type="point"><point name="position" x="0" y="0" z="{LIGHT_H}"/>
        <rgb name="intensity" value="{', '.join(map(str, intensity))}"/></emitter>""")
    img = caustica.render(scene, "pt", spp=spp, seed=3, max_depth=2).image.astype(np.float64)

    # L(x, y) = ρ/π · I cos θ / d² with cos θ = h/d.
    x, y = pixel_footprints(AW, AH, FOV_X, CAM_H)
    d2 = x * x + y * y + LIGHT_H ** 2
    f = LIGHT_H / d2 ** 1.5                                   # cos θ / d²
    mean_f, std_f = f.mean(axis=2), f.std(axis=2)
    expected = mean_f[..., None] * intensity * np.asarray(PLANE_RHO) / math.pi
    # The only randomness is the sub-pixel jitter: the standard error of a pixel is the spread
    # of the radiance over its footprint / sqrt(spp).  Allow 5 sigma + 1e-4 relative for the
    # quadrature and float32 rounding.
    tol = (N_SIGMA * std_f / math.sqrt(spp))[..., None] * intensity * np.asarray(PLANE_RHO) / math.pi
    tol = tol + 1e-4 * expected
    assert np.all(np.abs(img - expected) <= tol), np.max(np.abs(img - expected) / tol)

    # The centre pixel is right under the light: ρ/π · I / h² up to its (small) footprint.
    centre = img[AH // 2, AW // 2]
    np.testing.assert_allclose(centre, np.asarray(PLANE_RHO) / math.pi * intensity / LIGHT_H ** 2, rtol=0.02)
    # An offset pixel: ρ/π · I cos θ / d² at its centre, up to its footprint.
    px, py = AW - 2, 1
    cx = CAM_H * math.tan(math.radians(FOV_X / 2)) * (1 - 2 * (px + 0.5) / AW)
    cy = CAM_H * math.tan(math.radians(FOV_X / 2)) * AH / AW * (1 - 2 * (py + 0.5) / AH)
    d = math.sqrt(cx * cx + cy * cy + LIGHT_H ** 2)
    np.testing.assert_allclose(img[py, px], np.asarray(PLANE_RHO) / math.pi * intensity * (LIGHT_H / d) / d ** 2,
                               rtol=0.02)


def test_ray_counts_are_exact_over_a_plane():
    # Every camera ray hits the plane; the point light above it is in front of every hit, so
    # each path traces one shadow ray, then one bounce ray that escapes: 2 extension rays.
    # max_depth=1 stops at the first hit (emitters only): no shadow ray, no bounce.
    scene = plane_scene(f"""<emitter type="point"><point name="position" x="0" y="0" z="{LIGHT_H}"/>
        <rgb name="intensity" value="1, 1, 1"/></emitter>""")
    for max_depth, ext_per_path, shadow_per_path in ((-1, 2, 1), (2, 2, 1), (1, 1, 0)):
        r = caustica.render(scene, "pt", spp=3, seed=1, max_depth=max_depth)
        paths = AW * AH * 3
        assert r.stats["camera_rays"] == paths
        assert r.stats["extension_rays"] == ext_per_path * paths
        assert r.stats["shadow_rays"] == shadow_per_path * paths


def test_square_area_light_over_plane():
    radiance = np.array([4.0, 6.0, 8.0])
    half = 0.5                                                # a 1 x 1 light
    seeds, spp = range(24), 64
    scene = plane_scene(f"""<shape type="rectangle">
        <transform name="to_world">
            <scale value="{half}"/><rotate x="1" angle="180"/><translate z="{LIGHT_H}"/>
        </transform>
        <emitter type="area"><rgb name="radiance" value="{', '.join(map(str, radiance))}"/></emitter>
    </shape>""")
    imgs = np.stack([caustica.render(scene, "pt", spp=spp, seed=s, max_depth=2).image
                     for s in seeds]).astype(np.float64)
    img = imgs.mean(axis=0)

    x, y = pixel_footprints(AW, AH, FOV_X, CAM_H)
    factor = square_irradiance_factor(x, y, half, LIGHT_H).mean(axis=2)
    expected = factor[..., None] * radiance * np.asarray(PLANE_RHO) / math.pi
    # Noise: the standard error of each pixel's mean over the 24 independent seeds, from their
    # sample standard deviation (23 degrees of freedom); allow 5 sigma + 1e-4 relative.
    se = imgs.std(axis=0, ddof=1) / math.sqrt(len(seeds))
    tol = N_SIGMA * se + 1e-4 * expected
    assert np.all(se > 0)
    assert np.all(np.abs(img - expected) <= tol), np.max(np.abs(img - expected) / tol)
    # The whole image's mean is much tighter than any pixel: within 5 of its own sigmas.
    se_mean = np.sqrt((se ** 2).sum(axis=(0, 1))) / (AW * AH)
    np.testing.assert_array_less(np.abs(img.mean(axis=(0, 1)) - expected.mean(axis=(0, 1))), N_SIGMA * se_mean)


# --------------------------------------------------------------------------- 2. white furnace

FURNACE_RHO = np.array([0.3, 0.6, 0.8])
FURNACE_LE = np.array([1.0, 2.0, 0.5])
FURNACE_SHAPES = {
    "sphere": '<shape type="sphere"><float name="radius" value="2"/><boolean name="flip_normals" value="true"/>',
    "cube": '<shape type="cube"><transform name="to_world"><scale value="2"/></transform>'
            '<boolean name="flip_normals" value="true"/>',
}


def furnace_scene(kind: str):
    return scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0.1, -0.2, 0.3), (1, 0.5, -1), (0, 1, 0), 70, 16, 16)}
        {FURNACE_SHAPES[kind]}
            <bsdf type="diffuse"><rgb name="reflectance" value="{', '.join(map(str, FURNACE_RHO))}"/></bsdf>
            <emitter type="area"><rgb name="radiance" value="{', '.join(map(str, FURNACE_LE))}"/></emitter>
        </shape>
    </scene>""")


@pytest.fixture(scope="module")
def furnace_scenes():
    return {k: furnace_scene(k) for k in FURNACE_SHAPES}


@pytest.mark.parametrize("kind, max_depth", [("sphere", 1), ("sphere", 2), ("sphere", 3), ("sphere", 8),
                                             ("sphere", -1), ("cube", 1), ("cube", 3), ("cube", -1)])
def test_white_furnace(furnace_scenes, kind, max_depth):
    img = caustica.render(furnace_scenes[kind], "pt", spp=64, seed=11, max_depth=max_depth).image.astype(np.float64)
    # Mitsuba's convention: max_depth = n keeps emission after at most n - 1 bounces.
    if max_depth < 0:
        expected = FURNACE_LE / (1 - FURNACE_RHO)
    else:
        expected = FURNACE_LE * (1 - FURNACE_RHO ** max_depth) / (1 - FURNACE_RHO)
    if max_depth == 1:
        # The camera ray sees the emitter and stops: no randomness at all.
        np.testing.assert_allclose(img, np.broadcast_to(FURNACE_LE, img.shape), rtol=1e-6)
        return
    # Every pixel has the same expectation, so the pixels are 256 independent samples of it:
    # the image mean's standard error is the pixels' standard deviation / 16.  5 sigma.
    pix = img.reshape(-1, 3)
    se = pix.std(axis=0, ddof=1) / math.sqrt(len(pix))
    assert np.all(np.isfinite(pix))
    got = pix.mean(axis=0)
    assert np.all(np.abs(got - expected) <= N_SIGMA * se + 1e-6 * expected), (got, expected, se)


# --------------------------------------------------------------------------- shared render helpers

CMP_RES = 32
CMP_SEEDS = (1, 2, 3, 4)      # independent renders of each image, to measure its noise
CMP_SPP = {"cornell-pyramid": 256, "cornell-diacaustic": 512, "mirror-point": 128, "sphere-area": 256}


@pytest.fixture(scope="module")
def scene_paths(request, test_scenes_dir):
    """The paper's scenes from the shared folder (the project's built-in copies when it is
    missing; tests/test_scene_loader.py checks they are identical) and the tests' own scenes."""
    try:
        shared = request.getfixturevalue("shared_scenes_dir")
    except pytest.skip.Exception:
        shared = None
    paths = {name: shared / f"{name}.xml" if shared else builtin_scene_path(name)
             for name in ("cornell-pyramid", "cornell-diacaustic")}
    paths.update({name: test_scenes_dir / f"{name}.xml" for name in ("mirror-point", "sphere-area")})
    return paths


class _Renders:
    """Renders made once per module: caustica's and Mitsuba's, one per seed of CMP_SEEDS, at CMP_RES."""

    def __init__(self, paths):
        self.paths = paths
        self.cache = {}

    def caustica(self, name):
        key = ("caustica", name)
        if key not in self.cache:
            scene = caustica.load_scene(self.paths[name])
            self.cache[key] = [caustica.render(scene, "pt", spp=CMP_SPP[name], res=CMP_RES, seed=s).image
                               for s in CMP_SEEDS]
        return self.cache[key]

    def mitsuba(self, mi, name):
        key = ("mitsuba", name)
        if key not in self.cache:
            scene = mi.load_file(str(self.paths[name]), res=CMP_RES, spp=CMP_SPP[name])
            self.cache[key] = [np.array(mi.render(scene, spp=CMP_SPP[name], seed=s), dtype=np.float32)[..., :3]
                               for s in CMP_SEEDS]
        return self.cache[key]


@pytest.fixture(scope="module")
def renders(scene_paths):
    return _Renders(scene_paths)


# --------------------------------------------------------------------------- 3a. Mitsuba 3 comparison

@pytest.mark.parametrize("name", ["cornell-pyramid", "cornell-diacaustic", "mirror-point", "sphere-area"])
def test_matches_mitsuba(renders, mi, name):
    assert_images_agree(renders.caustica(name), renders.mitsuba(mi, name), label=name)


# --------------------------------------------------------------------------- 3b. shared reference images

@pytest.mark.parametrize("name", ["cornell-pyramid", "cornell-diacaustic"])
def test_matches_reference_image(renders, refs_dir, name):
    ref, meta = load_reference(refs_dir, name)
    factor = ref.shape[0] // CMP_RES
    ref_small = downsample(ref, factor)       # box filter of box filters: exactly the 32x32 box filter
    # The reference's own noise: its JSON gives the per-pixel relative RMS error at 256x256;
    # a block of BLOCK² low-res pixels averages (BLOCK·factor)² of those pixels.
    rel = meta["noise"]["est_rel_rmse_of_full"]
    ref_se = rel * block_means(ref_small) / (BLOCK * factor)
    assert_images_agree(renders.caustica(name), [ref_small], extra_se=ref_se, label=f"{name} vs reference")


def test_diacaustic_caustic_region_matches_reference(renders, refs_dir):
    name = "cornell-diacaustic"
    ref, meta = load_reference(refs_dir, name)
    mask = read_png_mask(refs_dir / f"{name}_256_caustic_mask.png")
    factor = ref.shape[0] // CMP_RES
    # The mask's coverage of each low-res pixel weights both images the same way.
    w = downsample(mask.astype(np.float64), factor)
    ref_small = downsample(ref, factor)
    images = renders.caustica(name)
    wsum = w.sum()
    got = (w[..., None] * np.mean(np.stack(images).astype(np.float64), axis=0)).sum(axis=(0, 1)) / wsum
    want = (w[..., None] * ref_small).sum(axis=(0, 1)) / wsum
    # caustica's noise: the pixels are independent, so the weighted mean's variance is
    # Σ w² var / (Σ w)² with each pixel's variance measured over the renders.  (With only 2
    # renders of 1024 spp this was unreliable: one pair of seeds out of 8 sat 6 "sigmas"
    # off; 4 renders of 256 spp stayed within 1.2 sigmas in 8 trials.)
    se = np.sqrt((w[..., None] ** 2 * pixel_var_of_mean(images)).sum(axis=(0, 1))) / wsum
    # The reference's: its per-pixel relative RMS error over the masked 256x256 pixels
    # (a lower bound there, as caustic pixels are the noisiest; doubled to be safe).
    ref_se = 2 * meta["noise"]["est_rel_rmse_of_full"] * want / math.sqrt(mask.sum())
    tol = N_SIGMA * np.sqrt(se ** 2 + ref_se ** 2) + 0.002 * want
    assert np.all(np.abs(got - want) <= tol), (got, want, se, ref_se)


# --------------------------------------------------------------------------- 4. determinism

@pytest.fixture(scope="module")
def small_diacaustic():
    return caustica.load_scene(builtin_scene_path("cornell-diacaustic"))


def test_same_bits_for_any_thread_count(small_diacaustic):
    one = caustica.render(small_diacaustic, "pt", spp=4, res=24, seed=7, threads=1).image
    two = caustica.render(small_diacaustic, "pt", spp=4, res=24, seed=7, threads=2).image
    assert one.tobytes() == two.tobytes()


def test_same_seed_same_bits_other_seed_other_image(small_diacaustic):
    a = caustica.render(small_diacaustic, "pt", spp=4, res=24, seed=7).image
    b = caustica.render(small_diacaustic, "pt", spp=4, res=24, seed=7).image
    c = caustica.render(small_diacaustic, "pt", spp=4, res=24, seed=8).image
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, c)
    # Different seeds are different samples almost everywhere, not a shifted copy.
    assert np.mean(np.any(a != c, axis=2)) > 0.9


# --------------------------------------------------------------------------- 5. depth semantics

def project(cam, points):
    """Film coordinates (px, py) in pixels of world points, for caustica's CameraParams."""
    rel = np.asarray(points, np.float64) - cam.origin
    local = rel @ cam.basis            # the basis columns are camera x, y, z in world space
    sx = (1 - local[:, 0] / local[:, 2] / cam.tan_half_x) / 2
    sy = (1 - local[:, 1] / local[:, 2] / cam.tan_half_y) / 2
    return sx * cam.width, sy * cam.height


def inside_convex(px, py, x, y):
    """True where points (x, y) lie inside the convex polygon (px, py) (either winding)."""
    cross = [(px[(k + 1) % len(px)] - px[k]) * (y - py[k]) - (py[(k + 1) % len(px)] - py[k]) * (x - px[k])
             for k in range(len(px))]
    return np.all(np.stack(cross) > 0, axis=0) | np.all(np.stack(cross) < 0, axis=0)


def test_max_depth_1_shows_only_emitters(small_diacaustic):
    res, spp = 80, 64
    img = caustica.render(small_diacaustic, "pt", spp=spp, res=res, seed=5, max_depth=1).image.astype(np.float64)
    # The light: a 3 x 3 square at y = 19.99, radiance 40, seen from below through the open front.
    corners = [(-1.5, 19.99, -1.5), (1.5, 19.99, -1.5), (1.5, 19.99, 1.5), (-1.5, 19.99, 1.5)]
    px, py = project(small_diacaustic.camera(res, res), corners)
    area = 0.5 * abs(np.dot(px, np.roll(py, 1)) - np.dot(py, np.roll(px, 1)))    # shoelace, in pixels
    assert np.all(img[..., 0] == img[..., 1]) and np.all(img[..., 1] == img[..., 2])
    v = img[..., 0]
    assert v.max() <= 40.0 * (1 + 1e-6)
    # Pixels clear of the light's projected bounding box see only walls, floor and glass: exactly 0.
    yy, xx = np.mgrid[0:res, 0:res]
    near = (xx + 1 > px.min()) & (xx < px.max()) & (yy + 1 > py.min()) & (yy < py.max())
    assert np.all(v[~near] == 0.0)
    # Pixels wholly inside the light's projection see exactly its radiance.
    full = np.ones((res, res), bool)
    for dx in (0, 1):
        for dy in (0, 1):
            full &= inside_convex(px, py, xx + dx, yy + dy)
    assert full.sum() >= 3
    np.testing.assert_allclose(v[full], 40.0, rtol=1e-6)
    # The covered area: each pixel's value / 40 estimates its covered fraction c with binomial
    # standard error sqrt(c (1 - c) / spp); 5 sigma of the sum + 0.01 pixel.
    c = v / 40.0
    se = math.sqrt(np.sum(c * (1 - c)) / spp)
    assert abs(c.sum() - area) <= N_SIGMA * se + 0.01, (c.sum(), area, se)


def test_max_depth_1_point_light_scene_is_black(scene_paths):
    # Point lights are invisible to camera rays; nothing else emits.
    scene = caustica.load_scene(scene_paths["mirror-point"])
    img = caustica.render(scene, "pt", spp=4, res=16, seed=1, max_depth=1).image
    assert not img.any()
