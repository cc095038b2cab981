"""Mitsuba 3 scene files as users have them: <include>, <path>, $parameters across files, and the
sensor, film, sampler, spectrum and integrator settings Mitsuba 3 documents (docs/scenes.md)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from caustica.errors import SceneError
from caustica.scene import load_scene_file, parse_scene_string

SENSOR = """<sensor type="perspective"><float name="fov" value="45"/>
<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>"""


def scene(body: str, sensor: str = SENSOR) -> str:
    return f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{sensor}\n{body}\n</scene>\n'


def write(path: Path, text: str) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


def one_line_error(path: Path, defaults=None) -> str:
    with pytest.raises(SceneError) as e:
        load_scene_file(path, defaults)
    msg = str(e.value)
    assert "\n" not in msg, msg
    return msg


# ----------------------------------------------------------------------------- <include>, <path>, $name

def test_include_is_relative_to_the_including_file(tmp_path):
    write(tmp_path / "parts" / "box.xml",
          '<scene version="3.0.0">\n<include filename="../mats/white.xml"/>\n'
          '<shape type="cube" id="box"><ref id="white"/></shape>\n</scene>')
    write(tmp_path / "mats" / "white.xml",
          '<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.8"/></bsdf>')
    main = write(tmp_path / "main.xml", scene('<include filename="parts/box.xml"/>'))
    d = load_scene_file(main)
    (box,) = d.shapes
    assert box.id == "box" and box.source == f"{tmp_path / 'parts' / 'box.xml'}:3"
    assert d.materials[box.material].rgb == (0.8, 0.8, 0.8)
    assert [p.name for p in d.files] == ["main.xml", "box.xml", "white.xml"]


def test_path_adds_folders_for_includes_and_meshes(tmp_path):
    write(tmp_path / "lib" / "lights.xml", '<scene version="3.0.0"><shape type="rectangle" id="light">'
                                           '<emitter type="area"/></shape></scene>')
    ply = "\n".join(["ply", "format ascii 1.0", "element vertex 3", "property float x", "property float y",
                     "property float z", "element face 1", "property list uchar int vertex_indices",
                     "end_header", "0 0 0", "1 0 0", "0 1 0", "3 0 1 2", ""])
    write(tmp_path / "assets" / "meshes" / "tri.ply", ply)
    main = write(tmp_path / "scenes" / "main.xml",
                 scene('<path value="../lib"/>\n<path value="../assets"/>\n<include filename="lights.xml"/>\n'
                       '<shape type="ply" id="tri"><string name="filename" value="meshes/tri.ply"/></shape>'))
    d = load_scene_file(main)
    assert [s.id for s in d.shapes] == ["light", "tri"]
    assert d.shapes[1].mesh.triangles.shape == (1, 3)
    assert (tmp_path / "assets" / "meshes" / "tri.ply").resolve() in [p.resolve() for p in d.files]
    # without the <path>, the mesh is not found, and the error says where it looked
    main.write_text(scene('<shape type="ply"><string name="filename" value="meshes/tri.ply"/></shape>'))
    assert "mesh file 'meshes/tri.ply' not found; searched: " in one_line_error(main)


def test_parameters_reach_included_files(tmp_path):
    write(tmp_path / "ball.xml", '<scene version="3.0.0">\n<default name="r" value="2"/>\n'
                                 '<default name="albedo" value="0.3"/>\n'
                                 '<shape type="sphere"><float name="radius" value="$r"/>'
                                 '<bsdf type="diffuse"><float name="reflectance" value="$albedo"/></bsdf></shape>\n'
                                 '</scene>')
    main = write(tmp_path / "main.xml", scene('<default name="albedo" value="0.6"/>\n<include filename="ball.xml"/>'))
    d = load_scene_file(main)
    radius = lambda d: np.linalg.norm(d.shapes[0].to_world[:3, 0])
    # the including file's default wins over the included one's; an included default fills the gap
    assert radius(d) == pytest.approx(2.0) and d.materials[d.shapes[0].material].rgb == (0.6, 0.6, 0.6)
    # -D wins over both, and may name a parameter only an included file uses
    d = load_scene_file(main, {"r": "3", "albedo": "0.1"})
    assert radius(d) == pytest.approx(3.0) and d.materials[d.shapes[0].material].rgb == (0.1, 0.1, 0.1)
    # an include's file name may use $name
    write(tmp_path / "main2.xml", scene('<default name="part" value="ball"/>\n<include filename="$part.xml"/>'))
    assert len(load_scene_file(tmp_path / "main2.xml").shapes) == 1


def test_an_include_loop_is_one_line_naming_the_files_and_lines(tmp_path):
    write(tmp_path / "a.xml", '<scene version="3.0.0">\n\n<include filename="b.xml"/>\n</scene>')
    write(tmp_path / "b.xml", '<scene version="3.0.0">\n<include filename="a.xml"/>\n</scene>')
    main = write(tmp_path / "main.xml", scene('<include filename="a.xml"/>'))
    msg = one_line_error(main)
    assert msg.startswith(f"{tmp_path / 'b.xml'}:2: <include>: include loop: {main}:5 includes a.xml; "
                          f"{tmp_path / 'a.xml'}:3 includes b.xml; {tmp_path / 'b.xml'}:2 includes a.xml"), msg
    # a file including itself, and the main file included again
    write(tmp_path / "self.xml", '<scene version="3.0.0"><include filename="self.xml"/></scene>')
    main.write_text(scene('<include filename="self.xml"/>'))
    assert "include loop" in one_line_error(main)
    write(tmp_path / "back.xml", '<scene version="3.0.0"><include filename="main.xml"/></scene>')
    main.write_text(scene('<include filename="back.xml"/>'))
    assert "include loop" in one_line_error(main)


@pytest.mark.parametrize("body, words", [
    ('<include filename="nope.xml"/>', "<include>: included file 'nope.xml' not found"),
    ('<include/>', "<include>: missing attribute 'filename'"),
    ('<path value="no-such-folder"/>', "<path>: folder 'no-such-folder' not found"),
    ('<shape type="cube"><path value="."/></shape>', "<path> must be a child of <scene>"),
    ('<include filename="$missing.xml"/>', "uses $missing, which is not defined"),
])
def test_include_and_path_errors(tmp_path, body, words):
    main = write(tmp_path / "main.xml", scene(body))
    msg = one_line_error(main)
    assert msg.startswith(f"{main}:5: ") and words in msg, msg


def test_errors_inside_an_included_file_name_that_file(tmp_path):
    write(tmp_path / "bad.xml", '<scene version="3.0.0">\n<shape type="sphere">\n'
                                '<float name="radius" value="-1"/></shape></scene>')
    main = write(tmp_path / "main.xml", scene('<include filename="bad.xml"/>'))
    assert one_line_error(main).startswith(f"{tmp_path / 'bad.xml'}:3: <float name=\"radius\">")
    write(tmp_path / "broken.xml", '<scene version="3.0.0">\n<shape type="cube">\n</scene>')
    main.write_text(scene('<include filename="broken.xml"/>'))
    assert one_line_error(main).startswith(f"{tmp_path / 'broken.xml'}:3: malformed XML")


# ----------------------------------------------------------------------------- the sensor

def sensor(inner: str, kind: str = "perspective", film: str = "") -> str:
    return (f'<sensor type="{kind}">{inner}<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" '
            f'up="0, 1, 0"/></transform>{film}</sensor>')


FILM_WH = '<film type="hdrfilm"><integer name="width" value="{}"/><integer name="height" value="{}"/></film>'


@pytest.mark.parametrize("inner", [
    "",                                                        # Mitsuba's default: a 50 mm lens, diagonal
    '<string name="focal_length" value="28mm"/>',
    '<string name="focal_length" value="85"/>',
    '<float name="fov" value="40"/><string name="fov_axis" value="diagonal"/>',
    '<float name="fov" value="40"/><string name="fov_axis" value="y"/>',
    '<float name="fov" value="40"/><string name="fov_axis" value="smaller"/>',
    '<float name="fov" value="40"/><string name="fov_axis" value="larger"/>',
])
@pytest.mark.parametrize("size", [(64, 48), (30, 90)])
def test_field_of_view_as_mitsuba_reads_it(mi, inner, size):
    from caustica.camera import tan_half_angles
    xml = scene("", sensor(inner, film=FILM_WH.format(*size)))
    theirs = mi.traverse(mi.load_string(xml).sensors()[0])["x_fov"]
    cam = parse_scene_string(xml).camera
    tx, ty = tan_half_angles(cam.fov_deg, cam.fov_axis, *size)
    assert tx == pytest.approx(np.tan(np.radians(float(np.ravel(theirs)[0])) / 2), rel=1e-5)
    assert tx / ty == pytest.approx(size[0] / size[1])


def test_clip_planes(tmp_path):
    cam = parse_scene_string(scene("", sensor('<float name="fov" value="45"/>'))).camera
    assert (cam.near_clip, cam.far_clip) == (1e-2, 1e4)          # Mitsuba's defaults
    body = '<shape type="sphere" id="s"><point name="center" value="0, 0, -3"/></shape>'  # reaches depth 9 from the camera
    for far in ("10", "9.01"):
        d = parse_scene_string(scene(body, sensor(f'<float name="fov" value="45"/><float name="near_clip" value="0.5"/>'
                                                  f'<float name="far_clip" value="{far}"/>')))
        assert (d.camera.near_clip, d.camera.far_clip) == (0.5, float(far))
    # a far plane that would cut a shape: refused, as caustica does not clip there
    path = write(tmp_path / "far.xml", scene(body, sensor('<float name="fov" value="45"/>\n<float name="far_clip" value="7"/>')))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:4: <float name=\"far_clip\">: far_clip=7 would hide the parts of the scene beyond it "
                          f"(they reach 9 along the view axis)"), msg
    # a rectangle's far corner counts, not its centre
    rect = '<shape type="rectangle"><transform name="to_world"><scale value="10"/><rotate x="1" angle="80"/></transform></shape>'
    path.write_text(scene(rect, sensor('<float name="fov" value="45"/><float name="far_clip" value="12"/>')))
    assert "they reach 14.85 along the view axis" in one_line_error(path)


@pytest.mark.parametrize("inner, words", [
    ('<float name="fov" value="45"/><string name="focal_length" value="50mm"/>', "either 'fov' or 'focal_length'"),
    ('<string name="focal_length" value="wide"/>', "focal_length='wide' is not a positive length"),
    ('<string name="focal_length" value="-5mm"/>', "focal_length='-5mm' is not a positive length"),
    ('<float name="fov" value="45"/><string name="fov_axis" value="z"/>', "unknown fov_axis 'z'; supported: x, y, diagonal"),
    ('<float name="fov" value="45"/><float name="principal_point_offset_x" value="0.1"/>', "off-centre"),
    ('<float name="fov" value="45"/><float name="near_clip" value="2"/><float name="far_clip" value="1"/>',
     "near_clip (2) must be smaller than far_clip (1)"),
])
def test_sensor_setting_errors(tmp_path, inner, words):
    path = write(tmp_path / "cam.xml", scene("", sensor(inner)))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:3: ") and words in msg, msg


def test_settings_that_change_nothing_in_a_pinhole_image_are_accepted():
    inner = ('<float name="fov" value="45"/><float name="focus_distance" value="3"/>'
             '<float name="shutter_open" value="0"/><float name="shutter_close" value="1"/>'
             '<float name="principal_point_offset_x" value="0"/>')
    plain = parse_scene_string(scene("", sensor('<float name="fov" value="45"/>'))).camera
    cam = parse_scene_string(scene("", sensor(inner))).camera
    assert (cam.fov_deg, cam.fov_axis, cam.near_clip) == (plain.fov_deg, plain.fov_axis, plain.near_clip)
    # a thin lens of aperture 0 is a pinhole; a real aperture is read (depth of field: tests/test_sensors.py)
    lens = parse_scene_string(scene("", sensor(inner + '<float name="aperture_radius" value="0"/>', "thinlens"))).camera
    assert np.array_equal(lens.to_world, plain.to_world) and lens.fov_deg == plain.fov_deg and lens.aperture_radius == 0
    lens = parse_scene_string(scene("", sensor(inner + '<float name="aperture_radius" value="0.1"/>', "thinlens"))).camera
    assert (lens.aperture_radius, lens.focus_distance) == (0.1, 3.0)


# ----------------------------------------------------------------------------- film and sampler

def film(inner: str) -> str:
    return sensor('<float name="fov" value="45"/>',
                  film=f'<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="24"/>'
                       f'\n{inner}</film>')


def test_film_settings_that_change_nothing_in_the_image_are_accepted(mi):
    inner = ('<string name="file_format" value="OpenEXR"/><string name="pixel_format" value="rgba"/>'
             '<string name="component_format" value="float32"/><boolean name="banner" value="false"/>'
             '<boolean name="sample_border" value="true"/><integer name="crop_offset_x" value="0"/>'
             '<integer name="crop_width" value="32"/><integer name="crop_height" value="24"/>'
             '<rfilter type="box"/>')
    xml = scene("", film(inner))
    mi.load_string(xml)   # all of it is Mitsuba 3's
    plain = parse_scene_string(scene("", film(""))).camera
    cam = parse_scene_string(xml).camera
    assert (cam.width, cam.height, cam.fov_deg) == (plain.width, plain.height, plain.fov_deg) == (32, 24, 45)
    # sample_border is read (the reconstruction filter honours it), off by default as in Mitsuba
    assert cam.sample_border and not plain.sample_border
    for fmt in ("rgbe", "pfm", "exr"):
        parse_scene_string(scene("", film(f'<string name="file_format" value="{fmt}"/>')))
    for fmt in ("float16", "uint32"):
        parse_scene_string(scene("", film(f'<string name="component_format" value="{fmt}"/>')))


@pytest.mark.parametrize("fmt, written", [("luminance", "luminance (Y)"), ("luminance_alpha", "(Y, A)"),
                                         ("xyz", "CIE XYZ (X, Y, Z)"), ("xyza", "(X, Y, Z, A)")])
def test_a_pixel_format_other_than_rgb_renders_rgb_with_a_note(mi, tmp_path, fmt, written):
    """The same light in other channels (issue 20: a pixel format is accepted): the image is caustica's linear sRGB,
    and the description carries one note with the film's line and what Mitsuba would write."""
    xml = scene("", film(f'<string name="pixel_format" value="{fmt}"/>'))
    mi.load_string(xml)
    path = write(tmp_path / "film.xml", xml)
    desc = load_scene_file(path)
    assert (desc.camera.width, desc.camera.height) == (32, 24)
    assert len(desc.loader_notes) == 1 and desc.loader_notes[0].startswith(f"{path}:4: pixel_format='{fmt}'") and \
        "linear sRGB" in desc.loader_notes[0] and written in desc.loader_notes[0], desc.loader_notes
    assert load_scene_file(write(tmp_path / "plain.xml", scene("", film("")))).loader_notes == []


@pytest.mark.parametrize("kind", ["perspective", "thinlens"])
def test_a_perspective_camera_that_scales_is_refused_as_mitsuba_refuses_it(mi, tmp_path, kind):
    """Mitsuba 3: "Scale factors in the camera-to-world transformation are not allowed!" (caustica stretched the view
    instead); a mirror (scale -1) is no scale."""
    lens = '<float name="aperture_radius" value="0"/>' if kind == "thinlens" else ""
    scaled = scene("", f'<sensor type="{kind}">{lens}<transform name="to_world"><scale x="2" y="1" z="1"/>'
                       f'<translate z="5"/></transform></sensor>')
    with pytest.raises(RuntimeError, match="Scale factors"):
        mi.load_string(scaled)
    path = write(tmp_path / "scaled.xml", scaled)
    assert one_line_error(path).startswith(f"{path}:3: ") and "must not scale" in one_line_error(path)
    mirrored = scaled.replace('x="2"', 'x="-1"')
    mi.load_string(mirrored)
    assert parse_scene_string(mirrored).camera is not None


def test_the_first_of_several_sensors_is_rendered_as_mitsuba_renders_it(mi, tmp_path):
    """Mitsuba 3 loads every <sensor> and its render() takes the first: caustica reads and checks them all, renders the
    first (the one Mitsuba's sensors()[0] is) and says so in one note; a fault in another is still reported."""
    second = sensor('<float name="fov" value="70"/>').replace("0, 0, 5", "0, 0, 9")
    xml = scene("", sensor('<float name="fov" value="30"/>') + "\n" + second + "\n" + second)
    theirs = mi.load_string(xml).sensors()
    assert len(theirs) == 3 and np.array(theirs[0].world_transform().matrix)[2, 3] == 5.0   # the first one's origin
    path = write(tmp_path / "sensors.xml", xml)
    desc = load_scene_file(path)
    assert desc.camera.fov_deg == 30.0
    assert desc.loader_notes == [f"{path}: the scene has 3 <sensor>s: caustica renders the first, as Mitsuba's "
                                 "render() does by default; the other 2 (line 4, line 5) are read, not rendered"]
    bad = write(tmp_path / "bad.xml", xml.replace('value="70"', 'value="-70"', 1))
    assert "fov" in one_line_error(bad)
    # what reading the others leaves behind is dropped: the first sensor's far_clip is the one checked (here it
    # would hide the sphere 5 away), a later one's inline medium is not the scene's, nor its film's note
    sphere = '<shape type="sphere"/>'
    clipped = scene(sphere, sensor('<float name="fov" value="30"/><float name="far_clip" value="2"/>') + "\n" +
                    second.replace('<float name="fov" value="70"/>', '<float name="fov" value="70"/><medium '
                                   'type="homogeneous" name="medium"/>').replace(
                        "</sensor>", film('<string name="pixel_format" value="xyz"/>').split("</transform>", 1)[1]))
    mi.load_string(clipped)
    assert "far_clip" in one_line_error(write(tmp_path / "clipped.xml", clipped))
    desc = load_scene_file(write(tmp_path / "unclipped.xml", clipped.replace('value="2"', 'value="20"')))
    assert desc.media == [] and len(desc.loader_notes) == 1, (desc.media, desc.loader_notes)


def test_a_volume_texture_loads_unused_and_is_refused_where_a_shape_uses_it(mi, tmp_path):
    """Mitsuba's tutorial LEGO scene declares a diffuse BSDF whose reflectance is a `volume` texture and uses it
    nowhere.  caustica looks textures up at (u, v), not at a world position, so it reads and checks such a texture
    (its grid's file too) and refuses it only where a shape's BSDF uses it, naming both."""
    from caustica.scene.volume_files import write_grid
    write_grid(tmp_path / "red.vol", np.full((2, 2, 2, 3), 0.5, np.float32))
    bsdf = ('<bsdf type="diffuse" id="vol"><texture type="volume" name="reflectance"><volume type="gridvolume" '
            'name="volume"><string name="filename" value="red.vol"/></volume></texture></bsdf>')
    unused = write(tmp_path / "unused.xml", scene(bsdf + '<shape type="sphere"/>'))
    mi.load_file(str(unused))
    assert load_scene_file(unused).materials   # loads
    used = write(tmp_path / "used.xml", scene(bsdf + '<shape type="sphere"><ref id="vol"/></shape>'))
    mi.load_file(str(used))
    msg = one_line_error(used)
    assert msg.startswith(f"{used}:5: a volume texture") and f"the sphere at {used}:5" in msg and \
        "checkerboard, bitmap" in msg, msg
    twice = write(tmp_path / "twice.xml", scene(bsdf + '<shape type="sphere"><ref id="vol"/></shape>'
                                                '<shape type="cube"><ref id="vol"/></shape>'))
    msg = one_line_error(twice)   # one error a texture, however many shapes use it
    assert "the sphere at" in msg and "and 1 other shape)" in msg, msg
    missing = write(tmp_path / "missing.xml", scene(bsdf.replace("red.vol", "absent.vol") + '<shape type="sphere"/>'))
    assert "absent.vol" in one_line_error(missing)
    constant = write(tmp_path / "constant.xml", scene('<bsdf type="diffuse"><texture type="volume" '
                                                      'name="reflectance"/></bsdf>'))
    mi.load_file(str(constant))
    assert load_scene_file(constant).materials   # no volume: Mitsuba's constant 0.75
    spot = write(tmp_path / "spot.xml", scene('<emitter type="spot"><texture type="volume" name="texture"><volume '
                                              'type="gridvolume" name="volume"><string name="filename" value="red.vol"/>'
                                              '</volume></texture></emitter><shape type="sphere"/>'))
    assert "spot emitter's texture cannot be a volume texture" in one_line_error(spot)   # always used


def test_a_comment_holding_two_dashes_is_read_as_mitsuba_reads_it(mi, tmp_path):
    """XML forbids '--' inside a comment and expat refuses it; Mitsuba's parser takes it (published scenes open with
    a licence header of lines beginning '--', NVlabs/sionna's), and so does caustica, with the lines kept."""
    header = "<!--\n-- SPDX-License-Identifier: Apache-2.0\n-- two -- dashes --->\n"
    xml = header + scene('<shape type="sphere"><float name="radius" value="-1"/></shape>').split("\n", 1)[1]
    mi.load_string(xml.replace('value="-1"', 'value="1"'))
    path = write(tmp_path / "dashes.xml", xml)
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:7: <float name=\"radius\">"), msg   # the line after the three of the comment
    assert load_scene_file(write(tmp_path / "ok.xml", xml.replace('value="-1"', 'value="1"'))).camera.fov_deg == 45.0
    assert "malformed XML" in one_line_error(write(tmp_path / "open.xml", "<!-- -- never closed\n" + scene("")))


@pytest.mark.parametrize("inner, words", [
    ('<string name="pixel_format" value="cmyk"/>', "unknown pixel_format 'cmyk'; supported: rgb, rgba, luminance"),
    ('<string name="file_format" value="png"/>', "unknown file_format 'png'; supported: openexr, exr, rgbe, pfm"),
    ('<string name="component_format" value="int8"/>', "unknown component_format 'int8'"),
    ('<integer name="crop_width" value="16"/>', "a crop window (crop_offset_x=0, crop_offset_y=0, crop_width=16, "
                                                "crop_height=24) smaller than the 32 x 24 film is not supported"),
    ('<integer name="crop_offset_x" value="20"/><integer name="crop_width" value="16"/>',
     "must lie inside the 32 x 24 film"),
    ('<integer name="crop_offset_y" value="-1"/>', "'crop_offset_y' must not be negative"),
])
def test_film_setting_errors(tmp_path, inner, words):
    path = write(tmp_path / "film.xml", scene("", film(inner)))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:4: ") and words in msg, msg


@pytest.mark.parametrize("kind, extra", [
    ("independent", '<integer name="seed" value="3"/>'),
    ("stratified", '<boolean name="jitter" value="false"/>'),
    ("multijitter", '<boolean name="jitter" value="true"/>'),
    ("orthogonal", '<integer name="strength" value="2"/>'),
    ("ldsampler", ""),
])
@pytest.mark.parametrize("count", [10, 16, 37])
def test_every_mitsuba_sampler_gives_its_sample_count(mi, kind, extra, count):
    """sample_count is the samples per pixel, rounded as Mitsuba's sampler rounds it (stratified to a square...)."""
    s = sensor('<float name="fov" value="45"/>',
               film=f'<sampler type="{kind}"><integer name="sample_count" value="{count}"/>{extra}</sampler>')
    theirs = mi.load_string(scene("", s)).sensors()[0].sampler().sample_count()
    assert parse_scene_string(scene("", s)).spp == theirs >= count
    assert (theirs == count) == (kind == "independent" or count == 16 and kind != "orthogonal")
    with pytest.raises(SceneError, match=f"unknown property 'warp' of <sampler type=\"{kind}\">"):
        parse_scene_string(scene("", s.replace("</sampler>", '<float name="warp" value="1"/></sampler>')))


# ----------------------------------------------------------------------------- <spectrum>

SPECTRA = ["0.5", "400:0.1, 500:0.6, 600:0.3, 700:0.9", "360:1, 830:1", "550:2, 560:2",
           "300:0.2,450:0.9,900:0.1"]


def spectrum_scene(kind: str, value: str) -> tuple[str, str]:
    """(XML with one sphere whose reflectance, radiance or medium's sigma_t is the spectrum, Mitsuba's key)."""
    attr = f'<spectrum name="{{}}" value="{value}"/>'
    if kind == "bsdf":
        body, key = f'<shape type="sphere"><bsdf type="diffuse">{attr.format("reflectance")}</bsdf></shape>', \
            "bsdf.reflectance.value"
    elif kind == "emitter":
        body, key = f'<shape type="sphere"><emitter type="area">{attr.format("radiance")}</emitter></shape>', \
            "emitter.radiance.value"
    else:
        body, key = (f'<medium type="homogeneous" id="m">{attr.format("sigma_t")}</medium>'
                     f'<shape type="sphere"><ref name="interior" id="m"/><bsdf type="null"/></shape>',
                     "interior_medium.sigma_t.value.value")
    return scene(body, sensor('<float name="fov" value="45"/>')), key


def spectrum_rgb(d, kind):
    s = d.shapes[0]
    return {"bsdf": lambda: d.materials[s.material].rgb, "emitter": lambda: s.emitter_radiance,
            "medium": lambda: d.media[0].sigma_t}[kind]()


def test_a_constant_spectrum_is_grey_except_on_an_emitter():
    xml, _ = spectrum_scene("bsdf", "0.5")
    assert spectrum_rgb(parse_scene_string(xml), "bsdf") == (0.5, 0.5, 0.5)
    xml, _ = spectrum_scene("bsdf", "360:0.5, 830:0.5")     # flat over the visible range: grey within 1e-3
    assert spectrum_rgb(parse_scene_string(xml), "bsdf") == pytest.approx((0.5, 0.5, 0.5), abs=1e-3)
    # an emitter's flat spectrum is D65-relative, so not white in sRGB (Mitsuba's RGB variants do the same)
    xml, _ = spectrum_scene("emitter", "1")
    assert spectrum_rgb(parse_scene_string(xml), "emitter") == pytest.approx((1.204794, 0.948291, 0.908916), abs=1e-6)


@pytest.mark.parametrize("kind", ["bsdf", "emitter", "medium"])
@pytest.mark.parametrize("value", SPECTRA)
def test_spectra_convert_to_rgb_as_mitsuba_does(mi, kind, value):
    xml, key = spectrum_scene(kind, value)
    theirs = np.ravel(np.array(mi.traverse(mi.load_string(xml).shapes()[0])[key]))
    mine = np.array(spectrum_rgb(parse_scene_string(xml), kind))
    np.testing.assert_allclose(mine, np.broadcast_to(theirs, (3,)), atol=1e-6)


def test_spectrum_from_an_spd_file(tmp_path):
    write(tmp_path / "data" / "refl.spd", "# a reflectance\n400 0.1\n500 0.6\n\n600 0.3  # comment\n700 0.9\n")
    path = write(tmp_path / "s.xml", scene('<path value="data"/><shape type="sphere"><bsdf type="diffuse">'
                                           '<spectrum name="reflectance" filename="refl.spd"/></bsdf></shape>'))
    d = load_scene_file(path)
    xml, _ = spectrum_scene("bsdf", SPECTRA[1])
    assert spectrum_rgb(d, "bsdf") == spectrum_rgb(parse_scene_string(xml), "bsdf")
    assert tmp_path / "data" / "refl.spd" in d.files


@pytest.mark.parametrize("value, words", [
    ("half", "'half' is not a number"),
    ("500:0.5", "needs at least 2 pairs, got 1"),
    ("600:0.5, 500:0.2", "wavelengths must increase, but 500 follows 600"),
    ("400:0.5, 500", "'500' is not a wavelength:value pair"),
    ("400:0.5, 500:x", "'500:x' is not a pair of numbers"),
])
def test_bad_spectra_are_one_line_with_file_and_line(tmp_path, capsys, value, words):
    from caustica.cli import main
    path = write(tmp_path / "bad.xml", scene(f'<shape type="sphere"><bsdf type="diffuse">\n'
                                             f'<spectrum name="reflectance" value="{value}"/></bsdf></shape>'))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:6: <spectrum name=\"reflectance\">: ") and words in msg, msg
    assert main(["render", str(path), "--method", "pt", "-q", "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err
    assert err == f"caustica: error: {msg}\n" and not (tmp_path / "x.exr").exists()


@pytest.mark.parametrize("attrs, words", [
    ('type="blackbody"', "a spectrum plugin (<spectrum type='blackbody'>) is not supported"),
    ('value="0.5" filename="a.spd"', "either value= or filename=, not both"),
    ('filename="none.spd"', "spectrum file 'none.spd' not found"),
])
def test_spectrum_element_errors(tmp_path, attrs, words):
    path = write(tmp_path / "bad.xml", scene(f'<shape type="sphere"><bsdf type="diffuse">\n'
                                             f'<spectrum name="reflectance" {attrs}/></bsdf></shape>'))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:6: ") and words in msg, msg


# ----------------------------------------------------------------------------- <integrator>

def integrator_of(xml_integrator: str):
    return parse_scene_string(scene(xml_integrator, sensor('<float name="fov" value="45"/>')))


def test_the_integrator_settings_are_read():
    d = integrator_of('<integrator type="path"><integer name="max_depth" value="8"/><integer name="rr_depth" value="3"/>'
                      '<boolean name="hide_emitters" value="true"/></integrator>')
    st = d.integrator_settings
    assert (st.type, st.max_depth, st.rr_depth, st.hide_emitters, st.wrapper) == ("path", 8, 3, True, "")
    assert st.source == "<string>:4" and d.integrator == "path" and d.integrator_source == "<string>:4"
    # without an <integrator>: Mitsuba's defaults (its default integrator is path)
    st = integrator_of("").integrator_settings
    assert (st.type, st.max_depth, st.rr_depth, st.hide_emitters, st.source) == ("path", -1, 5, False, "")


def test_a_moment_integrator_stands_for_the_one_it_wraps():
    d = integrator_of('<integrator type="moment">\n<integrator type="volpath"><integer name="max_depth" value="4"/>'
                      '</integrator></integrator>')
    st = d.integrator_settings
    assert (st.type, st.max_depth, st.wrapper, st.source, st.wrapper_source) == \
        ("volpath", 4, "moment", "<string>:5", "<string>:4")
    assert d.integrator == "volpath" and d.integrator_props == {"max_depth": 4}
    # so the note about the integrator is the wrapped one's: pt with the file's settings says nothing
    assert d.integrator_note("pt", {"max_depth": 4, "rr_depth": 5}) is None


@pytest.mark.parametrize("xml, kind, props", [
    ('<integrator type="direct"><integer name="emitter_samples" value="4"/></integrator>', "direct",
     {"emitter_samples": 4}),
    ('<integrator type="ptracer"><integer name="samples_per_pass" value="16"/></integrator>', "ptracer",
     {"samples_per_pass": 16}),
    ('<integrator type="bdpt"/>', "bdpt", {}),      # not Mitsuba 3's: recorded, caustica picks its own method
])
def test_other_integrators_are_recorded(xml, kind, props):
    d = integrator_of(xml)
    assert (d.integrator_settings.type, d.integrator_settings.props, d.integrator_settings.max_depth) == (kind, props, -1)


@pytest.mark.parametrize("inner, words", [
    ('<integer name="max_depth" value="-2"/>', "'max_depth' must be at least -1, got -2"),
    ('<integer name="rr_depth" value="0"/>', "'rr_depth' must be positive, got 0"),
    ('<float name="max_depth" value="3"/>', "'max_depth' must be given as <integer>"),
    ('<string name="hide_emitters" value="yes"/>', "'hide_emitters' must be given as <boolean>"),
])
def test_integrator_setting_errors(tmp_path, inner, words):
    path = write(tmp_path / "int.xml", scene(f'<integrator type="moment"><integrator type="path">\n{inner}'
                                             f'</integrator></integrator>', sensor('<float name="fov" value="45"/>')))
    msg = one_line_error(path)
    assert msg.startswith(f"{path}:5: ") and words in msg, msg


# ----------------------------------------------------------------------------- one report of every problem

MANY = """<sensor type="perspective"><float name="fov" value="45"/>
<film type="hdrfilm"><string name="pixel_format" value="rgb"/><boolean name="banner" value="no"/>
<rfilter type="mitchell"/></film></sensor>
<texture type="noise" id="checks"/>
<bsdf type="blendbsdf" id="blend"/>
<shape type="torus"/>
<shape type="sphere"><float name="radius" value="1"/><float name="smoothness" value="1"/>
<bsdf type="diffuse"><spectrum name="reflectance" value="600:1, 500:1"/></bsdf></shape>
<shape type="cube"><ref id="blend"/></shape>
<emitter type="envmap"><string name="filename" value="sky.exr"/></emitter>
<include filename="more.xml"/>
<shape type="rectangle"><emitter type="area"><rgb name="radiance" value="1"/></emitter></shape>"""


def test_every_problem_is_listed_in_one_message(tmp_path, capsys):
    from caustica.cli import main
    write(tmp_path / "more.xml", '<scene version="3.0.0">\n<emitter type="sunsky"/>\n</scene>')
    path = write(tmp_path / "many.xml", f'<scene version="3.0.0">\n{MANY}\n</scene>\n')
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    head, *items = str(e.value).split("\n")
    assert head == f"{path}: 9 problems, each with its file and line (and what is supported there):"
    expected = [
        (3, '<boolean name="banner">: value=\'no\' is not a boolean'),
        (4, "<rfilter type=\"mitchell\">: unknown rfilter type 'mitchell'; supported: box, tent, gaussian"),
        (5, "<texture type=\"noise\" id=\"checks\">: unknown texture type 'noise'; supported: "
            "checkerboard, bitmap, mesh_attribute, rawconstant, volume"),
        (6, "<bsdf type=\"blendbsdf\" id=\"blend\">: a blendbsdf nests exactly 2 BSDFs, found 0"),
        (7, "<shape type=\"torus\">: unknown shape type 'torus'; supported: rectangle, cube, sphere"),
        (8, "<float name=\"smoothness\">: unknown property 'smoothness' of <shape type=\"sphere\">; supported: "),
        (9, "<spectrum name=\"reflectance\">: wavelengths must increase, but 500 follows 600"),
        (11, "<string name=\"filename\">: environment map 'sky.exr' not found; searched: "),
    ]
    assert len(items) == 9
    for item, (line, words) in zip(items, expected):
        assert item.startswith(f"  {path}:{line}: {words}"), item
    assert items[8].startswith(f"  {tmp_path / 'more.xml'}:2: <emitter type=\"sunsky\">: unknown emitter type 'sunsky'")
    # the command line prints it as one error, exit 2, nothing written
    assert main(["render", str(path), "--method", "pt", "-q", "-o", str(tmp_path / "x.exr")]) == 2
    err = capsys.readouterr().err
    assert err == f"caustica: error: {e.value}\n" and not (tmp_path / "x.exr").exists()


def test_a_single_problem_keeps_its_one_line_message(tmp_path):
    path = write(tmp_path / "one.xml", scene('<shape type="torus"/>\n<shape type="cube"/>'))
    assert one_line_error(path) == (f"{path}:5: <shape type=\"torus\">: unknown shape type 'torus'; supported: "
                                    f"rectangle, cube, sphere, disk, cylinder, obj, ply, serialized, linearcurve, "
                                    f"bsplinecurve, sdfgrid, shapegroup, instance")
    # a shape that uses a broken BSDF is not a second problem: the BSDF is
    path.write_text(scene('<bsdf type="diffuse" id="d"><float name="gloss" value="1"/></bsdf>\n'
                          '<shape type="cube"><ref id="d"/></shape><shape type="sphere"><ref id="d"/></shape>'))
    assert one_line_error(path).startswith(f"{path}:5: <float name=\"gloss\">: unknown property 'gloss'")


def test_reading_stops_where_going_on_is_not_safe(tmp_path):
    # malformed XML: nothing after it can be read
    path = write(tmp_path / "bad.xml", scene('<shape type="torus"/>\n<shape type="cube">'))
    assert one_line_error(path).startswith(f"{path}:7: malformed XML")
    # an undefined $name: reported (every one) before anything is interpreted
    path.write_text(scene('<shape type="torus"/>\n<shape type="sphere"><float name="radius" value="$r"/></shape>\n'
                          '<shape type="sphere"><float name="radius" value="$q"/></shape>'))
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    lines = str(e.value).split("\n")
    assert lines[0] == f"{path}: 2 problems, each with its file and line (and what is supported there):"
    assert "uses $r, which is not defined" in lines[1] and "uses $q, which is not defined" in lines[2]


# ----------------------------------------------------------------------------- elements given by reference

def test_an_area_emitter_declared_at_the_top_level_and_given_by_reference(mi, tmp_path):
    by_ref = ('<emitter type="area" id="light"><rgb name="radiance" value="2, 3, 4"/></emitter>\n'
              '<shape type="rectangle" id="lamp"><ref id="light"/><bsdf type="diffuse"/></shape>')
    nested = '<shape type="rectangle" id="lamp"><emitter type="area"><rgb name="radiance" value="2, 3, 4"/></emitter>' \
             '<bsdf type="diffuse"/></shape>'
    a = parse_scene_string(scene(by_ref, sensor('<float name="fov" value="45"/>')))
    b = parse_scene_string(scene(nested, sensor('<float name="fov" value="45"/>')))
    assert a.shapes[0].emitter_radiance == b.shapes[0].emitter_radiance == (2.0, 3.0, 4.0)
    assert a.materials[a.shapes[0].material] == b.materials[b.shapes[0].material]
    theirs = mi.load_string(scene(by_ref, sensor('<float name="fov" value="45"/>'))).shapes()[0]
    assert theirs.is_emitter()
    # declared and never used: refused, as Mitsuba refuses an area emitter without a shape
    path = write(tmp_path / "lonely.xml", scene('<emitter type="area" id="light"/>', sensor('<float name="fov" value="45"/>')))
    assert one_line_error(path).startswith(f"{path}:4: <emitter type=\"area\" id=\"light\">: an area emitter must be "
                                           f"nested inside a <shape> or given to one by <ref id=\"light\"/>")


def test_a_sampler_and_film_declared_at_the_top_level(mi):
    xml = scene('<sampler type="stratified" id="my_sampler"><integer name="sample_count" value="16"/></sampler>\n'
                '<film type="hdrfilm" id="my_film"><integer name="width" value="40"/><integer name="height" value="30"/>'
                '</film>',
                sensor('<float name="fov" value="45"/><ref id="my_sampler"/><ref id="my_film"/>'))
    sensor_ = mi.load_string(xml).sensors()[0]
    d = parse_scene_string(xml)
    assert d.spp == sensor_.sampler().sample_count() == 16
    assert (d.camera.width, d.camera.height) == tuple(sensor_.film().size()) == (40, 30)
    with pytest.raises(SceneError, match="a <sampler> at the top level needs an id="):
        parse_scene_string(scene('<sampler type="independent"/>'))


def test_a_rotation_about_an_axis_that_is_not_unit_is_mitsubas_matrix(mi):
    xf = '<transform name="to_world"><rotate x="0" y="1" z="1" angle="30"/><translate x="1"/></transform>'
    xml = scene(f'<shape type="cube" id="c">{xf}</shape>', sensor('<float name="fov" value="45"/>'))
    b = mi.load_string(xml).shapes()[0].bbox()
    pos = parse_scene_string(xml).shapes[0].mesh.positions
    np.testing.assert_allclose(pos.min(0), np.array(b.min), atol=1e-5)
    np.testing.assert_allclose(pos.max(0), np.array(b.max), atol=1e-5)


def test_a_medium_s_sampling_settings_are_accepted(mi):
    xml = scene('<medium type="homogeneous" id="m"><boolean name="sample_emitters" value="false"/>'
                '<boolean name="has_spectral_extinction" value="false"/><float name="scale" value="2"/></medium>'
                '<shape type="sphere"><ref name="interior" id="m"/><bsdf type="null"/></shape>',
                sensor('<float name="fov" value="45"/>'))
    mi.load_string(xml)
    assert parse_scene_string(xml).media[0].sigma_t == (2.0, 2.0, 2.0)


# ----------------------------------------------------------------------------- .serialized meshes

def serialized_file(path: Path, meshes, version: int = 4) -> Path:
    """Write meshes [(positions, triangles, normals or None, double, extras)] as Mitsuba's .serialized format."""
    import struct
    import zlib
    out, offsets = b"", []
    for positions, triangles, normals, double, extras in meshes:
        flags = (0x0001 if normals is not None else 0) | (0x2000 if double else 0x1000) | \
            (0x0002 if "uv" in extras else 0) | (0x0008 if "color" in extras else 0)
        f = "<f8" if double else "<f4"
        body = struct.pack("<I", flags) + (b"mesh\0" if version == 4 else b"")
        body += struct.pack("<QQ", len(positions), len(triangles)) + np.asarray(positions, f).tobytes()
        if normals is not None:
            body += np.asarray(normals, f).tobytes()
        if "uv" in extras:
            body += np.zeros((len(positions), 2), f).tobytes()
        if "color" in extras:
            body += np.ones((len(positions), 3), f).tobytes()
        body += np.asarray(triangles, "<u4").tobytes()
        offsets.append(len(out))
        out += struct.pack("<HH", 0x041C, version) + zlib.compress(body)
    out += b"".join(struct.pack("<Q" if version == 4 else "<I", o) for o in offsets) + struct.pack("<I", len(meshes))
    path.write_bytes(out)
    return path


TETRA = (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float), np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))


@pytest.mark.parametrize("version", [3, 4])
def test_serialized_meshes_load_as_in_mitsuba(mi, tmp_path, version):
    rng = np.random.default_rng(1)
    normals = rng.normal(size=(4, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    path = serialized_file(tmp_path / "m.serialized", [
        (TETRA[0], TETRA[1], None, False, ()),
        (TETRA[0] * 2 + 1, TETRA[1], normals, True, ("uv", "color")),
        (TETRA[0] - 3, TETRA[1][:2], normals, False, ("uv",)),
    ], version)
    for index in range(3):
        xml = scene(f'<shape type="serialized" id="s"><string name="filename" value="{path}"/>'
                    f'<integer name="shape_index" value="{index}"/><transform name="to_world"><rotate x="1" angle="30"/>'
                    f'<translate y="2"/></transform></shape>', sensor('<float name="fov" value="45"/>'))
        theirs = mi.load_string(xml).shapes()[0]
        mesh = parse_scene_string(xml).shapes[0].mesh
        assert theirs.face_count() == len(mesh.triangles) == (4 if index < 2 else 2)
        b = theirs.bbox()
        np.testing.assert_allclose(mesh.positions.min(0), np.array(b.min), atol=1e-6)
        np.testing.assert_allclose(mesh.positions.max(0), np.array(b.max), atol=1e-6)
        # without normals in the file (index 0) both compute angle-weighted vertex normals (smooth shading)
        params = mi.traverse(theirs)
        np.testing.assert_allclose(mesh.normals, np.array(params["vertex_normals"]).reshape(-1, 3), atol=1e-6)


@pytest.mark.parametrize("content, words", [
    (b"\x1c\x04\x05\x00" + b"\0" * 40, ".serialized version 5 is not supported; supported: 3, 4"),
    (b"PLY whatever", "is not a Mitsuba .serialized file"),
    (None, "holds 1 meshes (shape_index 0..0); shape_index 1 is out of range"),
    ("cut", "is cut short or corrupt"),
])
def test_serialized_errors(tmp_path, content, words):
    path = tmp_path / "m.serialized"
    if content is None or content == "cut":
        serialized_file(path, [(TETRA[0], TETRA[1], None, False, ())])
        if content == "cut":
            import struct
            import zlib
            body = zlib.compress(struct.pack("<I", 0x1000) + b"cut\0" + struct.pack("<QQ", 4, 4) + b"\0" * 20)
            path.write_bytes(struct.pack("<HH", 0x041C, 4) + body)
    else:
        path.write_bytes(content)
    index = 1 if content is None else 0
    xml = write(tmp_path / "s.xml", scene(f'<shape type="serialized">\n<string name="filename" value="m.serialized"/>'
                                          f'<integer name="shape_index" value="{index}"/></shape>'))
    msg = one_line_error(xml)
    assert msg.startswith(f"{xml}:6: <string name=\"filename\">: mesh file ") and words in msg, msg


# ----------------------------------------------------------------------------- files older than version 2.0

OLD = '''<scene version="{version}"><sensor type="perspective"><float name="fov" value="45"/><string name="fovAxis" value="y"/>
<transform name="toWorld"><lookat origin="0,0,5" target="0,0,0" up="0,1,0"/></transform>
<sampler type="independent"><integer name="sampleCount" value="7"/></sampler></sensor>
<shape type="sphere" id="s"><transform name="toWorld"><scale value="2"/></transform>
<bsdf type="diffuse"><rgb name="diffuseReflectance" value="0.3"/></bsdf></shape>
<shape type="sphere" id="g"><bsdf type="dielectric"><float name="intIOR" value="1.7"/></bsdf></shape>
</scene>'''


def test_the_names_of_mitsuba_0_6_files_are_upgraded_as_mitsuba_3_does(mi, tmp_path):
    from caustica.scene.xml_loader import camel_to_snake
    assert [camel_to_snake(n) for n in ("toWorld", "intIOR", "sampleCount", "fov", "specularReflectance")] == \
        ["to_world", "int_ior", "sample_count", "fov", "specular_reflectance"]
    xml = OLD.format(version="0.6.0")
    theirs = mi.load_string(xml)
    d = parse_scene_string(xml)
    assert d.spp == theirs.sensors()[0].sampler().sample_count() == 7 and d.camera.fov_axis == "y"
    assert d.materials[d.shapes[0].material].rgb == (0.3, 0.3, 0.3) and d.materials[d.shapes[1].material].int_ior == 1.7
    np.testing.assert_allclose(d.shapes[0].to_world, np.array(mi.traverse(theirs.shapes()[0])["to_world"].matrix))
    # an old file included by a new one is upgraded, the new one is not
    shapes_only = OLD.format(version="0.5.0").split("</sensor>\n", 1)[1]   # the two shapes and </scene>
    write(tmp_path / "old.xml", '<scene version="0.5.0">' + shapes_only)
    main = write(tmp_path / "main.xml", scene('<include filename="old.xml"/>', sensor('<float name="fov" value="45"/>')))
    assert len(load_scene_file(main).shapes) == 2
    main.write_text(OLD.format(version="3.0.0"))
    assert "unknown property 'fovAxis'" in str(pytest.raises(SceneError, load_scene_file, main).value)


# ----------------------------------------------------------------------------- instances

GROUP = '''<shape type="shapegroup" id="group">
  <shape type="rectangle"><transform name="to_world"><rotate y="1" angle="-30"/><translate x="0.5"/></transform></shape>
  <shape type="sphere"><point name="center" value="-3, 0, 0"/><float name="radius" value="0.5"/></shape>
  <shape type="disk"><transform name="to_world"><rotate x="1" angle="90"/><translate y="5"/></transform></shape>
</shape>
<shape type="instance"><ref id="group"/></shape>
<shape type="instance"><ref id="group"/><transform name="to_world"><rotate x="1" angle="40"/><scale value="1.5"/>
  <translate x="20"/></transform></shape>
<shape type="instance"><ref id="group"/><transform name="to_world"><scale x="-1"/><translate x="-20"/></transform></shape>'''


def bounds(s):
    """A shape's bounding box as Mitsuba computes it (meshes: vertices; sphere: centre +- radius; disk: its rim)."""
    if s.mesh is not None:
        return s.mesh.positions.min(0), s.mesh.positions.max(0)
    lin, c = s.to_world[:3, :3], s.to_world[:3, 3]
    e = np.linalg.norm(lin, axis=1) if s.kind == "sphere" else np.sqrt(lin[:, 0] ** 2 + lin[:, 1] ** 2)
    return c - e, c + e


def test_instances_place_copies_of_their_shapegroup_as_mitsuba_does(mi):
    xml = scene(GROUP, sensor('<float name="fov" value="45"/>'))
    theirs = mi.load_string(xml)
    d = parse_scene_string(xml)
    assert len(d.shapes) == 9 and [s.kind for s in d.shapes[:3]] == ["mesh", "sphere", "disk"]
    # each instance's bounding box is Mitsuba's: the group's box (the identity instance) through its to_world
    lo = np.min([bounds(s)[0] for s in d.shapes[:3]], axis=0)
    hi = np.max([bounds(s)[1] for s in d.shapes[:3]], axis=0)
    corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    for inst, m in zip(theirs.shapes(), [np.eye(4)] + [d.shapes[3 * i].to_world @ np.linalg.inv(d.shapes[0].to_world)
                                                      for i in (1, 2)]):
        b = inst.bbox()
        placed = (corners @ m.T)[:, :3]
        np.testing.assert_allclose(placed.min(0), np.array(b.min), atol=1e-5)
        np.testing.assert_allclose(placed.max(0), np.array(b.max), atol=1e-5)
    # the instanced rectangles face the way Mitsuba's do (a ray at each centre), the mirrored copy included
    for rect in d.shapes[0::3]:
        p = rect.mesh.positions
        centre = p.mean(axis=0)
        a, b, c = p[rect.mesh.triangles[0]]
        n = np.cross(b - a, c - a)   # the front side, as caustica's kernels see it: the winding
        n /= np.linalg.norm(n)
        origin = centre + 3 * n
        si = theirs.ray_intersect(mi.Ray3f(mi.Point3f(*origin), mi.Vector3f(*(-n))))
        assert si.is_valid()
        np.testing.assert_allclose(np.array(si.p), centre, atol=1e-4)
        assert float(np.dot(np.array(si.n), n)) > 0.999, rect.source
    with pytest.raises(SceneError, match="an instance needs a <ref> to a <shape type=\"shapegroup\">"):
        parse_scene_string(scene('<bsdf type="diffuse" id="b"/><shape type="instance"><ref id="b"/></shape>'))
    with pytest.raises(SceneError, match="cannot be an emitter"):
        parse_scene_string(scene('<shape type="shapegroup" id="g"><shape type="sphere"><emitter type="area"/></shape>'
                                 '</shape><shape type="instance"><ref id="g"/></shape>'))


def test_an_alias_names_an_element_a_second_time(mi, tmp_path):
    xml = scene('<bsdf type="diffuse" id="white"><rgb name="reflectance" value="0.7"/></bsdf>\n'
                '<alias id="white" as="paint"/>\n<shape type="cube" id="c"><ref id="paint"/></shape>',
                sensor('<float name="fov" value="45"/>'))
    theirs = np.ravel(np.array(mi.traverse(mi.load_string(xml).shapes()[0])["bsdf.reflectance.value"]))
    np.testing.assert_allclose(theirs, 0.7, rtol=1e-6)
    d = parse_scene_string(xml)
    assert d.materials[d.shapes[0].material].rgb == (0.7, 0.7, 0.7)
    path = write(tmp_path / "alias.xml", scene('<bsdf type="diffuse" id="a"/><bsdf type="diffuse" id="b"/>\n'
                                               '<alias id="a" as="b"/>'))
    assert "<alias id=\"a\">: id 'b' is already used on" in one_line_error(path)
    path.write_text(scene('<alias id="nothing" as="b"/>'))
    assert "<alias id=\"nothing\">: no element has id 'nothing'" in one_line_error(path)


def test_an_area_emitter_named_by_a_broken_shape_is_not_a_second_problem(tmp_path):
    path = write(tmp_path / "s.xml", scene('<emitter type="area" id="light"/>\n<shape type="torus"><ref id="light"/></shape>'))
    assert one_line_error(path).startswith(f"{path}:6: <shape type=\"torus\">: unknown shape type 'torus'")


def test_a_path_folder_comes_before_the_scene_s_own_as_in_mitsuba(mi, tmp_path):
    """Mitsuba's file resolver prepends each <path>: a file in a <path> folder wins over one beside the scene."""
    def ply(path, faces):
        rows = ["0 0 0", "1 0 0", "1 1 0", "0 1 0"]
        head = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
                "property float z", f"element face {len(faces)}", "property list uchar int vertex_indices",
                "end_header"]
        write(path, "\n".join(head + rows + [f"3 {a} {b} {c}" for a, b, c in faces]) + "\n")
    ply(tmp_path / "m.ply", [(0, 1, 2)])
    ply(tmp_path / "lib" / "m.ply", [(0, 1, 2), (0, 2, 3)])
    path = write(tmp_path / "s.xml", scene('<path value="lib"/><shape type="ply" id="m">'
                                           '<string name="filename" value="m.ply"/></shape>',
                                           sensor('<float name="fov" value="45"/>')))
    assert mi.load_file(str(path)).shapes()[0].face_count() == 2
    assert len(load_scene_file(path).shapes[0].mesh.triangles) == 2
