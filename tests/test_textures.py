"""Textures (bsdfs/textures.py, scene/textures.py): Mitsuba 3's checkerboard and bitmap on a BSDF's colour.

1. Lookups against values computed by hand: the checkerboard's colours and ``to_uv``; a bitmap's texels at their
   centres (nearest and bilinear), between them, beyond the image with each wrap mode; sRGB decoding, ``raw``,
   an EXR's linear values.
2. The same lookups against Mitsuba 3's own textures (``scalar_rgb``) at random (u, v), every filter and wrap mode.
3. Surface coordinates: Mitsuba's (u, v) at the same hits, for the rectangle, cube, sphere, disk, cylinder, an OBJ
   (v flipped, a vertex with two texture coordinates), a PLY and a .serialized mesh.
4. Renders against Mitsuba 3 of one small scene (a checkerboard floor and sphere, a bitmap on an OBJ wall and on a
   rectangle, a checkerboard mirror, under an area light), ``pt`` and ``sppm``: image mean within 2 % and every
   block within 5 sigmas of both renders' noise (tests/imagestats.py, as tests/test_glossy.py compares).
5. Bad input: a missing texture file, a file that is not an image, an unknown wrap mode, a texture where it is not
   supported -> one line naming file and line, exit 2.
"""
from __future__ import annotations

import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

import caustica
from caustica.bsdfs import build_material_table, textures
from caustica.geometry.scene_geometry import intersect, surface_uv
from caustica.jit import borrowed, kernel
from caustica.scene.description import BITMAP, CHECKERBOARD, FILTER_TYPES, WRAP_MODES, SceneDescription, Texture
from caustica.scene.textures import read_texels, srgb_to_linear
from imagestats import assert_images_agree

# --------------------------------------------------------------------------- 1. lookups by hand


@kernel
def lookup_many(mats, t, uvs, out):
    """out[i] = texture t's RGB at uvs[i]."""
    mats = borrowed(mats)
    for i in range(uvs.shape[0]):
        c = textures.colour(mats, 0, (uvs[i, 0], uvs[i, 1], -1.0, 0.0, 0.0))
        out[i, 0], out[i, 1], out[i, 2] = c


def lookup(tex: Texture, uvs) -> np.ndarray:
    from caustica.scene.description import DIFFUSE, Material, Camera
    desc = SceneDescription(camera=Camera(np.eye(4), 45.0), materials=[Material(DIFFUSE, texture=tex)])
    mats = build_material_table(desc)
    uvs = np.asarray(uvs, dtype=np.float64).reshape(-1, 2)
    out = np.zeros((len(uvs), 3))
    lookup_many(mats, 0, uvs, out)
    return out


def affine(scale=(1.0, 1.0), offset=(0.0, 0.0)):
    return np.array([[scale[0], 0.0, offset[0]], [0.0, scale[1], offset[1]]])


def test_checkerboard_colours_by_hand():
    c0, c1 = (0.9, 0.1, 0.2), (0.05, 0.6, 0.3)
    tex = Texture(CHECKERBOARD, color0=c0, color1=c1)
    got = lookup(tex, [(0.25, 0.25), (0.75, 0.25), (0.25, 0.75), (0.75, 0.75), (-0.25, -0.25), (1.25, 0.25),
                       (0.5, 0.5)])
    # color0 where u's and v's fractional parts are both above 1/2 or both not (Mitsuba's checkerboard.cpp)
    np.testing.assert_array_equal(got, [c0, c1, c1, c0, c0, c0, c0])
    scaled = Texture(CHECKERBOARD, color0=c0, color1=c1, to_uv=affine((4.0, 4.0), (0.5, 0.0)))
    # (0.1, 0.1) -> (0.9, 0.4): c1; (0.2, 0.2) -> (1.3, 0.8): c1; (0.05, 0.05) -> (0.7, 0.2): c1; (0.2, 0.05) -> c0
    np.testing.assert_array_equal(lookup(scaled, [(0.1, 0.1), (0.2, 0.2), (0.05, 0.05), (0.2, 0.05)]),
                                  [c1, c1, c1, c0])


#: A 3 x 2 image (width 3, height 2), row 0 on top, in linear RGB.
IMG = np.array([[[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]],
                [[0.0, 0.25, 0.0], [0.0, 0.5, 0.0], [0.0, 1.0, 1.0]]], np.float32)


def bitmap(filter_type="bilinear", wrap="repeat", texels=IMG) -> Texture:
    return Texture(BITMAP, texels=texels, filter=FILTER_TYPES[filter_type], wrap=WRAP_MODES[wrap])


def centre(i, j, w=3, h=2):
    return ((i + 0.5) / w, (j + 0.5) / h)


@pytest.mark.parametrize("filter_type", ["nearest", "bilinear"])
@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
def test_bitmap_at_texel_centres_is_the_texel(filter_type, wrap):
    uvs = [centre(i, j) for j in range(2) for i in range(3)]
    np.testing.assert_allclose(lookup(bitmap(filter_type, wrap), uvs), IMG.reshape(-1, 3), atol=1e-12)


def test_bitmap_bilinear_between_texels_by_hand():
    got = lookup(bitmap(), [(1 / 3, 0.25), (0.5, 0.5), (1 / 3 + 1 / 12, 0.25)])
    np.testing.assert_allclose(got[0], (IMG[0, 0] + IMG[0, 1]) / 2, atol=1e-12)       # midway along a row
    np.testing.assert_allclose(got[1], (IMG[0, 1] + IMG[1, 1]) / 2, atol=1e-12)       # midway down a column
    np.testing.assert_allclose(got[2], 0.25 * IMG[0, 0] + 0.75 * IMG[0, 1], atol=1e-12)


def test_bitmap_wrap_modes_by_hand():
    # nearest, beyond the image: u = -1/6 is texel column -1, u = 7/6 column 3, v = 1.25 row 2
    uvs = [(-1 / 6, 0.25), (7 / 6, 0.75), (0.5, 1.25)]
    np.testing.assert_allclose(lookup(bitmap("nearest", "repeat"), uvs), [IMG[0, 2], IMG[1, 0], IMG[0, 1]])
    np.testing.assert_allclose(lookup(bitmap("nearest", "mirror"), uvs), [IMG[0, 0], IMG[1, 2], IMG[1, 1]])
    np.testing.assert_allclose(lookup(bitmap("nearest", "clamp"), uvs), [IMG[0, 0], IMG[1, 2], IMG[1, 1]])
    # bilinear at the corner (0, 0): the four texels around (-1/2, -1/2)
    corner = [(0.0, 0.0)]
    np.testing.assert_allclose(lookup(bitmap("bilinear", "repeat"), corner)[0],
                               (IMG[0, 0] + IMG[0, 2] + IMG[1, 0] + IMG[1, 2]) / 4, atol=1e-12)
    np.testing.assert_allclose(lookup(bitmap("bilinear", "mirror"), corner)[0], IMG[0, 0], atol=1e-12)
    np.testing.assert_allclose(lookup(bitmap("bilinear", "clamp"), corner)[0], IMG[0, 0], atol=1e-12)
    # mirror: period 2 in u; clamp: the edge texel anywhere beyond
    np.testing.assert_allclose(lookup(bitmap("nearest", "mirror"), [(2 - 1 / 6, 0.25)]), [IMG[0, 0]])
    np.testing.assert_allclose(lookup(bitmap("nearest", "clamp"), [(-5.0, 9.0)]), [IMG[1, 0]])


def png(path, pixels):
    from PIL import Image
    Image.fromarray(np.asarray(pixels, np.uint8)).save(path)
    return path


def test_srgb_decoding_raw_and_exr(tmp_path):
    px = np.array([[[0, 10, 128], [255, 64, 200]], [[1, 2, 3], [90, 180, 250]]], np.uint8)
    path = png(tmp_path / "a.png", px)
    by_hand = np.vectorize(lambda c: c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4)(px / 255.0)
    np.testing.assert_allclose(read_texels(path), by_hand, rtol=1e-6)
    np.testing.assert_allclose(srgb_to_linear(px / 255.0), by_hand, rtol=1e-12)
    np.testing.assert_allclose(read_texels(path, raw=True), px / 255.0, rtol=1e-6)
    grey = png(tmp_path / "g.png", px[..., 0])
    np.testing.assert_allclose(read_texels(grey), np.repeat(by_hand[..., :1], 3, axis=2), rtol=1e-6)
    from caustica.imageio import write_exr
    lin = np.array([[[0.1, 2.5, 0.0], [0.7, 0.2, 9.0]], [[0.3, 0.3, 0.3], [1e-3, 0.5, 0.25]]], np.float32)
    write_exr(tmp_path / "l.exr", lin)
    np.testing.assert_array_equal(read_texels(tmp_path / "l.exr"), lin)


# --------------------------------------------------------------------------- 2. lookups against Mitsuba


@pytest.mark.parametrize("filter_type", ["nearest", "bilinear"])
@pytest.mark.parametrize("wrap", ["repeat", "mirror", "clamp"])
def test_bitmap_lookups_match_mitsuba(mi, tmp_path, filter_type, wrap):
    rng = np.random.default_rng(3)
    path = png(tmp_path / "r.png", rng.integers(0, 256, size=(5, 7, 3)))
    theirs = mi.load_dict({"type": "bitmap", "filename": str(path), "filter_type": filter_type, "wrap_mode": wrap,
                           "to_uv": mi.ScalarTransform4f().translate([0.1, -0.3, 0.0]).scale([1.5, 2.0, 1.0])})
    tex = bitmap(filter_type, wrap, read_texels(path))
    tex.to_uv = affine((1.5, 2.0), (0.1, -0.3))
    uvs = rng.uniform(-1.5, 2.5, size=(400, 2))
    ours = lookup(tex, uvs)
    si = mi.SurfaceInteraction3f()
    for uv, mine in zip(uvs, ours):
        si.uv = mi.Point2f(*uv)
        np.testing.assert_allclose(mine, np.array(theirs.eval(si)), atol=2e-6, err_msg=str(uv))


def test_checkerboard_matches_mitsuba(mi):
    theirs = mi.load_string('<texture version="3.0.0" type="checkerboard"><rgb name="color0" value="0.9, 0.1, 0.2"/>'
                            '<rgb name="color1" value="0.05, 0.6, 0.3"/><transform name="to_uv"><scale x="3" y="5"/>'
                            '<rotate z="1" angle="30"/><translate x="0.2"/></transform></texture>')
    from caustica.scene import transforms as tf
    m = tf.translate([0.2, 0, 0]) @ tf.rotate([0, 0, 1], 30.0) @ tf.scale([3.0, 5.0, 1.0])
    tex = Texture(CHECKERBOARD, color0=(0.9, 0.1, 0.2), color1=(0.05, 0.6, 0.3), to_uv=m[np.ix_([0, 1], [0, 1, 3])])
    rng = np.random.default_rng(4)
    uvs = rng.uniform(-2, 2, size=(500, 2))
    ours = lookup(tex, uvs)
    si = mi.SurfaceInteraction3f()
    agree = 0
    for uv, mine in zip(uvs, ours):
        si.uv = mi.Point2f(*uv)
        agree += np.allclose(mine, np.array(theirs.eval(si)), atol=1e-6)
    assert agree >= 498    # a point within float32 rounding of a square's edge may fall on either side


# --------------------------------------------------------------------------- 3. surface coordinates


SENSOR = ('<sensor type="perspective"><float name="fov" value="45"/><transform name="to_world">'
          '<lookat origin="0, -4, 3" target="0, 0, 0.5" up="0, 0, 1"/></transform>'
          '<film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/></film></sensor>')


def obj_file(path):
    """A two-triangle quad whose vertex 0 has texture coordinates 1 in one face and 5 in the other."""
    path.write_text("v -1 0 0\nv 1 0 0\nv 1 0 2\nv -1 0 2\nvt 0.1 0.2\nvt 0.9 0.1\nvt 0.8 0.9\nvt 0.2 0.7\n"
                    "vt 0.3 0.3\nvn 0 -1 0\nf 1/1/1 2/2/1 3/3/1\nf 1/5/1 3/3/1 4/4/1\n")
    return path


def ply_file(path):
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "property float u\nproperty float v\nelement face 2\nproperty list uchar int vertex_indices\n"
                    "end_header\n-1 0 0 0.1 0.2\n1 0 0 0.9 0.1\n1 0 2 0.8 0.9\n-1 0 2 0.2 0.7\n3 0 1 2\n3 0 2 3\n")
    return path


def serialized_file(path):
    """One mesh (the quad of :func:`ply_file`) with texture coordinates, Mitsuba's .serialized version 4."""
    pos = np.array([[-1, 0, 0], [1, 0, 0], [1, 0, 2], [-1, 0, 2]], "<f4")
    uv = np.array([[0.1, 0.2], [0.9, 0.1], [0.8, 0.9], [0.2, 0.7]], "<f4")
    body = struct.pack("<I", 0x0002 | 0x1000) + b"quad\0" + struct.pack("<QQ", 4, 2) + pos.tobytes() + uv.tobytes()
    body += np.array([[0, 1, 2], [0, 2, 3]], "<u4").tobytes()
    path.write_bytes(struct.pack("<HH", 0x041C, 4) + zlib.compress(body) + struct.pack("<QI", 0, 1))
    return path


def shape_xml(kind, tmp_path) -> str:
    place = ('<transform name="to_world"><scale x="1.3" y="0.8" z="1.1"/><rotate x="1" y="0.4" angle="35"/>'
             '<translate z="0.6"/></transform>')
    return {
        "rectangle": f'<shape type="rectangle">{place}',
        "cube": f'<shape type="cube">{place}',
        "sphere": '<shape type="sphere"><point name="center" x="0.1" y="0.2" z="0.5"/><float name="radius" '
                  'value="0.9"/><transform name="to_world"><rotate y="1" angle="40"/></transform>',
        # (under a to_world that shears, Mitsuba 3.9's disk gives other (u, v) than its own to_world implies)
        "disk": '<shape type="disk"><transform name="to_world"><scale x="1.3" y="0.8"/><rotate x="0.6" y="0.8" '
                'angle="35"/><translate z="0.6"/></transform>',
        "cylinder": '<shape type="cylinder"><point name="p0" x="0" y="0" z="-0.2"/><point name="p1" x="0.3" y="0.2" '
                    'z="1.2"/><float name="radius" value="0.7"/>',
        "obj": f'<shape type="obj"><string name="filename" value="{obj_file(tmp_path / "q.obj")}"/>',
        "obj-unflipped": f'<shape type="obj"><string name="filename" value="{obj_file(tmp_path / "q.obj")}"/>'
                         '<boolean name="flip_tex_coords" value="false"/>',
        "ply": f'<shape type="ply"><string name="filename" value="{ply_file(tmp_path / "q.ply")}"/>',
        "serialized": f'<shape type="serialized"><string name="filename" '
                      f'value="{serialized_file(tmp_path / "q.serialized")}"/>',
        "ply-without-uv": '<shape type="ply"><string name="filename" value="'
                          f'{write_plain_ply(tmp_path / "p.ply")}"/>',
    }[kind] + '<bsdf type="diffuse"><texture name="reflectance" type="checkerboard"/></bsdf></shape>'


def write_plain_ply(path):
    path.write_text("ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n"
                    "element face 2\nproperty list uchar int vertex_indices\nend_header\n"
                    "-1 0 0\n1 0 0\n1 0 2\n-1 0 2\n3 0 1 2\n3 0 2 3\n")
    return path


@kernel
def uv_many(geom, origins, dirs, out):
    """out[i] = (hit?, u, v) of ray i."""
    geom = borrowed(geom)
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim >= 0:
            u, v = surface_uv(geom, prim, o, d, t, b1, b2)[:2]
            out[i, 0], out[i, 1], out[i, 2] = 1.0, u, v


@pytest.mark.parametrize("kind", ["rectangle", "cube", "sphere", "disk", "cylinder", "obj", "obj-unflipped", "ply",
                                  "serialized", "ply-without-uv"])
def test_surface_coordinates_match_mitsuba(mi, tmp_path, kind):
    xml = (f'<scene version="3.0.0">{SENSOR}{shape_xml(kind, tmp_path)}'
           '<emitter type="point"><point name="position" x="0" y="0" z="50"/></emitter></scene>')
    (tmp_path / "s.xml").write_text(xml)
    geom = caustica.load_scene(tmp_path / "s.xml").tables[0]
    theirs = mi.load_string(xml)
    rng = np.random.default_rng(7)
    n = 400
    targets = rng.uniform(-1.2, 1.2, size=(n, 3)) + [0.0, 0.0, 0.6]
    origins = rng.normal(size=(n, 3))
    origins = 6.0 * origins / np.linalg.norm(origins, axis=1, keepdims=True)
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ours = np.zeros((n, 3))
    uv_many(geom, origins, dirs, ours)
    hits = 0
    for i in range(n):
        si = theirs.ray_intersect(mi.Ray3f(mi.Point3f(*origins[i]), mi.Vector3f(*dirs[i])))
        if not si.is_valid():
            assert ours[i, 0] == 0.0
            continue
        assert ours[i, 0] == 1.0
        hits += 1
        diff = np.abs(ours[i, 1:] - np.array(si.uv))
        if kind in ("sphere", "cylinder"):
            diff[0] = min(diff[0], 1.0 - diff[0])     # the azimuth's seam
        if kind == "disk":
            diff[1] = min(diff[1], 1.0 - diff[1])
        assert np.all(diff < 2e-4), (kind, i, ours[i, 1:], np.array(si.uv))
    assert hits > 40


# --------------------------------------------------------------------------- 4. renders against Mitsuba


def textured_scene(tmp_path, filter_type="bilinear") -> Path:
    """A checkerboard floor and sphere, a bitmap (a generated 6 x 4 PNG) on an OBJ wall and on a rectangle facing
    it, a mirror whose specular_reflectance is a checkerboard, under an area light."""
    rng = np.random.default_rng(11)
    png(tmp_path / "t.png", rng.integers(20, 256, size=(4, 6, 3)))
    obj_file(tmp_path / "wall.obj")
    xml = f'''<scene version="3.0.0">
<integrator type="path"/>
{SENSOR}
<texture type="checkerboard" id="checks">
  <rgb name="color0" value="0.8, 0.75, 0.7"/><rgb name="color1" value="0.1, 0.2, 0.5"/>
  <transform name="to_uv"><scale x="4" y="4"/></transform>
</texture>
<bsdf type="diffuse" id="floor"><ref name="reflectance" id="checks"/></bsdf>
<shape type="rectangle"><transform name="to_world"><scale value="2"/></transform><ref id="floor"/></shape>
<shape type="sphere"><point name="center" x="-0.7" y="-0.4" z="0.45"/><float name="radius" value="0.45"/>
  <bsdf type="diffuse"><texture name="reflectance" type="checkerboard">
    <transform name="to_uv"><scale x="6" y="3"/></transform></texture></bsdf></shape>
<shape type="obj"><string name="filename" value="wall.obj"/>
  <transform name="to_world"><scale x="2"/><translate y="1.5"/></transform>
  <bsdf type="twosided"><bsdf type="diffuse"><texture name="reflectance" type="bitmap">
    <string name="filename" value="t.png"/><string name="filter_type" value="{filter_type}"/>
  </texture></bsdf></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale x="0.5" y="0.4"/><rotate x="1" angle="80"/>
  <rotate z="1" angle="-30"/><translate x="0.8" y="-0.2" z="0.5"/></transform>
  <bsdf type="twosided"><bsdf type="diffuse"><texture name="reflectance" type="bitmap">
    <string name="filename" value="t.png"/><string name="wrap_mode" value="mirror"/>
    <transform name="to_uv"><scale x="2" y="1.5"/></transform>
  </texture></bsdf></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale x="0.5" y="0.35"/><rotate x="1" angle="90"/>
  <translate x="0.1" y="0.9" z="0.4"/></transform>
  <bsdf type="conductor"><texture name="specular_reflectance" type="checkerboard">
    <rgb name="color0" value="0.9, 0.8, 0.3"/><rgb name="color1" value="0.3, 0.3, 0.9"/></texture></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate x="1" angle="180"/>
  <translate z="3"/></transform><emitter type="area"><rgb name="radiance" value="12"/></emitter></shape>
</scene>
'''
    path = tmp_path / "textured.xml"
    path.write_text(xml)
    return path


SEEDS = (1, 2, 3, 4)


@pytest.fixture(scope="module")
def mitsuba_textured(mi, tmp_path_factory):
    path = textured_scene(tmp_path_factory.mktemp("textured"))
    theirs = mi.load_file(str(path))
    return path, [np.array(mi.render(theirs, spp=512, seed=s), dtype=np.float32)[..., :3] for s in SEEDS]


def test_textured_scene_pt_matches_mitsuba(mitsuba_textured):
    path, theirs = mitsuba_textured
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=128, res=32, seed=s).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="textured scene, pt")


def test_textured_scene_sppm_matches_mitsuba(mitsuba_textured):
    path, theirs = mitsuba_textured
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "sppm", passes=128, res=32, seed=s, max_bounces=64, termination="roulette",
                            photons=2000).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="textured scene, sppm")


# --------------------------------------------------------------------------- 5. bad input


BAD = {
    "missing file": ('<texture name="reflectance" type="bitmap"><string name="filename" value="nowhere.png"/>'
                     '</texture>', 6, ["nowhere.png", "not found"]),
    "not an image": ('<texture name="reflectance" type="bitmap"><string name="filename" value="notes.png"/>'
                     '</texture>', 6, ["notes.png", "not an image"]),
    "not an EXR": ('<texture name="reflectance" type="bitmap"><string name="filename" value="notes.exr"/>'
                   '</texture>', 6, ["notes.exr", "cannot read EXR image"]),
    "unknown wrap mode": ('<texture name="reflectance" type="bitmap"><string name="filename" value="ok.png"/>'
                          '<string name="wrap_mode" value="wrap"/></texture>', 6, ["wrap_mode", "'wrap'",
                                                                                  "repeat, mirror, clamp"]),
    "unknown filter": ('<texture name="reflectance" type="bitmap"><string name="filename" value="ok.png"/>'
                       '<string name="filter_type" value="cubic"/></texture>', 6, ["cubic", "nearest, bilinear"]),
    "textured glass reflectance": ('<texture name="specular_reflectance" type="checkerboard"/>', 6,
                                   ["specular_reflectance", "not supported", "a texture for 'specular_transmittance'"]),
    "texture in a texture": ('<texture name="reflectance" type="checkerboard"><texture name="color0" '
                             'type="checkerboard"/></texture>', 6, ["texture inside a texture"]),
}


@pytest.mark.parametrize("case", list(BAD))
def test_bad_textures_exit_2_one_line(cli, tmp_path, case):
    body, line, words = BAD[case]
    (tmp_path / "notes.png").write_text("these are not pixels\n")
    (tmp_path / "notes.exr").write_text("these are not pixels either\n")
    png(tmp_path / "ok.png", np.full((2, 2, 3), 100))
    bsdf = "dielectric" if case == "textured glass reflectance" else "diffuse"
    path = tmp_path / "bad.xml"
    path.write_text(f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere">\n'
                    f'<bsdf type="{bsdf}">\n{body}\n</bsdf>\n</shape>\n</scene>\n')
    code, _, err = cli("render", path, "--res", "8", "--spp", "1", "-q", "-o", tmp_path / "o.exr")
    assert code == 2, err
    msg = err.strip()
    assert "\n" not in msg and f"bad.xml:{line}" in msg, msg
    for w in words:
        assert w in msg, (w, msg)


RAW_SCENE = """<scene version="3.0.0">
    <sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 0, 3" target="0, 0, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
            <rfilter type="box"/></film></sensor>
    <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
    <shape type="sphere"><bsdf type="diffuse">{reflectance}</bsdf></shape>
</scene>"""


@pytest.mark.parametrize("given", ['<float name="value" value="0.3"/>', '<rgb name="value" value="0.3, 0.3, 0.3"/>',
                                   '<vector name="value" value="0.3, 0.3, 0.3"/>'])
def test_rawconstant_is_its_value_everywhere(tmp_path, given):
    """Mitsuba's rawconstant (a value as given, no colour conversion): a sphere whose reflectance is a rawconstant 0.3
    renders as one whose reflectance is 0.3 (the same numbers, up to the texel's float32)."""
    import caustica
    images = []
    for reflectance in (f'<texture type="rawconstant" name="reflectance">{given}</texture>',
                        '<rgb name="reflectance" value="0.3"/>'):
        path = tmp_path / "s.xml"
        path.write_text(RAW_SCENE.format(reflectance=reflectance))
        images.append(caustica.render(path, "pt", spp=4, seed=1).image)
    assert np.allclose(images[0], images[1], rtol=1e-6, atol=0)


def test_rawconstant_without_a_value_is_refused(tmp_path):
    from caustica.errors import SceneError
    from caustica.scene import load_scene_description
    path = tmp_path / "s.xml"
    path.write_text(RAW_SCENE.format(reflectance='<texture type="rawconstant" name="reflectance"/>'))
    with pytest.raises(SceneError) as exc:
        load_scene_description(str(path))
    assert "rawconstant" in str(exc.value) and "s.xml:7" in str(exc.value), str(exc.value)
