"""Sensors other than the perspective pinhole: Mitsuba 3's orthographic sensor and thin lens.

1. Geometry: an orthographic camera's rays are parallel (along to_world's camera +z) and start on the
   near plane, inside [-1, 1] x [-1/aspect, 1/aspect] scaled by to_world.
2. Against Mitsuba 3 (``scalar_rgb``): tests/scenes/ortho.xml (a 32 x 24 film, a scaled view) rendered by
   ``pt`` and by Mitsuba's path integrator, block by block within the noise of both (tests/imagestats.py).
3. Bad input: a zero scale (a flat view) is one line naming the file and line (the loader's transform check).
4. Thin lens: the rays of one film position through every point of the lens meet on the plane in focus;
   tests/scenes/thinlens.xml against Mitsuba 3 as in 2; a scaled to_world is refused as Mitsuba refuses it.
"""
from __future__ import annotations

import numpy as np
import pytest

import caustica
from caustica.camera import generate_ray
from caustica.jit import borrowed, kernel
from imagestats import assert_images_agree


@kernel
def rays_of(cam, n, out):
    """Rays at n x n film positions of pixel-centred uniforms: out[i] = (origin xyz, direction xyz)."""
    cam = borrowed(cam)
    k = 0
    for j in range(n):
        for i in range(n):
            o, d = generate_ray(cam, (i * cam.width) // n, (j * cam.height) // n, 0.5, 0.5, np.uint64(k))
            out[k, 0], out[k, 1], out[k, 2] = o
            out[k, 3], out[k, 4], out[k, 5] = d
            k += 1


def test_orthographic_rays_are_parallel_from_the_scaled_near_plane(test_scenes_dir):
    scene = caustica.load_scene(test_scenes_dir / "ortho.xml")
    cam = scene.camera()
    assert cam.orthographic and (cam.width, cam.height) == (32, 24)
    out = np.zeros((64, 6))
    rays_of(cam, 8, out)
    view = np.array([0.0, -2.3, -6.0]) / np.linalg.norm([0.0, -2.3, -6.0])
    np.testing.assert_allclose(out[:, 3:], np.broadcast_to(view, (64, 3)), atol=1e-12)
    # origins, in the camera frame: x within 2.2 * [-1, 1], y within 2.2 * [-0.75, 0.75], on the near plane
    m = np.asarray(scene.description.camera.to_world)
    local = np.linalg.solve(m[:3, :3], (out[:, :3] - m[:3, 3]).T).T
    assert np.all(np.abs(local[:, 0]) <= 1.0) and np.all(np.abs(local[:, 1]) <= 0.75)
    assert local[:, 0].max() > 0.8 and local[:, 1].max() > 0.6
    np.testing.assert_allclose(local[:, 2], scene.description.camera.near_clip, atol=1e-12)


def test_orthographic_matches_mitsuba(mi, test_scenes_dir):
    """tests/scenes/ortho.xml: image mean within 2 %, every 4x4 block within 5 sigmas of both renders' noise."""
    path = test_scenes_dir / "ortho.xml"
    scene = caustica.load_scene(path)
    seeds = (1, 2, 3, 4)
    ours = [caustica.render(scene, "pt", spp=128, seed=s).image for s in seeds]
    theirs_scene = mi.load_file(str(path), spp=512)
    theirs = [np.array(mi.render(theirs_scene, spp=512, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    assert ours[0].shape == theirs[0].shape == (24, 32, 3)
    assert_images_agree(ours, theirs, label="orthographic")


def test_thin_lens_rays_of_one_film_position_meet_in_the_plane_in_focus(test_scenes_dir):
    scene = caustica.load_scene(test_scenes_dir / "thinlens.xml")
    cam = scene.camera()
    assert cam.aperture_radius == 0.25 and cam.focus_distance == 6.0
    out = np.zeros((64, 6))
    lens_rays(cam, 64, out)
    m = np.asarray(scene.description.camera.to_world)
    axis = m[:3, 2] / np.linalg.norm(m[:3, 2])
    o, d = out[:, :3], out[:, 3:]
    t = (6.0 - (o - m[:3, 3]) @ axis) / (d @ axis)     # to the plane at depth 6
    hits = o + t[:, None] * d
    assert np.ptp(hits, axis=0).max() < 1e-9, np.ptp(hits, axis=0)
    # the lens points (where the rays cross depth 0) spread over the disc of radius 0.25
    t0 = -((o - m[:3, 3]) @ axis) / (d @ axis)
    r = np.linalg.norm(o + t0[:, None] * d - m[:3, 3], axis=1)
    assert r.max() <= 0.25 + 1e-12 and r.max() > 0.15


@kernel
def lens_rays(cam, n, out):
    """n rays of pixel (10, 20)'s centre, with n sample keys: out[i] = (origin xyz, direction xyz)."""
    cam = borrowed(cam)
    for k in range(n):
        o, d = generate_ray(cam, 10, 20, 0.5, 0.5, np.uint64(1000 + k))
        out[k, 0], out[k, 1], out[k, 2] = o
        out[k, 3], out[k, 4], out[k, 5] = d


@pytest.mark.parametrize("focus", ["6", "3"])
def test_thin_lens_matches_mitsuba(mi, test_scenes_dir, focus):
    """tests/scenes/thinlens.xml in focus on the ball, then in front of it: block by block within the noise."""
    path = test_scenes_dir / "thinlens.xml"
    scene = caustica.load_scene(path, focus=focus)
    seeds = (1, 2, 3, 4)
    ours = [caustica.render(scene, "pt", spp=128, seed=s).image for s in seeds]
    theirs_scene = mi.load_file(str(path), spp=512, focus=float(focus))
    theirs = [np.array(mi.render(theirs_scene, spp=512, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    assert_images_agree(ours, theirs, label=f"thin lens, focus {focus}")


@pytest.mark.parametrize("sensor, message", [
    ('<sensor type="orthographic">\n<transform name="to_world"><scale x="0" y="1"/></transform>\n</sensor>',
     r'<transform name="to_world">: the transform is degenerate'),
    ('<sensor type="thinlens"><float name="aperture_radius" value="0.1"/>\n'
     '<transform name="to_world"><scale value="2"/></transform>\n</sensor>',
     r'<transform name="to_world">: a perspective sensor\'s to_world must not scale'),
], ids=["flat-orthographic", "scaled-thin-lens"])
def test_a_sensor_transform_mitsuba_refuses_is_refused(tmp_path, sensor, message):
    """A zero scale (a flat orthographic view) and a thin lens's scaling to_world: one error naming file and line."""
    from caustica.errors import SceneError
    path = tmp_path / "s.xml"
    path.write_text(f'<scene version="3.0.0">\n{sensor}\n<shape type="sphere"><emitter type="area"/></shape>\n'
                    f'</scene>\n')
    with pytest.raises(SceneError, match=r"s\.xml:3: " + message):
        caustica.load_scene(path)
