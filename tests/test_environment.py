"""Environment emitters (Mitsuba 3's ``constant`` and ``envmap``): loader, tables, and renders against
analytic values and Mitsuba 3."""
from __future__ import annotations

import math

import numpy as np
import pytest

from caustica.emitters import ENV, env_pdf, env_radiance, env_sample
from caustica.imageio import write_exr
from caustica.scene import load_scene_description
from caustica.tables import compile_scene

SENSOR = """<sensor type="perspective"><float name="fov" value="30"/>
  <transform name="to_world"><lookat origin="0,0,6" target="0,0,0" up="0,1,0"/></transform>
  <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
  <rfilter type="box"/></film></sensor>"""


def write_scene(tmp_path, body: str, name: str = "env.xml"):
    path = tmp_path / name
    path.write_text(f'<scene version="3.0.0">\n{SENSOR}\n<shape type="sphere"/>\n{body}\n</scene>\n')
    return path


def sun_map(path, h=16, w=32, sky=0.3, sun=200.0, at=(4, 9)):
    """A small lat-long map: a uniform bluish sky and one bright texel (a "sun")."""
    img = np.empty((h, w, 3), np.float32)
    img[:] = (0.6 * sky, 0.8 * sky, sky)
    img[at] = (sun, 0.9 * sun, 0.7 * sun)
    write_exr(path, img)
    return path


ENVMAP = ('<emitter type="envmap"><string name="filename" value="{f}"/><float name="scale" value="{s}"/>'
          '<transform name="to_world"><rotate y="1" angle="{a}"/></transform></emitter>')


@pytest.mark.parametrize("case, body, expected", [
    ("missing", '<emitter type="envmap"><string name="filename" value="nope.exr"/></emitter>',
     ":7: <string name=\"filename\">: environment map 'nope.exr' not found"),
    ("not an image", '<emitter type="envmap"><string name="filename" value="junk.png"/></emitter>',
     "not an image file"),
    ("negative scale", '<emitter type="envmap"><string name="filename" value="sky.exr"/>'
                       '<float name="scale" value="-1"/></emitter>', "'scale' must not be negative"),
    ("hdr", '<emitter type="envmap"><string name="filename" value="sky.hdr"/></emitter>', "'.hdr' images are not"),
    ("two", '<emitter type="constant"/>\n<emitter type="constant"/>', "only one environment emitter"),
])
def test_bad_environment_is_one_line_exit_2(tmp_path, capsys, case, body, expected):
    from caustica.cli import main
    (tmp_path / "junk.png").write_text("not a png")
    (tmp_path / "sky.hdr").write_text("#?RADIANCE\n")
    sun_map(tmp_path / "sky.exr")
    path = write_scene(tmp_path, body)
    code = main(["render", str(path), "--method", "pt", "-q", "-o", str(tmp_path / "x.exr")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("caustica: error: ") and err.count("\n") == 1, err
    assert str(path) in err and expected in err, err


def test_constant_and_envmap_are_read_into_the_light_table(tmp_path):
    scene = compile_scene(load_scene_description(str(write_scene(
        tmp_path, '<emitter type="constant"><rgb name="radiance" value="0.5, 1, 2"/></emitter>'))))
    lights = scene.lights
    assert list(lights.kind) == [ENV] and lights.env[0] == 0 and lights.env_constant[0] == 1
    r = lights.env_sphere[3]
    assert r == pytest.approx(math.sqrt(3), rel=1e-3)   # the unit sphere's box, as Mitsuba bounds it
    assert np.allclose(lights.power[0], np.pi * r * r * 4 * np.pi * np.array([0.5, 1, 2]))
    assert env_radiance(lights, (0.0, 1.0, 0.0)) == (0.5, 1.0, 2.0)

    sun_map(tmp_path / "sky.exr")
    scene = compile_scene(load_scene_description(str(write_scene(
        tmp_path, ENVMAP.format(f="sky.exr", s=2, a=30)))))
    assert scene.lights.env_constant[0] == 0 and scene.lights.env_image.shape == (16, 32, 3)
    assert scene.lights.env_image.max() == pytest.approx(400.0)   # scale applied


def test_envmap_lookup_matches_mitsuba_and_sampling_density_is_consistent(tmp_path, mi):
    """Mitsuba's own envmap (its eval) at random directions gives caustica's radiance (float32 precision);
    env_sample's density and radiance are env_pdf's and env_radiance's, and the density integrates to 1."""
    sun_map(tmp_path / "sky.exr")
    lights = compile_scene(load_scene_description(str(write_scene(
        tmp_path, ENVMAP.format(f="sky.exr", s=2, a=30))))).lights
    em = mi.load_dict({"type": "envmap", "filename": str(tmp_path / "sky.exr"), "scale": 2.0,
                       "to_world": mi.ScalarTransform4f().rotate([0, 1, 0], 30)})
    rng = np.random.default_rng(5)
    d = rng.normal(size=(4000, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    for x in d[:1500]:
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(-x)
        assert np.allclose(env_radiance(lights, tuple(x)), np.array(em.eval(si)), rtol=1e-4, atol=1e-5)
    pdf = np.array([env_pdf(lights, tuple(x)) for x in d])
    # uniform directions: E[pdf] 4π = 1, within 5 standard errors
    est = pdf * 4 * np.pi
    assert abs(est.mean() - 1.0) < 5 * est.std() / math.sqrt(len(est))
    for u in rng.random((500, 2)):
        w, p, rad = env_sample(lights, u[0], u[1])
        assert p == pytest.approx(env_pdf(lights, w), rel=1e-9)
        assert np.allclose(rad, env_radiance(lights, w), rtol=1e-9)


CONSTANT_SPHERE = ('<shape type="sphere"><bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.5, 0.8"/></bsdf>'
                   '</shape>\n<emitter type="constant"><rgb name="radiance" value="1.5, 1.0, 0.5"/></emitter>')
RHO_L = np.array([0.2 * 1.5, 0.5 * 1.0, 0.8 * 0.5])


def constant_sphere(tmp_path):
    path = tmp_path / "const.xml"
    path.write_text(f'<scene version="3.0.0">\n{SENSOR}\n{CONSTANT_SPHERE}\n</scene>\n')
    return path


def on_sphere(image):
    """The pixels wholly on the unit sphere seen from 6 units with a 30 degree field on 16 pixels (its image is
    5.0 pixels in radius): the box-filtered pixels within 3.5 pixels of the centre."""
    h, w = image.shape[:2]
    y, x = np.mgrid[:h, :w]
    inside = (x + 0.5 - w / 2) ** 2 + (y + 0.5 - h / 2) ** 2 < 3.5 ** 2
    return image[inside]


def check_rho_l(pixels, what):
    """Every pixel estimates ρ L independently: their mean is within 5 standard errors of it (ρ L exactly
    when the estimate has no noise), and no pixel is beyond 6 standard deviations."""
    mean = pixels.mean(axis=0)
    sd = pixels.std(axis=0, ddof=1)
    se = sd / math.sqrt(len(pixels))
    assert np.all(np.abs(mean - RHO_L) <= 5 * se + 1e-6 * RHO_L), (what, mean, RHO_L, se)
    assert np.all(np.abs(pixels - RHO_L) <= 6 * sd + 1e-6 * RHO_L), (what, pixels, RHO_L, sd)
    return mean, se


def test_pt_diffuse_sphere_under_a_constant_environment_is_rho_l(tmp_path):
    """A convex diffuse object under uniform radiance L: every point reflects ρ L (no interreflection)."""
    import caustica
    image = caustica.render(str(constant_sphere(tmp_path)), "pt", spp=64, threads=2).image
    check_rho_l(on_sphere(image), "pt")
    # the environment seen directly, in full (the corners miss the sphere)
    assert np.allclose(image[0, 0], (1.5, 1.0, 0.5))
