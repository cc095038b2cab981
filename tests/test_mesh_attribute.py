"""Mitsuba 3's ``mesh_attribute`` texture (bsdfs/textures.py: attribute_rgb; scene/meshes.py: ply_attributes).

1. PLY properties become Mitsuba's attributes: names (r g b -> vertex_color, name_0 -> vertex_name,
   name_r name_g name_b -> vertex_name_color), uchar kept as 0..255, other integers scaled and sRGB-decoded
   (measured with Mitsuba 3.9.1).
2. Texture values at many hits against Mitsuba's ``texture.eval(si)`` (si from ``scene.ray_intersect``): a vertex
   colour (barycentric), a face colour, a one-channel face weight (grey), with to_world, flip_normals and a scale.
3. A small scene (a vertex-coloured diffuse mesh and a blend weighted by a face attribute, under an area light):
   pt and sppm against Mitsuba's path tracer (tests/imagestats.py).
4. Bad input: an attribute the mesh lacks, a mesh_attribute on a sphere, a 4-channel (rgba) colour -> one line,
   exit 2.
"""
from __future__ import annotations

import struct

import numpy as np
import pytest
from imagestats import assert_images_agree

import caustica
from caustica.bsdfs import textures
from caustica.geometry.scene_geometry import intersect, surface_uv
from caustica.jit import borrowed, kernel
from caustica.scene.meshes import load_mesh_file


def grid_ply(path, n=4, seed=3, alpha=False):
    """A binary PLY: an n x n grid of quads in [-1, 1]^2 (z = 0) cut into triangles, with float vertex colours
    (r g b [a]), a float face colour (color_0..2), a face weight (weight_0) and a uchar vertex property (k_0)."""
    rng = np.random.default_rng(seed)
    xs = np.linspace(-1.0, 1.0, n + 1)
    verts = [(x, y, 0.0) for y in xs for x in xs]
    tris = []
    for j in range(n):
        for i in range(n):
            a, b, c, d = j * (n + 1) + i, j * (n + 1) + i + 1, (j + 1) * (n + 1) + i + 1, (j + 1) * (n + 1) + i
            tris += [(a, b, c), (a, c, d)]
    vc = rng.uniform(0.05, 0.95, size=(len(verts), 4 if alpha else 3))
    fc = rng.uniform(0.05, 0.95, size=(len(tris), 3))
    fw = rng.uniform(0.0, 1.0, size=len(tris))
    k = rng.integers(0, 256, size=len(verts))
    chans = "rgba" if alpha else "rgb"
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(verts)}",
            *[f"property float {c}" for c in "xyz"], *[f"property float {c}" for c in chans], "property uchar k_0",
            f"element face {len(tris)}", "property list uchar int vertex_indices",
            *[f"property float color_{i}" for i in range(3)], "property float weight_0", "end_header"]
    body = b"".join(struct.pack(f"<3f{len(chans)}fB", *v, *c, int(kk)) for v, c, kk in zip(verts, vc, k))
    body += b"".join(struct.pack("<B3i4f", 3, *t, *c, w) for t, c, w in zip(tris, fc, fw))
    path.write_bytes(("\n".join(head) + "\n").encode() + body)
    return path


def test_ply_properties_become_mitsubas_attributes(tmp_path):
    mesh = load_mesh_file(grid_ply(tmp_path / "g.ply", n=2))
    assert sorted(mesh.attributes) == ["face_color", "face_weight", "vertex_color", "vertex_k"]
    assert mesh.attributes["vertex_color"].shape == (9, 3) and mesh.attributes["face_weight"].shape == (8, 1)
    assert mesh.attributes["vertex_k"].max() > 1.0          # uchar: 0..255, as Mitsuba 3.9 keeps it
    (tmp_path / "i.ply").write_text(
        "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
        "property ushort q_r\nproperty ushort q_g\nproperty ushort q_b\nproperty short s_0\n"
        "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
        "0 0 0 30000 0 65535 -32767\n1 0 0 0 0 0 100\n0 1 0 0 0 0 32767\n3 0 1 2\n")
    a = load_mesh_file(tmp_path / "i.ply").attributes
    # Mitsuba 3.9.1: a ushort 30000 reads 0.17701484, a short 100 0.00023621137, -32767 -0.07739938
    np.testing.assert_allclose(a["vertex_q_color"][0], [0.17701484, 0.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(a["vertex_s"][:, 0], [-0.07739938, 0.00023621137, 1.0], rtol=1e-6)


# --------------------------------------------------------------------------- 2. values against Mitsuba

@kernel
def colours_at(geom, mats, origins, dirs, out):
    """out[i] = (hit?, RGB of the hit's material colour) for ray i."""
    geom, mats = borrowed(geom), borrowed(mats)
    for i in range(origins.shape[0]):
        o = (origins[i, 0], origins[i, 1], origins[i, 2])
        d = (dirs[i, 0], dirs[i, 1], dirs[i, 2])
        prim, t, b1, b2 = intersect(geom, o, d, np.inf)
        if prim >= 0:
            c = textures.colour(mats, geom.prim_material[prim], surface_uv(geom, prim, o, d, t, b1, b2))
            out[i, 0], out[i, 1], out[i, 2], out[i, 3] = 1.0, c[0], c[1], c[2]


@pytest.mark.parametrize("name,scale", [("vertex_color", 1.0), ("face_color", 0.7), ("face_weight", 1.0),
                                        ("vertex_k", 0.002)])
def test_values_match_mitsuba(mi, tmp_path, name, scale):
    grid_ply(tmp_path / "g.ply")
    xml = f'''<scene version="3.0.0">
<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
</film></sensor>
<shape type="ply"><string name="filename" value="g.ply"/><boolean name="flip_normals" value="true"/>
  <transform name="to_world"><rotate x="1" angle="30"/><scale x="1.5"/><translate z="0.2"/></transform>
  <bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance">
    <string name="name" value="{name}"/><float name="scale" value="{scale}"/></texture></bsdf></shape>
<emitter type="point"><point name="position" x="0" y="0" z="50"/></emitter>
</scene>'''
    (tmp_path / "s.xml").write_text(xml)
    scene = caustica.load_scene(tmp_path / "s.xml")
    geom, mats = scene.tables[0], scene.tables[1]
    theirs = mi.load_string(xml.replace('value="g.ply"', f'value="{tmp_path / "g.ply"}"'))
    tex = mi.load_dict({"type": "mesh_attribute", "name": name, "scale": scale})
    rng = np.random.default_rng(5)
    n = 300
    targets = np.column_stack([rng.uniform(-1.4, 1.4, n), rng.uniform(-0.9, 0.9, n), np.full(n, 0.2)])
    origins = targets + rng.normal(size=(n, 3)) * [0.5, 0.5, 0.0] + [0.0, 0.0, 4.0]
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ours = np.zeros((n, 4))
    colours_at(geom, mats, origins, dirs, ours)
    hits = 0
    for i in range(n):
        si = theirs.ray_intersect(mi.Ray3f(mi.Point3f(*origins[i]), mi.Vector3f(*dirs[i])))
        assert ours[i, 0] == float(si.is_valid())
        if si.is_valid():
            hits += 1
            np.testing.assert_allclose(ours[i, 1:], np.array(tex.eval(si)), rtol=1e-5, atol=1e-6)
    assert hits > 150


# --------------------------------------------------------------------------- 3. renders against Mitsuba

def attribute_scene(tmp_path) -> str:
    grid_ply(tmp_path / "g.ply", n=3)
    return f'''<scene version="3.0.0">
<integrator type="path"/>
<sensor type="perspective"><float name="fov" value="45"/>
  <transform name="to_world"><lookat origin="0, -3.2, 3.2" target="0, 0, 0.2" up="0, 0, 1"/></transform>
  <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
  <rfilter type="box"/></film></sensor>
<shape type="ply"><string name="filename" value="{tmp_path / "g.ply"}"/>
  <transform name="to_world"><scale value="1.5"/></transform>
  <bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="vertex_color"/>
  </texture></bsdf></shape>
<shape type="ply"><string name="filename" value="{tmp_path / "g.ply"}"/>
  <transform name="to_world"><scale value="0.5"/><rotate x="1" angle="70"/><translate x="0.3" y="0.4" z="0.6"/>
  </transform>
  <bsdf type="blendbsdf"><texture type="mesh_attribute" name="weight">
    <string name="name" value="face_weight"/></texture>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.1, 0.6, 0.7"/></bsdf>
    <bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="face_color"/>
    </texture></bsdf></bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="180"/>
  <translate z="2.5"/></transform><emitter type="area"><rgb name="radiance" value="15"/></emitter></shape>
</scene>'''


SEEDS = (1, 2, 3, 4)


@pytest.fixture(scope="module")
def mitsuba_attribute(mi, tmp_path_factory):
    folder = tmp_path_factory.mktemp("attr")
    path = folder / "attr.xml"
    path.write_text(attribute_scene(folder))
    theirs = mi.load_file(str(path))
    return path, [np.array(mi.render(theirs, spp=512, seed=s), dtype=np.float32)[..., :3] for s in SEEDS]


def test_attribute_scene_pt_matches_mitsuba(mitsuba_attribute):
    path, theirs = mitsuba_attribute
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=128, res=32, seed=s).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="mesh_attribute scene, pt")


def test_attribute_scene_sppm_matches_mitsuba(mitsuba_attribute):
    path, theirs = mitsuba_attribute
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "sppm", passes=128, res=32, seed=s, max_bounces=64, termination="roulette",
                            photons=2000).image for s in SEEDS]
    assert_images_agree(ours, theirs, label="mesh_attribute scene, sppm")


# --------------------------------------------------------------------------- 4. bad input

@pytest.mark.parametrize("shape,name,words", [
    ('<shape type="ply"><string name="filename" value="g.ply"/>', "vertex_weight",
     ("no attribute", "vertex_weight", "vertex_color")),
    ('<shape type="sphere">', "vertex_color", ("sphere", "no mesh")),
    ('<shape type="ply"><string name="filename" value="a.ply"/>', "vertex_color", ("4 channels", "3 or 1")),
    ('<shape type="ply"><string name="filename" value="g.ply"/>', "color", ("vertex_", "face_")),
])
def test_bad_mesh_attributes_are_one_line(cli, tmp_path, shape, name, words):
    grid_ply(tmp_path / "g.ply", n=1)
    grid_ply(tmp_path / "a.ply", n=1, alpha=True)
    xml = tmp_path / "s.xml"
    xml.write_text(f'''<scene version="3.0.0"><sensor type="perspective"/>
{shape}<bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="{name}"/>
</texture></bsdf></shape><emitter type="point"><point name="position" x="0" y="0" z="50"/></emitter>
</scene>''')
    code, _, err = cli("render", xml, "--res", "8", "-q", "-o", tmp_path / "out" / "x.exr")
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("caustica: error: "), err
    assert "s.xml:" in lines[0]
    for w in words:
        assert w in lines[0], (w, lines[0])


def test_shared_and_instanced_meshes_keep_their_attributes(mi, tmp_path):
    """One BSDF shared by two shapes of the same file, and the mesh placed by two instances (one mirrored, which
    reverses its triangles' winding): the values at hits against Mitsuba's."""
    grid_ply(tmp_path / "g.ply")
    xml = f'''<scene version="3.0.0">
<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/>
</film></sensor>
<bsdf type="diffuse" id="shared"><texture type="mesh_attribute" name="reflectance">
  <string name="name" value="vertex_color"/></texture></bsdf>
<shape type="ply"><string name="filename" value="{tmp_path / "g.ply"}"/><ref id="shared"/>
  <transform name="to_world"><scale value="0.5"/><translate x="-1" y="1"/></transform></shape>
<shape type="ply"><string name="filename" value="{tmp_path / "g.ply"}"/><ref id="shared"/>
  <transform name="to_world"><scale value="0.5"/><rotate z="1" angle="40"/><translate x="1" y="1"/></transform></shape>
<shape type="shapegroup" id="group"><shape type="ply"><string name="filename" value="{tmp_path / "g.ply"}"/>
  <bsdf type="diffuse"><texture type="mesh_attribute" name="reflectance"><string name="name" value="face_color"/>
  </texture></bsdf></shape></shape>
<shape type="instance"><ref id="group"/><transform name="to_world"><scale value="0.5"/><translate x="-1" y="-1"/>
  </transform></shape>
<shape type="instance"><ref id="group"/><transform name="to_world"><scale x="-0.5" y="0.5" z="0.5"/>
  <translate x="1" y="-1"/></transform></shape>
<emitter type="point"><point name="position" x="0" y="0" z="50"/></emitter>
</scene>'''
    (tmp_path / "s.xml").write_text(xml)
    scene = caustica.load_scene(tmp_path / "s.xml")
    geom, mats = scene.tables[0], scene.tables[1]
    theirs = mi.load_string(xml)
    rng = np.random.default_rng(9)
    n = 400
    targets = np.column_stack([rng.uniform(-1.6, 1.6, n), rng.uniform(-1.6, 1.6, n), np.zeros(n)])
    origins = targets + rng.normal(size=(n, 3)) * [0.4, 0.4, 0.0] + [0.0, 0.0, 4.0]
    dirs = targets - origins
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    ours = np.zeros((n, 4))
    colours_at(geom, mats, origins, dirs, ours)
    hits = 0
    for i in range(n):
        si = theirs.ray_intersect(mi.Ray3f(mi.Point3f(*origins[i]), mi.Vector3f(*dirs[i])))
        assert ours[i, 0] == float(si.is_valid())
        if si.is_valid():
            hits += 1
            np.testing.assert_allclose(ours[i, 1:], np.array(si.bsdf().eval_diffuse_reflectance(si)),
                                       rtol=1e-5, atol=1e-6)
    assert hits > 100
