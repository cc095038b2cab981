"""Curve shapes (Mitsuba 3's ``linearcurve`` and ``bsplinecurve``), tessellated by caustica.scene.curves: the file
format and its errors, the tube's geometry against the analytic swept sphere, and renders against Mitsuba 3."""
from __future__ import annotations

import math

import numpy as np
import pytest

import caustica
from caustica.errors import SceneError
from caustica.scene.curves import SIDES, curve_mesh, read_curves
from imagestats import assert_images_agree

#: Mitsuba's documentation curve (common/meshes/curve_doc.txt of mitsuba-data): a zigzag of constant radius.
ZIGZAG = "-1 0 -1 0.1\n-0.5 0 1 0.1\n-0.25 0 -1 0.1\n0 0 1 0.1\n0.25 0 -1 0.1\n0.5 0 1 0.1\n1 0 -1 0.1\n"
#: A second curve, its radius growing from 0 and falling back to 0.
TAPERED = "\n-1 0.5 0 0.0\n-0.5 0.5 0.3 0.15\n0 0.6 0 0.2\n0.5 0.5 0.3 0.1\n1 0.5 0 0.0\n"

SCENE = """<scene version="3.0.0">
    <default name="spp" value="64"/>
    <integrator type="path"><integer name="max_depth" value="4"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -3.5, 1.5" target="0, 0, -0.1" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1.0"/></emitter>
    <shape type="KIND">
        <string name="filename" value="curves.txt"/>
        <transform name="to_world"><rotate z="1" angle="ANGLE"/><scale value="1.2"/></transform>
        <bsdf type="twosided"><bsdf type="diffuse">
            <texture name="reflectance" type="checkerboard">
                <transform name="to_uv"><scale x="2" y="10"/></transform>
            </texture>
        </bsdf></bsdf>
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="3"/><translate z="-1.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.3, 0.4, 0.5"/></bsdf>
    </shape>
</scene>
"""


def write_curves(tmp_path, text, name="curves.txt"):
    path = tmp_path / name
    path.write_text(text)
    return path


def mesh_area(mesh):
    p, t = mesh.positions, mesh.triangles
    return 0.5 * np.linalg.norm(np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]]), axis=1).sum()


def polygon_factor():
    """A ring of SIDES facets inscribed in a circle: its perimeter over the circle's."""
    return SIDES * math.sin(math.pi / SIDES) / math.pi


def test_file_format_curves_and_points(tmp_path):
    curves = read_curves(write_curves(tmp_path, "  \n" + ZIGZAG + TAPERED + "\n\n"), "bsplinecurve")
    assert [c.shape for c in curves] == [(7, 4), (5, 4)]
    assert curves[1][2].tolist() == [0.0, 0.6, 0.0, 0.2]


def test_straight_tubes_have_the_swept_spheres_area(tmp_path):
    """A straight curve of constant radius r and length L: a tube of area 2 pi r L (times the facets' perimeter
    factor); a linear curve adds two end spheres of area 4 pi r^2 (the joint between collinear segments adds a
    sphere inside the tube, whose area the sum counts but no ray sees)."""
    r, length = 0.2, 3.0
    pts = "\n".join(f"{x} 1 2 {r}" for x in np.linspace(-1.5, 1.5, 4)) + "\n"
    path = write_curves(tmp_path, pts)
    # the B-spline of equally spaced collinear points runs from the second point's sixth-way mark: length L * 2 / 3
    b = curve_mesh(read_curves(path, "bsplinecurve"), "bsplinecurve", None)
    assert mesh_area(b) == pytest.approx(2 * math.pi * r * length / 3 * polygon_factor(), rel=1e-9)
    lin = curve_mesh(read_curves(path, "linearcurve"), "linearcurve", None)
    spheres = 4 * 4 * math.pi * r * r          # one per control point
    assert mesh_area(lin) == pytest.approx(2 * math.pi * r * length * polygon_factor() + spheres, rel=0.02)


def test_tapered_segment_lies_on_the_swept_spheres_envelope(tmp_path):
    """A linear segment whose radius grows: every vertex is at distance r(s) from the centre c(s) of the sphere it
    touches, along its normal, and the normals are unit; the winding agrees with the normals."""
    path = write_curves(tmp_path, "0 0 0 0.1\n2 0 0 0.5\n")
    mesh = curve_mesh(read_curves(path, "linearcurve"), "linearcurve", None)
    p, n, t = mesh.positions, mesh.normals, mesh.triangles
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0)
    tube = slice(0, 2 * (SIDES + 1))                 # the segment's two rings come first
    # the sphere centre each tube vertex touches: p - r n, on the axis, with r interpolated there
    centre = p[tube] - 0.1 * n[tube]
    first = slice(0, SIDES + 1)
    assert np.allclose(centre[first], 0.0, atol=1e-12)
    end = p[SIDES + 1:2 * (SIDES + 1)] - 0.5 * n[SIDES + 1:2 * (SIDES + 1)]
    assert np.allclose(end, [2.0, 0.0, 0.0], atol=1e-12)
    g = np.cross(p[t[:, 1]] - p[t[:, 0]], p[t[:, 2]] - p[t[:, 0]])
    big = np.linalg.norm(g, axis=1) > 1e-12
    assert np.all(np.einsum("ij,ij->i", g[big], n[t[big]].mean(axis=1)) > 0)


@pytest.mark.parametrize("text, words", [
    ("0 0 0\n1 1 1 0.1\n", ["line 1", "four numbers"]),
    ("0 0 0 0.1\n1 1 1 -0.1\n2 2 2 0.1\n3 3 3 0.1\n", ["line 2", "radius must be >= 0"]),
    ("0 0 0 0.1\n1 1 1 nan\n2 2 2 0.1\n3 3 3 0.1\n", ["line 2", "finite"]),
    ("0 0 0 0.1\n1 1 1 0.1\n\n2 2 2 0.1\n", ["line 1", "at least 4"]),
    ("\n\n", ["no control points"]),
])
def test_bad_curve_files_are_refused(tmp_path, text, words):
    with pytest.raises(SceneError) as exc:
        read_curves(write_curves(tmp_path, text), "bsplinecurve")
    for w in words:
        assert w in str(exc.value), (w, str(exc.value))


def test_bad_curve_scene_is_one_line_exit_2(tmp_path, cli):
    write_curves(tmp_path, "0 0 0 0.1\n1 x 1 0.1\n")
    scene = tmp_path / "s.xml"
    scene.write_text(SCENE.replace("KIND", "linearcurve").replace("ANGLE", "0"))
    code, _, err = cli("render", str(scene), "-o", str(tmp_path / "o.exr"), "--spp", "1", "--res", "8")
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert "curves.txt" in err and "line 2" in err and f"{scene}:" in err, err
    (tmp_path / "curves.txt").unlink()
    code, _, err = cli("render", str(scene), "-o", str(tmp_path / "o.exr"), "--spp", "1", "--res", "8")
    assert code == 2 and err.count("\n") == 1 and "curves.txt" in err, err


@pytest.mark.parametrize("kind, text, angle", [("bsplinecurve", ZIGZAG + TAPERED, 0),
                                               ("linearcurve", ZIGZAG + TAPERED, 20)])
def test_curves_render_as_mitsuba_renders_them(tmp_path, mi, kind, text, angle):
    """pt against Mitsuba 3's path tracer on textured curves over a floor under a constant sky, 32 px, four seeds
    each.  The B-splines' open ends face sideways (angle 0): Mitsuba sees through an open end (it culls a curve's
    back faces) where the mesh shows the tube's inside (caustica.scene.curves), so a view into one differs; at 20
    degrees the zigzag's first end faces the camera and one 4 x 4 block measured 0.49 against Mitsuba's 0.59."""
    write_curves(tmp_path, text)
    path = tmp_path / "s.xml"
    path.write_text(SCENE.replace("KIND", kind).replace("ANGLE", str(angle)))
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=64, seed=s).image for s in range(4)]
    ms = mi.load_file(str(path))
    theirs = [np.array(mi.render(ms, spp=64, seed=s), dtype=np.float32)[..., :3] for s in range(4)]
    assert_images_agree(ours, theirs, label=kind)
