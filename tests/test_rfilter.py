"""Reconstruction filters: box, tent and gaussian, as Mitsuba 3 defines them, applied by sampling.

1. The sampled sub-pixel offsets follow the filter (restricted to the film at its edges): a
   chi-square test of their histogram against the filter's own integral, with equal-probability
   bins and the statistic's 1e-6 quantile as the bound; and the map from the uniform number is
   monotone (so stratified numbers stay stratified).
2. Images: a small scene of emitting rectangles with sharp edges (some at the film's edge), where
   a pixel's value is exactly the filter's mass over the emitters, rendered by ``pt`` and by
   Mitsuba 3 (``scalar_rgb``) from the same XML; per pixel within the noise of both.  A film
   without ``<rfilter>`` is Mitsuba's default, a gaussian of stddev 0.5, in both renderers.
3. Bad input: an unknown filter, a negative or zero radius or stddev, a property the filter does
   not take: one line naming the file and line, exit 2.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numba
import numpy as np
import pytest

from caustica.errors import SceneError
from caustica.sampling.filters import BOX, GAUSSIAN, TENT, film_position
from caustica.scene import load_scene_file, parse_scene_string
from caustica.scene.description import ReconstructionFilter

N_SIGMA = 5.0


# ----------------------------------------------------------------------------- the filters, written out

def density(kind: str, radius: float, stddev: float, x, steps: int = 0):
    """Mitsuba 3's filters (src/rfilters/*.cpp), written out here independently of the kernels.

    ``steps``: evaluate as Mitsuba's scalar variants do, from a table of ``steps`` values over
    [0, radius] (each the value at its step's inner end; 0 beyond), rather than the formula.
    """
    x = np.asarray(x, dtype=np.float64)
    if steps:
        r = support(kind, radius, stddev)
        i = np.minimum(np.floor(np.abs(x) * steps / r), steps)
        return np.where(i >= steps, 0.0, density(kind, radius, stddev, r * i / steps))
    if kind == "tent":
        return np.maximum(0.0, 1.0 - np.abs(x) / radius)
    if kind == "gaussian":   # cut off at 4 deviations, where it reaches 0
        return np.maximum(0.0, np.exp(-x * x / (2 * stddev ** 2)) - math.exp(-16.0 / 2))
    return ((x >= -0.5) & (x < 0.5)).astype(np.float64)


def support(kind: str, radius: float, stddev: float) -> float:
    """The filter's radius: the box's 1/2, the tent's radius, the gaussian's 4 deviations."""
    return {"box": 0.5, "tent": radius, "gaussian": 4.0 * stddev}[kind]


def mass(kind, radius, stddev, lo, hi, steps=0, n=40_001) -> float:
    """∫ filter over [lo, hi] by the trapezoid rule on n points (error ~1e-9 of the total here)."""
    if hi <= lo:
        return 0.0
    x = np.linspace(lo, hi, n)
    return float(np.trapezoid(density(kind, radius, stddev, x, steps), x))


def window(kind, radius, stddev, p, n, border=False):
    """The offsets from pixel p's centre that its samples may take: the support, cut at the film's edges."""
    r = support(kind, radius, stddev)
    c = p + 0.5
    return (-r, r) if border else (max(-r, -c), min(r, n - c))


@numba.njit
def _positions(kind, radius, stddev, border, p, n, us):
    out = np.empty(us.size)
    for i in range(us.size):
        out[i] = film_position(kind, radius, stddev, border, p, n, us[i])
    return out


KIND_CODES = {"box": BOX, "tent": TENT, "gaussian": GAUSSIAN}


def positions(kind, radius, stddev, p, n, us, border=False):
    r = support(kind, radius, stddev)
    return _positions(KIND_CODES[kind], r, stddev if kind == "gaussian" else 0.0, border, p, n, us)


def chi2_quantile(dof: int, p_false: float) -> float:
    """The (1 - p_false) quantile of chi-square with dof degrees of freedom (Wilson-Hilferty; its
    relative error is below 1e-3 for dof >= 30 at these tails)."""
    lo, hi = 0.0, 10.0
    for _ in range(100):                       # z with P(N(0,1) > z) = p_false
        z = 0.5 * (lo + hi)
        lo, hi = (z, hi) if 0.5 * math.erfc(z / math.sqrt(2)) > p_false else (lo, z)
    a = 2.0 / (9.0 * dof)
    return dof * (1.0 - a + z * math.sqrt(a)) ** 3


# ----------------------------------------------------------------------------- 1. the offsets' distribution

#: (kind, tent radius, gaussian stddev, pixel, film size, sample_border)
HISTOGRAM_CASES = {
    "box": ("box", 0.0, 0.0, 3, 8, False),
    "tent inside": ("tent", 1.0, 0.0, 5, 16, False),
    "tent r=1.6 at the edge": ("tent", 1.6, 0.0, 0, 16, False),
    "gaussian inside": ("gaussian", 0.0, 0.5, 7, 16, False),
    "gaussian at the edge": ("gaussian", 0.0, 0.5, 15, 16, False),
    "gaussian cut on both sides": ("gaussian", 0.0, 0.5, 1, 3, False),
    "gaussian sample_border": ("gaussian", 0.0, 0.5, 0, 16, True),
    "gaussian stddev 0.2": ("gaussian", 0.0, 0.2, 4, 9, False),
    "gaussian stddev 1.7": ("gaussian", 0.0, 1.7, 2, 40, False),
}
N_SAMPLES = 200_000
N_BINS = 50


@pytest.mark.parametrize("case", list(HISTOGRAM_CASES))
def test_offsets_follow_the_filter(case):
    kind, radius, stddev, p, n, border = HISTOGRAM_CASES[case]
    lo, hi = window(kind, radius, stddev, p, n, border)
    # Equal-probability bins from the filter's integral, so each expects N_SAMPLES / N_BINS samples.
    x = np.linspace(lo, hi, 200_001)
    f = density(kind, radius, stddev, x)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))])
    edges = np.interp(np.linspace(0, cdf[-1], N_BINS + 1), cdf, x)
    us = np.random.default_rng(20261203).random(N_SAMPLES)
    off = positions(kind, radius, stddev, p, n, us, border) - (p + 0.5)
    assert off.min() >= lo - 1e-12 and off.max() <= hi + 1e-12, (off.min(), off.max(), lo, hi)
    counts = np.histogram(off, bins=np.concatenate([[-np.inf], edges[1:-1], [np.inf]]))[0]
    expected = N_SAMPLES / N_BINS
    chi2 = float(np.sum((counts - expected) ** 2 / expected))
    bound = chi2_quantile(N_BINS - 1, 1e-6)
    assert chi2 <= bound, f"{case}: chi2 {chi2:.1f} > {bound:.1f} ({N_BINS - 1} dof)"


def test_the_histogram_test_has_power():
    """The same statistic rejects a near miss: tent offsets judged against a gaussian of the same spread,
    and untruncated gaussian offsets judged against the film-truncated distribution at the edge."""
    us = np.random.default_rng(5).random(N_SAMPLES)
    bound = chi2_quantile(N_BINS - 1, 1e-6)
    for sampled, judged in ((("tent", 1.2, 0.0, 7, 16, False), ("gaussian", 0.0, 0.5, 7, 16, False)),
                            (("gaussian", 0.0, 0.5, 0, 16, True), ("gaussian", 0.0, 0.5, 0, 16, False))):
        kind, radius, stddev, p, n, border = judged
        lo, hi = window(kind, radius, stddev, p, n, border)
        x = np.linspace(lo, hi, 200_001)
        f = density(kind, radius, stddev, x)
        cdf = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(x))])
        edges = np.interp(np.linspace(0, cdf[-1], N_BINS + 1), cdf, x)
        off = positions(*sampled[:5], us, sampled[5]) - (sampled[3] + 0.5)
        counts = np.histogram(off, bins=np.concatenate([[-np.inf], edges[1:-1], [np.inf]]))[0]
        chi2 = float(np.sum((counts - N_SAMPLES / N_BINS) ** 2 / (N_SAMPLES / N_BINS)))
        assert chi2 > 10 * bound, (sampled, judged, chi2)


@pytest.mark.parametrize("case", list(HISTOGRAM_CASES))
def test_offsets_are_monotone_in_u(case):
    """A monotone map keeps SPPM's (0, 2)-sequence stratified: sorted numbers give sorted positions,
    0 gives the window's start, and no number leaves the window."""
    kind, radius, stddev, p, n, border = HISTOGRAM_CASES[case]
    us = np.linspace(0.0, 1.0, 100_001)[:-1]
    pos = positions(kind, radius, stddev, p, n, us, border)
    assert np.all(np.diff(pos) >= 0.0)
    lo, hi = window(kind, radius, stddev, p, n, border)
    # Where the window is the gaussian's whole support its CDF is flat at the ends (the filter reaches 0
    # there), so the inverse is good to about sqrt(2 eps / f'(4σ)) ~ 3e-7 pixel; elsewhere to 1e-12.
    assert p + 0.5 + lo <= pos[0] <= p + 0.5 + lo + 1e-6
    assert pos[-1] <= p + 0.5 + hi


def test_box_is_the_uniform_jitter_bit_for_bit():
    us = np.random.default_rng(1).random(1000)
    assert np.array_equal(positions("box", 0.0, 0.0, 3, 8, us), 3 + us)


# ----------------------------------------------------------------------------- 2. images against Mitsuba 3

W, H = 16, 12
#: Emitting rectangles (radiance 1) in pixel coordinates: x0, x1, y0, y1.  Edges fall at fractions of
#: a pixel; one lies 0.4 px inside the film's left edge, one 0.3 px inside its bottom edge, and one
#: rectangle reaches beyond the top-right corner, so the truncation at the film's edge is tested too.
RECTS = ((0.4, 5.3, 3.6, 8.25), (9.7, 13.2, 7.5, 11.7), (14.6, 20.0, -3.0, 2.3))


def edge_scene_xml(rfilter: str) -> str:
    """Camera at z = 1 looking down -z with a 90° horizontal field of view: on the plane z = 0 one
    pixel is 1/8 unit and pixel coordinates (px, py) are world (px / 8 - 1, 0.75 - py / 8)."""
    shapes = []
    for a, b, c, d in RECTS:
        x0, x1, y0, y1 = a / 8 - 1, b / 8 - 1, 0.75 - d / 8, 0.75 - c / 8
        shapes.append(f"""<shape type="rectangle"><transform name="to_world">
            <scale x="{(x1 - x0) / 2}" y="{(y1 - y0) / 2}"/><translate x="{(x0 + x1) / 2}" y="{(y0 + y1) / 2}"/>
            </transform><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>""")
    return f"""<scene version="3.0.0">
    <integrator type="path"/>
    <sensor type="perspective"><float name="fov" value="90"/>
        <transform name="to_world"><lookat origin="0, 0, 1" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{W}"/><integer name="height" value="{H}"/>{rfilter}</film>
    </sensor>
    {''.join(shapes)}
</scene>"""


def expected_image(kind, radius, stddev, steps=0):
    """Each pixel's value: the filter's mass over the emitters (the film-truncated filter, per axis)."""
    out = np.zeros((H, W))
    for py in range(H):
        for px in range(W):
            for a, b, c, d in RECTS:
                v = 1.0
                for p, n, e0, e1 in ((px, W, a, b), (py, H, c, d)):
                    lo, hi = window(kind, radius, stddev, p, n)
                    cen = p + 0.5
                    v *= (mass(kind, radius, stddev, max(lo, e0 - cen), min(hi, e1 - cen), steps)
                          / mass(kind, radius, stddev, lo, hi, steps))
                out[py, px] += v
    return out


#: name -> (<rfilter> XML, kind, tent radius, gaussian stddev)
IMAGE_CASES = {
    "gaussian": ('<rfilter type="gaussian"/>', "gaussian", 0.0, 0.5),
    "gaussian stddev 0.35": ('<rfilter type="gaussian"><float name="stddev" value="0.35"/></rfilter>',
                             "gaussian", 0.0, 0.35),
    "tent": ('<rfilter type="tent"/>', "tent", 1.0, 0.0),
    "tent radius 1.6": ('<rfilter type="tent"><float name="radius" value="1.6"/></rfilter>', "tent", 1.6, 0.0),
    # no <rfilter>: both renderers take Mitsuba's default, the gaussian of stddev 0.5
    "no rfilter": ("", "gaussian", 0.0, 0.5),
}
SPP = 1024          # caustica, one render
MI_SEEDS, MI_SPP = 32, 128   # Mitsuba: 32 renders, for a per-pixel standard error from their spread


def binomial_tolerance(p, n, p_false=1e-6):
    """How far the mean of n Bernoulli(p) samples may stray from p: Bernstein's inequality at
    two-sided probability p_false, t = L/3 + sqrt((L/3)² + 2 n p (1 - p) L) counts with
    L = ln(2 / p_false).  About 5.3 standard errors when n p is large; still a bound (about 10
    counts) where n p is below 1 and the normal approximation fails (a single hit in a pixel
    the filter barely reaches)."""
    L = math.log(2.0 / p_false)
    return (L / 3 + np.sqrt((L / 3) ** 2 + 2 * n * p * (1 - p) * L)) / n


def caustica_pt(xml: str, spp: int = SPP) -> np.ndarray:
    import caustica
    from caustica.tables import compile_scene
    return caustica.render(compile_scene(parse_scene_string(xml)), "pt", spp=spp, seed=11).image[..., 0].astype(
        np.float64)


@pytest.mark.mitsuba
@pytest.mark.parametrize("case", list(IMAGE_CASES))
def test_sharp_edges_match_mitsuba(mi, case):
    """Every sample of this scene is 1 (an emitter) or 0, so caustica's pixel is a binomial mean about
    the expected value v, bounded by Bernstein's inequality (:func:`binomial_tolerance`).  Mitsuba's
    pixel is a ratio of filter-weighted sums; its standard error comes from the spread of 32 seeds.

    Mitsuba's scalar variants evaluate the filter from a 31-step table, not the formula caustica
    samples (and Mitsuba's JIT variants evaluate); the difference of the two images is computed
    here, from the filter alone, and allowed on top of the noise.  The test checks that this
    is what Mitsuba does, that caustica matches the formula within its binomial noise, and that the
    box filter (what caustica did before) would fail the same comparison.
    """
    rf, kind, radius, stddev = IMAGE_CASES[case]
    xml = edge_scene_xml(rf)
    scene = mi.load_string(xml)
    theirs = np.stack([np.asarray(mi.render(scene, seed=k, spp=MI_SPP))[..., 0] for k in range(MI_SEEDS)])
    m_mean = theirs.mean(axis=0).astype(np.float64)
    m_se = theirs.std(axis=0, ddof=1) / math.sqrt(MI_SEEDS)

    exact = expected_image(kind, radius, stddev)
    stepped = expected_image(kind, radius, stddev, steps=31)
    floor = 1e-5   # float32 sums: a pixel wholly inside or outside an emitter is 1 or 0 up to rounding

    # Mitsuba scalar_rgb is the 31-step filter, within its noise.
    z_steps = np.abs(m_mean - stepped) / (N_SIGMA * m_se + floor)
    assert z_steps.max() <= 1.0, (case, np.unravel_index(z_steps.argmax(), z_steps.shape), z_steps.max())

    ours = caustica_pt(xml)
    c_tol = binomial_tolerance(np.clip(exact, 0.0, 1.0), SPP)
    # caustica is the filter's formula, within its binomial noise.
    z_exact = np.abs(ours - exact) / (c_tol + floor)
    assert z_exact.max() <= 1.0, (case, np.unravel_index(z_exact.argmax(), z_exact.shape), z_exact.max())

    # caustica against Mitsuba: the noise of both plus the 31-step table's own difference.
    tol = np.sqrt(c_tol ** 2 + (N_SIGMA * m_se) ** 2) + np.abs(stepped - exact) + floor
    z = np.abs(ours - m_mean) / tol
    worst = np.unravel_index(z.argmax(), z.shape)
    assert z.max() <= 1.0, f"{case}: pixel {worst}: {ours[worst]:.4f} vs Mitsuba {m_mean[worst]:.4f} (tol {tol[worst]:.4f})"

    # Power: the box filter's image (the uniform jitter, what caustica did before) fails the same
    # comparison, its binomial noise taken from its own expected image.
    boxed = caustica_pt(edge_scene_xml('<rfilter type="box"/>'))
    box_exact = expected_image("box", 0.0, 0.0)
    tol_box = (np.sqrt(binomial_tolerance(box_exact, SPP) ** 2 + (N_SIGMA * m_se) ** 2)
               + np.abs(stepped - exact) + floor)
    assert np.sum(np.abs(boxed - m_mean) > tol_box) >= 10, case


#: Every method draws its camera rays through camera.generate_ray: the same filter.  (method, settings,
#: samples per pixel); photons are few: the emitters are black and nothing else is in the scene.
METHOD_CASES = {
    "pm": ("pm", dict(photons=1000, spp=256), 256),
    "spm": ("spm", dict(streams=100, spp=256), 256),
    "sppm": ("sppm", dict(photons=1000, passes=256), 256),
    "pspm": ("pspm", dict(streams=100, passes=128), 128),
}


@pytest.mark.parametrize("case", list(METHOD_CASES))
def test_every_method_gets_the_filter(case):
    """The gaussian edge scene by the photon methods: the filter's exact mass per pixel, within the
    binomial bound of their samples per pixel (sppm's and pspm's passes are stratified, which only
    lowers their noise)."""
    import caustica
    from caustica.tables import compile_scene
    method, settings, n = METHOD_CASES[case]
    rf, kind, radius, stddev = IMAGE_CASES["gaussian"]
    scene = compile_scene(parse_scene_string(edge_scene_xml(rf)))
    img = caustica.render(scene, method, seed=5, **settings).image[..., 0].astype(np.float64)
    exact = expected_image(kind, radius, stddev)
    z = np.abs(img - exact) / (binomial_tolerance(np.clip(exact, 0.0, 1.0), n) + 1e-5)
    assert z.max() <= 1.0, (case, np.unravel_index(z.argmax(), z.shape), z.max())


def test_a_film_without_rfilter_is_mitsubas_gaussian():
    """Mitsuba 3's default (src/render/film.cpp): a gaussian of stddev 0.5, cut off at radius 2 = 4
    stddev; for a sensor without a film too.  It renders the same bits as the explicit gaussian."""
    import caustica
    from caustica.camera import camera_params
    from caustica.tables import compile_scene
    d = parse_scene_string(edge_scene_xml(""))
    assert d.camera.rfilter == ReconstructionFilter("gaussian", stddev=0.5)
    cam = camera_params(d.camera)
    assert (cam.filter_kind, cam.filter_radius, cam.filter_stddev) == (GAUSSIAN, 2.0, 0.5)
    no_film = parse_scene_string('<scene version="3.0.0"><sensor type="perspective"><float name="fov" value="45"/>'
                                 '</sensor><shape type="rectangle"/></scene>')
    assert no_film.camera.rfilter == ReconstructionFilter("gaussian", stddev=0.5)
    implicit, explicit = (caustica.render(compile_scene(parse_scene_string(edge_scene_xml(rf))), "pt", spp=4,
                                          seed=3, threads=1).image for rf in ("", '<rfilter type="gaussian"/>'))
    assert implicit.tobytes() == explicit.tobytes()


@pytest.mark.mitsuba
def test_mitsubas_default_filter_is_this_gaussian(mi):
    """What the test above takes as Mitsuba's default is what Mitsuba 3 builds for a film without one."""
    rf = mi.load_string(edge_scene_xml("")).sensors()[0].film().rfilter()
    assert str(rf).startswith("GaussianFilter[stddev=0.50,"), str(rf)
    assert rf.radius() == pytest.approx(2.0)


def test_filters_are_read_with_mitsubas_defaults():
    for rf, want in [('<rfilter type="gaussian"/>', ("gaussian", 0.5)),
                     ('<rfilter type="gaussian"><float name="stddev" value="0.3"/></rfilter>', ("gaussian", 0.3)),
                     ('<rfilter type="tent"/>', ("tent", 1.0)),
                     ('<rfilter type="tent"><integer name="radius" value="2"/></rfilter>', ("tent", 2.0))]:
        f = parse_scene_string(edge_scene_xml(rf)).camera.rfilter
        assert (f.kind, f.stddev if f.kind == "gaussian" else f.radius) == want


def test_the_sidecar_records_the_filter():
    import caustica
    from caustica.tables import compile_scene
    for rf, want in [("", {"type": "gaussian", "stddev": 0.5}),
                     ('<rfilter type="box"/>', {"type": "box"}),
                     ('<rfilter type="gaussian"/>', {"type": "gaussian", "stddev": 0.5}),
                     ('<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>',
                      {"type": "tent", "radius": 1.5})]:
        scene = compile_scene(parse_scene_string(edge_scene_xml(rf)))
        assert caustica.render(scene, "pt", spp=1, threads=1).stats["rfilter"] == want


# ----------------------------------------------------------------------------- 3. bad input

BAD_FILTERS = {
    "unknown type": ('<rfilter type="mitchell"/>', "supported: box, tent, gaussian"),
    "negative radius": ('<rfilter type="tent">\n<float name="radius" value="-1"/></rfilter>', "'radius' must be positive"),
    "zero radius": ('<rfilter type="tent">\n<float name="radius" value="0"/></rfilter>', "'radius' must be positive"),
    "negative stddev": ('<rfilter type="gaussian">\n<float name="stddev" value="-0.5"/></rfilter>',
                        "'stddev' must be positive"),
    "radius of a gaussian": ('<rfilter type="gaussian">\n<float name="radius" value="3"/></rfilter>', "radius"),
    "two filters": ('<rfilter type="box"/>\n<rfilter type="tent"/>', "only one <rfilter>"),
}


def bad_scene(tmp_path, rfilter: str):
    """The filter's first line is line 4 of the file, a property on its own line line 5."""
    path = tmp_path / "bad-filter.xml"
    path.write_text('<scene version="3.0.0">\n<sensor type="perspective"><float name="fov" value="45"/>\n'
                    '<film type="hdrfilm">\n' + rfilter + "\n</film></sensor>\n</scene>\n")
    return path


@pytest.mark.parametrize("case", list(BAD_FILTERS))
def test_bad_filters_name_file_and_line(tmp_path, case):
    rf, part = BAD_FILTERS[case]
    path = bad_scene(tmp_path, rf)
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    msg = str(e.value)
    line = 4 if case == "unknown type" else 5
    assert f"bad-filter.xml:{line}:" in msg and part in msg, msg
    assert "\n" not in msg


def test_bad_filter_exits_2_with_one_line(tmp_path):
    path = bad_scene(tmp_path, BAD_FILTERS["negative stddev"][0])
    env = dict(os.environ, COLUMNS="200")
    proc = subprocess.run([sys.executable, "-m", "caustica", "render", str(path), "-o", str(tmp_path / "x.exr"),
                           "-q"], capture_output=True, text=True, env=env, timeout=300)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("caustica: error: ") and "bad-filter.xml:5:" in lines[0], lines
    assert not list(tmp_path.glob("x.*"))


def test_gaussian_table_is_close_to_the_filter():
    """The tabulated inverse CDF samples a CDF within 2e-7 of the filter's, against the CDF written out
    here by quadrature: the sampled CDF at z is the fraction u whose tabulated position is z."""
    z = np.linspace(-4.0, 4.0, 160_001)
    f = density("gaussian", 0.0, 1.0, z)
    exact = np.concatenate([[0.0], np.cumsum(0.5 * (f[1:] + f[:-1]) * np.diff(z))])
    exact /= exact[-1]
    us = np.linspace(0.0, 1.0, 2_000_001)
    zs = positions("gaussian", 0.0, 1.0, 50, 100, us) - 50.5
    sampled = np.interp(z, zs, us)
    err = np.abs(sampled - exact)
    assert err.max() < 2e-7, err.max()
