"""The radiance estimate (caustica.photons.estimate): filter normalisation, flux density
against known irradiance (synthetic photons and photons traced by the real kernels),
and the same-side rule of SPEC §3.

Statistics used throughout (Poisson photon process of density λ per unit area, each
photon of power φ, irradiance E = λ φ):

* k-nearest with the 'none' filter, r = distance of the k-th photon:  A = π r² is
  Gamma(k, λ) distributed, so  E[k φ / A] = E · k / (k - 1)  and the relative standard
  deviation of the estimate is 1 / sqrt(k - 2)  (inverse-gamma moments).  For a density
  that is *linear* in position the measure of every disc about x is λ(x) π r², so the
  same holds exactly with λ = λ(x).
* fixed radius R (fewer than k photons found, r = R):  Σ W(d_p, R) φ is unbiased for any
  kernel W normalised to 1 over the disc (Campbell's theorem), with variance
  λ φ² ∫ W² dA.

Tolerances are 5 standard deviations on one estimate and 5 standard deviations of the
mean over independent query points (discs that do not overlap): with fixed seeds the
tests are deterministic, and a 5-sigma band keeps the false-failure rate of a reseeded
run negligible (≈1e-6 for a Gaussian; the inverse-gamma tail for k = 100 is a little
heavier but still ≈1e-5) while a normalisation error of a few per cent over 30 points
is still caught.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from caustica.photons.density_filters import FILTERS, filter_weight
from caustica.photons.estimate import flux_density
from caustica.photons.records import CAUSTIC, EMPTY, INDIRECT, build_photon_map, \
    map_from_buffers
from caustica.photons.trace import TERMINATION_CAP, trace_photon_pass
from caustica.sampling.rng import STREAM_PHOTON
from caustica.tables import compile_scene
from caustica.scene.xml_loader import parse_scene_string

FILTER_NAMES = ("none", "cone", "gaussian", "epanechnikov")


# ----------------------------------------------------------------------------- helpers

def radial_integral(filt, r2, power=1, n=64):
    """∫_disc W(d, r)^power dA by Gauss-Legendre in d on [0, r] (dA = 2π d dd)."""
    r = math.sqrt(r2)
    x, w = np.polynomial.legendre.leggauss(n)
    d = 0.5 * r * (x + 1.0)
    vals = np.array([filter_weight(FILTERS[filt], float(di * di), r2) for di in d])
    return float(np.sum(0.5 * r * w * vals ** power * 2.0 * math.pi * d))


def estimate(pmap, p, n, k, r_max, filt="none"):
    idx = np.empty(k, np.int64)
    d2 = np.empty(k)
    (e0, e1, e2), count = flux_density(pmap, (tuple(map(float, p)), tuple(map(float, n)), (None, 0)),
                                       (k, float(r_max), FILTERS[filt]), (idx, d2), None)
    return np.array([e0, e1, e2]), count


def plane_map(xy, power, normal=(0.0, 0.0, 1.0)):
    n = xy.shape[0]
    pos = np.zeros((n, 3))
    pos[:, :2] = xy
    dirs = np.tile(-np.asarray(normal, float), (n, 1))
    nrm = np.tile(np.asarray(normal, float), (n, 1))
    pw = np.tile(np.asarray(power, float), (n, 1))
    return build_photon_map(pos, dirs, pw, nrm)


def sample_linear(rng, n, a, b):
    """n points on [-1, 1]^2 with density ∝ a + b·x (rejection)."""
    out = np.empty((0, 2))
    while out.shape[0] < n:
        xy = rng.uniform(-1.0, 1.0, (2 * n, 2))
        keep = rng.uniform(0.0, a + abs(b), 2 * n) < a + b * xy[:, 0]
        out = np.concatenate([out, xy[keep]])
    return out[:n]


QUERIES = [(x, y) for x in np.linspace(-0.5, 0.5, 6) for y in np.linspace(-0.5, 0.5, 5)]


# ----------------------------------------------------------------------------- filters

@pytest.mark.parametrize("filt", FILTER_NAMES)
@pytest.mark.parametrize("r", [1e-3, 0.37, 3.0, 250.0])
def test_filter_integrates_to_one(filt, r):
    assert radial_integral(filt, r * r) == pytest.approx(1.0, rel=1e-9)


@pytest.mark.parametrize("filt", FILTER_NAMES)
def test_filter_nonnegative_and_radial(filt):
    r2 = 4.0
    w = [filter_weight(FILTERS[filt], d2, r2) for d2 in np.linspace(0.0, r2, 101)]
    assert min(w) >= 0.0
    assert all(a >= b - 1e-15 for a, b in zip(w, w[1:]))  # non-increasing in d


# ----------------------------------------------------------------------------- synthetic photons

@pytest.fixture(scope="module")
def linear_field():
    """N photons of equal power Φ_tot / N on the plane z = 0, square [-1, 1]², drawn with
    irradiance E(x, y) = E0 (1 + 0.5 x); Φ_tot = ∫ E dA = 4 E0."""
    rng = np.random.default_rng(20240601)
    n, e0 = 200_000, 3.0
    xy = sample_linear(rng, n, 1.0, 0.5)
    phi = np.array([1.0, 0.5, 2.0]) * 4.0 * e0 / n
    return plane_map(xy, phi), e0, phi, n


def test_knn_none_filter_matches_linear_irradiance(linear_field):
    pmap, e0, phi, n = linear_field
    k = 100
    rel = []
    for qx, qy in QUERIES:
        est, count = estimate(pmap, (qx, qy, 0.0), (0, 0, 1), k, 1e3)
        assert count == k
        exact = e0 * (1.0 + 0.5 * qx) * np.array([1.0, 0.5, 2.0])
        expected = exact * k / (k - 1)   # the known bias of k / (π r_k²)
        r = est / expected - 1.0
        np.testing.assert_allclose(r, r[0], atol=1e-6)  # colour: one common scale factor
        # one estimate: 5 sigma, sigma = 1 / sqrt(k - 2)
        assert abs(r[0]) < 5.0 / math.sqrt(k - 2), (qx, qy, est, expected)
        rel.append(r[0])
    # The queries are 0.2 apart, the discs' radius is ≈ 0.025: independent estimates.
    assert abs(np.mean(rel)) < 5.0 / math.sqrt((k - 2) * len(rel)), np.mean(rel)


@pytest.mark.parametrize("filt", FILTER_NAMES)
def test_fixed_radius_every_filter_unbiased(linear_field, filt):
    """Fewer than k photons within R: r = R and every normalised kernel is unbiased."""
    pmap, e0, phi, n = linear_field
    R, k = 0.08, 4000            # λ π R² ≈ 50000 · 0.02 ≈ 1000 photons per disc << k
    w2 = radial_integral(filt, R * R, power=2)
    rel = []
    for qx, qy in QUERIES:
        est, count = estimate(pmap, (qx, qy, 0.0), (0, 0, 1), k, R, filt)
        assert 0 < count < k
        lam = n / 4.0 * (1.0 + 0.5 * qx) / 1.0   # photons per unit area (density ∝ 1 + 0.5x, mean 1)
        exact = lam * phi[0]
        sigma = math.sqrt(lam * w2) * phi[0] / exact       # relative std of one estimate
        r = est[0] / exact - 1.0
        assert abs(r) < 5.0 * sigma, (filt, qx, qy, r, sigma)
        rel.append(r / sigma)
    # queries 0.2 apart > 2R: independent; the mean of standardised errors ~ N(0, 1/M)
    assert abs(np.mean(rel)) < 5.0 / math.sqrt(len(rel)), np.mean(rel)


def test_fixed_radius_counts_every_photon_exactly():
    """A hand-made case: photons at known distances, R fixed, k large — exact sums per filter."""
    d = np.array([0.0, 0.1, 0.25, 0.5, 0.9, 1.2])       # the last one is outside R = 1
    xy = np.stack([d, np.zeros_like(d)], axis=1)
    pmap = plane_map(xy, (2.0, 1.0, 0.5))
    for filt in FILTER_NAMES:
        est, count = estimate(pmap, (0, 0, 0), (0, 0, 1), 50, 1.0, filt)
        assert count == 5
        want = sum(filter_weight(FILTERS[filt], float(x * x), 1.0) for x in d[:5]) * 2.0
        assert est[0] == pytest.approx(want, rel=1e-6)   # positions are float32
    # k = 3: r is the third nearest (0.25), photons beyond are not used
    est, count = estimate(pmap, (0, 0, 0), (0, 0, 1), 3, 1.0, "none")
    assert count == 3
    assert est[0] == pytest.approx(3 * 2.0 / (math.pi * 0.25 ** 2), rel=1e-6)


# ----------------------------------------------------------------------------- the same-side rule

def test_other_side_photons_neither_counted_nor_shrink_radius():
    rng = np.random.default_rng(7)
    front = rng.uniform(-1, 1, (20_000, 2))
    # a much denser layer right at the query point, arriving from the other side
    back = rng.normal(0.0, 0.02, (20_000, 2))
    pos = np.zeros((40_000, 3))
    pos[:20_000, :2] = front
    pos[20_000:, :2] = back
    nrm = np.zeros((40_000, 3))
    nrm[:20_000, 2] = 1.0
    nrm[20_000:, 2] = -1.0
    pw = np.ones((40_000, 3)) * 1e-3
    both = build_photon_map(pos, -nrm, pw, nrm)
    only_front = build_photon_map(pos[:20_000], -nrm[:20_000], pw[:20_000], nrm[:20_000])
    for q in [(0.0, 0.0, 0.0), (0.01, -0.02, 0.0), (0.3, 0.3, 0.0)]:
        for k, R in [(50, 1.0), (5000, 0.05)]:
            for filt in FILTER_NAMES:
                a, ca = estimate(both, q, (0, 0, 1), k, R, filt)
                b, cb = estimate(only_front, q, (0, 0, 1), k, R, filt)
                assert ca == cb
                np.testing.assert_allclose(a, b, rtol=1e-12)
                # and seen from the other side, only the back layer counts
                a, ca = estimate(both, q, (0, 0, -1), k, R, filt)
                assert ca == min(k, int(np.sum(np.hypot(*(back - np.asarray(q[:2])).T) <= R)))
    # perpendicular records (dot == 0) do not count either
    side = build_photon_map(pos[:100], -nrm[:100], pw[:100], np.tile([1.0, 0.0, 0.0], (100, 1)))
    est, count = estimate(side, (0, 0, 0), (0, 0, 1), 10, 10.0)
    assert count == 0 and not est.any()


def test_empty_map_and_nothing_in_range():
    pmap = plane_map(np.array([[5.0, 5.0]]), (1.0, 1.0, 1.0))
    est, count = estimate(pmap, (0, 0, 0), (0, 0, 1), 10, 1.0)
    assert count == 0 and not est.any()
    z = np.zeros((0, 3))
    est, count = estimate(build_photon_map(z, z, z, z), (0, 0, 0), (0, 0, 1), 10, 1.0)
    assert count == 0 and not est.any()


# ----------------------------------------------------------------------------- a BSDF that is evaluated

@pytest.mark.parametrize("alpha", [0.2, 0.05])
@pytest.mark.parametrize("filt", FILTER_NAMES)
def test_bsdf_weighted_estimate_matches_brute_force(filt, alpha):
    """At a point that evaluates its BSDF (pplastic: pm's gather there) each of the k nearest records is weighted by
    f(d, -its direction) of the lobes the point holds: the whole BSDF at alpha 0.2, the diffuse lobe alone at 0.05,
    whose narrow glossy lobe is the camera path's (bsdfs.splits_lobes): the estimate against the same records summed
    by hand with the BSDF's own eval_pdf or eval_part; the records, their count and r are those of the plain estimate
    (the weights change nothing else)."""
    import types
    from caustica.bsdfs import ALL_LOBES, DIFFUSE_PART, build_material_table, eval_part
    from caustica.geometry.scene_geometry import NO_UV
    from caustica.scene.description import GGX, PPLASTIC, Material
    mats = build_material_table(types.SimpleNamespace(materials=[Material(
        PPLASTIC, (0.6, 0.3, 0.1), int_ior=1.6, ext_ior=1.0, specular=(0.9, 0.8, 1.0), distribution=GGX,
        alpha=alpha)]))
    part = ALL_LOBES if alpha >= 0.1 else DIFFUSE_PART
    rng = np.random.default_rng(5)
    n = 3000
    pos = np.zeros((n, 3))
    pos[:, :2] = rng.uniform(-1, 1, (n, 2))
    dirs = rng.normal(size=(n, 3))
    dirs[:, 2] = -np.abs(dirs[:, 2])   # arriving from above
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    power = rng.uniform(0.1, 1.0, (n, 3))
    pmap = build_photon_map(pos, dirs, power, np.tile([0.0, 0.0, 1.0], (n, 1)))
    up = (0.0, 0.0, 1.0)
    d = tuple(np.array([0.4, -0.2, -1.0]) / np.linalg.norm([0.4, -0.2, -1.0]))   # the camera path arriving
    for k, R in [(50, 1.0), (4000, 0.3)]:
        for q in [(0.0, 0.0, 0.0), (0.5, -0.3, 0.0)]:
            idx, d2 = np.empty(k, np.int64), np.empty(k)
            _, count = flux_density(pmap, (q, up, (None, 0)), (k, R, FILTERS[filt]), (idx, d2), None)
            weighted, count_w = flux_density(pmap, (q, up, (None, 0)), (k, R, FILTERS[filt]), (idx, d2),
                                             (mats, 0, d, up, up, NO_UV))
            assert count_w == count > 0 and (count == k) == (k == 50)
            r2 = d2[:count].max() if count == k else R * R
            want = np.zeros(3)
            for j in range(count):
                i = idx[j]
                c, scale, _ = eval_part(mats, 0, d, up, up, NO_UV, tuple(-pmap.direction[i].astype(np.float64)),
                                        part)
                want += filter_weight(FILTERS[filt], d2[j], r2) * scale * np.array(c) * pmap.power[i]
            np.testing.assert_allclose(weighted, want, rtol=1e-9)


# ----------------------------------------------------------------------------- real kernels: a diffuse sphere

SPHERE_R = 5.0
RHO = 0.5
INTENSITY = (2.0, 1.0, 3.0)
LIGHT_POS = (1.0, 2.0, -0.5)   # off centre: the direct light is not uniform, the bounced light is

SPHERE_XML = f"""<?xml version="1.0"?>
<scene version="3.0.0">
  <sensor type="perspective"><float name="fov" value="45"/>
    <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
  <shape type="sphere"><float name="radius" value="{SPHERE_R}"/><boolean name="flip_normals" value="true"/>
    <bsdf type="diffuse"><float name="reflectance" value="{RHO}"/></bsdf></shape>
  <emitter type="point"><point name="position" x="{LIGHT_POS[0]}" y="{LIGHT_POS[1]}" z="{LIGHT_POS[2]}"/>
    <rgb name="intensity" value="{', '.join(map(str, INTENSITY))}"/></emitter>
</scene>
"""


@pytest.fixture(scope="module")
def sphere_photons():
    """Photons traced by the real kernels inside a closed diffuse sphere (inward normals).

    Inside a diffuse sphere every surface element sees every other one with the form factor
    dA / (4π R²), so the irradiance due to light that bounced b >= 1 times is uniform:
    E_b = ρ^b Φ / (4π R²) whatever the light's position.  Photon maps store exactly those
    (b = 1 .. mr); and a chord disc of radius r cuts a cap of area exactly π r² out of the
    sphere (Archimedes), so the k-nearest estimate has no geometric bias here.
    """
    scene = compile_scene(parse_scene_string(SPHERE_XML, ".", None, "sphere.xml"))
    n, mr = 200_000, 3
    buf, _, _ = trace_photon_pass(scene, (11, STREAM_PHOTON, n), (mr, TERMINATION_CAP))
    return buf, n, mr


def _sphere_queries(m=24, seed=3):
    """m points on the sphere, well apart (a Fibonacci lattice), with inward normals."""
    i = np.arange(m) + 0.5
    z = 1.0 - 2.0 * i / m
    phi = math.pi * (1.0 + 5 ** 0.5) * i
    u = np.stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z], axis=1)
    return u * SPHERE_R, -u


def test_sphere_records_live_on_the_sphere(sphere_photons):
    buf, n, mr = sphere_photons
    keep = buf.kind != EMPTY
    assert np.all(buf.kind[keep] == INDIRECT)          # no specular surface: nothing is a caustic
    p = buf.position[keep].astype(np.float64)
    np.testing.assert_allclose(np.linalg.norm(p, axis=1), SPHERE_R, rtol=1e-5)
    # normals point inwards (the side the photons arrive from), directions hit the front
    nrm = buf.normal[keep].astype(np.float64)
    np.testing.assert_allclose(np.einsum("ij,ij->i", nrm, -p / SPHERE_R), 1.0, atol=1e-4)
    assert np.all(np.einsum("ij,ij->i", buf.direction[keep], nrm) < 0)


def test_sphere_irradiance_one_bounce_knn(sphere_photons):
    """Only the records of the first bounce (slot 0 of each photon): E_1 = ρ Φ / (4π R²)."""
    buf, n, mr = sphere_photons
    slot0 = np.arange(n) * (mr + 1)
    first = slot0[buf.kind[slot0] != EMPTY]
    assert first.size > 0.999 * n            # a closed sphere: practically every photon bounces
    pmap = build_photon_map(buf.position[first], buf.direction[first], buf.power[first], buf.normal[first])
    phi = 4.0 * math.pi * np.asarray(INTENSITY)
    e1 = RHO * phi / (4.0 * math.pi * SPHERE_R ** 2)
    k = 400       # r ≈ 0.45; 60 queries ≈ 2.3 apart: independent discs, mean within 5σ = 3.2 %
    rel = []
    for p, nrm in zip(*_sphere_queries(60)):
        est, count = estimate(pmap, p, nrm, k, 10.0)
        assert count == k
        r = est / (e1 * k / (k - 1)) - 1.0
        np.testing.assert_allclose(r, r[0], atol=1e-5)
        assert abs(r[0]) < 5.0 / math.sqrt(k - 2), (p, est, e1)
        rel.append(r[0])
    assert abs(np.mean(rel)) < 5.0 / math.sqrt((k - 2) * len(rel)), np.mean(rel)


def test_sphere_irradiance_all_bounces_fixed_radius(sphere_photons):
    """The whole map (bounces 1..mr), fixed radius: E = Φ/(4πR²) Σ_b ρ^b, unbiased for every filter."""
    buf, n, mr = sphere_photons
    pmap = map_from_buffers(buf, (INDIRECT, CAUSTIC))
    phi = 4.0 * math.pi * np.asarray(INTENSITY)
    area = 4.0 * math.pi * SPHERE_R ** 2
    e_b = [RHO ** b * phi[0] / area for b in range(1, mr + 1)]
    R = 0.6                                   # a cap of area π R² = 1.13 on a sphere of area 314
    for filt in FILTER_NAMES:
        w2 = radial_integral(filt, R * R, power=2)
        # Var = Σ_b λ_b φ_b² ∫W² with λ_b = N / area and φ_b = ρ^b Φ / N
        sigma = math.sqrt(sum(n / area * (RHO ** b * phi[0] / n) ** 2 * w2 for b in range(1, mr + 1)))
        rel = []
        for p, nrm in zip(*_sphere_queries()):
            est, count = estimate(pmap, p, nrm, 20_000, R, filt)
            assert 0 < count < 20_000
            z = (est[0] - sum(e_b)) / sigma
            assert abs(z) < 5.0, (filt, p, est[0], sum(e_b), sigma)
            rel.append(z)
        assert abs(np.mean(rel)) < 5.0 / math.sqrt(len(rel)), (filt, np.mean(rel))
