"""Mitsuba 3's thindielectric (bsdfs/thindielectric.py): a thin glass slab through the scattering interface.

1. Against Mitsuba 3's own BSDF (``scalar_rgb``): at several angles, from both sides, with eta above and below 1,
   the reflection probability (Mitsuba's ``sample``'s pdf for its reflection, 1 - its ``eval_null_transmission``),
   both directions, eta 1 and weight 1; ``eval``/``pdf`` are 0 everywhere.
2. The slab's reflectance is the sum of its inter-reflections, R = F + (1 - F)² F / (1 - F²), and R + T = 1: a white
   slab neither loses nor creates energy; ``sample`` reflects with frequency R (5 standard errors) with weight 1.
3. Scenes against Mitsuba (tests/scenes/thindielectric.xml: a tilted pane and a thin-walled bubble over a diffuse
   floor, the floor under the pane lit only through it): pt, sppm and PM+C, image mean within 2 % and every 4x4
   block within 5 sigmas of both renderers' noise (tests/imagestats.py); the bubble holding a medium, pt against
   Mitsuba's volpath: the medium inside is entered through the sheet as through any shape with an interior.
   At max_depth 3 the scene under ``volpath`` (the straight-on lobe is Mitsuba's ``Null`` event: no bounce, shadow rays
   pass with 1 - R) and under ``path`` (a bounce; shadow rays blocked): pt against Mitsuba's same integrator, and a
   shadow ray through the pane against Mitsuba's ``eval_null_transmission`` at several angles (pt's tables only).
4. Input: the loader's defaults and named IORs; a negative IOR, a negative tint, a textured reflectance, a twosided
   wrapper -> one line naming file and line.
"""
from __future__ import annotations

import math
import types

import numpy as np
import pytest

import caustica
from caustica.geometry.scene_geometry import NO_UV
from caustica import bsdfs
from caustica.bsdfs.optics import fresnel_dielectric
from caustica.jit import borrowed, kernel
from caustica.scene.description import THINDIELECTRIC, Material
from imagestats import assert_images_agree
from test_glossy import assert_refused_in_one_line, draw, incident, write_scene

NG = (0.0, 0.0, 1.0)
UV = NO_UV   # surface coordinates off any texture


def table(int_ior=1.5, ext_ior=1.0):
    """A one-material table built as a scene's is (build_material_table)."""
    mat = Material(THINDIELECTRIC, (1.0, 1.0, 1.0), int_ior=int_ior, ext_ior=ext_ior)
    return bsdfs.build_material_table(types.SimpleNamespace(materials=[mat]))


@kernel
def branches_kernel(mats, d, out):
    """out = (reflected xyz, transmitted xyz, F, eta, transmitted tint rgb, eval's f·scale r, pdf) for a ray along d."""
    mats = borrowed(mats)
    wr, wt, F, eta, (_, c) = bsdfs.delta_branches(mats, 0, d, NG, NG, UV)
    f, s, pdf = bsdfs.eval_pdf(mats, 0, d, NG, NG, UV, wr)
    out[0], out[1], out[2] = wr
    out[3], out[4], out[5] = wt
    out[6], out[7] = F, eta
    out[8], out[9], out[10] = c
    out[11], out[12] = f[0] * s, pdf


def branches(mats, d):
    out = np.zeros(13)
    branches_kernel(mats, d, out)
    return out


def slab_reflectance_by_series(F, terms=200):
    """R and T of a slab by summing its paths: R, TRT, TR³T, ... and TT, TR²T, ..."""
    R = F + sum((1 - F) ** 2 * F ** (2 * k + 1) for k in range(terms))
    T = sum((1 - F) ** 2 * F ** (2 * k) for k in range(terms))
    return R, T


IORS = [(1.5, 1.0), (2.0, 1.0), (1.0, 1.33)]     # eta 1.5, 2, and below 1 (total internal reflection when grazing)
THETAS = [0.0, 30.0, 60.0, 85.0]


@pytest.mark.parametrize("iors", IORS, ids=[f"{a}-{b}" for a, b in IORS])
def test_bsdf_values_match_mitsuba(mi, iors):
    mats = table(*iors)
    theirs = mi.load_dict({"type": "thindielectric", "int_ior": iors[0], "ext_ior": iors[1]})
    ctx = mi.BSDFContext()
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    for theta in THETAS:
        for below in (False, True):
            d = incident(theta, below)
            wi = -np.array(d)                       # Mitsuba's si.wi: towards where the ray came from
            si.wi = mi.Vector3f(*wi)
            ours = branches(mats, d)
            t_mi = float(theirs.eval_null_transmission(si)[0])
            bs_r, w_r = theirs.sample(ctx, si, 0.0, mi.Point2f(0.5, 0.5))
            assert abs(ours[6] - (1.0 - t_mi)) <= 1e-6, (iors, theta, below, ours[6], t_mi)
            assert abs(ours[6] - float(bs_r.pdf)) <= 1e-6
            np.testing.assert_allclose(ours[0:3], np.array(bs_r.wo), atol=1e-6)
            assert float(bs_r.eta) == 1.0 and np.allclose(np.array(w_r), 1.0)
            if t_mi > 0.0:
                bs_t, w_t = theirs.sample(ctx, si, 1.0 - 1e-7, mi.Point2f(0.5, 0.5))
                assert abs((1.0 - ours[6]) - float(bs_t.pdf)) <= 1e-6
                np.testing.assert_allclose(ours[3:6], np.array(bs_t.wo), atol=1e-6)   # straight on: -wi
                np.testing.assert_allclose(ours[3:6], d, atol=0)
                assert float(bs_t.eta) == 1.0 and np.allclose(np.array(w_t), 1.0)
            assert ours[7] == 1.0                                       # no change of relative IOR
            # delta lobes only: nothing to evaluate towards any direction, in either renderer
            assert ours[11] == 0.0 and ours[12] == 0.0
            assert float(theirs.eval(ctx, si, bs_r.wo)[0]) == 0.0 and float(theirs.pdf(ctx, si, bs_r.wo)) == 0.0


@pytest.mark.parametrize("iors", IORS, ids=[f"{a}-{b}" for a, b in IORS])
def test_white_slab_reflects_its_interreflections_and_conserves_energy(iors):
    mats = table(*iors)
    eta = iors[0] / iors[1]
    for theta in THETAS:
        for below in (False, True):
            d = incident(theta, below)
            F, _ = fresnel_dielectric(math.cos(math.radians(theta)), eta)   # the outside's eta from either side
            R, T = slab_reflectance_by_series(F)
            if F < 1.0:
                assert abs(R + T - 1.0) < 1e-12
                assert abs(R - (F + (1 - F) ** 2 * F / (1 - F * F))) < 1e-12
            else:
                R = 1.0
            ours = branches(mats, d)
            assert abs(ours[6] - R) < 1e-12, (iors, theta, below, ours[6], R)
            n = 40_000
            out = draw(mats, d, n=n, seed=2)
            assert np.all(out[:, 0] == 1.0)
            assert np.all(out[:, 4:7] == 1.0)           # weight 1 on either lobe: R + T = 1 exactly
            assert np.all(out[:, 7] == 0.0) and np.all(out[:, 13] == 1.0)
            refl = out[:, 12] == bsdfs.DELTA_REFLECTION
            assert np.all(refl | (out[:, 12] == bsdfs.DELTA_TRANSMISSION))
            assert abs(refl.mean() - R) <= 5 * math.sqrt(R * (1 - R) / n) + 1e-12, (theta, refl.mean(), R)
            np.testing.assert_allclose(out[~refl, 1:4], np.broadcast_to(d, (int((~refl).sum()), 3)), atol=0)
            np.testing.assert_allclose(out[refl, 1:4], np.broadcast_to((d[0], d[1], -d[2]), (int(refl.sum()), 3)),
                                       atol=1e-12)


def test_slab_is_a_caustic_caster():
    """Purely delta: the photon methods aim caustic photons at it and follow it as a specular bounce."""
    assert table().flags[0] == bsdfs.DELTA_REFLECTION | bsdfs.DELTA_TRANSMISSION
    scene = caustica.load_scene(SCENE)
    names = [s.id for s in scene.description.shapes]
    assert sorted(names[i] for i in scene.specular_shapes()) == ["bubble", "pane"]


# --------------------------------------------------------------------------- scenes against Mitsuba 3

SCENE = __import__("pathlib").Path(__file__).parent / "scenes" / "thindielectric.xml"
SEEDS = (1, 2, 3, 4)


def mitsuba_renders(mi, path, spp=512, **defaults):
    theirs_scene = mi.load_file(str(path), res=32, spp=spp, **defaults)
    return [np.array(mi.render(theirs_scene, spp=spp, seed=s), dtype=np.float32)[..., :3] for s in SEEDS]


@pytest.fixture(scope="module")
def mitsuba_images(mi):
    return mitsuba_renders(mi, SCENE)


@pytest.mark.parametrize("method, params", [
    ("pt", {"spp": 128}),
    ("sppm", {"passes": 48, "photons": 20_000, "termination": "roulette", "max_bounces": 64}),
    ("pm", {"photons": 200_000, "caustic_photons": 100_000, "spp": 16, "termination": "roulette",
            "max_bounces": 64})])
def test_thin_glass_scene_matches_mitsuba(mitsuba_images, method, params):
    """pt, sppm after 48 passes and PM+C (roulette, mr = 64: no depth truncation) against Mitsuba's path tracer."""
    scene = caustica.load_scene(SCENE)
    ours = [caustica.render(scene, method, res=32, seed=s, **params).image for s in range(4)]
    assert_images_agree(ours, mitsuba_images, label=f"{method} thindielectric")


def test_thin_bubble_holding_a_medium_matches_mitsuba_volpath(mi, tmp_path):
    """The bubble's interior is a fog: a ray passing straight through the sheet enters it (the shape's interior
    medium, whatever its BSDF), as in Mitsuba's volpath."""
    s = SCENE.read_text()
    s = s.replace('<integrator type="path"/>', '<integrator type="volpath"/>\n    <medium type="homogeneous" id="fog">'
                  '<rgb name="sigma_t" value="0.375, 0.625, 1"/><float name="scale" value="4"/>'
                  '<float name="albedo" value="0.8"/></medium>')
    s = s.replace('<string name="int_ior" value="water"/>\n        </bsdf>',
                  '<string name="int_ior" value="water"/>\n        </bsdf>\n        <ref name="interior" id="fog"/>')
    assert s.count('id="fog"') == 2
    path = tmp_path / "thin-fog.xml"
    path.write_text(s)
    scene = caustica.load_scene(path)
    assert scene.has_media
    ours = [caustica.render(scene, "pt", spp=128, res=32, seed=k).image for k in SEEDS]
    theirs = mitsuba_renders(mi, path)
    assert_images_agree(ours, theirs, label="thindielectric bubble of fog")


def depth3_scene(tmp_path, integrator):
    """tests/scenes/thindielectric.xml under Mitsuba's ``integrator`` at max_depth 3: the floor under the pane is lit
    only through it, directly (light sampling through the slab) under volpath, by a path crossing it under path."""
    s = SCENE.read_text().replace('<integrator type="path"/>', f'<integrator type="{integrator}"><integer '
                                  f'name="max_depth" value="3"/></integrator>')
    path = tmp_path / f"thin-{integrator}-3.xml"
    path.write_text(s)
    return path


@pytest.mark.parametrize("integrator", ["volpath", "path"])
def test_thin_glass_at_max_depth_3_matches_mitsubas_integrator(mi, tmp_path, integrator):
    """Mitsuba's volpath does not count a pass through the slab (its Null lobe) against max_depth and lets shadow rays
    through it; its path counts it and blocks them.  pt follows the scene's integrator (null_thin_dielectric)."""
    path = depth3_scene(tmp_path, integrator)
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=128, res=32, seed=k).image for k in SEEDS]
    theirs = mitsuba_renders(mi, path)
    assert_images_agree(ours, theirs, label=f"thindielectric {integrator} max_depth 3")


DISTANT_LIGHTS = {
    "directional": '<emitter type="directional"><vector name="direction" x="0.3" y="-1" z="-0.2"/>'
                   '<rgb name="irradiance" value="3, 2.8, 2.5"/></emitter>',
    "constant": '<emitter type="constant"><rgb name="radiance" value="0.8, 0.9, 1"/></emitter>'}


@pytest.mark.parametrize("light", list(DISTANT_LIGHTS))
def test_distant_light_through_pane_under_volpath_matches_mitsuba(mi, tmp_path, light):
    """Direct light only (max_depth 2) from a light at infinity instead of the area light: the floor under the pane and
    under the bubble is lit by shadow rays through the slab (1 - R), the directional's and the environment's as the
    area light's (media.distant_light_shadow)."""
    s = depth3_scene(tmp_path, "volpath").read_text().replace('value="3"/></integrator>', 'value="2"/></integrator>')
    start = s.index('<shape type="rectangle" id="light">')
    s = s[:start] + DISTANT_LIGHTS[light] + '\n</scene>\n'
    path = tmp_path / f"thin-{light}.xml"
    path.write_text(s)
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=128, res=32, seed=k).image for k in SEEDS]
    theirs = mitsuba_renders(mi, path)
    assert_images_agree(ours, theirs, label=f"thindielectric volpath, {light} light")


def test_shadow_ray_through_pane_passes_mitsubas_null_transmission(mi):
    """A shadow ray crossing the pane at angle theta from its normal (either way) keeps 1 - R of its light in pt's
    tables for a volpath scene: Mitsuba's eval_null_transmission.  The scene's own tables (the photon methods') block
    it."""
    from caustica.media import transmittance
    scene = caustica.load_scene(SCENE)
    geom, mats, lights, media = scene.with_null_thin_dielectric().tables
    pane = next(m for m in range(len(mats.kind)) if mats.kind[m] == THINDIELECTRIC and mats.eta[m] > 1.9)
    assert mats.flags[pane] & bsdfs.NULL_TRANSMISSION and not scene.tables[1].flags[pane] & bsdfs.NULL_TRANSMISSION
    theirs = mi.load_dict({"type": "thindielectric", "int_ior": 2.0})   # the pane's ($ior), ext_ior air as ours
    si = mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    c = np.array([-0.6, 1.2, 0.2])                    # the pane's centre, its normal n = R_x(-60°) z
    n = np.array([0.0, math.sin(math.radians(60)), math.cos(math.radians(60))])
    x = np.array([1.0, 0.0, 0.0])                     # in the pane, perpendicular to n
    for theta in (0.0, 30.0, 60.0, 80.0):
        w = math.cos(math.radians(theta)) * n + math.sin(math.radians(theta)) * x
        si.wi = mi.Vector3f(0.0, math.sin(math.radians(theta)), math.cos(math.radians(theta)))
        expected = float(theirs.eval_null_transmission(si)[0])
        assert 0.0 < expected < 1.0
        for sign in (1.0, -1.0):
            o, target = tuple(c - 0.3 * sign * w), tuple(c + 0.3 * sign * w)
            T, rays = transmittance(geom, mats, media, o, target, -1)
            assert rays == 2 and np.allclose(T, expected, rtol=0, atol=1e-6), (theta, sign, T, expected)
            T0, _ = transmittance(*[scene.tables[i] for i in (0, 1, 3)], o, target, -1)
            assert T0 == (0.0, 0.0, 0.0)


def test_scene_integrator_sets_null_thin_dielectric(tmp_path):
    from caustica.methods.pt import PathTracer
    for integrator, on in (("volpath", True), ("volpathmis", True), ("path", False)):
        d = caustica.load_scene(depth3_scene(tmp_path, integrator)).description
        assert PathTracer.scene_defaults(d)["null_thin_dielectric"] is on


# --------------------------------------------------------------------------- input

BAD = {
    "negative ior": ('<bsdf type="thindielectric"><float name="int_ior" value="-1.5"/></bsdf>',
                     ["int_ior", "positive"]),
    "unknown ior name": ('<bsdf type="thindielectric"><string name="ext_ior" value="vacuumm"/></bsdf>',
                         ["vacuumm", "bk7"]),
    "negative tint": ('<bsdf type="thindielectric"><float name="specular_reflectance" value="-0.5"/></bsdf>',
                      ["specular_reflectance", "negative"]),
    "textured": ('<bsdf type="thindielectric"><texture type="checkerboard" name="specular_reflectance"/></bsdf>',
                 ["specular_reflectance", "thindielectric"]),
    "twosided": ('<bsdf type="twosided"><bsdf type="thindielectric"/></bsdf>', ["twosided", "thindielectric"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_thin_glass_exits_2_one_line(cli, tmp_path, case):
    assert_refused_in_one_line(cli, tmp_path, *BAD[case])


def test_loader_reads_thindielectric(tmp_path):
    from caustica.scene import load_scene_file
    d = load_scene_file(write_scene(tmp_path, '<bsdf type="thindielectric"/>'))
    m = d.materials[d.shapes[0].material]
    assert (m.kind, m.rgb, m.int_ior, m.ext_ior) == (THINDIELECTRIC, (1.0, 1.0, 1.0), 1.5046, 1.000277)  # bk7 / air
    d = load_scene_file(write_scene(tmp_path, '<bsdf type="thindielectric"><string name="int_ior" value="water"/>'
                                              '<float name="ext_ior" value="1.1"/>'
                                              '<rgb name="specular_reflectance" value="1"/></bsdf>'))
    m = d.materials[d.shapes[0].material]
    assert (m.kind, m.int_ior, m.ext_ior) == (THINDIELECTRIC, 1.333, 1.1)


def test_null_transmitting_flags_thin_rows_of_a_copy_only():
    """pt's copy flags a thindielectric's row, not one inside a mask (whose shadow-ray pass probability would not add
    the slab's share); the table given stays unflagged; a table without thindielectric needs no copy."""
    from caustica.scene.description import DIFFUSE, MASK
    thin = dict(int_ior=1.5, ext_ior=1.0)
    mats = bsdfs.build_material_table(types.SimpleNamespace(materials=[
        Material(THINDIELECTRIC, (1.0, 1.0, 1.0), **thin), Material(MASK, (1.0, 1.0, 1.0), nested=(0,)),
        Material(THINDIELECTRIC, (1.0, 1.0, 1.0), **thin)]))
    flagged = bsdfs.null_transmitting(mats)
    assert [bool(f & bsdfs.NULL_TRANSMISSION) for f in flagged.flags] == [False, False, True]
    assert not np.any(mats.flags & bsdfs.NULL_TRANSMISSION)
    assert bsdfs.null_transmitting(bsdfs.build_material_table(types.SimpleNamespace(
        materials=[Material(DIFFUSE, (0.5, 0.5, 0.5))]))) is None


# ----------------------------------------------------------------------------- polarizer

POLARIZERS = """<scene version="3.0.0">
    <integrator type="{integrator}"/>
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.8, 0.5, 0.3"/></emitter>
    <shape type="rectangle"><transform name="to_world"><scale value="4"/></transform>
        <bsdf type="polarizer"/></shape>
    <shape type="rectangle"><transform name="to_world"><scale value="4"/><translate z="1"/></transform>
        <bsdf type="polarizer"><spectrum name="theta" value="90"/><rgb name="transmittance" value="1, 0.5, 0.2"/>
        <boolean name="polarizing" value="false"/></bsdf></shape>
</scene>
"""


@pytest.mark.parametrize("integrator", ["path", "volpath"])
def test_polarizers_pass_half_the_light_as_mitsubas_rgb_variants(tmp_path, integrator):
    """Mitsuba 3's ``polarizer`` in its RGB variants passes half the light times its transmittance, whatever its
    theta: the sky seen through two of them (one with a transmittance) is L / 2 x T / 2 in every pixel (a slab of
    eta 1 reflects nothing: Fresnel's F is 0 to rounding), under path and volpath alike."""
    path = tmp_path / "p.xml"
    path.write_text(POLARIZERS.format(integrator=integrator))
    scene = caustica.load_scene(str(path))
    mats = scene.materials
    assert set(mats.kind[:2]) == {THINDIELECTRIC}
    image = caustica.render(scene, "pt", spp=4, seed=1).image
    expected = np.array([0.8, 0.5, 0.3]) * 0.5 * 0.5 * np.array([1.0, 0.5, 0.2])
    assert np.allclose(image, expected, rtol=1e-6), (image[0, 0], expected)


def test_polarizers_texture_is_refused_in_one_line(cli, tmp_path):
    path = tmp_path / "p.xml"
    path.write_text(POLARIZERS.format(integrator="path").replace(
        '<rgb name="transmittance" value="1, 0.5, 0.2"/>', '<texture type="checkerboard" name="transmittance"/>'))
    code, _, err = cli("render", path, "--res", "8", "--spp", "1", "-q", "-o", tmp_path / "o.exr")
    assert code == 2 and "\n" not in err.strip(), err
    assert "p.xml:12:" in err and "texture for 'transmittance' of a polarizer" in err, err
