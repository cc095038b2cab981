"""Mitsuba 3's ``sdfgrid`` shape, tessellated at load by caustica.scene.sdfgrid: the mesh against the analytic
sphere it samples, its points and shading normals against Mitsuba's own ray intersections, renders against
Mitsuba 3, and the one-line refusals of what is not supported."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

import caustica
import caustica.scene.sdfgrid as sdfgrid
from caustica.errors import SceneError
from caustica.scene.meshes import to_world_mesh
from caustica.scene.sdfgrid import _sample, check_grid, sdf_mesh
from caustica.scene.volume_files import write_grid
from imagestats import assert_images_agree

SCENE = """<scene version="3.0.0">
    <default name="spp" value="64"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="35"/>
        <transform name="to_world"><lookat origin="0, -3.2, 2.2" target="0, 0, -0.2" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1.0"/></emitter>
    <emitter type="directional"><vector name="direction" value="1, 1, -2"/><rgb name="irradiance" value="3"/>
    </emitter>
    <shape type="sdfgrid">
        <string name="filename" value="grid.vol"/>
        <string name="normals" value="MODE"/>
        <transform name="to_world"><scale x="2.4" y="2.4" z="1.6"/><translate x="-1.2" y="-1.2" z="-0.9"/></transform>
        <bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.15"/></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="3"/><translate z="-0.9"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf>
    </shape>
</scene>
"""


def grid_points(nx, ny, nz):
    """Object-space coordinates (x, y, z) of the grid points, each (nz, ny, nx): the grid fills [0, 1]³."""
    z, y, x = np.meshgrid(np.linspace(0, 1, nz), np.linspace(0, 1, ny), np.linspace(0, 1, nx), indexing="ij")
    return x, y, z


def torus_grid(n=24):
    """A torus about z (major radius 0.3, minor 0.12, in the unit cube), its distance in object units."""
    x, y, z = grid_points(n, n, n)
    ring = np.hypot(x - 0.5, y - 0.5) - 0.3
    return np.hypot(ring, z - 0.5) - 0.12


def mesh_edges(t):
    e = np.sort(np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]]), axis=1)
    return np.unique(e, axis=0, return_counts=True)


@pytest.mark.parametrize("mode", ["smooth", "analytic"])
def test_sphere_grid_mesh_lies_on_the_sphere(mode):
    """A sphere's distance (centre c, radius r) sampled on a 17³ grid (spacing h = 1/16).  Every vertex is a zero
    of the trilinear interpolant F (to rounding), and F differs from the distance d by at most
    (h² / 8) * sum of |d_ii| <= 3 h² / (8 rho) where rho >= r - sqrt(3) h is the distance to c in the voxel; F's zero
    moves off d's by at most that over F's gradient, which is 1 (d's) within sqrt(3) h / rho.  Triangle centroids
    (convex combinations of vertices at most L apart) are at least sqrt(a² - L² / 3) from c when every vertex is at
    least a.  The mesh is closed with a sphere's topology, faces outward (its volume is positive), and its normals
    point away from c."""
    h, c, r = 1.0 / 16, np.array([0.5, 0.52, 0.47]), 0.3
    x, y, z = grid_points(17, 17, 17)
    f = np.sqrt((x - c[0]) ** 2 + (y - c[1]) ** 2 + (z - c[2]) ** 2) - r
    mesh = sdf_mesh(check_grid(f[..., None].astype(np.float32)), mode)
    p, t = mesh.positions, mesh.triangles
    F = check_grid(f[..., None].astype(np.float32))
    assert np.abs(_sample(F, p * 16)).max() < 1e-12
    rho = r - math.sqrt(3) * h
    delta = 3 * h * h / (8 * rho) / (1 - math.sqrt(3) * h / rho)
    dist = np.linalg.norm(p - c, axis=1)
    assert np.all(np.abs(dist - r) <= delta), (np.abs(dist - r).max(), delta)
    points, same = np.unique(p, axis=0, return_inverse=True)    # analytic: a vertex per voxel on voxel faces
    edges, counts = mesh_edges(same.reshape(-1)[t])
    assert np.all(counts == 2)                                   # closed
    length = np.linalg.norm(points[edges[:, 0]] - points[edges[:, 1]], axis=1).max()
    assert length <= math.sqrt(3) * h / sdfgrid.SUBDIVISIONS * (1 + 1e-9)      # inside one sub-cell
    centroid = np.linalg.norm(p[t].mean(axis=1) - c, axis=1)
    assert np.all(centroid >= math.sqrt((r - delta) ** 2 - length ** 2 / 3))
    assert len(points) - len(edges) + len(t) == 2               # a sphere's Euler characteristic
    a, b, cc = p[t[:, 0]] - c, p[t[:, 1]] - c, p[t[:, 2]] - c
    volume = np.einsum("ij,ij->i", a, np.cross(b, cc)).sum() / 6
    assert 4 / 3 * math.pi * (r - delta) ** 3 <= volume <= 4 / 3 * math.pi * (r + delta) ** 3
    radial = (p - c) / dist[:, None]
    n = mesh.normals / np.linalg.norm(mesh.normals, axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", n, radial) > 0.0)


def test_analytic_mode_splits_vertices_on_voxel_faces():
    """Analytic normals jump across voxel faces, so a vertex there is one per voxel (at the same point, with each
    voxel's gradient); smooth normals are continuous and share it."""
    f = check_grid(torus_grid(12)[..., None].astype(np.float32))
    smooth, analytic = sdf_mesh(f, "smooth"), sdf_mesh(f, "analytic")
    assert len(smooth.triangles) == len(analytic.triangles)
    assert len(analytic.positions) > len(smooth.positions)
    g = analytic.positions * 11
    on_face = np.any(np.abs(g - np.rint(g)) < 1e-9, axis=1)
    _, counts = np.unique(analytic.positions[on_face], axis=0, return_counts=True)
    assert counts.max() >= 2 and len(np.unique(analytic.positions, axis=0)) == len(smooth.positions)


@pytest.mark.parametrize("mode", ["smooth", "analytic"])
def test_points_and_normals_are_mitsubas(tmp_path, mi, mode):
    """Rays aimed at mesh vertices hit Mitsuba's sdfgrid there, and its shading normal is the vertex normal: an
    off-centre, lopsided field on a grid of 21 x 15 x 21 points (y differs: the axes' placement), scaled
    non-uniformly.  Mitsuba computes in float32 and stops its root search at 1e-5 of a voxel along the ray, so
    points agree within 2e-5 voxel and unit normals within 1e-5 (a few dozen float32 roundings of 6e-8).
    Vertices on voxel faces are left out: a ray crossing the surface exactly on a voxel face can pass through
    Mitsuba's surface (neither voxel's interval holds the root after rounding), a measure-zero set in a render."""
    nx, ny, nz = 21, 15, 21
    x, y, z = grid_points(nx, ny, nz)
    f = np.sqrt(((x - 0.45) / 0.35) ** 2 + ((y - 0.55) / 0.3) ** 2 + ((z - 0.5) / 0.25) ** 2) - 1.0 + 0.2 * x * y
    write_grid(tmp_path / "g.vol", f.astype(np.float32))
    m = np.array([[1.5, 0, 0, 0.2], [0, 1.0, 0, -0.1], [0, 0, 0.8, 0.3], [0, 0, 0, 1]])
    scene = mi.load_dict({"type": "scene", "s": {"type": "sdfgrid", "filename": str(tmp_path / "g.vol"),
                                                 "normals": mode, "to_world": mi.ScalarTransform4f(m)}})
    mesh = to_world_mesh(sdf_mesh(check_grid(f[..., None].astype(np.float32)), mode), m)
    res = np.array([nx - 1, ny - 1, nz - 1])
    g = (mesh.positions - m[:3, 3]) / np.diag(m)[:3] * res
    inner = np.nonzero(np.all(np.abs(g - np.rint(g)) > 1e-6, axis=1))[0]
    voxel = (np.diag(m)[:3] / res).max()
    for i in np.random.default_rng(0).choice(inner, 200, replace=False):
        p, n = mesh.positions[i], mesh.normals[i]
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*(p + 0.05 * n)), mi.Vector3f(*(-n))))
        assert si.is_valid(), i
        assert np.linalg.norm(np.array(si.p, np.float64) - p) < 2e-5 * voxel, i
        assert np.linalg.norm(np.array(si.sh_frame.n, np.float64) - n) < 1e-5, (i, np.array(si.sh_frame.n), n)


@pytest.mark.parametrize("mode", ["smooth", "analytic"])
def test_sdfgrid_renders_as_mitsuba_renders_it(tmp_path, mi, mode):
    """pt against Mitsuba 3's path tracer: a rough gold torus on a coarse grid (12³: the analytic normals show the
    voxels) scaled non-uniformly over a floor, under a sky and a sun, 32 px, 64 spp, four seeds each.  The check
    sees the normals: caustica's smooth torus against Mitsuba's analytic one differs (image means 0.815 vs 0.860)."""
    write_grid(tmp_path / "grid.vol", torus_grid(12).astype(np.float32))
    path = tmp_path / "s.xml"
    path.write_text(SCENE.replace("MODE", mode))
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=64, seed=s).image for s in range(4)]
    ms = mi.load_file(str(path))
    theirs = [np.array(mi.render(ms, spp=64, seed=s), dtype=np.float32)[..., :3] for s in range(4)]
    assert_images_agree(ours, theirs, label=mode)


def write_scene(tmp_path, shape_body: str, name="s.xml") -> str:
    path = tmp_path / name
    path.write_text(SCENE.split("    <shape type=\"sdfgrid\">")[0] + shape_body + "\n</scene>\n")
    return str(path)


SHAPE = """    <shape type="sdfgrid">
        <string name="filename" value="grid.vol"/>{extra}
    </shape>"""


@pytest.mark.parametrize("grid, extra, words", [
    ("truncated", "", ["grid.vol", "truncated"]),
    ("flat", "", ["grid.vol", "at least 2 grid points", "1 x 5 x 5"]),
    ("xz", "", ["grid.vol", "as many points along x as along z", "6 x 5 x 4"]),
    ("rgb", "", ["grid.vol", "3 channels", "sdfgrid"]),
    ("empty", "", ["grid.vol", "never change sign"]),
    ("ok", '\n        <string name="normals" value="flat"/>', ["unknown normals mode", "smooth, analytic"]),
    ("ok", '\n        <emitter type="area"><rgb name="radiance" value="1"/></emitter>', ["area emitter"]),
    ("ok", '\n        <boolean name="flip_normals" value="true"/>', ["flip_normals"]),
    ("ok", '\n        <bsdf type="roughconductor"><float name="alpha_u" value="0.1"/>'
           '<float name="alpha_v" value="0.3"/></bsdf>', ["anisotropic", "sdfgrid"]),
    ("missing", "", ["grid.vol", "not found"]),
])
def test_bad_sdfgrids_are_one_line_exit_2(tmp_path, cli, grid, extra, words):
    """What is not supported, or not a grid, is refused with one line naming the scene file, line and element."""
    vol = tmp_path / "grid.vol"
    if grid == "truncated":
        write_grid(vol, torus_grid(8).astype(np.float32))
        vol.write_bytes(vol.read_bytes()[:-10])
    elif grid == "flat":
        write_grid(vol, np.ones((5, 5, 1), np.float32))
    elif grid == "xz":
        write_grid(vol, torus_grid(6)[:4, :5, :6].astype(np.float32))
    elif grid == "rgb":
        write_grid(vol, np.stack([torus_grid(6)] * 3, axis=-1).astype(np.float32))
    elif grid == "empty":
        write_grid(vol, np.ones((4, 4, 4), np.float32))
    elif grid == "ok":
        write_grid(vol, torus_grid(8).astype(np.float32))
    scene = write_scene(tmp_path, SHAPE.format(extra=extra))
    code, _, err = cli("render", scene, "-o", str(tmp_path / "o.exr"), "--spp", "1", "--res", "8")
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert re.search(rf"{re.escape(scene)}:\d+: <(shape|string|emitter|boolean|bsdf)[ >]", err), err
    for w in words:
        assert w in err, (w, err)


def test_too_many_triangles_is_refused_with_the_estimate(tmp_path, monkeypatch):
    """A grid whose surface crosses more voxels than the triangle limit allows: refused before meshing, with the
    voxel count and the estimate."""
    write_grid(tmp_path / "grid.vol", torus_grid(24).astype(np.float32))
    monkeypatch.setattr(sdfgrid, "MAX_TRIANGLES", 1000)
    with pytest.raises(SceneError) as exc:
        caustica.load_scene(write_scene(tmp_path, SHAPE.format(extra="")))
    voxels = len(sdfgrid.occupied_voxels(check_grid(torus_grid(24)[..., None].astype(np.float32))))
    text = str(exc.value)
    assert "grid.vol" in text and f"{voxels:,} voxels" in text and \
        f"{sdfgrid.estimate_triangles(voxels):,} triangles" in text and "\n" not in text, text


def test_a_mesh_beyond_the_memory_budget_is_refused_with_the_estimate(monkeypatch):
    """On a machine with 10 MB (budget 60 %), the 24³ torus's estimated mesh (its crossed voxels x 16 x 8 triangles,
    BYTES_PER_TRIANGLE each) does not fit: refused before meshing, with the estimate in GB."""
    import caustica.memory
    monkeypatch.setattr(caustica.memory, "physical_memory_bytes", lambda: 10_000_000)
    f = check_grid(torus_grid(24)[..., None].astype(np.float32))
    voxels = len(sdfgrid.occupied_voxels(f))
    need = sdfgrid.estimate_triangles(voxels) * sdfgrid.BYTES_PER_TRIANGLE
    assert need > 6_000_000
    with pytest.raises(SceneError) as exc:
        sdf_mesh(f, what="sdf grid 'g.vol'")
    text = str(exc.value)
    assert text.startswith("sdf grid 'g.vol': its mesh") and f"{need / 1e9:.1f} GB" in text and "\n" not in text, text
