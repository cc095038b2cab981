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
    ("broken hdr", '<emitter type="envmap"><string name="filename" value="sky.hdr"/></emitter>',
     "the header ends before the resolution line"),
    ("pfm", '<emitter type="envmap"><string name="filename" value="sky.pfm"/></emitter>', "'.pfm' images are not"),
    ("two", '<emitter type="constant"/>\n<emitter type="constant"/>', "only one environment emitter"),
])
def test_bad_environment_is_one_line_exit_2(tmp_path, capsys, case, body, expected):
    from caustica.cli import main
    (tmp_path / "junk.png").write_text("not a png")
    (tmp_path / "sky.hdr").write_text("#?RADIANCE\n")
    (tmp_path / "sky.pfm").write_text("PF\n")
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
    assert list(lights.kind) == [ENV] and lights.env[0] == 0 and lights.env[1] == 1
    r = lights.env_data[3]
    assert r == pytest.approx(math.sqrt(3), rel=1e-3)   # the unit sphere's box, as Mitsuba bounds it
    assert np.allclose(lights.power[0], np.pi * r * r * 4 * np.pi * np.array([0.5, 1, 2]))
    assert env_radiance(lights, (0.0, 1.0, 0.0)) == (0.5, 1.0, 2.0)

    sun_map(tmp_path / "sky.exr")
    scene = compile_scene(load_scene_description(str(write_scene(
        tmp_path, ENVMAP.format(f="sky.exr", s=2, a=30)))))
    assert scene.lights.env[1] == 0 and scene.lights.env_image.shape == (16, 32, 3)
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


def sun_sky_map(path):
    """tests/scenes/envmap-sun.xml's map (32 x 64): a sky brighter towards the zenith, darker below the horizon,
    and a 2 x 2-texel sun about 45 degrees up."""
    h, w = 32, 64
    v = (np.arange(h) + 0.5) / h
    sky = 0.25 + 0.35 * (1 - v)
    img = np.empty((h, w, 3), np.float32)
    img[:] = np.stack([0.6 * sky, 0.8 * sky, sky], -1)[:, None, :]
    img[h // 2:] *= 0.3
    img[8:10, 20:22] = (400.0, 360.0, 280.0)
    write_exr(path, img)


def envmap_sun_scene(tmp_path, test_scenes_dir):
    path = tmp_path / "envmap-sun.xml"
    path.write_text((test_scenes_dir / "envmap-sun.xml").read_text())
    sun_sky_map(tmp_path / "sun.exr")
    return path


def test_pt_envmap_matches_mitsuba(mi, tmp_path, test_scenes_dir):
    """tests/scenes/envmap-sun.xml (a sun-and-sky map, rotated, over a diffuse floor and ball): caustica's pt and
    Mitsuba's path integrator agree, image mean within 2 % and every 4x4 block within 5 sigmas of both renders'
    noise (tests/imagestats.py)."""
    from imagestats import assert_images_agree
    path = envmap_sun_scene(tmp_path, test_scenes_dir)
    seeds = (1, 2, 3, 4)
    scene = caustica_load(path)
    import caustica
    ours = [caustica.render(scene, "pt", spp=64, seed=s, threads=2).image for s in seeds]
    theirs_scene = mi.load_file(str(path), spp=256)
    theirs = [np.array(mi.render(theirs_scene, spp=256, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    assert_images_agree(ours, theirs, label="envmap-sun pt")


def test_pt_hides_emitters_as_the_scene_asks_as_mitsuba_does(mi, tmp_path, test_scenes_dir):
    """The same scene with <boolean name="hide_emitters" value="true"/> in its path integrator: pt takes the setting
    from the scene (its background renders black: the environment the camera ray meets before any scattering adds
    nothing; what the floor and ball reflect of it stays) and agrees with Mitsuba as above; the same seed without
    hiding is as bright or brighter in every pixel."""
    from imagestats import assert_images_agree
    import caustica
    path = envmap_sun_scene(tmp_path, test_scenes_dir)
    path.write_text(path.read_text().replace('<integrator type="path"/>', '<integrator type="path"><boolean '
                                             'name="hide_emitters" value="true"/></integrator>'))
    scene = caustica_load(path)
    seeds = (1, 2, 3, 4)
    runs = [caustica.render(scene, "pt", spp=64, seed=s, threads=2) for s in seeds]
    assert all(r.stats["parameters"]["hide_emitters"] for r in runs)
    ours = [r.image for r in runs]
    theirs_scene = mi.load_file(str(path), spp=256)
    theirs = [np.array(mi.render(theirs_scene, spp=256, seed=s), dtype=np.float32)[..., :3] for s in seeds]
    assert_images_agree(ours, theirs, label="envmap-sun pt, hide_emitters")
    shown = caustica.render(scene, "pt", spp=64, seed=1, threads=2, hide_emitters=False).image
    assert np.all(ours[0] <= shown * (1 + 1e-6) + 1e-7)
    assert (ours[0][0] == 0).all() and (shown[0] > 0.1).all()   # the top row is sky


def caustica_load(path):
    import caustica
    return caustica.load_scene(str(path))


# ----------------------------------------------------------------------------- photons from the environment

from caustica.jit import borrowed, kernel  # noqa: E402
from caustica.photons.emission import emit_caustic_photon, emit_photon  # noqa: E402
from caustica.sampling.rng import path_key  # noqa: E402


@kernel
def emit_many(geom, lights, spheres, n, seed, out):
    """n photons of ``seed`` (global when spheres is empty, else aimed at them): origins, directions, powers, ok."""
    geom, lights = borrowed(geom), borrowed(lights)
    o_out, d_out, p_out, ok_out = out
    for i in range(n):
        key = path_key(seed, 3, i)
        if spheres.shape[0] == 0:
            o, d, power, _ = emit_photon(geom, lights, key, n)
            ok = True
        else:
            o, d, power, ok = emit_caustic_photon(geom, lights, spheres, key, n)
        for c in range(3):
            o_out[i, c] = o[c]
            d_out[i, c] = d[c]
            p_out[i, c] = power[c]
        ok_out[i] = ok


@kernel
def _radiance_integral(lights, nu, nv):
    """∫ L dω over the sphere by the midpoint rule on an nu x nv grid of (φ, cos θ)."""
    lights = borrowed(lights)
    acc = np.zeros(3)
    for i in range(nv):
        z = -1.0 + 2.0 * (i + 0.5) / nv
        r = math.sqrt(max(0.0, 1.0 - z * z))
        for j in range(nu):
            phi = 2.0 * math.pi * (j + 0.5) / nu
            L = env_radiance(lights, (r * math.cos(phi), z, r * math.sin(phi)))
            for c in range(3):
                acc[c] += L[c]
    return acc * (4.0 * math.pi / (nu * nv))


@pytest.mark.parametrize("aimed", [False, True])
def test_environment_photons_carry_the_flux_that_crosses_a_sphere(tmp_path, aimed):
    """The power of the environment's photons whose ray crosses a ball of radius a inside the scene's bounding
    sphere estimates the flux into it, π a² ∫ L dω (within 5 standard errors per channel): photons emitted
    everywhere (PM, SPM, SPPM), and photons aimed at two specular spheres (PM's caustic map), both balls."""
    sun_map(tmp_path / "sky.exr")
    scene = compile_scene(load_scene_description(str(write_scene(tmp_path, ENVMAP.format(f="sky.exr", s=1, a=70)))))
    targets = np.array([[0.0, 0.0, 0.0, 0.5], [0.6, 0.3, 0.0, 0.4]])
    n = 400_000
    out = (np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros(n, np.bool_))
    emit_many(scene.geometry, scene.lights, targets if aimed else np.zeros((0, 4)), n, 11, out)
    o, d, power, ok = out
    flux_L = _radiance_integral(scene.lights, 720, 720)
    for centre, a in ((targets[0, :3], targets[0, 3]), (targets[1, :3], targets[1, 3])):
        to_c = centre - o
        along = (to_c * d).sum(axis=1)
        miss2 = (to_c * to_c).sum(axis=1) - along ** 2
        hits = ok & (miss2 < a * a) & (along > 0)
        contrib = power * hits[:, None] * n          # per-photon estimates of the flux
        est = contrib.mean(axis=0)
        se = contrib.std(axis=0, ddof=1) / math.sqrt(n)
        expected = math.pi * a * a * flux_L
        assert np.all(np.abs(est - expected) <= 5 * se), (aimed, est, expected, se)
        if not aimed:   # every origin lies outside the bounding sphere, on its far side
            assert np.all(np.linalg.norm(o - scene.lights.env_data[:3], axis=1) >= scene.lights.env_data[3]
                          * (1 - 1e-9))


PHOTON_METHODS = {"pm": {}, "spm": {}, "sppm": {"passes": 4}, "pspm": {"passes": 4}}


@pytest.mark.parametrize("method", list(PHOTON_METHODS))
def test_photon_methods_diffuse_sphere_under_a_constant_environment_is_rho_l(tmp_path, method):
    """The photon methods' direct light takes the environment by cosine-weighted shadow rays: on a convex sphere
    nothing occludes them, so every pixel on it is ρ L to rounding, and the photons (which all escape after one
    bounce) add nothing; the environment seen directly is L."""
    import caustica
    image = caustica.render(str(constant_sphere(tmp_path)), method, threads=2, **PHOTON_METHODS[method]).image
    assert np.allclose(on_sphere(image), RHO_L, rtol=1e-5)
    assert np.allclose(image[0, 0], (1.5, 1.0, 0.5))


@pytest.fixture(scope="module")
def envmap_sun_mitsuba(mi, tmp_path_factory, test_scenes_dir):
    """Mitsuba 3's render of tests/scenes/envmap-sun.xml (2 seeds x 1024 spp) and the scene's path."""
    path = envmap_sun_scene(tmp_path_factory.mktemp("envmap-sun"), test_scenes_dir)
    scene = mi.load_file(str(path), spp=1024)
    return path, [np.array(mi.render(scene, spp=1024, seed=s), dtype=np.float64)[..., :3] for s in (1, 2)]


@pytest.mark.parametrize("method, params", [
    ("pm", {"photons": 100_000, "radius": 0.3}),
    ("pm", {"photons": 100_000, "caustic_photons": 50_000, "radius": 0.3}),
    ("spm", {"streams": 10_000, "radius": 0.3, "stream_radius": 0.1}),
    ("sppm", {"passes": 32}),
    ("pspm", {"passes": 32}),
])
def test_photon_methods_envmap_mean_matches_mitsuba(envmap_sun_mitsuba, method, params):
    """tests/scenes/envmap-sun.xml: the photon methods' image mean per channel within 2 % of Mitsuba's (the image
    mean criterion of tests/imagestats.py; the floor and ball light each other with the environment's photons).
    Measured on 2026-12-03: within 0.4 % for each (seed 1, 2 threads)."""
    import caustica
    path, theirs = envmap_sun_mitsuba
    ours = caustica.render(str(path), method, threads=2, seed=1, **params).image.mean(axis=(0, 1))
    ref = np.mean(theirs, axis=0).mean(axis=(0, 1))
    assert np.all(np.abs(ours / ref - 1) < 0.02), (method, params, ours, ref)


def test_envmap_to_world_is_a_rotation_to_exporters_precision(tmp_path):
    """A 6-digit rotation matrix (as in Mitsuba's own scenes) is read; a non-uniform scale is refused."""
    from caustica.errors import SceneError
    sun_map(tmp_path / "sky.exr")
    m = ("-0.224951 -0.000001 -0.974370 0 -0.974370 0.000000 0.224951 0 0.000000 1.000000 -0.000001 8.87 "
         "0 0 0 1")
    body = ('<emitter type="envmap"><string name="filename" value="sky.exr"/><transform name="to_world">'
            f'<matrix value="{m}"/></transform></emitter>')
    d = load_scene_description(str(write_scene(tmp_path, body)))
    assert np.allclose(d.environment.to_world @ d.environment.to_world.T, np.eye(3), atol=1e-12)
    body = ('<emitter type="envmap"><string name="filename" value="sky.exr"/><transform name="to_world">'
            '<scale x="2"/></transform></emitter>')
    with pytest.raises(SceneError, match="must be a rotation"):
        load_scene_description(str(write_scene(tmp_path, body, "bad.xml")))


def test_rgbe_files_read_as_mitsuba_reads_them(mi, tmp_path):
    """Radiance .hdr files Mitsuba writes (run-length encoded at 53 wide, flat at 6 wide) read to Mitsuba's own
    values, bit for bit."""
    from caustica.imageio import read_radiance_image
    rng = np.random.default_rng(0)
    for shape in ((37, 53, 3), (5, 6, 3)):
        img = (rng.random(shape) ** 4 * 50).astype(np.float32)
        img[3, 4] = 0
        mi.Bitmap(img).write(str(tmp_path / "t.hdr"))
        assert np.array_equal(read_radiance_image(tmp_path / "t.hdr"), np.array(mi.Bitmap(str(tmp_path / "t.hdr"))))


ABSORBER = """<scene version="3.0.0">
<medium type="homogeneous" id="ink"><rgb name="sigma_t" value="0, 0.5, 2"/><float name="albedo" value="0"/></medium>
<sensor type="perspective"><float name="fov" value="30"/>
  <transform name="to_world"><lookat origin="0,0,6" target="0,0,0" up="0,1,0"/></transform>
  <ref id="ink"/>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/><rfilter type="box"/></film>
</sensor>
<shape type="sphere"><point name="center" x="0" y="0" z="40"/><float name="radius" value="0.5"/></shape>
<emitter type="constant"><rgb name="radiance" value="2, 1, 0.5"/></emitter>
</scene>"""


@pytest.mark.parametrize("method", ["pt", "sppm"])
def test_environment_seen_from_inside_an_unbounded_absorber(tmp_path, method):
    """The camera sits in an absorbing medium that nothing bounds (sigma_t 0 in red only): the environment reaches
    it in red alone (docs/media.md, as Mitsuba's volpath).  pt escapes in a third of its flights with weight 3
    in red (mean within 5 standard errors); sppm's camera ray takes the transmittance exactly."""
    import caustica
    path = tmp_path / "ink.xml"
    path.write_text(ABSORBER)
    kw = {"spp": 64} if method == "pt" else {"passes": 2}
    pixels = caustica.render(str(path), method, threads=2, **kw).image.reshape(-1, 3).astype(np.float64)
    assert np.all(pixels[:, 1:] == 0.0)
    se = pixels[:, 0].std(ddof=1) / math.sqrt(len(pixels))
    assert abs(pixels[:, 0].mean() - 2.0) <= 5 * se + 1e-6, (pixels[:, 0].mean(), se)
