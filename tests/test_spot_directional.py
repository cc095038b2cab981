"""Spot and directional emitters (Mitsuba 3's ``spot`` and ``directional``): loader, falloff and power, direct light
against the analytic irradiance, photons' power, and renders against Mitsuba 3."""
from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from caustica.geometry.scene_geometry import NO_UV
from caustica.emitters import DIRECTIONAL, SPOT, spot_power_factor
from caustica.jit import borrowed, kernel
from caustica.lighting import direct_stratified
from caustica.media import light_sample
from caustica.sampling.rng import path_key
from caustica.scene import load_scene_description
from caustica.tables import compile_scene
from caustica.transport import ShadingPoint
from test_environment import emit_many

SENSOR = """<sensor type="perspective"><float name="fov" value="30"/>
  <transform name="to_world"><lookat origin="0,6,0.1" target="0,0,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
  <rfilter type="box"/></film></sensor>"""
FLOOR = ('<shape type="rectangle"><transform name="to_world"><scale value="5"/><rotate x="1" angle="-90"/></transform>'
         '</shape>')
SPOT_XML = ('<emitter type="spot"><transform name="to_world"><lookat origin="0.4, 2, -0.3" target="-0.5, 0, 0.2" '
            'up="0, 1, 0"/></transform><rgb name="intensity" value="3, 2, 1"/>'
            '<float name="cutoff_angle" value="{cutoff}"/><float name="beam_width" value="{beam}"/></emitter>')
SUN_XML = ('<emitter type="directional"><vector name="direction" value="0.5, -1, 0.3"/>'
           '<rgb name="irradiance" value="0.5, 0.6, 0.8"/></emitter>')


def write_scene(tmp_path, body: str, name: str = "s.xml"):
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n{SENSOR}\n{FLOOR}\n{body}\n</scene>\n')
    return path


def load(tmp_path, body):
    return compile_scene(load_scene_description(str(write_scene(tmp_path, body))))


def falloff(cos_t, cutoff_deg, beam_deg):
    """Mitsuba 3's spot falloff (src/emitters/spot.cpp), written out again: 1 within the beam, linear in the angle
    down to 0 at the cutoff."""
    theta = np.arccos(np.clip(cos_t, -1, 1))
    g, b = math.radians(cutoff_deg), math.radians(beam_deg)
    ramp = (g - theta) / (g - b) if g > b else np.zeros_like(theta)
    return np.where(cos_t > math.cos(g), np.where(cos_t >= math.cos(b), 1.0, ramp), 0.0)


# ----------------------------------------------------------------------------- loader

def test_spot_and_directional_are_read_into_the_light_table(tmp_path):
    """The spot's axis is its to_world's +z, its power 2π I ∫ f sin θ dθ (checked against a numerical integral);
    the directional light's direction is normalised and its power π R² E, R the scene's bounding radius."""
    scene = load(tmp_path, SPOT_XML.format(cutoff=30, beam=10) + SUN_XML)
    lights = scene.lights
    assert list(lights.kind) == [SPOT, DIRECTIONAL]
    axis = np.array([-0.9, -2.0, 0.5]) / np.linalg.norm([-0.9, -2.0, 0.5])
    assert np.allclose(lights.normal[0], axis) and np.allclose(lights.position[0], (0.4, 2, -0.3))
    theta = np.linspace(0, math.radians(30), 200_001)
    integral = np.trapezoid(falloff(np.cos(theta), 30, 10) * np.sin(theta), theta)
    assert spot_power_factor(math.radians(30), math.radians(10)) == pytest.approx(integral, rel=1e-8)
    assert spot_power_factor(0.3, 0.3) == pytest.approx(1 - math.cos(0.3), rel=1e-12)   # no ramp
    assert np.allclose(lights.power[0], 2 * math.pi * integral * np.array([3, 2, 1]), rtol=1e-8)
    assert np.allclose(lights.normal[1], np.array([0.5, -1, 0.3]) / np.linalg.norm([0.5, -1, 0.3]))
    r = lights.env_data[3]
    assert r == pytest.approx(5 * math.sqrt(2), rel=1e-3)   # the floor's box, as Mitsuba bounds the scene
    assert np.allclose(lights.power[1], math.pi * r * r * np.array([0.5, 0.6, 0.8]))
    assert np.allclose(lights.select_pdf, lights.power.mean(axis=1) / lights.power.mean(axis=1).sum())


def test_spot_defaults_are_mitsubas(tmp_path):
    """cutoff_angle 20 degrees, beam_width 3/4 of the cutoff; the spot shines along +z by default."""
    d = load_scene_description(str(write_scene(tmp_path, '<emitter type="spot"/>')))
    spot = d.point_lights[0]
    assert (spot.cutoff_angle, spot.beam_width, spot.axis, spot.intensity) == (20.0, 15.0, (0.0, 0.0, 1.0),
                                                                               (1.0, 1.0, 1.0))
    d = load_scene_description(str(write_scene(tmp_path, '<emitter type="spot"><float name="cutoff_angle" '
                                                         'value="40"/></emitter>', "b.xml")))
    assert d.point_lights[0].beam_width == 30.0


@pytest.mark.parametrize("body, words", [
    ('<emitter type="spot"><float name="cutoff_angle" value="-5"/></emitter>',
     ("<float name=\"cutoff_angle\">", "'cutoff_angle' must be within [0, 180] degrees, got -5")),
    ('<emitter type="spot"><float name="cutoff_angle" value="20"/><float name="beam_width" value="25"/></emitter>',
     ("<float name=\"beam_width\">", "'beam_width' must be within [0, cutoff_angle = 20] degrees, got 25")),
    ('<emitter type="spot"><texture type="bitmap" name="texture"><string name="filename" value="a.png"/></texture>'
     '</emitter>', ("'a.png' not found",)),
    ('<emitter type="spot"><transform name="to_world"><scale x="2"/></transform></emitter>',
     ("to_world must be a rotation with a uniform scale",)),
    ('<emitter type="spot"><point name="position" x="1" y="2" z="3"/></emitter>',
     ("unknown property 'position'",)),
    ('<emitter type="directional"><vector name="direction" x="0" y="0" z="0"/></emitter>',
     ("<vector name=\"direction\">", "needs a non-zero finite direction")),
    ('<emitter type="directional"><vector name="direction" x="0" y="-1" z="0"/><transform name="to_world">'
     '<rotate x="1" angle="90"/></transform></emitter>', ("give either 'direction' or 'to_world', not both",)),
    ('<emitter type="directional"><rgb name="irradiance" value="-1, 1, 1"/></emitter>',
     ("'irradiance' must not be negative",)),
])
def test_bad_spot_or_directional_is_one_line_exit_2(tmp_path, cli, body, words):
    path = write_scene(tmp_path, body)
    code, _, err = cli("render", path, "--method", "pt", "-q", "-o", tmp_path / "x.exr")
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert f"{path}:" in err and '<' in err, err
    for w in words:
        assert w in err, (w, err)


NESTED_EMITTERS = {"spot": SPOT_XML.format(cutoff=30, beam=10), "directional": SUN_XML,
                   "point": '<emitter type="point"><point name="position" x="0.2" y="1.5" z="0.3"/></emitter>',
                   "projector": '<emitter type="projector"><transform name="to_world"><lookat origin="0, 1.5, 0" '
                                'target="0, 0, 0" up="0, 0, 1"/></transform><float name="scale" value="5"/></emitter>'}


@pytest.mark.parametrize("kind", list(NESTED_EMITTERS))
def test_an_emitter_nested_in_a_shape_is_placed_by_its_own_parameters(tmp_path, mi, kind):
    """Mitsuba 3 takes a point, spot, projector or directional emitter as a shape's one emitter child; the shape
    neither moves nor emits it (3.9.1 renders the same image, bit for bit, as with the emitter at the top level:
    a spot inside the light rectangle of a published Cornell box).  A shape holding one and no BSDF is black, as
    any emitter's shape.  caustica reads it as the same light and the shape's material as Mitsuba's."""
    em = NESTED_EMITTERS[kind]
    shape = '<shape type="disk" id="holder"><transform name="to_world"><translate y="1"/></transform>{}</shape>'
    nested = load_scene_description(str(write_scene(tmp_path, shape.format(em), "nested.xml")))
    top = load_scene_description(str(write_scene(tmp_path, shape.format("") + em, "nested.xml")))   # same source
    lights = ("point_lights", "directional_lights", "projectors")
    for k in lights:   # field by field: a projector's frame is an array
        mine, theirs_top = getattr(nested, k), getattr(top, k)
        assert len(mine) == len(theirs_top), k
        for a, b in zip(mine, theirs_top):
            assert all(np.array_equal(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a)), k
    assert sum(len(getattr(nested, k)) for k in lights) == 1
    holder = next(s for s in nested.shapes if s.id == "holder")
    assert holder.emitter_radiance is None
    theirs = {s.id(): mi.traverse(s)["bsdf.reflectance.value"]
              for s in mi.load_file(str(write_scene(tmp_path, shape.format(em), "nested.xml"))).shapes()}
    assert nested.materials[holder.material].rgb == pytest.approx((theirs["holder"],) * 3) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("kind", ["constant", "envmap"])
def test_an_environment_nested_in_a_shape_is_refused(tmp_path, cli, kind):
    """Mitsuba 3 loads it, samples it and never sees it (escaped rays find no environment): refused, in one line."""
    path = write_scene(tmp_path, f'<shape type="sphere"><emitter type="{kind}"/></shape>')
    code, _, err = cli("render", path, "--method", "pt", "-q", "-o", tmp_path / "x.exr")
    assert code == 2 and err.count("\n") == 1, err
    assert f"{path}:7: <emitter type=\"{kind}\">: a {kind} emitter belongs at the top level of the scene" in err, err


def test_spot_falloff_and_directional_match_mitsuba(tmp_path, mi):
    """Mitsuba's own emitters' sample_direction at random points (I f / r² for the spot, E for the directional
    light, with their directions) equal caustica's light_sample of a scene with that one light (float32
    precision)."""
    T = mi.ScalarTransform4f
    spot = mi.load_dict({"type": "spot", "intensity": {"type": "rgb", "value": [3, 2, 1]}, "cutoff_angle": 30.0,
                         "beam_width": 10.0, "to_world": T().look_at(origin=[0.4, 2, -0.3], target=[-0.5, 0, 0.2],
                                                                      up=[0, 1, 0])})
    sun = mi.load_dict({"type": "directional", "direction": [0.5, -1, 0.3],
                        "irradiance": {"type": "rgb", "value": [0.5, 0.6, 0.8]}})
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-2.5, 2.5, 400), np.full(400, 1e-3), rng.uniform(-2.5, 2.5, 400)])
    for body, em in ((SPOT_XML.format(cutoff=30, beam=10), spot), (SUN_XML, sun)):
        scene = load(tmp_path, body)
        contrib, wi = _light_samples(scene.tables, points)
        for p, c, w in zip(points, contrib, wi):
            it = mi.Interaction3f()
            it.p = mi.Point3f(*p)
            ds, value = em.sample_direction(it, mi.Point2f(0.5, 0.5))
            value = np.array(value)
            cos = max(w[1], 0.0)
            assert np.allclose(c, value * cos, rtol=2e-5, atol=1e-7), (body, p, c, value * cos)
            if np.any(value > 0):
                assert np.allclose(w, np.array(ds.d), atol=1e-5)


@kernel
def _light_samples_kernel(tables, points, contrib, wi, direct):
    tables = borrowed(tables)
    up = (0.0, 1.0, 0.0)
    for i in range(points.shape[0]):
        at = ShadingPoint((points[i, 0], points[i, 1], points[i, 2]), up, up, up, 0, -1, NO_UV)
        c, w, _, _, _, _, _ = light_sample(tables, at, (0.5, 0.5, 0.5), False)
        e = direct_stratified(tables, at, path_key(1, 1, i), 0, (1, True, -1), -1, None)
        for k in range(3):
            contrib[i, k] = c[k]
            wi[i, k] = w[k]
            direct[i, k] = e[k]


def _light_samples(tables, points, with_direct=False):
    """Per point on the floor (normal +y): light_sample's contrib (E cos θ for the one light) and direction, and
    direct_stratified's E."""
    n = len(points)
    contrib, wi, direct = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    _light_samples_kernel(tables, np.ascontiguousarray(points, np.float64), contrib, wi, direct)
    return (contrib, wi, direct) if with_direct else (contrib, wi)


@pytest.mark.parametrize("cutoff, beam", [(30, 10), (45, 45), (60, 0)])
def test_irradiance_on_a_plane_is_analytic(tmp_path, cutoff, beam):
    """On the floor under a spot, both direct-light estimators (pt's light_sample, the photon methods'
    direct_stratified) give I f(θ) cos θ' / r² to rounding (θ from the spot's axis, θ' from the floor's normal);
    under the directional light E cos θ'."""
    rng = np.random.default_rng(4)
    points = np.column_stack([rng.uniform(-2.5, 2.5, 500), np.zeros(500), rng.uniform(-2.5, 2.5, 500)])
    scene = load(tmp_path, SPOT_XML.format(cutoff=cutoff, beam=beam))
    contrib, _, direct = _light_samples(scene.tables, points, with_direct=True)
    pos = np.array([0.4, 2, -0.3])
    axis = np.array([-0.9, -2.0, 0.5]) / np.linalg.norm([-0.9, -2.0, 0.5])
    to_p = points - pos
    r2 = (to_p ** 2).sum(axis=1)
    cos_axis = (to_p @ axis) / np.sqrt(r2)
    cos_floor = -to_p[:, 1] / np.sqrt(r2)
    expected = np.array([3, 2, 1]) * (falloff(cos_axis, cutoff, beam) * cos_floor / r2)[:, None]
    assert np.count_nonzero(expected[:, 0]) > 50 and np.count_nonzero(expected[:, 0] == 0) > 50
    assert np.allclose(contrib, expected, rtol=1e-9, atol=1e-12)
    assert np.allclose(direct, expected, rtol=1e-9, atol=1e-12)
    scene = load(tmp_path, SUN_XML)
    contrib, _, direct = _light_samples(scene.tables, points, with_direct=True)
    cos = 1 / np.linalg.norm([0.5, -1, 0.3])
    assert np.allclose(contrib, np.array([0.5, 0.6, 0.8]) * cos, rtol=1e-12)
    assert np.allclose(direct, np.array([0.5, 0.6, 0.8]) * cos, rtol=1e-12)


# ----------------------------------------------------------------------------- photons

def emit(scene, n, spheres=None):
    out = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, np.bool_))
    emit_many(scene.geometry, scene.lights, np.zeros((0, 4)) if spheres is None else spheres, n, 12, out)
    return out


def ball_flux(out, n, centre, a):
    """Per-photon estimates of the flux into a ball (centre, radius a) from the photons' rays: mean and its
    standard error per channel."""
    o, d, power, ok = out
    to_c = centre - o
    along = (to_c * d).sum(axis=1)
    hits = ok & ((to_c * to_c).sum(axis=1) - along ** 2 < a * a) & (along > 0)
    contrib = power * hits[:, None] * n
    return contrib.mean(axis=0), contrib.std(axis=0, ddof=1) / math.sqrt(n)


def test_photons_carry_the_lights_power(tmp_path):
    """The spot's photons' powers sum to its power within 5 standard errors (their falloff makes them vary); the
    directional light's sum to π R² E to rounding, from outside the scene's bounding sphere, along its direction."""
    n = 200_000
    scene = load(tmp_path, SPOT_XML.format(cutoff=30, beam=10))
    o, d, power, _ = emit(scene, n)
    total = power.sum(axis=0)
    se = power.std(axis=0, ddof=1) * math.sqrt(n)
    assert np.all(np.abs(total - scene.lights.power[0]) <= 5 * se), (total, scene.lights.power[0], se)
    assert np.allclose(o, scene.lights.position[0])
    assert np.all(d @ scene.lights.normal[0] >= math.cos(math.radians(30)) - 1e-12)
    scene = load(tmp_path, SUN_XML)
    o, d, power, _ = emit(scene, n)
    assert np.allclose(power.sum(axis=0), scene.lights.power[0], rtol=1e-9)
    assert np.allclose(d, scene.lights.normal[0])
    c, r = scene.lights.env_data[:3], scene.lights.env_data[3]
    assert np.all(np.linalg.norm(o - c, axis=1) >= r * (1 - 1e-9))


@pytest.mark.parametrize("light", ["spot", "directional"])
def test_caustic_photons_carry_the_flux_into_a_specular_sphere(tmp_path, light):
    """Photons aimed at two specular spheres (PM's caustic map) carry the flux into each ball that the photons
    emitted everywhere carry (within 5 combined standard errors; a spot's aimed photons outside its cone carry
    nothing); under the directional light both are π a² E."""
    n = 300_000
    scene = load(tmp_path, SPOT_XML.format(cutoff=30, beam=10) if light == "spot" else SUN_XML)
    targets = np.array([[-0.3, 0.3, 0.1, 0.3], [0.6, 0.4, -0.5, 0.4]])
    everywhere, aimed = emit(scene, n), emit(scene, n, targets)
    for centre, a in ((targets[0, :3], targets[0, 3]), (targets[1, :3], targets[1, 3])):
        est_e, se_e = ball_flux(everywhere, n, centre, a)
        est_a, se_a = ball_flux(aimed, n, centre, a)
        assert np.all(est_a > 0)
        assert np.all(np.abs(est_a - est_e) <= 5 * np.sqrt(se_a ** 2 + se_e ** 2)), (est_a, est_e, se_a, se_e)
        if light == "directional":
            expected = math.pi * a * a * np.array([0.5, 0.6, 0.8])
            assert np.all(np.abs(est_e - expected) <= 5 * se_e) and np.all(np.abs(est_a - expected) <= 5 * se_a)


# ----------------------------------------------------------------------------- against Mitsuba 3

SEEDS = (1, 2, 3, 4)


@pytest.fixture(scope="module")
def mitsuba_renders(mi, test_scenes_dir):
    """tests/scenes/spot-directional.xml rendered by Mitsuba 3: its path integrator (4 seeds x 256 spp), which like
    pt misses the mirror's caustics of the delta lights, and its ptracer (4 seeds x 1024 spp), which like the
    photon methods renders them."""
    from imagestats import mitsuba_path_and_ptracer
    path = test_scenes_dir / "spot-directional.xml"
    return (path, *mitsuba_path_and_ptracer(mi, path, SEEDS))


def test_pt_matches_mitsuba(mitsuba_renders):
    """caustica's pt and Mitsuba's path integrator agree: image mean within 2 % and every 4x4 block within 5 sigmas
    of both renders' noise (tests/imagestats.py)."""
    import caustica
    from imagestats import assert_images_agree
    path, theirs, _ = mitsuba_renders
    scene = caustica.load_scene(str(path))
    ours = [caustica.render(scene, "pt", spp=64, seed=s, threads=2).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="spot-directional pt")


def test_sppm_matches_mitsubas_ptracer(mitsuba_renders):
    """caustica's sppm (the mirror's caustics of the spot and the sun included) and Mitsuba's ptracer agree as
    above; Mitsuba's path integrator, which misses those caustics, is more than 2 % darker."""
    import caustica
    from imagestats import assert_images_agree
    path, without_caustics, theirs = mitsuba_renders
    scene = caustica.load_scene(str(path))
    ours = [caustica.render(scene, "sppm", passes=32, seed=s, threads=2).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="spot-directional sppm")
    assert np.mean(without_caustics) < 0.98 * np.mean(theirs)


@pytest.mark.parametrize("method, params, tol", [
    ("pm", {"photons": 100_000, "caustic_photons": 100_000}, 0.03),
    ("spm", {"streams": 10_000, "radius": 0.3, "stream_radius": 0.1}, 0.03),
    ("pspm", {"passes": 32}, 0.05),
])
def test_photon_methods_mean_matches_mitsubas_ptracer(mitsuba_renders, method, params, tol):
    """The other photon methods' image mean per channel near Mitsuba's ptracer (the photons of both lights, and pm's
    aimed caustic photons).  Measured on 2026-12-03 (seed 1): pm and spm within 2 %; pspm's mean at 32 passes
    moves by a few % with the seed (+3.9 % and +1.3 % for seeds 1 and 2), hence its 5 %.  spm takes a small stream
    radius: with the default 5 the associated photons spread each stream's power far beyond the spot's cone
    (+15 % here; +3.5 % with a point light in the spot's place)."""
    import caustica
    path, _, theirs = mitsuba_renders
    ours = caustica.render(str(path), method, threads=2, seed=1, **params).image.mean(axis=(0, 1))
    ref = np.mean(theirs, axis=0).mean(axis=(0, 1))
    assert np.all(np.abs(ours / ref - 1) < tol), (method, params, ours, ref)


def test_a_shape_referring_to_a_spot_is_one_clear_error(tmp_path, cli):
    """A spot declared at the top level is read there; a shape's <ref> to it would place it twice: refused."""
    path = write_scene(tmp_path, '<emitter type="spot" id="lamp"/>\n<shape type="sphere"><ref id="lamp"/></shape>')
    code, _, err = cli("render", path, "--method", "pt", "-q", "-o", tmp_path / "x.exr")
    assert code == 2 and err.count("\n") == 1, err
    assert f"{path}:8:" in err, err
    assert "a shape can refer only to an area emitter; 'lamp' (line 7) is a spot emitter" in err, err
