"""Projectors and textured spots (Mitsuba 3's ``projector`` and a ``spot``'s ``texture``): loader, the emitters'
values against Mitsuba's, the irradiance on a plane against the analytic one, emitted power and photons, and
renders against Mitsuba 3."""
from __future__ import annotations

import math

import numpy as np
import pytest

from caustica.emitters import PROJECTOR
from caustica.scene import load_scene_description
from caustica.tables import compile_scene
from test_spot_directional import _light_samples, ball_flux, emit

SENSOR = """<sensor type="perspective"><float name="fov" value="30"/>
  <transform name="to_world"><lookat origin="0,6,0.1" target="0,0,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
  <rfilter type="box"/></film></sensor>"""
FLOOR = ('<shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>'
         '</shape>')
#: an image of 6 x 4 texels (wider than high: the projector's aspect 3 / 2), sRGB-encoded in a PNG
IMAGE = np.random.default_rng(5).integers(0, 256, size=(4, 6, 3)).astype(np.uint8)
IMAGE[1, 2] = 0   # one black texel: no photon may leave through it (nearest filter)
PROJ_XML = ('<emitter type="projector"><transform name="to_world"><lookat origin="0.4, 2, -0.3" '
            'target="-0.2, 0, 0.2" up="0, 0, 1"/></transform><float name="scale" value="1.7"/>'
            '<float name="fov" value="{fov}"/>{irradiance}</emitter>')
BITMAP = ('<texture type="bitmap" name="{name}"><string name="filename" value="img.png"/>'
          '<string name="filter_type" value="{filter}"/><string name="wrap_mode" value="{wrap}"/></texture>')
CHECKER = ('<texture type="checkerboard" name="irradiance"><rgb name="color0" value="0.9, 0.5, 0.2"/>'
           '<rgb name="color1" value="0.1, 0.3, 0.6"/></texture>')
SPOT_XML = ('<emitter type="spot"><transform name="to_world"><lookat origin="-0.3, 2.2, 0.4" target="0.3, 0, -0.2" '
            'up="1, 0, 0"/></transform><rgb name="intensity" value="3, 2, 1"/><float name="cutoff_angle" value="35"/>'
            '<float name="beam_width" value="20"/>{texture}</emitter>')


def write_png(path, pixels=IMAGE):
    from PIL import Image
    Image.fromarray(pixels).save(path)
    return path


def write_scene(tmp_path, body: str, name: str = "s.xml"):
    write_png(tmp_path / "img.png")
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n{SENSOR}\n{FLOOR}\n{body}\n</scene>\n')
    return path


def load(tmp_path, body):
    return compile_scene(load_scene_description(str(write_scene(tmp_path, body))))


def srgb_to_linear(c):
    c = np.asarray(c, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def lookup(img, u, v, filt="bilinear", wrap="repeat"):
    """Mitsuba's bitmap lookup written out again (texel (i, j) centred at ((j + 1/2) / W, (i + 1/2) / H))."""
    h, w = img.shape[:2]

    def index(k, n):
        if wrap == "clamp":
            return np.clip(k, 0, n - 1)
        if wrap == "mirror":
            k = np.mod(k, 2 * n)
            return np.where(k >= n, 2 * n - 1 - k, k)
        return np.mod(k, n)
    if filt == "nearest":
        return img[index(np.floor(v * h).astype(int), h), index(np.floor(u * w).astype(int), w)]
    x, y = u * w - 0.5, v * h - 0.5
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    ax, ay = (x - x0)[:, None], (y - y0)[:, None]
    c = [[img[index(y0 + dy, h), index(x0 + dx, w)] for dx in (0, 1)] for dy in (0, 1)]
    return (1 - ay) * ((1 - ax) * c[0][0] + ax * c[0][1]) + ay * ((1 - ax) * c[1][0] + ax * c[1][1])


def look_at(origin, target, up):
    """Mitsuba's lookat frame: columns x = normalize(up x dir), y = dir x x, z = dir."""
    d = np.asarray(target, float) - origin
    d /= np.linalg.norm(d)
    x = np.cross(up, d)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(d, x), d])


def mitsuba_emitter(mi, tmp_path, kind, fov=50.0, filt="bilinear", wrap="repeat", irradiance="bitmap"):
    T = mi.ScalarTransform4f
    bitmap = {"type": "bitmap", "filename": str(write_png(tmp_path / "img.png")), "filter_type": filt,
              "wrap_mode": wrap}
    if kind == "projector":
        image = {"bitmap": bitmap, "checkerboard": {"type": "checkerboard",
                                                    "color0": {"type": "rgb", "value": [0.9, 0.5, 0.2]},
                                                    "color1": {"type": "rgb", "value": [0.1, 0.3, 0.6]}},
                 "rgb": {"type": "rgb", "value": [0.8, 0.6, 0.3]}}[irradiance]
        return mi.load_dict({"type": "projector", "scale": 1.7, "fov": fov, "irradiance": image,
                             "to_world": T().look_at(origin=[0.4, 2, -0.3], target=[-0.2, 0, 0.2], up=[0, 0, 1])})
    return mi.load_dict({"type": "spot", "intensity": {"type": "rgb", "value": [3, 2, 1]}, "cutoff_angle": 35.0,
                         "beam_width": 20.0, "texture": bitmap,
                         "to_world": T().look_at(origin=[-0.3, 2.2, 0.4], target=[0.3, 0, -0.2], up=[1, 0, 0])})


def projector_body(fov=50, filt="bilinear", wrap="repeat", irradiance="bitmap"):
    image = {"bitmap": BITMAP.format(name="irradiance", filter=filt, wrap=wrap), "checkerboard": CHECKER,
             "rgb": '<rgb name="irradiance" value="0.8, 0.6, 0.3"/>'}[irradiance]
    return PROJ_XML.format(fov=fov, irradiance=image)


SPOT_BODY = SPOT_XML.format(texture=BITMAP.format(name="texture", filter="bilinear", wrap="repeat"))


# ----------------------------------------------------------------------------- loader

def test_projector_is_read_as_mitsuba_reads_it(tmp_path):
    """The projector's frame is its lookat's, its x fov the given one, its y fov's tangent tan_x / aspect (the
    image's 6 / 4); π scale in its radiance; its power π s A × the texels' mean (A = 4 tan_x tan_y)."""
    scene = load(tmp_path, projector_body(fov=50))
    lights = scene.lights
    assert list(lights.kind) == [PROJECTOR]
    frame = look_at(np.array([0.4, 2, -0.3]), [-0.2, 0, 0.2], [0, 0, 1])
    assert np.allclose(np.column_stack([lights.edge1[0], lights.edge2[0], lights.normal[0]]), frame)
    tx = math.tan(math.radians(25))
    assert np.allclose(lights.cone[0, :3], (tx, tx / 1.5, 4 * tx * tx / 1.5))
    assert np.allclose(lights.radiance[0], math.pi * 1.7)
    mean = srgb_to_linear(IMAGE).reshape(-1, 3).mean(axis=0)
    assert np.allclose(lights.power[0], math.pi * 1.7 * 4 * tx * tx / 1.5 * mean, rtol=1e-6)


def test_projector_defaults_are_mitsubas(tmp_path, mi):
    """A bare projector: irradiance 1, scale 1, a 50 mm lens along the diagonal of a square image (as Mitsuba's
    x_fov 34.02 degrees)."""
    scene = load(tmp_path, '<emitter type="projector"/>')
    x_fov = float(str(mi.load_dict({"type": "projector"})).split("x_fov = ")[1].split(",")[0])
    assert math.degrees(2 * math.atan(scene.lights.cone[0, 0])) == pytest.approx(x_fov, abs=1e-4)
    assert scene.lights.cone[0, 0] == scene.lights.cone[0, 1]
    assert np.allclose(scene.lights.radiance[0], math.pi)


@pytest.mark.parametrize("body, words", [
    (PROJ_XML.format(fov="-10", irradiance=""), ('<float name="fov">', "fov must be between 0 and 180 degrees")),
    (PROJ_XML.format(fov="180", irradiance=""), ('<float name="fov">', "fov must be between 0 and 180 degrees")),
    (PROJ_XML.format(fov="40", irradiance='<texture type="bitmap" name="irradiance"><string name="filename" '
                                          'value="nowhere.png"/></texture>'),
     ('<string name="filename">', "nowhere.png", "not found")),
    (PROJ_XML.format(fov="40", irradiance='<texture type="bitmap" name="irradiance"/>'),
     ("a bitmap texture needs",)),
    (PROJ_XML.format(fov="40", irradiance='<texture type="bitmap" name="radiance"><string name="filename" '
                                          'value="img.png"/></texture>'),
     ("takes a texture only for 'irradiance', not for 'radiance'",)),
    (PROJ_XML.format(fov="40", irradiance='<texture type="bitmap" name="irradiance"><string name="filename" '
                                          'value="img.png"/><transform name="to_uv"><scale value="2"/></transform>'
                                          '</texture>'), ("'to_uv' is not supported",)),
    ('<emitter type="projector"><transform name="to_world"><scale value="2"/></transform></emitter>',
     ("projector's to_world must be a rigid motion",)),
    ('<emitter type="projector"><float name="scale" value="-1"/></emitter>', ("'scale' must not be negative",)),
    ('<emitter type="projector"><float name="fov" value="40"/><string name="focal_length" value="30mm"/></emitter>',
     ("give either 'fov' or 'focal_length'",)),
    (SPOT_XML.format(texture=BITMAP.format(name="texture", filter="nearest", wrap="clamp")).replace(
        'value="35"', 'value="95"'), ("'cutoff_angle' within (0, 90) degrees",)),
])
def test_bad_projector_or_spot_texture_is_one_line_exit_2(tmp_path, cli, body, words):
    path = write_scene(tmp_path, body)
    code, _, err = cli("render", path, "--method", "pt", "-q", "-o", tmp_path / "x.exr")
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert f"{path}:" in err and "<" in err, err
    for w in words:
        assert w in err, (w, err)


# ----------------------------------------------------------------------------- values against Mitsuba

@pytest.mark.parametrize("kind, fov, filt, wrap, irradiance", [
    ("projector", 50, "bilinear", "repeat", "bitmap"),
    ("projector", 70, "nearest", "clamp", "bitmap"),
    ("projector", 40, "bilinear", "mirror", "bitmap"),
    ("projector", 60, "bilinear", "repeat", "checkerboard"),
    ("projector", 60, "bilinear", "repeat", "rgb"),
    ("spot", 0, "bilinear", "repeat", "bitmap"),
])
def test_emitter_values_match_mitsuba(tmp_path, mi, kind, fov, filt, wrap, irradiance):
    """Mitsuba's sample_direction at random points of the floor (its value, times the floor's cosine) equals
    caustica's light_sample and direct_stratified there (float32 precision); points outside the image or the
    cone get 0 from both."""
    em = mitsuba_emitter(mi, tmp_path, kind, fov, filt, wrap, irradiance)
    body = projector_body(fov, filt, wrap, irradiance) if kind == "projector" else SPOT_BODY
    scene = load(tmp_path, body)
    rng = np.random.default_rng(8)
    points = np.column_stack([rng.uniform(-1.8, 1.8, 600), np.zeros(600), rng.uniform(-1.8, 1.8, 600)])
    contrib, wi, direct = _light_samples(scene.tables, points, with_direct=True)
    theirs = np.zeros_like(contrib)
    for k, p in enumerate(points):
        it = mi.Interaction3f()
        it.p = mi.Point3f(*p)
        ds, value = em.sample_direction(it, mi.Point2f(0.5, 0.5))
        theirs[k] = np.array(value) * max(float(ds.d[1]), 0.0)
    lit = theirs.max(axis=1) > 0
    assert lit.sum() > 60 and (~lit).sum() > 30, lit.sum()
    assert np.allclose(contrib, theirs, rtol=3e-5, atol=1e-6 * theirs.max())
    assert np.allclose(direct, theirs, rtol=3e-5, atol=1e-6 * theirs.max())


@pytest.mark.parametrize("filt, wrap", [("bilinear", "repeat"), ("nearest", "clamp")])
def test_irradiance_on_a_plane_is_analytic(tmp_path, filt, wrap):
    """A projector h above the floor looking straight down: the irradiance at the point (x, 0, z) is π s E(uv) / h²,
    uv = (1/2 − x_l / (2 h tan_x), 1/2 − y_l / (2 h tan_y)) in the projector's frame (E the image looked up as
    Mitsuba's bitmap), 0 outside the image; both direct-light estimators give it to rounding."""
    body = ('<emitter type="projector"><transform name="to_world"><lookat origin="0.3, 1.5, -0.2" '
            'target="0.3, 0, -0.2" up="0, 0, 1"/></transform><float name="scale" value="2.5"/>'
            f'<float name="fov" value="80"/>{BITMAP.format(name="irradiance", filter=filt, wrap=wrap)}</emitter>')
    scene = load(tmp_path, body)
    rng = np.random.default_rng(9)
    points = np.column_stack([rng.uniform(-2.5, 2.5, 800), np.zeros(800), rng.uniform(-2.5, 2.5, 800)])
    contrib, _, direct = _light_samples(scene.tables, points, with_direct=True)
    frame = look_at(np.array([0.3, 1.5, -0.2]), [0.3, 0, -0.2], [0, 0, 1])
    local = (points - [0.3, 1.5, -0.2]) @ frame
    h = 1.5
    tx = math.tan(math.radians(40))
    ty = tx / 1.5
    u = 0.5 - local[:, 0] / (2 * h * tx)
    v = 0.5 - local[:, 1] / (2 * h * ty)
    inside = (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)
    expected = math.pi * 2.5 * lookup(srgb_to_linear(IMAGE), u, v, filt, wrap) / h ** 2 * inside[:, None]
    assert inside.sum() > 100 and (~inside).sum() > 100
    assert np.allclose(contrib, expected, rtol=1e-6, atol=1e-9)
    assert np.allclose(direct, expected, rtol=1e-6, atol=1e-9)


# ----------------------------------------------------------------------------- power and photons

def mitsuba_power(em, n=40_000, seed=2):
    """The emitter's power from Mitsuba's own sample_ray (the mean of its weights over uniform samples) and the
    standard error of that mean; also the weights."""
    rng = np.random.default_rng(seed)
    u = rng.random((n, 4))
    w = np.array([np.array(em.sample_ray(0.0, 0.5, mi_point(em, a, b), mi_point(em, c, d))[1])
                  for a, b, c, d in u])
    return w.mean(axis=0), w.std(axis=0, ddof=1) / math.sqrt(n), w


def mi_point(em, a, b):
    import mitsuba as mi
    return mi.Point2f(a, b)


@pytest.mark.parametrize("kind, filt, wrap", [("projector", "bilinear", "repeat"), ("projector", "nearest", "clamp"),
                                              ("projector", "bilinear", "mirror"), ("spot", "bilinear", "repeat")])
def test_power_and_photons_match_mitsuba(tmp_path, mi, kind, filt, wrap):
    """The light table's power, the sum of caustica's photons' powers and the mean of Mitsuba's sample_ray weights
    agree (within 5 standard errors of the Monte Carlo sums).  A projector's photons are drawn by the image's
    luminance as Mitsuba's are: each photon's luminance is the same (the sampled density is proportional to the
    image's luminance, interpolated alike), and equal to Mitsuba's rays' (which are all alike too)."""
    em = mitsuba_emitter(mi, tmp_path, kind, 50, filt, wrap)
    scene = load(tmp_path, projector_body(50, filt, wrap) if kind == "projector" else SPOT_BODY)
    theirs, se_theirs, w = mitsuba_power(em)
    n = 200_000
    _, d, power, _ = emit(scene, n)
    ours = power.sum(axis=0)
    se_ours = power.std(axis=0, ddof=1) * math.sqrt(n)
    table = scene.lights.power[0]
    assert np.all(np.abs(table - theirs) <= 5 * se_theirs + 1e-9), (table, theirs, se_theirs)
    assert np.all(np.abs(ours - table) <= 5 * se_ours + 1e-9 * table), (ours, table, se_ours)
    if kind == "projector":
        lum = np.array([0.212671, 0.715160, 0.072169])
        assert np.allclose(power @ lum * n, (power @ lum * n)[0], rtol=1e-9)
        assert np.allclose(w @ lum, (power @ lum * n)[0], rtol=2e-5)
        # every photon leaves through the image's frustum, towards +z of the projector
        frame = np.column_stack([scene.lights.edge1[0], scene.lights.edge2[0], scene.lights.normal[0]])
        local = d @ frame
        assert np.all(np.abs(local[:, 0] / local[:, 2]) <= scene.lights.cone[0, 0] * (1 + 1e-9))
        assert np.all(np.abs(local[:, 1] / local[:, 2]) <= scene.lights.cone[0, 1] * (1 + 1e-9))


@pytest.mark.parametrize("kind", ["projector", "spot"])
def test_caustic_photons_carry_the_flux_into_a_specular_sphere(tmp_path, kind):
    """Photons aimed at two specular spheres (PM's caustic map) carry the flux into each ball that the photons
    emitted everywhere carry (within 5 combined standard errors)."""
    n = 300_000
    scene = load(tmp_path, projector_body(60) if kind == "projector" else SPOT_BODY)
    targets = np.array([[0.0, 0.3, 0.1, 0.3], [0.5, 0.4, -0.3, 0.35]])
    everywhere, aimed = emit(scene, n), emit(scene, n, targets)
    for centre, a in ((targets[0, :3], targets[0, 3]), (targets[1, :3], targets[1, 3])):
        est_e, se_e = ball_flux(everywhere, n, centre, a)
        est_a, se_a = ball_flux(aimed, n, centre, a)
        assert np.all(est_a > 0)
        assert np.all(np.abs(est_a - est_e) <= 5 * np.sqrt(se_a ** 2 + se_e ** 2)), (est_a, est_e, se_a, se_e)


# ----------------------------------------------------------------------------- against Mitsuba 3

SEEDS = (1, 2, 3, 4)


@pytest.fixture(scope="module")
def mitsuba_renders(mi, test_scenes_dir):
    """tests/scenes/projector.xml rendered by Mitsuba 3: its path integrator (4 seeds x 256 spp), which like pt
    misses the mirror's caustics of the delta lights, and its ptracer (4 seeds x 1024 spp), which like the photon
    methods renders them."""
    from imagestats import mitsuba_path_and_ptracer
    path = test_scenes_dir / "projector.xml"
    return (path, *mitsuba_path_and_ptracer(mi, path, SEEDS, files=("projector-image.png",)))


def test_pt_matches_mitsuba(mitsuba_renders):
    """caustica's pt and Mitsuba's path integrator agree: image mean within 2 % and every 4x4 block within 5 sigmas
    of both renders' noise (tests/imagestats.py)."""
    import caustica
    from imagestats import assert_images_agree
    path, theirs, _ = mitsuba_renders
    scene = caustica.load_scene(str(path))
    ours = [caustica.render(scene, "pt", spp=64, seed=s, threads=2).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="projector pt")


def test_sppm_matches_mitsubas_ptracer(mitsuba_renders):
    """caustica's sppm (the mirror's caustics of the projector and the spot included) and Mitsuba's ptracer agree
    as above; Mitsuba's path integrator, which misses those caustics, is more than 2 % darker."""
    import caustica
    from imagestats import assert_images_agree
    path, without_caustics, theirs = mitsuba_renders
    scene = caustica.load_scene(str(path))
    ours = [caustica.render(scene, "sppm", passes=32, seed=s, threads=2).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="projector sppm")
    assert np.mean(without_caustics) < 0.98 * np.mean(theirs)


def test_pspm_mean_matches_mitsubas_ptracer(mitsuba_renders):
    """pspm's image mean per channel within 5 % of Mitsuba's ptracer (test_spot_directional.py's tolerance for it).

    pm and spm are not checked here: their k-nearest estimates are biased in this scene, measured on 2026-12-03
    (seed 1) against the ptracer's mean: pm +5.2 / +2.0 / +2.8 % (R / G / B) with 100 000 photons of each kind,
    +3.9 / +0.8 / +2.0 % with 400 000, +3.5 / +0.4 / +1.6 % with 1 600 000; the same scene with a constant image
    and an untextured spot +2.4 / +2.2 / +2.1 % (400 000); spm (10 000 streams, radius 0.3, stream radius 0.1)
    +3.3 / +0.5 / +2.4 %.  Their photons are the ones sppm (checked block by block above) and pspm trace."""
    import caustica
    path, _, theirs = mitsuba_renders
    ours = caustica.render(str(path), "pspm", threads=2, seed=1, passes=32).image.mean(axis=(0, 1))
    ref = np.mean(theirs, axis=0).mean(axis=(0, 1))
    assert np.all(np.abs(ours / ref - 1) < 0.05), (ours, ref)
