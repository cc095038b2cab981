"""Participating media in scene files: Mitsuba 3's homogeneous medium, phase functions, the null BSDF.

What is read (sigma_t x scale, albedo, isotropic / hg phase, a shape's interior and exterior,
the sensor's medium, nested or by reference), Mitsuba's defaults, what makes a scene one
"with media", and every bad input as one line naming file, line and element (exit 2 from the
command line).  The renders are tested in tests/test_media_pt.py.
"""
from __future__ import annotations

import numpy as np
import pytest

import caustica
from caustica.errors import SceneError
from caustica.scene import load_scene_description, load_scene_file, parse_scene_string
from caustica.scene.description import DIFFUSE, HENYEY_GREENSTEIN, ISOTROPIC, NULL

SENSOR = ('<sensor type="perspective"><float name="fov" value="45"/>'
          '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform>{}</sensor>')
LIGHT = '<shape type="rectangle"><transform name="to_world"><translate z="-3"/></transform><emitter type="area"/></shape>'


def scene(body: str, sensor_inner: str = "") -> str:
    """A scene whose body starts on line 4 (the sensor is line 3)."""
    return f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{SENSOR.format(sensor_inner)}\n{body}\n</scene>\n'


def test_media_nested_referenced_and_defaults():
    d = parse_scene_string(scene("""<medium type="homogeneous" id="fog">
    <rgb name="sigma_t" value="0.1, 0.2, 0.4"/><float name="scale" value="2.5"/><rgb name="albedo" value="0.9, 0.8, 0.7"/>
    <phase type="hg"><float name="g" value="-0.3"/></phase>
</medium>
<shape type="cube" id="box"><bsdf type="null"/><ref name="interior" id="fog"/></shape>
<shape type="sphere" id="ball"><bsdf type="dielectric"/><ref name="exterior" id="fog"/>
    <medium type="homogeneous" name="interior"/></shape>
<shape type="sphere" id="hg"><medium type="homogeneous" name="exterior"><phase type="hg"/></medium></shape>
""", '<ref id="fog"/>'))
    assert len(d.media) == 3
    fog, inner, hg = d.media
    assert fog.sigma_t == pytest.approx((0.25, 0.5, 1.0)) and fog.albedo == (0.9, 0.8, 0.7)
    assert (fog.phase, fog.g, fog.id) == (HENYEY_GREENSTEIN, -0.3, "fog") and fog.source == "<string>:4"
    # Mitsuba's defaults: sigma_t 1, albedo 0.75, isotropic; hg's g 0.8
    assert inner.sigma_t == (1.0, 1.0, 1.0) and inner.albedo == (0.75, 0.75, 0.75) and inner.phase == ISOTROPIC
    assert (hg.phase, hg.g) == (HENYEY_GREENSTEIN, 0.8)
    by_id = {s.id: s for s in d.shapes}
    assert (by_id["box"].interior, by_id["box"].exterior) == (0, -1)
    assert d.materials[by_id["box"].material].kind == NULL
    assert (by_id["ball"].interior, by_id["ball"].exterior) == (1, 0)
    assert (by_id["hg"].interior, by_id["hg"].exterior) == (-1, 2)
    assert d.materials[by_id["hg"].material].kind == DIFFUSE      # the default BSDF
    assert d.camera.medium == 0 and d.has_media


def test_float_coefficients_and_a_nested_sensor_medium():
    d = parse_scene_string(scene("", '<medium type="homogeneous"><float name="sigma_t" value="0.5"/>'
                                     '<float name="albedo" value="1"/><phase type="isotropic"/></medium>'))
    assert d.media[0].sigma_t == (0.5, 0.5, 0.5) and d.media[0].albedo == (1.0, 1.0, 1.0)
    assert d.camera.medium == 0 and d.has_media


def test_what_makes_a_scene_one_with_media():
    # a medium defined but never used does not; a null boundary without a medium does
    assert not parse_scene_string(scene('<medium type="homogeneous" id="fog"/>' + LIGHT)).has_media
    assert parse_scene_string(scene('<shape type="cube"><bsdf type="null"/></shape>' + LIGHT)).has_media
    for name in ("cornell-diacaustic", "cornell-catacaustic", "cornell-pyramid"):
        d = load_scene_description(name)
        assert not d.has_media and d.media == [] and d.camera.medium == -1
        assert all(s.interior == -1 and s.exterior == -1 for s in d.shapes)


#: Bad media input: (body from line 4, or the sensor's inner elements; line; element; a word of the message).
MEDIUM = '<medium type="homogeneous">\n{}</medium>'
BAD = {
    "negative sigma_t": (MEDIUM.format('<rgb name="sigma_t" value="1, -0.5, 1"/>'), 5, '<rgb name="sigma_t">',
                         "must not be negative"),
    "NaN sigma_t": (MEDIUM.format('<float name="sigma_t" value="nan"/>'), 5, '<float name="sigma_t">',
                    "not a finite number"),
    "infinite sigma_t": (MEDIUM.format('<float name="sigma_t" value="inf"/>'), 5, '<float name="sigma_t">',
                         "not a finite number"),
    "negative albedo": (MEDIUM.format('<float name="albedo" value="-0.1"/>'), 5, '<float name="albedo">',
                        "must not be negative"),
    "NaN albedo": (MEDIUM.format('<rgb name="albedo" value="0.5, nan, 0.5"/>'), 5, '<rgb name="albedo">',
                   "not a finite number"),
    "albedo above 1": (MEDIUM.format('<rgb name="albedo" value="0.5, 1.5, 0.5"/>'), 5, '<rgb name="albedo">',
                       "[0, 1]"),
    "negative scale": (MEDIUM.format('<float name="scale" value="-2"/>'), 5, '<float name="scale">',
                       "must not be negative"),
    "NaN scale": (MEDIUM.format('<float name="scale" value="NaN"/>'), 5, '<float name="scale">', "finite"),
    "sigma_t x scale overflows": (MEDIUM.format('<float name="sigma_t" value="1e20"/><float name="scale" '
                                                'value="1e20"/>'), 5, '<float name="scale">', "float32"),
    "g = 1": (MEDIUM.format('<phase type="hg"><float name="g" value="1"/></phase>'), 5, '<float name="g">',
              "strictly between -1 and 1"),
    "g = -1": (MEDIUM.format('<phase type="hg"><float name="g" value="-1"/></phase>'), 5, '<float name="g">',
               "strictly between -1 and 1"),
    "g = 2.5": (MEDIUM.format('<phase type="hg"><float name="g" value="2.5"/></phase>'), 5, '<float name="g">',
                "strictly between -1 and 1"),
    "NaN g": (MEDIUM.format('<phase type="hg"><float name="g" value="nan"/></phase>'), 5, '<float name="g">',
              "finite"),
    "g on isotropic": (MEDIUM.format('<phase type="isotropic"><float name="g" value="0.5"/></phase>'), 5,
                       '<float name="g">', "unknown property 'g'"),
    "two phases": (MEDIUM.format('<phase type="isotropic"/><phase type="hg"/>'), 5, '<phase type="hg">',
                   "only one <phase>"),
    "unknown phase": (MEDIUM.format('<phase type="rayleigh"/>'), 5, '<phase type="rayleigh">',
                      "supported: isotropic, hg"),
    "unknown medium type": ('<medium type="sggx"/>', 4, '<medium type="sggx">',
                            "supported: homogeneous, heterogeneous"),
    "sigma_s (Mitsuba 0.6)": (MEDIUM.format('<float name="sigma_s" value="1"/>'), 5, '<float name="sigma_s">',
                              "supported: sigma_t, albedo, scale"),
    "a volume without its file": (MEDIUM.format('<volume type="gridvolume" name="albedo"/>'), 5, "<volume",
                                  'a gridvolume needs <string name="filename"'),
    "a grid of sigma_t in a homogeneous medium": (MEDIUM.format(
        '<volume type="gridvolume" name="sigma_t"><string name="filename" value="x.vol"/></volume>'), 5, "<volume",
        'needs <medium type="heterogeneous">'),
    "medium referenced but not defined": ('<shape type="cube"><bsdf type="null"/>\n<ref name="interior" id="fog"/>'
                                          '</shape>', 5, '<ref name="interior" id="fog">', "no element has id 'fog'"),
    "sensor's medium not defined": ('', 3, '<ref id="fog">', "no element has id 'fog'", '<ref id="fog"/>'),
    "a BSDF as a medium": ('<bsdf type="diffuse" id="white"/>\n<shape type="cube"><ref name="exterior" id="white"/>'
                           '</shape>', 5, '<ref name="exterior" id="white">', "a <medium> is needed here"),
    "a shape's medium without a name": ('<shape type="cube">\n<medium type="homogeneous"/></shape>', 5,
                                        '<medium type="homogeneous">', 'name="interior" or name="exterior"'),
    "a shape's medium named otherwise": ('<shape type="cube">\n<medium type="homogeneous" name="inside"/></shape>', 5,
                                         '<medium type="homogeneous" name="inside">', "supported: interior, exterior"),
    "two interiors": ('<medium type="homogeneous" id="a"/><shape type="cube"><ref name="interior" id="a"/>\n'
                      '<medium type="homogeneous" name="interior"/></shape>', 5,
                      '<medium type="homogeneous" name="interior">', "given twice"),
    "two sensor media": ('', 3, '<medium type="homogeneous">', "only one <medium>",
                         '<medium type="homogeneous"/><medium type="homogeneous"/>'),
    "twosided null": ('<bsdf type="twosided">\n<bsdf type="null"/></bsdf>', 5, '<bsdf type="null">',
                      "twosided cannot wrap a null BSDF"),
    "null with a property": ('<bsdf type="null">\n<float name="alpha" value="1"/></bsdf>', 5, '<float name="alpha">',
                             "unknown property 'alpha'"),
    "a medium inside a BSDF": ('<bsdf type="null">\n<medium type="homogeneous"/></bsdf>', 5,
                               '<medium type="homogeneous">', "unexpected element"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_media_are_one_line_naming_file_line_and_element(tmp_path, case):
    body, line, element, part, *sensor = BAD[case]
    path = tmp_path / "bad-scene.xml"
    path.write_text(scene(body, *sensor))
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    msg = str(e.value)
    assert "\n" not in msg and msg.startswith(f"{path}:{line}: {element}"), msg
    assert part in msg, msg


@pytest.mark.parametrize("case", ["negative sigma_t", "NaN sigma_t", "g = 1", "medium referenced but not defined"])
def test_bad_media_on_the_command_line_exit_2_with_one_line(cli, tmp_path, case):
    body, line, element, part, *sensor = BAD[case]
    path = tmp_path / "bad-scene.xml"
    path.write_text(scene(body, *sensor))
    code, out, err = cli("render", path, "--res", "8", "--spp", "1", "-q", "-o", tmp_path / "x.exr")
    assert code == 2 and out == "", (code, out, err)
    assert err.count("\n") == 1 and err.startswith(f"caustica: error: {path}:{line}: {element}"), err
    assert part in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad-scene.xml"]


def test_mitsuba_reads_the_same_media(tmp_path):
    """The subset is Mitsuba's: a scene using every element above loads in Mitsuba 3 too."""
    mi = pytest.importorskip("mitsuba")
    mi.set_variant("scalar_rgb")
    text = scene("""<medium type="homogeneous" id="fog"><rgb name="sigma_t" value="0.1, 0.2, 0.4"/>
    <float name="scale" value="2.5"/><rgb name="albedo" value="0.9, 0.8, 0.7"/><phase type="hg"><float name="g" value="-0.3"/></phase>
</medium>
<shape type="cube" id="box"><bsdf type="null"/><ref name="interior" id="fog"/></shape>
<shape type="sphere" id="ball"><bsdf type="dielectric"/><ref name="exterior" id="fog"/>
    <medium type="homogeneous" name="interior"><float name="albedo" value="1"/><phase type="isotropic"/></medium></shape>
""" + LIGHT, '<ref id="fog"/>')
    path = tmp_path / "media.xml"
    path.write_text(text)
    mi.load_file(str(path))
    d = load_scene_file(path)
    assert len(d.media) == 2 and d.has_media


# ----------------------------------------------------------------------------- methods

FOG_SCENE = scene('<shape type="cube"><bsdf type="null"/><medium type="homogeneous" name="interior"/></shape>\n'
                  + LIGHT)


@pytest.mark.parametrize("method", ["pt", "pm", "spm", "sppm", "pspm"])
def test_every_method_renders_a_scene_with_media(tmp_path, cli, method):
    """Every method takes media now (none refuses them): the command line writes a finite, lit image (a smoke
    test; accuracy is tests/test_media_photons.py's)."""
    path = tmp_path / "fog.xml"
    path.write_text(FOG_SCENE)
    out = tmp_path / "x.exr"
    code, _, err = cli("render", path, "--method", method, "--res", "8", "-q", "-o", out)
    assert code == 0, err
    img = caustica.render(str(path), method, res=8).image
    assert np.all(np.isfinite(img)) and img.mean() > 0


def test_the_photon_picture_of_a_scene_with_media_shows_its_surface_records(tmp_path, cli):
    from caustica.api import progress_factory, resolve_settings
    from caustica.photon_view import photon_picture
    path = tmp_path / "fog.xml"
    path.write_text(FOG_SCENE)
    code, _, err = cli("photons", path, "--method", "pm", "--res", "8", "-q", "-o", tmp_path / "x.png")
    assert code == 0 and (tmp_path / "x.png").exists(), err
    sc, cls, settings = resolve_settings("cornell-diacaustic-fog", "pm", res=16, photons=20_000)
    picture, stats = photon_picture(sc, cls, settings, progress_factory(False))
    assert stats["global_photons_stored"] > 0 and picture[:, :16].max() > 0   # the global map's panel


def test_integrator_note_for_media_scenes(tmp_path):
    path = tmp_path / "fog.xml"
    for kind in ("volpath", "path"):
        path.write_text(FOG_SCENE.replace("<scene version=\"3.0.0\">",
                                          f'<scene version="3.0.0"><integrator type="{kind}"/>'))
        d = load_scene_file(path)
        note = d.integrator_note("pt", {"max_depth": -1})
        if kind == "volpath":   # volpath is what pt does
            assert note is None
            assert d.integrator_note("pm", {}) is None   # the photon methods render media, to any depth
        else:                   # Mitsuba's path ignores media; pt does not
            assert note == (f"integrator 'path' in {path}:2 would ignore the scene's media in Mitsuba; pt renders "
                            f"them (as Mitsuba's volpath does)")


def test_a_note_for_a_medium_whose_mesh_faces_inwards(tmp_path, cli):
    """A mesh holding an interior medium with its faces turned inwards puts the medium outside it, where Mitsuba's
    camera paths (and pt's) keep it after they leave the mesh: the photon methods get a note (SceneDescription.
    media_note), so does a flipped sphere; pt gets none, nor does the same cube facing outwards, or a flat mesh (a
    rectangle)."""
    fog = '<medium type="homogeneous" id="fog"/>'
    shape = '<shape type="{}">{}<bsdf type="dielectric"/><ref name="interior" id="fog"/></shape>'
    flip = '<boolean name="flip_normals" value="true"/>'
    inward = parse_scene_string(scene(fog + shape.format("cube", flip)))
    note = inward.media_note("sppm")
    assert note is not None and "<string>:4" in note and "faces inwards" in note and "--method sppm" in note
    assert inward.media_note("pt") is None
    assert "faces inwards" in parse_scene_string(scene(fog + shape.format("sphere", flip))).media_note("spm")
    for ok in (shape.format("cube", ""), shape.format("rectangle", flip), shape.format("sphere", "")):
        assert parse_scene_string(scene(fog + ok)).media_note("pm") is None
    path = tmp_path / "inward.xml"
    path.write_text(scene(fog + shape.format("cube", flip) + LIGHT))
    code, _, err = cli("render", str(path), "--method", "sppm", "--passes", "1", "--res", "8", "-o", tmp_path / "o.exr")
    assert code == 0 and "note: the shape at" in err


# ----------------------------------------------------------------------------- the built-in fog scene

def test_fog_scene_is_the_diacaustic_scene_in_fog():
    import numpy as np
    fog = load_scene_description("cornell-diacaustic-fog")
    plain = load_scene_description("cornell-diacaustic")
    assert fog.has_media and fog.integrator == "volpath" and fog.camera.medium == -1   # the camera is outside
    assert [m.__dict__ for m in fog.materials[:len(plain.materials)]] == [m.__dict__ for m in plain.materials]
    np.testing.assert_array_equal(fog.camera.to_world, plain.camera.to_world)
    (medium,) = fog.media
    assert medium.sigma_t == (0.05, 0.05, 0.05) and medium.albedo == (0.9, 0.9, 0.9) and medium.phase == ISOTROPIC
    assert 1 / medium.sigma_t[0] == pytest.approx(20.0)         # the mean free path: the box's size
    by_id = {s.id: s for s in fog.shapes}
    assert [s.id for s in fog.shapes] == [s.id for s in plain.shapes] + ["fog_volume"]
    for s in plain.shapes:
        mine = by_id[s.id]
        assert (mine.kind, mine.material, mine.emitter_radiance) == (s.kind, s.material, s.emitter_radiance)
        if s.mesh is not None:
            np.testing.assert_array_equal(mine.mesh.positions, s.mesh.positions)
    assert (by_id["glass_sphere"].interior, by_id["glass_sphere"].exterior) == (-1, 0)   # no fog in the glass
    volume = by_id["fog_volume"]
    assert fog.materials[volume.material].kind == NULL and (volume.interior, volume.exterior) == (0, -1)
    lo, hi = volume.mesh.positions.min(axis=0), volume.mesh.positions.max(axis=0)
    np.testing.assert_allclose(lo, [-10.01, -0.01, -10.01])
    np.testing.assert_allclose(hi, [10.01, 20.01, 10.01])
