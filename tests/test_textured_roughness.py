"""Roughness given by a texture (Mitsuba 3's ``alpha``, ``alpha_u``, ``alpha_v`` of roughconductor and roughdielectric
as textures, read by their eval_1 at each surface point): the loader's rules, and pt against Mitsuba 3."""
from __future__ import annotations

import numpy as np
import pytest

import caustica
from caustica.errors import SceneError
from caustica.scene import load_scene_description
from imagestats import assert_images_agree

CHECKER = ('<texture name="{name}" type="checkerboard"><transform name="to_uv"><scale x="{s}" y="{s}"/></transform>'
           '<float name="color0" value="{a}"/><float name="color1" value="{b}"/></texture>')

SCENE = """<scene version="3.0.0">
    <integrator type="path"><integer name="max_depth" value="6"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="35"/>
        <transform name="to_world"><lookat origin="0, -4, 1.2" target="0, 0, 0.1" up="0, 0, 1"/></transform>
        <film type="hdrfilm"><integer name="width" value="32"/><integer name="height" value="32"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="0.3"/></emitter>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.4"/><translate x="1.5" y="-1" z="2"/></transform>
        <emitter type="area"><rgb name="radiance" value="30"/></emitter>
    </shape>
    <shape type="sphere">
        <point name="center" x="-0.55" y="0" z="0.1"/><float name="radius" value="0.5"/>
        {conductor}
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="0.45"/><rotate x="1" angle="70"/><translate x="0.55" y="0" z="0.1"/>
        </transform>
        {dielectric}
    </shape>
    <shape type="rectangle">
        <transform name="to_world"><scale value="3"/><translate z="-0.5"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.45, 0.4"/></bsdf>
    </shape>
</scene>
"""
CONDUCTOR = ('<bsdf type="roughconductor"><string name="material" value="Au"/><string name="distribution" '
             'value="{dist}"/>{alphas}</bsdf>')
DIELECTRIC = ('<bsdf type="roughdielectric"><string name="distribution" value="{dist}"/>'
              '<float name="int_ior" value="1.5"/>{alpha}</bsdf>')


def write(tmp_path, dist="beckmann", conductor=None, dielectric=None):
    alphas = (CHECKER.format(name="alpha_u", s=4, a=0.05, b=0.3) + CHECKER.format(name="alpha_v", s=4, a=0.3, b=0.05))
    conductor = conductor or CONDUCTOR.format(dist=dist, alphas=alphas)
    dielectric = dielectric or DIELECTRIC.format(dist=dist, alpha=CHECKER.format(name="alpha", s=3, a=0.0, b=0.4))
    path = tmp_path / "s.xml"
    path.write_text(SCENE.format(conductor=conductor, dielectric=dielectric))
    return path


def test_textures_reach_the_material_table(tmp_path):
    """alpha_u and alpha_v by two textures (anisotropic), alpha by one texture giving both."""
    scene = caustica.load_scene(write(tmp_path))
    mats = scene.materials
    rows = [i for i in range(len(mats.kind)) if mats.param_texture[i, 0] >= 0]
    assert len(rows) == 2
    pairs = sorted(tuple(mats.param_texture[i, :2]) for i in rows)
    assert pairs[0][0] != pairs[0][1] or pairs[1][0] != pairs[1][1]      # the conductor's two textures
    assert any(a == b for a, b in pairs)                                  # the dielectric's one


@pytest.mark.parametrize("conductor, words", [
    (CONDUCTOR.format(dist="ggx", alphas=CHECKER.format(name="alpha_u", s=1, a=0.1, b=0.2)), ["alpha_u", "together"]),
    (CONDUCTOR.format(dist="ggx", alphas=CHECKER.format(name="alpha", s=1, a=0.1, b=0.2)
                      + '<float name="alpha_u" value="0.1"/><float name="alpha_v" value="0.2"/>'), ["either alpha"]),
])
def test_bad_textured_roughness_is_refused(tmp_path, conductor, words):
    with pytest.raises(SceneError) as exc:
        load_scene_description(str(write(tmp_path, conductor=conductor)))
    for w in words:
        assert w in str(exc.value), (w, str(exc.value))


@pytest.mark.parametrize("dist", ["beckmann", "ggx"])
def test_textured_roughness_renders_as_mitsuba(tmp_path, mi, dist):
    """A gold sphere with checkered anisotropic roughness (alpha_u and alpha_v swapped between the checks) and a
    rough glass pane whose roughness is checkered between 0 (Mitsuba's clamp, 1e-4) and 0.4, under a small light and
    a constant sky: pt against Mitsuba's path tracer, four seeds each, 32 px."""
    path = write(tmp_path, dist)
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=256, seed=s).image for s in range(4)]
    ms = mi.load_file(str(path))
    theirs = [np.array(mi.render(ms, spp=256, seed=s), dtype=np.float32)[..., :3] for s in range(4)]
    assert_images_agree(ours, theirs, label=f"textured roughness, {dist}")
