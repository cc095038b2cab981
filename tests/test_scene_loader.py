"""The Mitsuba-XML scene loader: the paper's scenes, transforms, meshes, errors, and Mitsuba itself."""
from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

import caustica
from caustica.errors import SceneError
from caustica.scene import (builtin_scene_names, builtin_scene_path, describe_builtin,
                            load_scene_description, load_scene_file, parse_scene_string)
from caustica.scene import builtin as builtin_mod
from caustica.scene import transforms as tf
from caustica.scene.description import CONDUCTOR, CYLINDER, DIELECTRIC, DIFFUSE, DISK, MESH, SPHERE
from caustica.scene.meshes import cube_mesh, load_mesh_file, rectangle_mesh, to_world_mesh

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
BUNNY = [d / "bunny.ply" for d in builtin_mod.data_search_dirs(None) if (d / "bunny.ply").is_file()]
HALF_RING = builtin_mod.BUILTIN_DIR / "half_ring.obj"

PAPER_CAMERA = np.array([[-1, 0, 0, 0], [0, 1, 0, 10], [0, 0, -1, 42], [0, 0, 0, 1]], dtype=float)


def face_normals(mesh):
    p = mesh.positions[mesh.triangles]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# ----------------------------------------------------------------------------- paper scenes

def _load(name, **kw):
    if name == "cornell-bunny" and not BUNNY:
        pytest.skip("bunny.ply (the Stanford bunny) is not on the data search path")
    return load_scene_description(name, **kw)


@pytest.mark.parametrize("name", ["cornell-diacaustic", "cornell-catacaustic", "cornell-pyramid",
                                  "cornell-bunny"])
def test_paper_scene_common(name):
    d = _load(name)
    assert d.source == name
    cam = d.camera
    assert cam.fov_deg == 34 and cam.fov_axis == "smaller"
    assert (cam.width, cam.height) == (512, 512)
    np.testing.assert_allclose(cam.to_world, PAPER_CAMERA, atol=1e-12)
    assert d.spp == 16 and d.integrator == "path" and d.integrator_props == {"max_depth": -1}
    emitters = [s for s in d.shapes if s.emitter_radiance is not None]
    assert len(emitters) == 1 and emitters[0].emitter_radiance == (40.0, 40.0, 40.0)
    assert d.point_lights == []
    light = emitters[0].mesh
    assert np.allclose(light.positions[:, 1], 19.99)
    assert np.allclose(face_normals(light), [0, -1, 0])  # faces down
    area = 0.5 * np.linalg.norm(np.cross(*(light.positions[light.triangles][:, 1:] -
                                           light.positions[light.triangles][:, :1]).transpose(1, 0, 2)),
                                axis=1).sum()
    assert area == pytest.approx(9.0)
    by_id = {s.id: s for s in d.shapes}
    floor = by_id["floor"].mesh
    assert np.allclose(floor.positions[:, 1], 0) and np.allclose(face_normals(floor), [0, 1, 0])
    assert floor.positions[:, 0].min() == pytest.approx(-10) and floor.positions[:, 2].max() == pytest.approx(10)
    assert np.allclose(face_normals(by_id["left"].mesh), [1, 0, 0])
    assert np.allclose(face_normals(by_id["right"].mesh), [-1, 0, 0])
    assert np.allclose(face_normals(by_id["back"].mesh), [0, 0, 1])
    assert np.allclose(face_normals(by_id["ceiling"].mesh), [0, -1, 0])
    assert d.materials[by_id["left"].material].rgb == (0.75, 0.0, 0.0)
    assert d.materials[by_id["right"].material].rgb == (0.0, 0.0, 0.75)
    for s in d.shapes:
        assert s.source.endswith(".xml:" + s.source.rsplit(":", 1)[1]) and int(s.source.rsplit(":", 1)[1]) > 0


def test_diacaustic():
    d = _load("cornell-diacaustic")
    assert len(d.shapes) == 7
    sphere = d.shapes[-1]
    assert sphere.kind == SPHERE and sphere.id == "glass_sphere"
    np.testing.assert_allclose(sphere.to_world, tf.translate([4, 4, 2]) @ tf.scale(4))
    m = d.materials[sphere.material]
    assert m.kind == DIELECTRIC and m.int_ior == 1.5 and m.ext_ior == 1.0 and m.is_specular


def test_catacaustic():
    d = _load("cornell-catacaustic")
    assert len(d.shapes) == 7
    mirror = d.shapes[-1]
    assert mirror.kind == MESH and mirror.mesh.triangles.shape == (256, 3)
    assert mirror.mesh.normals is not None and mirror.mesh.normals.shape == (258, 3)
    m = d.materials[mirror.material]
    assert m.kind == CONDUCTOR and m.twosided and m.rgb == (1.0, 1.0, 1.0)
    lo, hi = mirror.mesh.positions.min(0), mirror.mesh.positions.max(0)
    np.testing.assert_allclose([lo[1], hi[1]], [0, 5], atol=1e-6)
    np.testing.assert_allclose([lo[0], hi[0]], [-3.5, 3.5], atol=1e-6)


def test_pyramid():
    d = _load("cornell-pyramid")
    cubes = [s for s in d.shapes if s.id.startswith("box")]
    assert len(d.shapes) == 12 and len(cubes) == 6
    for c in cubes:
        assert c.mesh.triangles.shape == (12, 3) and c.mesh.normals is None
        size = c.mesh.positions.max(0) - c.mesh.positions.min(0)
        np.testing.assert_allclose(size, [3, 3, 3])
    tops = sorted(c.mesh.positions[:, 1].max() for c in cubes)
    np.testing.assert_allclose(tops, [3, 3, 3, 6, 6, 9])


def test_bunny():
    d = _load("cornell-bunny")
    bunny = d.shapes[-1]
    # bunny.ply has no normals: angle-weighted vertex normals, as Mitsuba computes them (smooth shading)
    assert bunny.mesh.triangles.shape == (16301, 3) and bunny.mesh.normals.shape == bunny.mesh.positions.shape
    assert np.allclose(np.linalg.norm(bunny.mesh.normals, axis=1), 1.0)
    lo, hi = bunny.mesh.positions.min(0), bunny.mesh.positions.max(0)
    assert 8.5 < hi[1] - lo[1] < 9.5 and abs(lo[1]) < 0.1


def test_defaults_override():
    d = load_scene_description("cornell-diacaustic", res=64, spp=3, max_depth=5)
    assert (d.camera.width, d.camera.height, d.spp) == (64, 64, 3)
    assert d.integrator_props == {"max_depth": 5}
    d = load_scene_file(builtin_scene_path("cornell-pyramid"), {"res": "32"})
    assert d.camera.width == 32


def test_builtins_shipped_and_in_sync():
    names = builtin_scene_names()
    paper = ["cornell-diacaustic", "cornell-catacaustic", "cornell-pyramid", "cornell-bunny"]
    assert names == paper + ["cornell-diacaustic-fog"]   # the fog scene: tests/test_media_scene.py
    for n in names:
        assert builtin_scene_path(n).is_file()
        line = describe_builtin(n)
        assert line.startswith(n + ": ") and "\n" not in line
    assert HALF_RING.is_file() and not (builtin_mod.BUILTIN_DIR / "bunny.ply").exists()
    if not (SHARED / "scenes").is_dir():
        pytest.skip("shared/scenes not present")
    for n in paper:
        mine = builtin_scene_path(n).read_text()
        theirs = (SHARED / "scenes" / f"{n}.xml").read_text()
        strip = lambda t: [ln for ln in t.replace("../data/", "").splitlines() if "<!--" not in ln
                           and "-->" not in ln and not ln.strip().startswith(("It is", "base at"))]
        assert strip(mine) == strip(theirs), n
    assert HALF_RING.read_bytes() == (SHARED / "data" / "half_ring.obj").read_bytes()


def test_unknown_builtin_lists_names():
    with pytest.raises(SceneError, match="cornell-diacaustic.*cornell-bunny"):
        load_scene_description("cornell-nothing")


def test_bunny_missing_says_where_to_get_it(tmp_path, monkeypatch):
    monkeypatch.setenv("CAUSTICA_DATA_PATH", str(tmp_path / "empty"))
    monkeypatch.setattr(builtin_mod, "_repo_data_dirs", lambda: [])
    monkeypatch.chdir(tmp_path)
    with pytest.raises(SceneError) as e:
        load_scene_description("cornell-bunny")
    msg = str(e.value)
    for part in ("cornell-bunny.xml:", "bunny.ply", "Stanford", "bun_zipper.ply", "CAUSTICA_DATA_PATH",
                 str(tmp_path / "empty"), str(builtin_mod.BUILTIN_DIR)):
        assert part in msg


@pytest.mark.skipif(not BUNNY, reason="bunny.ply not available")
def test_bunny_found_through_env(tmp_path, monkeypatch):
    monkeypatch.setenv("CAUSTICA_DATA_PATH", os.pathsep.join([str(tmp_path), str(BUNNY[0].parent)]))
    monkeypatch.setattr(builtin_mod, "_repo_data_dirs", lambda: [])
    monkeypatch.chdir(tmp_path)
    assert load_scene_description("cornell-bunny").shapes[-1].mesh.triangles.shape[0] == 16301


# ----------------------------------------------------------------------------- transforms

def M(op, **attrs):
    return tf.op_matrix(op, {k: str(v) for k, v in attrs.items()})


def test_translate_scale():
    np.testing.assert_array_equal(M("translate", x=1, z=3)[:3, 3], [1, 0, 3])
    np.testing.assert_array_equal(M("translate", value="1, 2 3")[:3, 3], [1, 2, 3])
    np.testing.assert_array_equal(np.diag(M("scale", value=2)), [2, 2, 2, 1])
    np.testing.assert_array_equal(np.diag(M("scale", value="1, 2, 3")), [1, 2, 3, 1])
    np.testing.assert_array_equal(np.diag(M("scale", y=5)), [1, 5, 1, 1])


def test_rotate_right_handed():
    R = M("rotate", x=1, angle=90)
    np.testing.assert_allclose(R[:3, :3] @ [0, 1, 0], [0, 0, 1], atol=1e-15)
    R = M("rotate", y=1, angle=90)
    np.testing.assert_allclose(R[:3, :3] @ [0, 0, 1], [1, 0, 0], atol=1e-15)
    R = M("rotate", value="0, 0, 1", angle=90)
    np.testing.assert_allclose(R[:3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-15)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    np.testing.assert_allclose(M("rotate", z=1, angle=30)[:3, :3], [[c, -s, 0], [s, c, 0], [0, 0, 1]])
    # a non-unit axis: Mitsuba 3's matrix (Rodrigues with the axis as given, not a rotation)
    C = 1 - c
    np.testing.assert_allclose(M("rotate", y=1, z=1, angle=30)[:3, :3],
                               [[c, -s, s], [s, C + c, C], [-s, C, C + c]], atol=1e-15)
    with pytest.raises(ValueError, match="zero"):
        M("rotate", angle=10)


def test_matrix_and_order():
    vals = list(range(16))
    np.testing.assert_array_equal(M("matrix", value=" ".join(map(str, vals))), np.arange(16.0).reshape(4, 4))
    np.testing.assert_array_equal(M("matrix", value="1,2,3,4,5,6,7,8,9")[:3, :3], [[1, 2, 3], [4, 5, 6], [7, 8, 9]])
    # Document order: scale first, then translate (each op on the left).
    m = tf.compose([M("scale", value=2), M("translate", x=1)])
    np.testing.assert_allclose(m @ [1, 0, 0, 1], [3, 0, 0, 1])


def test_lookat_hand_computed():
    m = M("lookat", origin="1, 2, 3", target="1, 2, 13", up="0, 1, 0")
    # dir = +z, left = up x dir = +x, new_up = dir x left = +y
    np.testing.assert_allclose(m, [[1, 0, 0, 1], [0, 1, 0, 2], [0, 0, 1, 3], [0, 0, 0, 1]])
    m = M("lookat", origin="0, 0, 0", target="1, 0, 0", up="0, 0, 1")
    # dir = +x, left = z x x = +y, new_up = x x y = +z
    np.testing.assert_allclose(m[:3, :3], [[0, 0, 1], [1, 0, 0], [0, 1, 0]], atol=1e-15)
    with pytest.raises(ValueError):
        M("lookat", origin="0,0,0", target="0,1,0", up="0,1,0")


# ----------------------------------------------------------------------------- meshes

def test_builtin_meshes():
    r = rectangle_mesh()
    assert r.triangles.shape == (2, 3) and np.allclose(face_normals(r), [0, 0, 1])
    c = cube_mesh()
    assert c.triangles.shape == (12, 3) and c.normals is None
    centres = c.positions[c.triangles].mean(axis=1)
    assert np.all(np.einsum("ij,ij->i", face_normals(c), centres) > 0)  # outward
    assert np.allclose(c.positions.min(0), -1) and np.allclose(c.positions.max(0), 1)
    f = to_world_mesh(c, None, flip_normals=True)
    np.testing.assert_allclose(face_normals(f), -face_normals(c))


def test_obj_normals_transformed():
    local = load_mesh_file(HALF_RING)
    assert local.normals is not None
    m = tf.scale([2.0, 1.0, 0.5])
    w = to_world_mesh(local, m, flip_normals=True)
    expect = local.normals @ np.linalg.inv(m[:3, :3])  # inverse transpose, row vectors
    expect /= np.linalg.norm(expect, axis=1, keepdims=True)
    np.testing.assert_allclose(w.normals, -expect)
    np.testing.assert_array_equal(w.triangles, local.triangles[:, ::-1])
    np.testing.assert_allclose(w.positions, local.positions * [2, 1, 0.5])


def write_ply(path, normals: bool, quad: bool = True):
    v = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)]
    head = ["ply", "format ascii 1.0", "element vertex 4", "property float x", "property float y",
            "property float z"]
    if normals:
        head += ["property float nx", "property float ny", "property float nz"]
    faces = ["4 0 1 2 3"] if quad else ["3 0 1 2", "3 0 2 3"]
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    rows = [" ".join(map(str, p + ((0, 0, 1) if normals else ()))) for p in v]
    path.write_text("\n".join(head + rows + faces))


def test_ply(tmp_path):
    write_ply(tmp_path / "n.ply", True)
    write_ply(tmp_path / "p.ply", False)
    a, b = load_mesh_file(tmp_path / "n.ply"), load_mesh_file(tmp_path / "p.ply")
    assert a.triangles.shape == (2, 3) and np.allclose(a.normals, [0, 0, 1])
    assert b.normals is None and np.allclose(face_normals(b), [0, 0, 1])


def test_bad_mesh_files(tmp_path):
    (tmp_path / "empty.obj").write_text("# nothing\n")
    (tmp_path / "junk.ply").write_bytes(b"not a ply at all\x00\x01")
    for name in ("empty.obj", "junk.ply", "missing.obj"):
        with pytest.raises(SceneError, match=name):
            load_mesh_file(tmp_path / name)


# ----------------------------------------------------------------------------- elements

SENSOR = """<sensor type="perspective"><float name="fov" value="45"/>
<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/></transform></sensor>"""


def scene(body: str, sensor: str = SENSOR) -> str:
    return f'<?xml version="1.0"?>\n<scene version="3.0.0">\n{sensor}\n{body}\n</scene>\n'


def test_materials_refs_emitters(tmp_path):
    d = parse_scene_string(scene("""
<bsdf type="twosided" id="mirror"><ref id="m1"/></bsdf>
<shape type="disk"><bsdf type="conductor" id="m1"><float name="specular_reflectance" value="0.8"/></bsdf></shape>
<shape type="cube"><ref id="mirror"/></shape>
<shape type="rectangle"><ref name="bsdf" id="m1"/><emitter type="area"><float name="radiance" value="2"/></emitter></shape>
<shape type="sphere"><bsdf type="dielectric"><string name="int_ior" value="water"/><string name="ext_ior" value="vacuum"/></bsdf></shape>
<shape type="cylinder"><boolean name="flip_normals" value="true"/></shape>
<emitter type="point"><point name="position" x="1" y="2" z="3"/><rgb name="intensity" value="1, 2, 3"/></emitter>
<emitter type="point"><transform name="to_world"><translate x="4"/></transform></emitter>
"""), ".", None, "t.xml")
    mats, shapes = d.materials, d.shapes
    assert [s.kind for s in shapes] == [DISK, MESH, MESH, SPHERE, CYLINDER]
    m1 = mats[shapes[0].material]
    assert m1.kind == CONDUCTOR and m1.rgb == (0.8, 0.8, 0.8) and not m1.twosided
    assert mats[shapes[1].material].twosided and mats[shapes[1].material].kind == CONDUCTOR
    assert shapes[2].material == shapes[0].material and shapes[2].emitter_radiance == (2.0, 2.0, 2.0)
    glass = mats[shapes[3].material]
    assert glass.kind == DIELECTRIC and glass.int_ior == 1.333 and glass.ext_ior == 1.0
    default = mats[shapes[4].material]
    assert default.kind == DIFFUSE and default.rgb == (0.5, 0.5, 0.5) and shapes[4].flip_normals
    assert [(p.position, p.intensity) for p in d.point_lights] == [
        ((1.0, 2.0, 3.0), (1.0, 2.0, 3.0)), ((4.0, 0.0, 0.0), (1.0, 1.0, 1.0))]
    # defaults: Mitsuba's film, sampler and dielectric
    assert (d.camera.width, d.camera.height, d.spp, d.camera.fov_axis) == (768, 576, 4, "x")
    d = parse_scene_string(scene('<shape type="sphere"><bsdf type="dielectric"/></shape>'))
    assert (d.materials[0].int_ior, d.materials[0].ext_ior) == (1.5046, 1.000277)


def test_cylinder_matches_p0_p1():
    d = parse_scene_string(scene("""<shape type="cylinder"><point name="p0" value="1, 1, 1"/>
<point name="p1" value="1, 4, 1"/><float name="radius" value="0.5"/></shape>"""))
    m = d.shapes[0].to_world
    np.testing.assert_allclose(m @ [0, 0, 0, 1], [1, 1, 1, 1], atol=1e-12)
    np.testing.assert_allclose(m @ [0, 0, 1, 1], [1, 4, 1, 1], atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(m[:3, 0]), 0.5)
    np.testing.assert_allclose(np.linalg.norm(m[:3, 1]), 0.5)


# ----------------------------------------------------------------------------- errors

FILM = '<film type="hdrfilm">{}</film>'
ERROR_CASES = {
    "malformed": ("<shape type=\"cube\">\n</scene>", 5, "malformed XML"),
    "unknown element": ("<texture type=\"bitmap\"/>", 4, "<texture"),
    "unknown shape type": ("<shape type=\"torus\"/>", 4, "torus"),
    "unknown property": ("<shape type=\"cube\"><float name=\"radius\" value=\"1\"/></shape>", 4, "radius"),
    "bad number": ("<shape type=\"sphere\">\n<float name=\"radius\" value=\"1.x\"/></shape>", 5, "1.x"),
    "negative radius": ("<shape type=\"sphere\"><float name=\"radius\" value=\"-2\"/></shape>", 4, "radius"),
    "missing mesh": ("<shape type=\"obj\"><string name=\"filename\" value=\"nope.obj\"/></shape>", 4, "nope.obj"),
    "conductor unknown material": ("<bsdf type=\"conductor\"><string name=\"material\" value=\"Xy\"/></bsdf>", 4,
                                   "unknown conductor material 'Xy'"),
    "wrong property type": ("<shape type=\"sphere\"><string name=\"radius\" value=\"1\"/></shape>", 4, "<float>"),
    "undefined parameter": ("<shape type=\"sphere\"><float name=\"radius\" value=\"$r\"/></shape>", 4, "$r"),
    "unknown ref": ("<shape type=\"cube\"><ref id=\"nothing\"/></shape>", 4, "nothing"),
    "unknown bsdf": ("<bsdf type=\"blendbsdf\"/>", 4, "blendbsdf"),
    "envmap without a file": ("<emitter type=\"envmap\"/>", 4, "an envmap needs a 'filename'"),
    "area at top level": ("<emitter type=\"area\"/>", 4, "inside a <shape>"),
    "unknown ior": ("<bsdf type=\"dielectric\"><string name=\"int_ior\" value=\"glass\"/></bsdf>", 4, "glass"),
}
SENSOR_ERRORS = {
    "negative sample_count": ('<sampler type="independent"><integer name="sample_count" value="-1"/></sampler>',
                              "sample_count"),
    "zero width": (FILM.format('<integer name="width" value="0"/>'), "width"),
    "zero height": (FILM.format('<integer name="height" value="0"/>'), "height"),
    "unknown rfilter": (FILM.format('<rfilter type="mitchell"/>'), "mitchell"),
    "unknown sampler": ('<sampler type="sobol"/>', "sobol"),
    "far_clip before near_clip": ('<float name="far_clip" value="0.001"/>', "far_clip"),
}


@pytest.mark.parametrize("case", list(ERROR_CASES))
def test_errors_name_file_and_line(tmp_path, case):
    body, line, part = ERROR_CASES[case]
    path = tmp_path / "bad-scene.xml"
    path.write_text(scene(body, SENSOR.replace("\n", " ")))
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    msg = str(e.value)
    assert f"bad-scene.xml:{line}:" in msg and part in msg, msg


@pytest.mark.parametrize("case", list(SENSOR_ERRORS))
def test_sensor_errors(tmp_path, case):
    inner, part = SENSOR_ERRORS[case]
    path = tmp_path / "cam.xml"
    path.write_text(scene("", f'<sensor type="perspective"><float name="fov" value="45"/>\n{inner}\n</sensor>'))
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    assert "cam.xml:4:" in str(e.value) and part in str(e.value), str(e.value)


def test_missing_scene_file(tmp_path):
    with pytest.raises(SceneError, match="no-such.xml"):
        load_scene_file(tmp_path / "no-such.xml")
    with pytest.raises(SceneError, match="no-such.xml"):
        load_scene_description(str(tmp_path / "no-such.xml"))


def test_error_lists_supported():
    with pytest.raises(SceneError, match="supported: rectangle, cube, sphere, disk, cylinder, obj, ply"):
        parse_scene_string(scene('<shape type="torus"/>'))
    with pytest.raises(SceneError, match="supported: to_world, flip_normals"):
        parse_scene_string(scene('<shape type="cube"><float name="r" value="1"/></shape>'))


# ----------------------------------------------------------------------------- against Mitsuba

def analytic_bbox(s):
    m = s.to_world
    lin, c0 = m[:3, :3], m[:3, 3]
    if s.kind == SPHERE:
        e = np.linalg.norm(lin, axis=1)
        return c0 - e, c0 + e
    e = np.sqrt(lin[:, 0] ** 2 + lin[:, 1] ** 2)
    if s.kind == DISK:
        return c0 - e, c0 + e
    c1 = c0 + lin[:, 2]
    return np.minimum(c0, c1) - e, np.maximum(c0, c1) + e


def mitsuba_xml(tmp_path) -> Path:
    write_ply(tmp_path / "quad.ply", True, quad=False)  # Mitsuba's PLY reader takes triangles only
    text = f"""<scene version="3.0.0">
  <default name="res" value="64"/>
  <sensor type="perspective">
    <float name="fov" value="40"/><string name="fov_axis" value="y"/>
    <transform name="to_world"><lookat origin="1, 2, 8" target="0.5, 0, 0" up="0, 1, 0.2"/><rotate z="1" angle="10"/></transform>
    <film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="48"/><rfilter type="box"/></film>
  </sensor>
  <shape type="rectangle" id="rect"><transform name="to_world"><scale x="2" y="3"/><rotate x="0.6" z="0.8" angle="30"/><translate value="1, 2, 3"/></transform></shape>
  <shape type="cube" id="cube"><transform name="to_world"><scale value="0.5, 1, 2"/><rotate y="1" angle="20"/><translate x="-2"/></transform></shape>
  <shape type="sphere" id="sphere"><point name="center" value="1, 1, -1"/><float name="radius" value="0.7"/><transform name="to_world"><scale value="2"/><translate z="1"/></transform></shape>
  <shape type="disk" id="disk"><transform name="to_world"><scale value="1.5, 0.5, 1"/><rotate x="1" angle="60"/><translate y="3"/></transform></shape>
  <shape type="cylinder" id="cyl"><point name="p0" x="0" y="0" z="0"/><point name="p1" x="1" y="2" z="0.5"/><float name="radius" value="0.3"/>
     <transform name="to_world"><matrix value="1 0 0 0.5  0 1 0 0  0 0 1 -1  0 0 0 1"/></transform></shape>
  <shape type="obj" id="ring"><string name="filename" value="{HALF_RING}"/><transform name="to_world"><scale value="0.5, 1, 2"/><rotate x="1" angle="-40"/></transform></shape>
  <shape type="ply" id="quad"><string name="filename" value="quad.ply"/><transform name="to_world"><translate x="3"/></transform></shape>
</scene>"""
    path = tmp_path / "mini.xml"
    path.write_text(text)
    return path


DEFAULT_BSDF_XML = """<shape type="rectangle" id="light"><emitter type="area"/></shape>
<shape type="rectangle" id="plain"/>"""


def test_default_bsdf_is_black_on_an_emitter_grey_elsewhere():
    """Mitsuba 3 gives a shape without a BSDF a diffuse one, reflectance 0.5, or 0 when it emits."""
    d = parse_scene_string(scene(DEFAULT_BSDF_XML))
    light, plain = d.shapes
    assert d.materials[light.material].kind == DIFFUSE and d.materials[light.material].rgb == (0.0, 0.0, 0.0)
    assert d.materials[plain.material].kind == DIFFUSE and d.materials[plain.material].rgb == (0.5, 0.5, 0.5)


def test_default_bsdfs_agree_with_mitsuba(mi):
    theirs = {s.id(): mi.traverse(s)["bsdf.reflectance.value"] for s in mi.load_string(
        '<scene version="3.0.0">' + DEFAULT_BSDF_XML + "</scene>").shapes()}
    d = parse_scene_string(scene(DEFAULT_BSDF_XML))
    assert {s.id: d.materials[s.material].rgb[0] for s in d.shapes} == pytest.approx(theirs)


def test_against_mitsuba_shapes_and_sensor(mi, tmp_path):
    path = mitsuba_xml(tmp_path)
    theirs = mi.load_file(str(path))
    mine = load_scene_file(path)
    by_id = {s.id(): s for s in theirs.shapes()}
    assert set(by_id) == {s.id for s in mine.shapes}
    for s in mine.shapes:
        ms = by_id[s.id]
        b = ms.bbox()
        lo, hi = (s.mesh.positions.min(0), s.mesh.positions.max(0)) if s.mesh is not None else analytic_bbox(s)
        np.testing.assert_allclose(lo, np.array(b.min), atol=1e-5, err_msg=s.id)
        np.testing.assert_allclose(hi, np.array(b.max), atol=1e-5, err_msg=s.id)
        params = mi.traverse(ms)
        if s.mesh is not None:
            assert ms.face_count() == s.mesh.triangles.shape[0], s.id
        if "to_world" in params and s.kind != MESH:
            np.testing.assert_allclose(np.array(params["to_world"].matrix), s.to_world, atol=1e-5, err_msg=s.id)
        if s.mesh is not None and s.mesh.normals is not None:
            # Mitsuba may reorder the vertices: compare (position, normal) rows as sets.
            a = np.hstack([np.array(params["vertex_positions"]).reshape(-1, 3),
                           np.array(params["vertex_normals"]).reshape(-1, 3)])
            c = np.hstack([s.mesh.positions, s.mesh.normals])
            sort = lambda x: x[np.lexsort(np.round(x, 4).T[::-1])]
            np.testing.assert_allclose(sort(a), sort(c), atol=1e-5, err_msg=s.id)
    sensor = theirs.sensors()[0]
    np.testing.assert_allclose(np.array(sensor.world_transform().matrix), mine.camera.to_world, atol=1e-5)
    assert tuple(sensor.film().size()) == (mine.camera.width, mine.camera.height) == (64, 48)


def test_against_mitsuba_paper_camera_and_iors(mi):
    path = builtin_scene_path("cornell-pyramid")
    theirs = mi.load_file(str(path), res=32)
    mine = load_scene_file(path, {"res": "32"})
    np.testing.assert_allclose(np.array(theirs.sensors()[0].world_transform().matrix), mine.camera.to_world,
                               atol=1e-5)
    assert theirs.sensors()[0].sampler().sample_count() == mine.spp
    # Mitsuba merges meshes that share a BSDF, so compare the total triangle count.
    assert sum(s.face_count() for s in theirs.shapes()) == sum(len(s.mesh.triangles) for s in mine.shapes) == 84
    from caustica.scene.xml_loader import IOR_TABLE
    for name, ior in IOR_TABLE.items():
        bsdf = mi.load_dict({"type": "dielectric", "int_ior": name, "ext_ior": "vacuum"})
        assert mi.traverse(bsdf)["eta"] == pytest.approx(ior, rel=1e-6), name


def test_against_mitsuba_mirrored_shapes_face_the_same_way(mi):
    """A mirroring to_world: Mitsuba 3 emits and scatters on the side of a shape's shading frame, which for a rectangle
    and a cube is their normal through the inverse transpose (their winding, the geometric normal, turns), and turns a
    sphere inside out (sphere.cpp flips its normals).  caustica's front side is that side (the staircase2 scene of
    Bitterli's, as converted for Mitsuba 3, has its doorway's light rectangle mirrored: black in caustica before)."""
    xml = scene("""<shape type="rectangle" id="r"><transform name="to_world"><scale x="-1"/></transform></shape>
<shape type="cube" id="c"><transform name="to_world"><scale y="-1"/><translate z="-5"/></transform></shape>""")
    theirs = mi.load_string(xml)
    mine = {s.id: s for s in parse_scene_string(xml).shapes}
    si = theirs.ray_intersect(mi.Ray3f([0.1, 0.2, 5], [0, 0, -1]))
    assert np.dot(np.array(si.sh_frame.n), face_normals(mine["r"].mesh)[0]) > 0.99
    ray = mi.Ray3f([0.1, 0.2, -10], [0, 0, 1])  # hits the cube's -z face
    si = theirs.ray_intersect(ray)
    cube = mine["c"].mesh
    n = face_normals(cube)
    hit = [i for i, f in enumerate(n) if abs(f[2]) > 0.99 and cube.positions[cube.triangles[i], 2].mean() < -5.5]
    assert hit and np.dot(np.array(si.sh_frame.n), n[hit[0]]) > 0.99


MIRRORED = {"rectangle": '<scale x="-1"/>', "rectangle, axes swapped": '<matrix value="0 0 1 0 0 1 0 0 1 0 0 0 0 0 0 1"/>',
            "disk": '<scale x="-1"/>', "cube": '<scale y="-1"/>', "sphere": '<scale x="-1"/>',
            "sphere, two mirrors": '<scale x="-1" y="-1"/>', "cylinder": '<scale x="-1"/>'}


@pytest.mark.parametrize("case", list(MIRRORED))
def test_mirrored_emitters_light_the_side_mitsuba_lights(mi, tmp_path, case):
    """An emitting shape under a mirroring to_world, seen from +z, -z and +x: caustica's pt and Mitsuba's path
    tracer see the same radiance (1 on the emitting side, the faint sky elsewhere; 8 x 8 pixels, 16 spp)."""
    kind = case.split(",")[0]
    for origin in ("0, 0, 6", "0, 0, -6", "6, 0, 0.5"):
        path = tmp_path / "mirrored.xml"
        path.write_text(f'''<scene version="3.0.0"><integrator type="path"><integer name="max_depth" value="2"/></integrator>
<sensor type="perspective"><float name="fov" value="10"/>
<transform name="to_world"><lookat origin="{origin}" target="0, 0, 0.5" up="0, 1, 0"/></transform>
<film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/><rfilter type="box"/></film></sensor>
<shape type="{kind}"><transform name="to_world">{MIRRORED[case]}</transform>
<bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf><emitter type="area"><rgb name="radiance" value="1"/></emitter>
</shape><emitter type="constant"><rgb name="radiance" value="0.001"/></emitter></scene>''')
        ours = caustica.render(caustica.load_scene(path), "pt", spp=16, res=8, seed=1).image.mean()
        theirs = np.array(mi.render(mi.load_file(str(path)), spp=16), np.float64)[..., :3].mean()
        # a face seen edge-on covers pixels partly: its mean is noisy at 16 spp, a face seen from its back is 0.001
        assert abs(ours - theirs) < 0.05, (case, origin, ours, theirs)


@pytest.mark.parametrize("kind", ["ply", "obj"])
def test_a_mesh_file_without_normals_shades_smoothly_as_in_mitsuba(mi, tmp_path, kind):
    """Mitsuba 3 gives a mesh file without vertex normals angle-weighted vertex normals, computed in world
    space (unless face_normals): the published teapot of tutorials/scenes/simple.xml rendered faceted, 14 of
    768 4x4 blocks beyond 5 sigmas at 1024 spp x 4 seeds (the same image mean), none with face_normals."""
    # a bumpy square: 9 shared vertices, 8 triangles of different sizes and angles
    pts = [(x, y, 0.3 * ((x * 7 + y * 3) % 5) / 4) for y in (0.0, 0.4, 1.0) for x in (0.0, 0.7, 1.0)]
    tris = [(0, 1, 4), (0, 4, 3), (1, 2, 5), (1, 5, 4), (3, 4, 7), (3, 7, 6), (4, 5, 8), (4, 8, 7)]
    if kind == "ply":
        (tmp_path / "m.ply").write_text("ply\nformat ascii 1.0\nelement vertex 9\nproperty float x\nproperty float y\n"
                                        "property float z\nelement face 8\nproperty list uchar int vertex_indices\n"
                                        "end_header\n" + "".join(f"{x} {y} {z}\n" for x, y, z in pts)
                                        + "".join(f"3 {a} {b} {c}\n" for a, b, c in tris))
    else:
        (tmp_path / "m.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in pts)
                                        + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in tris))
    xf = '<transform name="to_world"><scale x="2" y="0.5" z="3"/><rotate x="1" angle="30"/></transform>'
    for extra, smooth in (("", True), ('<boolean name="face_normals" value="true"/>', False)):
        path = tmp_path / "s.xml"
        path.write_text(scene(f'<shape type="{kind}"><string name="filename" value="{tmp_path / f"m.{kind}"}"/>'
                              f'{extra}{xf}</shape>'))
        mesh = load_scene_file(path).shapes[0].mesh
        if not smooth:
            assert mesh.normals is None
            continue
        params = mi.traverse(mi.load_file(str(path)))
        key = next(k for k in params.keys() if k.endswith("vertex_normals"))
        # per triangle corner (Mitsuba's OBJ reader numbers the vertices in their order of use)
        faces = np.array(params[key.replace("vertex_normals", "faces")]).reshape(-1, 3)
        theirs = np.array(params[key]).reshape(-1, 3)[faces]
        where = np.array(params[key.replace("vertex_normals", "vertex_positions")]).reshape(-1, 3)[faces]
        assert np.allclose(mesh.positions[mesh.triangles], where, atol=1e-6)
        assert mesh.normals is not None and np.allclose(mesh.normals[mesh.triangles], theirs, atol=1e-5)


# ----------------------------------------------------------------------------- hostile input (issue #8)

def load_strict(tmp_path, body: str, sensor: str = SENSOR.replace("\n", " "), name: str = "bad-scene.xml",
                defaults=None):
    """Load scene(body) from a file with every warning an error: a bad input gives one clean SceneError."""
    path = tmp_path / name
    path.write_text(scene(body, sensor))
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return load_scene_file(path, defaults)


def scene_error(tmp_path, body: str, sensor: str = SENSOR.replace("\n", " "), defaults=None) -> str:
    with pytest.raises(SceneError) as e:
        load_strict(tmp_path, body, sensor, defaults=defaults)
    msg = str(e.value)
    assert "\n" not in msg and len(msg) < 400, msg
    return msg


RECT = '<shape type="rectangle">{}</shape>'
XF = '<transform name="to_world">{}</transform>'
#: Values that overflow float32 (the image's type) or compose to a matrix that does:
#: (body on line 4, the element the message names, a word of the message).
OUT_OF_RANGE = {
    "radiance 1e300": (RECT.format('<emitter type="area">\n<rgb name="radiance" value="1e300"/></emitter>'),
                       5, '<rgb name="radiance">', "out of range"),
    "intensity 1e39": ('<emitter type="point">\n<rgb name="intensity" value="1, 1e39, 1"/></emitter>',
                       5, '<rgb name="intensity">', "out of range"),
    "scale 1e200": (RECT.format(XF.format('\n<scale value="1e200"/>')), 5, "<scale>", "out of range"),
    "scales that compose past float32": (RECT.format('\n' + XF.format('<scale value="1e20"/><scale value="1e20"/>')),
                                         5, '<transform name="to_world">', "1e+40"),
    "translate 1e39": (RECT.format(XF.format('\n<translate x="1e39"/>')), 5, "<translate>", "out of range"),
    "radius 1e308": ('<shape type="sphere">\n<float name="radius" value="1e308"/></shape>',
                     5, '<float name="radius">', "out of range"),
    "sphere radius x scale past float32": ('<shape type="sphere"><float name="radius" value="1e30"/>'
                                           + XF.format('<scale value="1e10"/>') + '</shape>',
                                           4, '<shape type="sphere">', "center and radius"),
    "cylinder radius x scale past float32": ('<shape type="cylinder"><float name="radius" value="1e30"/>'
                                             + XF.format('<scale value="1e10"/>') + '</shape>',
                                             4, '<shape type="cylinder">', "p0, p1 and the radius"),
    "mesh vertices past float32": (RECT.format(XF.format('<scale value="3e38"/><translate x="3e38"/>')),
                                   4, '<shape type="rectangle">', "beyond"),
    "ior 1e40": ('<bsdf type="dielectric"><float name="int_ior" value="1e40"/></bsdf>',
                 4, '<float name="int_ior">', "out of range"),
}


@pytest.mark.parametrize("case", list(OUT_OF_RANGE))
def test_values_beyond_float32_are_errors(tmp_path, case):
    body, line, element, part = OUT_OF_RANGE[case]
    msg = scene_error(tmp_path, body)
    assert f"bad-scene.xml:{line}: {element}" in msg and part in msg, msg


DEGENERATE = {
    "shape scale 0": (RECT.format(XF.format('<scale value="0"/>')), '<transform name="to_world">'),
    "shape scale 1e-13 in one axis": (RECT.format(XF.format('<scale x="1e-13"/>')), '<transform name="to_world">'),
    "shape scale 1e-39 (below float32)": (RECT.format(XF.format('<scale value="1e-39"/>')),
                                          '<transform name="to_world">'),
    "projective matrix": (RECT.format(XF.format('<matrix value="1 0 0 0  0 1 0 0  0 0 1 0  0 0 0.5 1"/>')),
                          '<transform name="to_world">'),
    "point emitter scale 0": ('<emitter type="point">' + XF.format('<scale value="0"/>') + '</emitter>',
                              '<transform name="to_world">'),
}


@pytest.mark.parametrize("case", list(DEGENERATE))
def test_degenerate_transforms_are_errors(tmp_path, case):
    body, element = DEGENERATE[case]
    msg = scene_error(tmp_path, body)
    assert f"bad-scene.xml:4: {element}" in msg and ("degenerate" in msg or "projective" in msg), msg


def test_degenerate_sensor_transform_is_an_error(tmp_path):
    """Shapes were checked, the sensor was not: a zero scale rendered black."""
    sensor = ('<sensor type="perspective"><float name="fov" value="45"/>\n'
              '<transform name="to_world"><lookat origin="0, 0, 5" target="0, 0, 0" up="0, 1, 0"/>'
              '<scale value="0"/></transform></sensor>')
    msg = scene_error(tmp_path, RECT.format(""), sensor)
    assert 'bad-scene.xml:4: <transform name="to_world">' in msg and "degenerate" in msg, msg


def test_large_but_representable_values_still_load(tmp_path):
    d = load_strict(tmp_path, RECT.format(XF.format('<scale value="1e30"/>')
                                          + '<emitter type="area"><rgb name="radiance" value="1e30"/></emitter>')
                    + '<shape type="sphere"><float name="radius" value="1e-5"/></shape>')
    assert d.shapes[0].emitter_radiance == (1e30,) * 3
    assert np.abs(d.shapes[0].mesh.positions).max() == pytest.approx(1e30)
    assert d.shapes[1].to_world[0, 0] == pytest.approx(1e-5)


SAMPLER = '<sampler type="independent"><integer name="sample_count" value="{}"/></sampler>'
#: Integers the kernels cannot honour, on line 4 of the sensor: (sensor child, element named, a word).
HUGE_INTEGERS = {
    "sample_count 2^63": (SAMPLER.format(2**63), '<integer name="sample_count">', "int32"),
    "sample_count 2^20 + 1": (SAMPLER.format(2**20 + 1), '<integer name="sample_count">', "1,048,576"),
    "width 2^31": (FILM.format(f'<integer name="width" value="{2**31}"/>'), '<integer name="width">', "int32"),
    "height -2^40": (FILM.format(f'<integer name="height" value="{-2**40}"/>'), '<integer name="height">',
                     "int32"),
    "film of 10^10 pixels": (FILM.format('<integer name="width" value="100000"/>'
                                         '<integer name="height" value="100000"/>'),
                             '<film type="hdrfilm">', "10,000,000,000 pixels"),
    "5,000-digit width": (FILM.format(f'<integer name="width" value="{"9" * 5000}"/>'),
                          '<integer name="width">', "(5,000 characters)"),
}


@pytest.mark.parametrize("case", list(HUGE_INTEGERS))
def test_huge_integers_are_refused_with_a_bound(tmp_path, case):
    inner, element, part = HUGE_INTEGERS[case]
    msg = scene_error(tmp_path, "", f'<sensor type="perspective"><float name="fov" value="45"/>\n{inner}\n</sensor>')
    assert f"bad-scene.xml:4: {element}" in msg and part in msg, msg
    assert len(msg) < 300 and "9" * 50 not in msg, msg


def test_largest_allowed_integers_load(tmp_path):
    from caustica.scene.xml_loader import MAX_SAMPLE_COUNT
    d = load_strict(tmp_path, "", f'<sensor type="perspective"><float name="fov" value="45"/>'
                                  f'{SAMPLER.format(MAX_SAMPLE_COUNT)}'
                                  + FILM.format('<integer name="width" value="46340"/>'
                                                '<integer name="height" value="46340"/>') + '</sensor>')
    assert d.spp == 2**20 and (d.camera.width, d.camera.height) == (46340, 46340)
    assert tf.parse_int(" +0000000000000000000000000000000000000000007 ") == 7


def test_echoed_values_are_shortened(tmp_path):
    long_type = "torus" * 1000
    msg = scene_error(tmp_path, f'<shape type="{long_type}"/>')
    assert "bad-scene.xml:4:" in msg and "(5,000 characters)" in msg and long_type not in msg, msg
    msg = scene_error(tmp_path, f'<shape type="sphere"><float name="radius" value="{"1" * 3000}.x"/></shape>')
    assert "(3,002 characters)" in msg and "1" * 100 not in msg, msg


def test_deep_nesting_is_one_error_not_a_recursion_error(tmp_path):
    from caustica.scene.xml_loader import MAX_NESTING_DEPTH
    n = 5000
    msg = scene_error(tmp_path, RECT.format('<bsdf type="twosided">' * n + '<bsdf type="diffuse"/>' + "</bsdf>" * n))
    assert "bad-scene.xml:4: <bsdf type=\"twosided\">" in msg and f"at most {MAX_NESTING_DEPTH} levels" in msg, msg
    msg = scene_error(tmp_path, "<a>\n" * n + "</a>" * n)
    assert f"bad-scene.xml:{4 + MAX_NESTING_DEPTH - 1}: <a>" in msg and "nested" in msg, msg
    # 500 twosided BSDFs wrapping each other through <ref>: each element is shallow, the chain is not
    chain = '<bsdf type="diffuse" id="b0"/>\n' + "".join(
        f'<bsdf type="twosided" id="b{i}"><ref id="b{i - 1}"/></bsdf>\n' for i in range(1, 500))
    msg = scene_error(tmp_path, chain + RECT.format('<ref id="b499"/>'))
    assert "bad-scene.xml:" in msg and f"more than {MAX_NESTING_DEPTH} deep" in msg, msg
    # Twosided nested a few levels still loads.
    d = load_strict(tmp_path, RECT.format('<bsdf type="twosided">' * 3 + '<bsdf type="diffuse"/>' + "</bsdf>" * 3))
    assert d.materials[d.shapes[0].material].twosided


@pytest.mark.parametrize("encoding", ["klingon", "shift_jis", "rot13"])
def test_unknown_xml_encoding_is_one_error(tmp_path, encoding):
    path = tmp_path / "enc.xml"
    path.write_text(scene(RECT.format("")).replace('<?xml version="1.0"?>',
                                                   f'<?xml version="1.0" encoding="{encoding}"?>'))
    with pytest.raises(SceneError) as e:
        load_scene_file(path)
    msg = str(e.value)
    assert f"enc.xml:1: <?xml encoding='{encoding}'?>" in msg and "supported: UTF-8" in msg, msg


def test_single_byte_xml_encoding_loads(tmp_path):
    path = tmp_path / "latin.xml"
    path.write_bytes(scene(RECT.format("")).replace('<?xml version="1.0"?>',
                                                    '<?xml version="1.0" encoding="ISO-8859-1"?>\n<!-- caf\xe9 -->')
                     .encode("latin-1"))
    assert load_scene_file(path).shapes[0].kind == MESH


def write_ascii_ply(path, vertex_count_claimed: int, rows=("0 0 0", "1 0 0", "0 1 0"), comment: str = ""):
    head = ["ply", "format ascii 1.0"] + ([f"comment {comment}"] if comment else []) + [
        f"element vertex {vertex_count_claimed}", "property float x", "property float y", "property float z",
        "element face 1", "property list uchar int vertex_indices", "end_header"]
    path.write_bytes("\n".join(head + list(rows) + ["3 0 1 2", ""]).encode("latin-1"))


def mesh_error(path) -> str:
    import warnings
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(SceneError) as e:
            load_mesh_file(path)
    msg = str(e.value)
    assert "\n" not in msg and path.name in msg, msg
    return msg


def test_ply_header_promising_more_than_the_file_holds(tmp_path):
    """A header claiming 2e9 vertices was reported as 'holds no triangles'."""
    write_ascii_ply(tmp_path / "claims.ply", 2_000_000_000)
    msg = mesh_error(tmp_path / "claims.ply")
    assert "2,000,000,000 'vertex' and 1 'face'" in msg and "only 4 lines follow end_header" in msg, msg
    write_ascii_ply(tmp_path / "toomany.ply", 3_000_000_000)
    assert "at most 2,147,483,647" in mesh_error(tmp_path / "toomany.ply")
    # binary: 2e9 float vertices need 24 GB; the file has 36 bytes
    head = (b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty float x\n"
            b"property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\n"
            b"end_header\n")
    (tmp_path / "claims-bin.ply").write_bytes(head + np.zeros(9, np.float32).tobytes())
    msg = mesh_error(tmp_path / "claims-bin.ply")
    assert "at least 24,000,000,000 bytes" in msg and "only 36 bytes" in msg, msg


def test_mesh_vertex_beyond_float32_is_one_clean_error(tmp_path):
    """A PLY 'float' of 1e39 printed numpy's overflow warning before the error."""
    write_ascii_ply(tmp_path / "big.ply", 3, rows=("1e39 0 0", "1 0 0", "0 1 0"))
    msg = mesh_error(tmp_path / "big.ply")
    assert "vertex 0 is (inf, 0.0, 0.0)" in msg and "float32" in msg, msg
    (tmp_path / "big.obj").write_text("v 0 0 1e300\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert "vertex 0 is (0.0, 0.0, 1e+300)" in mesh_error(tmp_path / "big.obj")


def test_meshes_with_latin1_bytes_load(tmp_path):
    """One Latin-1 byte in an OBJ comment failed with ModuleNotFoundError: charset_normalizer."""
    (tmp_path / "latin.obj").write_bytes(b"# mod\xe8le de caf\xe9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    m = load_mesh_file(tmp_path / "latin.obj")
    assert m.triangles.tolist() == [[0, 1, 2]] and np.allclose(face_normals(m), [0, 0, 1])
    write_ascii_ply(tmp_path / "latin.ply", 3, comment="mod\xe8le")
    assert load_mesh_file(tmp_path / "latin.ply").triangles.tolist() == [[0, 1, 2]]
    # and through a scene file
    d = load_strict(tmp_path, '<shape type="obj"><string name="filename" value="latin.obj"/></shape>')
    assert d.shapes[0].mesh.triangles.shape == (1, 3)


PARAM_SENSOR = ('<sensor type="perspective"><float name="fov" value="45"/>'
                '<film type="hdrfilm"><integer name="width" value="$res"/><integer name="height" value="$res"/></film>'
                '<sampler type="independent"><integer name="sample_count" value="$spp"/></sampler></sensor>')


def test_unused_or_empty_defines_are_errors(tmp_path):
    body = '<default name="res" value="8"/>\n<default name="spp" value="2"/>\n<default name="unused" value="1"/>'
    assert load_strict(tmp_path, body, PARAM_SENSOR, defaults={"res": "4", "spp": 3}).spp == 3
    msg = scene_error(tmp_path, body, PARAM_SENSOR, defaults={"nosuch": "3"})
    assert "bad-scene.xml: -D nosuch=3: the scene has no parameter $nosuch" in msg, msg
    assert msg.endswith("the scene's parameters: res, spp"), msg
    msg = scene_error(tmp_path, body, PARAM_SENSOR, defaults={"rse": "3"})
    assert "(did you mean 'res'?)" in msg, msg
    msg = scene_error(tmp_path, body, PARAM_SENSOR, defaults={"": "16"})
    assert "-D =16: a define needs a name" in msg, msg
    msg = scene_error(tmp_path, body, PARAM_SENSOR, defaults={"unused": "2"})
    assert "line 6" in msg and "never uses $unused" in msg, msg
    # a scene without parameters
    assert "parameters: (none)" in scene_error(tmp_path, RECT.format(""), defaults={"res": "4"})


def test_duplicate_default_is_an_error(tmp_path):
    msg = scene_error(tmp_path, '<default name="res" value="8"/>\n<default name="res" value="16"/>', PARAM_SENSOR
                      .replace("$spp", "1"))
    assert "bad-scene.xml:5: <default name=\"res\">" in msg and "given twice (first on line 4)" in msg, msg
    msg = scene_error(tmp_path, '<default name="2x" value="8"/>')
    assert "bad-scene.xml:4:" in msg and "cannot be used as $name" in msg, msg


@pytest.mark.parametrize("define", ["nosuch=3", "=16", "rse=64"])
def test_cli_refuses_unused_defines(tmp_path, capsys, define):
    from caustica.cli import main
    code = main(["render", "cornell-diacaustic", "-D", define, "-q", "-o", str(tmp_path / "x.exr")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert f"cornell-diacaustic.xml: -D {define}: " in err, err
    assert "the scene's parameters: max_depth, res, spp" in err and not list(tmp_path.iterdir()), err


def test_integrator_note_says_what_caustica_does_with_the_scenes_integrator(tmp_path):
    d = load_strict(tmp_path, '<integrator type="bdpt"><integer name="max_depth" value="8"/></integrator>')
    assert d.integrator == "bdpt" and d.integrator_source.endswith("bad-scene.xml:4")
    note = d.integrator_note("spm", {})
    assert note == f"integrator 'bdpt' in {d.integrator_source} is not used; the method is --method spm " \
                   f"('caustica methods' lists them)"
    assert d.integrator_note("pt", {"max_depth": 8}).startswith("integrator 'bdpt'")
    # Mitsuba's path is pt: a note only when pt runs with settings other than the file's
    d = load_strict(tmp_path, '<integrator type="path"><integer name="max_depth" value="5"/></integrator>')
    assert d.integrator_note("pt", {"max_depth": 5, "rr_depth": 5}) is None
    assert d.integrator_note("spm", {"max_bounces": 4, "max_depth": 5, "hide_emitters": False}) is None
    note = d.integrator_note("spm", {"max_bounces": 4})   # a method without the depth settings
    assert note.endswith("asks for max_depth=5; --method spm renders with max_depth -1 (the method does not read "
                         "the file's)"), note
    note = d.integrator_note("pt", {"max_depth": -1, "rr_depth": 5})
    assert "asks for max_depth=5; pt runs with max_depth=-1 (a setting given to pt wins" in note, note
    assert load_strict(tmp_path, '<integrator type="path"/>').integrator_note("spm", {}) is None
    # the photon methods take max_depth: a note only when one runs with another (a value given wins)
    assert d.integrator_note("sppm", {"max_depth": 5, "hide_emitters": False}) is None
    note = d.integrator_note("sppm", {"max_depth": 3, "hide_emitters": False})
    assert "asks for max_depth=5; --method sppm renders with max_depth 3 (a value given wins over the file's" \
        in note, note
    # no <integrator>: nothing to say
    assert load_strict(tmp_path, "").integrator_note("pt", {}) is None
    assert load_scene_description("cornell-diacaustic").integrator_note("pt", {"max_depth": -1}) is None


@pytest.mark.parametrize("integrator, expect", [
    ('<integrator type="path"><integer name="max_depth" value="2"/><integer name="rr_depth" value="3"/>'
     '</integrator>', {"max_depth": 2, "rr_depth": 3}),
    ('<integrator type="moment"><integrator type="volpath"><integer name="max_depth" value="3"/></integrator>'
     '</integrator>', {"max_depth": 3, "rr_depth": 5}),
    # volpathmis (spectral MIS) has volpath's expectation and settings: a published scene asking for max_depth 6
    # rendered 14 % too bright when pt bounced on (tests/scenes/participating_media, docs/scenes.md)
    ('<integrator type="moment"><integrator type="volpathmis"><integer name="max_depth" value="6"/>'
     '<integer name="rr_depth" value="4"/></integrator></integrator>', {"max_depth": 6, "rr_depth": 4}),
    ('<integrator type="direct"/>', {"max_depth": 2, "rr_depth": 5}),
    ('<integrator type="bdpt"><integer name="max_depth" value="3"/></integrator>', {"max_depth": -1, "rr_depth": 5}),
    ("", {"max_depth": -1, "rr_depth": 5}),
])
def test_pt_takes_the_depths_of_the_scenes_integrator(tmp_path, integrator, expect):
    """pt renders Mitsuba's path / volpath / direct image: their max_depth and rr_depth are its defaults
    (a file asking for max_depth 2 rendered 4.6 % too bright when pt bounced on), a value given wins;
    other integrators' settings are not pt's."""
    import caustica
    path = tmp_path / "s.xml"
    path.write_text(scene(integrator + '\n<emitter type="point"><point name="position" value="0, 0, 3"/></emitter>\n'
                          + RECT.format("")))
    r = caustica.render(str(path), "pt", res=4, spp=1, threads=1)
    assert {k: r.stats["parameters"][k] for k in expect} == expect, r.stats["parameters"]
    assert caustica.render(str(path), "pt", res=4, spp=1, threads=1, max_depth=7).stats["parameters"]["max_depth"] == 7
    if "volpath" in integrator:   # what the file asks is what pt does: no note
        assert r.stats["integrator_note"] is None, r.stats["integrator_note"]


@pytest.mark.parametrize("method, budget", [("pt", {"spp": 1}), ("sppm", {"passes": 1}), ("pspm", {"passes": 1})])
def test_a_scene_asking_for_max_depth_0_is_refused(tmp_path, method, budget):
    import caustica
    path = tmp_path / "s.xml"
    path.write_text(scene('<integrator type="path"><integer name="max_depth" value="0"/></integrator>\n'
                          '<emitter type="point"><point name="position" value="0, 0, 3"/></emitter>\n' + RECT.format("")))
    with pytest.raises(caustica.errors.ParameterError, match=r"s\.xml:\d+: max_depth 0 renders nothing"):
        caustica.render(str(path), method, res=4, threads=1, **budget)


def test_cli_notes_an_unused_integrator_before_rendering(tmp_path, capsys):
    from caustica.cli import main
    path = tmp_path / "bdpt.xml"
    path.write_text(scene('<integrator type="bdpt"/>\n' + RECT.format('<emitter type="area"/>')))
    # --res 0 is refused when the render starts: the note comes first, on its own line
    code = main(["render", str(path), "--method", "pm", "--res", "0", "-q", "-o", str(tmp_path / "x.exr")])
    err = capsys.readouterr().err.splitlines()
    assert code == 2 and len(err) == 2, err
    assert err[0] == f"caustica: note: integrator 'bdpt' in {path}:5 is not used; the method is --method pm " \
                     f"('caustica methods' lists them)"
    assert err[1].startswith("caustica: error: --res"), err


def test_render_records_the_integrator_note(tmp_path):
    import caustica
    path = tmp_path / "bdpt.xml"
    path.write_text(scene('<integrator type="bdpt"/>\n<emitter type="point"><point name="position" value="0, 0, 3"/>'
                          '</emitter>\n' + RECT.format("")))
    result = caustica.render(str(path), "pt", res=4, spp=1, threads=1)
    assert result.stats["integrator_note"].startswith(f"integrator 'bdpt' in {path}:5 is not used")
    assert caustica.render("cornell-diacaustic", "pt", res=4, spp=1, threads=1).stats["integrator_note"] is None


def test_film_too_large_for_memory_names_the_film(tmp_path, monkeypatch):
    """A film too large for memory said "lower --res" without naming the file and line."""
    import caustica
    from caustica import memory
    from caustica.errors import ParameterError
    path = tmp_path / "big-film.xml"
    path.write_text(scene(RECT.format('<emitter type="area"/>'),
                          '<sensor type="perspective"><float name="fov" value="45"/>\n'
                          + FILM.format('<integer name="width" value="1000"/><integer name="height" value="1000"/>')
                          + "</sensor>"))
    loaded = caustica.load_scene(str(path))
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 10_000_000)
    with pytest.raises(ParameterError) as e:
        caustica.api.resolve_settings(loaded, "pt")
    msg = str(e.value)
    assert msg.startswith(f"{path}:4: <film>: a 1000x1000 image would need about") and "pass --res" in msg, msg
    with pytest.raises(ParameterError) as e:
        caustica.api.resolve_settings(loaded, "pt", res="900x900")
    assert str(e.value).startswith("a 900x900 image") and str(e.value).endswith("lower --res"), str(e.value)
    assert caustica.api.resolve_settings(loaded, "pt", res=16)[2]["width"] == 16


def test_emitted_power_beyond_float32_is_an_error(tmp_path):
    """Radiance and size each within float32, their product not: photon powers would be infinite."""
    from caustica.tables import compile_scene
    d = load_strict(tmp_path, RECT.format('<emitter type="area"/>') + "\n"
                    + '<shape type="sphere"><float name="radius" value="1e10"/>\n'
                      '<emitter type="area"><rgb name="radiance" value="1e20"/></emitter></shape>')
    with pytest.raises(SceneError) as e:
        compile_scene(d)
    msg = str(e.value)
    assert msg.startswith(f"{d.source}:5: the emitter's power (pi x radiance x area) is 3.95e+41 W"), msg
    d = load_strict(tmp_path, RECT.format("")
                    + '\n<emitter type="point"><rgb name="intensity" value="1e38"/></emitter>')
    with pytest.raises(SceneError, match=r"bad-scene.xml:5: the emitter's power \(4 pi x intensity\)"):
        compile_scene(d)
    d = load_strict(tmp_path, RECT.format('<emitter type="area"><rgb name="radiance" value="1e30"/></emitter>'))
    assert compile_scene(d).lights.power.max() == pytest.approx(4e30 * math.pi)


@pytest.mark.parametrize("chunk", [1 << 20, 1])
def test_a_mirrored_mesh_with_vertex_normals_faces_the_normals_side(monkeypatch, chunk):
    """A mirroring to_world turns a triangle's winding but not its (inverse-transposed) vertex normals; Mitsuba
    evaluates the BSDF in the shading frame, so the lit side is the normals' (its various_shapes test scene: three
    mirrored rectangle meshes, black in caustica before 2026-12-06).  to_world_mesh turns such triangles back, in
    chunks of any size; a mesh without normals keeps its mirrored winding (the geometric normal is all Mitsuba has)."""
    import numpy as np
    from caustica.scene import meshes
    monkeypatch.setattr(meshes, "_WINDING_CHUNK", chunk)
    positions = np.array([[-1.0, 0.0, -1.0], [-1.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 0.0, -1.0]])
    triangles = np.array([[0, 1, 2], [0, 2, 3]])
    mirror = np.diag([-0.5, -0.5, -0.5, 1.0])

    def winding(mesh):
        p = mesh.positions[mesh.triangles]
        return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 1]

    lit = meshes.to_world_mesh(meshes.Mesh(positions, triangles, np.tile([0.0, 1.0, 0.0], (4, 1)), None, None), mirror)
    assert np.all(lit.normals[:, 1] < 0) and np.all(winding(lit) < 0)
    bare = meshes.to_world_mesh(meshes.Mesh(positions, triangles, None, None, None), mirror)
    assert np.all(winding(bare) > 0)
