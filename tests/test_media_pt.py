"""The path tracer through participating media (``pt`` on a scene with media; methods/pt.py).

1. Beer-Lambert: the transmittance kernel against exp(-sigma_t d) through null boundaries
   (and 0 through glass); an emitter seen through an absorbing slab, whose free flights make
   every sample a coin toss with a known variance; a plane lit by a point light through an
   absorbing slab (exact shadow-ray transmittance: only the sub-pixel jitter is random).
2. Single scattering with a closed form: a point light at the camera inside a spherical
   shell of medium (max_depth = 2 keeps exactly one scattering event); the radiance of
   every pixel is sigma_s p(mu = -1) I exp(c a) [F(b) - F(a)] with c = 2 sigma_t and
   F(t) = -exp(-c t) / t + c E1(c t), isotropic and Henyey-Greenstein, grey and RGB.
3. Energy conservation: a white-furnace sphere filled (wholly, or in a null-bounded ball)
   with a medium of albedo 1 keeps L = Le / (1 - rho) whatever sigma_t and the phase.
4. Bits: scenes without media render exactly as the surface path tracer; media renders give
   the same bits for any thread count.
5. Mitsuba 3's volpath (scalar_rgb) on a small scene of media, glass and null boundaries, and on
   the built-in cornell-diacaustic-fog (tests/imagestats.py: image mean within 2 %, block means within noise).

Tolerances are derived from noise measured in each test (or, for the slab, computed), as
in tests/test_pt.py; 5 sigma.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import exp1

import caustica
from caustica.media import transmittance
from caustica.scene import parse_scene_string
from caustica.tables import compile_scene
from imagestats import N_SIGMA, assert_images_agree


def scene_from_xml(text: str):
    return compile_scene(parse_scene_string(text))


def rgb(v) -> str:
    return ", ".join(str(float(c)) for c in v)


def sensor_xml(origin, target, up, fov, width, height, inner="") -> str:
    return f"""<sensor type="perspective">
        <float name="fov" value="{fov}"/>
        <transform name="to_world"><lookat origin="{rgb(origin)}" target="{rgb(target)}" up="{rgb(up)}"/></transform>
        <film type="hdrfilm"><integer name="width" value="{width}"/><integer name="height" value="{height}"/>
            <rfilter type="box"/></film>
        {inner}
    </sensor>"""


def film_tangents(width, height, fov_x_deg, n_sub=32):
    """(a, b): camera-space x / z and y / z of sub-pixel midpoints, shape (height, width, n_sub²).

    A camera ray through film point (sx, sy) has the direction (a, b, 1) (Mitsuba's pinhole,
    see tests/test_pt.py); the box filter averages over these points (the films of :func:`sensor_xml`
    say ``<rfilter type="box"/>``: without it a film is Mitsuba's gaussian).
    """
    tan_x = math.tan(math.radians(fov_x_deg) / 2)
    tan_y = tan_x * height / width
    sub = (np.arange(n_sub) + 0.5) / n_sub
    su, sv = np.meshgrid(sub, sub, indexing="xy")
    px = np.arange(width)[None, :, None] + su.ravel()[None, None, :]
    py = np.arange(height)[:, None, None] + sv.ravel()[None, None, :]
    a = tan_x * (1 - 2 * px / width)
    b = tan_y * (1 - 2 * py / height)
    return np.broadcast_to(a, (height, width, n_sub * n_sub)), np.broadcast_to(b, (height, width, n_sub * n_sub))


def slab_xml(z0, z1, medium_inner: str, half=50.0) -> str:
    """A null-bounded slab z0 <= z <= z1 (a flat cube, 2 half wide) filled with the given medium."""
    return f"""<shape type="cube">
        <transform name="to_world"><scale x="{half}" y="{half}" z="{(z1 - z0) / 2}"/><translate z="{(z0 + z1) / 2}"/></transform>
        <bsdf type="null"/>
        <medium type="homogeneous" name="interior">{medium_inner}</medium>
    </shape>"""


SIGMA_RGB = np.array([0.2, 0.5, 1.0])


# --------------------------------------------------------------------------- 1. Beer-Lambert

def test_transmittance_kernel_is_beer_lambert_through_null_boundaries_and_zero_through_glass():
    # Two slabs with different media, one inside a glass-free gap, then a glass pane.
    scene = scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0, 0, 10), (0, 0, 0), (0, 1, 0), 30, 8, 8)}
        {slab_xml(1.0, 2.0, f'<rgb name="sigma_t" value="{rgb(SIGMA_RGB)}"/><float name="albedo" value="0.5"/>')}
        {slab_xml(3.0, 3.5, '<float name="sigma_t" value="0.8"/>')}
        <shape type="rectangle"><transform name="to_world"><scale value="50"/><translate z="6"/></transform>
            <bsdf type="dielectric"/></shape>
        <emitter type="point"><point name="position" value="0, 0, 20"/></emitter>
    </scene>""")
    g, m, media = scene.geometry, scene.materials, scene.media
    for direction in ((0.0, 0.0, 1.0), (0.3, -0.2, 0.9)):
        d = np.asarray(direction) / np.linalg.norm(direction)
        o = tuple(np.array([0.1, 0.2, 0.0]))
        end = tuple(np.array(o) + d * (5.5 / d[2]))               # z = 5.5, below the glass
        T, rays = transmittance(g, m, media, o, end, -1)
        path = 1.0 / d[2]                                          # length through a slab of thickness 1
        want = np.exp(-SIGMA_RGB * path) * np.exp(-0.8 * 0.5 * path)
        # Each crossing starts the next segment a few 1e-6 units off the surface (vec.offset_origin), which
        # skips that much medium: 3e-5 of the optical depth here, hence 1e-4.
        np.testing.assert_allclose(T, want, rtol=1e-4)
        assert rays == 5                                           # four null faces crossed, then the end
        beyond = tuple(np.array(o) + d * (7.0 / d[2]))             # past the glass pane
        assert transmittance(g, m, media, o, beyond, -1)[0] == (0.0, 0.0, 0.0)
        # starting inside the first slab (z = 1.5): half of it, then the second
        inside = tuple(np.array(o) + d * (1.5 / d[2]))
        T, _ = transmittance(g, m, media, inside, end, media.interior[0])
        np.testing.assert_allclose(T, np.exp(-SIGMA_RGB * path / 2) * np.exp(-0.8 * 0.5 * path), rtol=1e-4)


EMITTER_LE = np.array([1.0, 2.0, 3.0])
SW, SH, SFOV = 9, 7, 40.0


@pytest.mark.parametrize("sigma", [(0.7, 0.7, 0.7), tuple(SIGMA_RGB)], ids=["grey", "rgb"])
def test_emitter_seen_through_an_absorbing_slab(sigma):
    """L = Le exp(-sigma_t / cos) behind a slab of thickness 1 and albedo 0 (max_depth = 1: emission only)."""
    sigma = np.asarray(sigma)
    spp = 256
    scene = scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0, 0, 3), (0, 0, 0), (0, 1, 0), SFOV, SW, SH)}
        {slab_xml(1.0, 2.0, f'<rgb name="sigma_t" value="{rgb(sigma)}"/><float name="albedo" value="0"/>')}
        <shape type="rectangle"><transform name="to_world"><scale value="20"/></transform>
            <emitter type="area"><rgb name="radiance" value="{rgb(EMITTER_LE)}"/></emitter></shape>
    </scene>""")
    img = caustica.render(scene, "pt", spp=spp, seed=5, max_depth=1).image.astype(np.float64)
    a, b = film_tangents(SW, SH, SFOV)
    path = np.sqrt(1 + a * a + b * b)[..., None]                    # 1 / cos: the slab's thickness is 1
    T = np.exp(-sigma * path)
    P = T.mean(axis=-1, keepdims=True)                               # the chance to fly through (mixture)
    m1 = (EMITTER_LE * T).mean(axis=2)                               # expected pixel value
    m2 = (EMITTER_LE ** 2 * T ** 2 / P).mean(axis=2)                 # E[X^2] of one sample: (Le T / P)^2 w.p. P
    se = np.sqrt((m2 - m1 ** 2) / spp)
    assert np.all(np.abs(img - m1) <= N_SIGMA * se + 1e-5 * m1), np.max(np.abs(img - m1) / se)
    se_mean = np.sqrt((se ** 2).sum(axis=(0, 1))) / (SW * SH)
    assert np.all(np.abs(img.mean(axis=(0, 1)) - m1.mean(axis=(0, 1))) <= N_SIGMA * se_mean)


PLANE_RHO = np.array([0.8, 0.5, 0.2])
INTENSITY = np.array([10.0, 20.0, 30.0])


@pytest.mark.parametrize("albedo", [0.0, 0.7])
def test_point_light_through_a_slab_onto_a_plane(albedo):
    """Direct light (max_depth = 2) through a slab between the plane and the light, the camera under it.

    L = rho / pi I cos / d^2 exp(-sigma_t 1 / cos): shadow rays carry the exact transmittance, so
    only the sub-pixel jitter is random (as in tests/test_pt.py's point light test).  The medium's
    albedo does not matter at max_depth = 2: light scattered in the slab needs a second event.
    """
    h, cam_h, fov, w, hh, spp = 2.0, 0.25, 90.0, 9, 7, 64
    scene = scene_from_xml(f"""<scene version="3.0.0">
        {sensor_xml((0, 0, cam_h), (0, 0, 0), (0, 1, 0), fov, w, hh)}
        <shape type="rectangle"><transform name="to_world"><scale value="50"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="{rgb(PLANE_RHO)}"/></bsdf></shape>
        {slab_xml(0.5, 1.5, f'<rgb name="sigma_t" value="{rgb(SIGMA_RGB)}"/><float name="albedo" value="{albedo}"/>')}
        <emitter type="point"><point name="position" value="0, 0, {h}"/><rgb name="intensity" value="{rgb(INTENSITY)}"/></emitter>
    </scene>""")
    img = caustica.render(scene, "pt", spp=spp, seed=3, max_depth=2).image.astype(np.float64)
    a, b = film_tangents(w, hh, fov)
    x, y = cam_h * a, cam_h * b                                     # where the rays meet z = 0
    d2 = x * x + y * y + h * h
    cos = h / np.sqrt(d2)
    f = (cos / d2)[..., None] * np.exp(-SIGMA_RGB / cos[..., None])
    expected = f.mean(axis=2) * INTENSITY * PLANE_RHO / math.pi
    tol = N_SIGMA * f.std(axis=2) / math.sqrt(spp) * INTENSITY * PLANE_RHO / math.pi + 1e-4 * expected
    assert np.all(np.abs(img - expected) <= tol), np.max(np.abs(img - expected) / tol)


# --------------------------------------------------------------------------- 2. single scattering

def single_scattering_shell(sigma_t, albedo, g, intensity, a, b):
    """sigma_s p(-1) I ∫_a^b exp(-2 sigma_t (t - a)) / t^2 dt, per channel (closed form with E1)."""
    sigma_t, albedo = np.asarray(sigma_t, float), np.asarray(albedo, float)
    c = 2 * sigma_t

    def F(t):
        return -np.exp(-c * t) / t + c * exp1(c * t)
    integral = np.exp(c * a) * (F(b) - F(a))
    phase_back = (1 - g * g) / (4 * math.pi * (1 + g) ** 3)      # HG at mu = -1 (isotropic: g = 0)
    return sigma_t * albedo * phase_back * np.asarray(intensity) * integral


def test_single_scattering_closed_form_formula():
    # The E1 antiderivative against brute-force midpoint quadrature.
    sigma, a, b = np.array([0.3, 0.9, 2.0]), 1.0, 3.0
    t = a + (np.arange(200000) + 0.5) / 200000 * (b - a)
    brute = (np.exp(-2 * sigma[:, None] * (t - a)) / t ** 2).sum(axis=1) * (b - a) / len(t)
    got = single_scattering_shell(sigma, 1.0, 0.0, 4 * math.pi, a, b) / (sigma * 1.0)
    np.testing.assert_allclose(got, brute, rtol=1e-8)


SHELL_A, SHELL_B = 1.0, 3.0
SHELL_I = np.array([20.0, 30.0, 40.0])


def shell_scene(medium_inner, res=16):
    """A point light at the camera, in vacuum inside a null sphere of radius a; the medium up to radius b."""
    return scene_from_xml(f"""<scene version="3.0.0">
        <medium type="homogeneous" id="shell">{medium_inner}</medium>
        {sensor_xml((0, 0, 0), (0.3, 0.2, -1), (0, 1, 0), 70, res, res)}
        <shape type="sphere"><float name="radius" value="{SHELL_A}"/><bsdf type="null"/><ref name="exterior" id="shell"/></shape>
        <shape type="sphere"><float name="radius" value="{SHELL_B}"/><bsdf type="null"/><ref name="interior" id="shell"/></shape>
        <emitter type="point"><point name="position" value="0, 0, 0"/><rgb name="intensity" value="{rgb(SHELL_I)}"/></emitter>
    </scene>""")


@pytest.mark.parametrize("sigma, albedo, g", [
    ((0.6, 0.6, 0.6), (0.8, 0.8, 0.8), None),
    ((0.3, 0.9, 2.0), (0.9, 0.6, 0.3), None),
    ((0.3, 0.9, 2.0), (0.9, 0.6, 0.3), -0.4),
    ((0.6, 0.6, 0.6), (1.0, 1.0, 1.0), 0.6),
], ids=["grey isotropic", "rgb isotropic", "rgb hg backwards", "grey hg forwards"])
def test_single_scattering_in_a_shell_has_a_closed_form(sigma, albedo, g):
    phase = '<phase type="isotropic"/>' if g is None else f'<phase type="hg"><float name="g" value="{g}"/></phase>'
    scene = shell_scene(f'<rgb name="sigma_t" value="{rgb(sigma)}"/><rgb name="albedo" value="{rgb(albedo)}"/>{phase}')
    img = caustica.render(scene, "pt", spp=64, seed=2, max_depth=2).image.astype(np.float64)
    expected = single_scattering_shell(sigma, albedo, 0.0 if g is None else g, SHELL_I, SHELL_A, SHELL_B)
    # Every pixel has the same expectation (the setting is spherically symmetric about the camera),
    # so the pixels are independent samples of it: the mean's standard error is their spread / 16.
    pix = img.reshape(-1, 3)
    se = pix.std(axis=0, ddof=1) / math.sqrt(len(pix))
    assert np.all(se > 0) and np.all(se < 0.05 * expected)
    got = pix.mean(axis=0)
    assert np.all(np.abs(got - expected) <= N_SIGMA * se), (got, expected, se)


# --------------------------------------------------------------------------- 3. energy conservation

FURNACE_RHO = np.array([0.3, 0.6, 0.8])
FURNACE_LE = np.array([1.0, 2.0, 0.5])


def furnace_media_scene(kind, sigma_t="0.4, 0.8, 1.6"):
    fog = (f'<medium type="homogeneous" id="fog"><rgb name="sigma_t" value="{sigma_t}"/><float name="albedo" '
           'value="1"/><phase type="hg"><float name="g" value="0.5"/></phase></medium>')
    walls = f"""<shape type="sphere"><float name="radius" value="2"/><boolean name="flip_normals" value="true"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="{rgb(FURNACE_RHO)}"/></bsdf>
            <emitter type="area"><rgb name="radiance" value="{rgb(FURNACE_LE)}"/></emitter>
        </shape>"""
    if kind == "filled":      # the room full of fog: the camera's medium; the walls have none
        return scene_from_xml(f"""<scene version="3.0.0">{fog}
            {sensor_xml((0.1, -0.2, 0.3), (1, 0.5, -1), (0, 1, 0), 70, 16, 16, '<ref id="fog"/>')}{walls}</scene>""")
    # a ball of fog behind a null boundary, the camera in vacuum
    return scene_from_xml(f"""<scene version="3.0.0">{fog}
        {sensor_xml((0.1, -0.2, 0.3), (1, 0.5, -1), (0, 1, 0), 70, 16, 16)}{walls}
        <shape type="sphere"><point name="center" value="0.6, 0.3, -0.6"/><float name="radius" value="0.9"/>
            <bsdf type="null"/><ref name="interior" id="fog"/></shape>
    </scene>""")


@pytest.mark.parametrize("kind", ["filled", "ball"])
def test_scattering_with_albedo_1_conserves_energy_in_a_closed_furnace(kind):
    img = caustica.render(furnace_media_scene(kind), "pt", spp=64, seed=11).image.astype(np.float64)
    expected = FURNACE_LE / (1 - FURNACE_RHO)
    pix = img.reshape(-1, 3)
    se = pix.std(axis=0, ddof=1) / math.sqrt(len(pix))
    assert np.all(np.isfinite(pix))
    got = pix.mean(axis=0)
    assert np.all(np.abs(got - expected) <= N_SIGMA * se + 1e-6 * expected), (got, expected, se)


def test_a_furnace_with_albedo_below_1_loses_energy():
    # The same furnace with albedo 0.5 is darker than Le / (1 - rho): the test above could fail.
    scene = scene_from_xml(f"""<scene version="3.0.0">
        <medium type="homogeneous" id="fog"><float name="sigma_t" value="0.8"/><float name="albedo" value="0.5"/></medium>
        {sensor_xml((0.1, -0.2, 0.3), (1, 0.5, -1), (0, 1, 0), 70, 16, 16, '<ref id="fog"/>')}
        <shape type="sphere"><float name="radius" value="2"/><boolean name="flip_normals" value="true"/>
            <bsdf type="diffuse"><rgb name="reflectance" value="{rgb(FURNACE_RHO)}"/></bsdf>
            <emitter type="area"><rgb name="radiance" value="{rgb(FURNACE_LE)}"/></emitter></shape>
    </scene>""")
    pix = caustica.render(scene, "pt", spp=32, seed=1).image.astype(np.float64).reshape(-1, 3)
    se = pix.std(axis=0, ddof=1) / math.sqrt(len(pix))
    assert np.all(pix.mean(axis=0) + N_SIGMA * se < FURNACE_LE / (1 - FURNACE_RHO))


# --------------------------------------------------------------------------- 4. bits

def test_media_renders_have_the_same_bits_for_any_thread_count():
    scene = furnace_media_scene("ball")
    one = caustica.render(scene, "pt", spp=4, seed=7, threads=1).image
    two = caustica.render(scene, "pt", spp=4, seed=7, threads=2).image
    assert one.tobytes() == two.tobytes()
    assert not np.array_equal(one, caustica.render(scene, "pt", spp=4, seed=8, threads=2).image)


def test_scenes_without_media_compile_to_a_medium_table_of_vacuum():
    """Every scene has a medium table (one loop per role renders both); without media it says vacuum everywhere."""
    scene = caustica.load_scene("cornell-diacaustic", res=16)
    assert not scene.has_media
    assert np.all(scene.media.interior == -1) and np.all(scene.media.exterior == -1)
    assert scene.media.camera[0] == -1 and scene.media.null_surfaces[0] == 0
    # a medium defined but used by nothing changes nothing either
    text = scene.description.files[0].read_text().replace(
        "<sensor ", '<medium type="homogeneous" id="unused"/>\n    <sensor ')
    other = compile_scene(parse_scene_string(text, base_dir=scene.description.files[0].parent))
    assert not other.has_media
    vacuum = ("interior", "exterior", "camera", "null_surfaces")   # where media are (the unused one is listed)
    for a, b in zip((scene.geometry, scene.materials, scene.lights, [getattr(scene.media, f) for f in vacuum]),
                    (other.geometry, other.materials, other.lights, [getattr(other.media, f) for f in vacuum])):
        for x, y in zip(a, b):
            assert x.dtype == y.dtype and x.tobytes() == y.tobytes()
    r1 = caustica.render(scene, "pt", spp=2, res=16, seed=4, threads=2).image
    r2 = caustica.render(other, "pt", spp=2, res=16, seed=4, threads=2).image
    assert r1.tobytes() == r2.tobytes()


# --------------------------------------------------------------------------- 5. Mitsuba 3

CMP_RES = 32
CMP_SEEDS = (1, 2, 3, 4)      # independent renders of each image, to measure its noise (tests/imagestats.py)
CMP_SPP = {"media-glass": 256, "cornell-diacaustic-fog": 512}


def media_renders(mi, path, spp, max_depth=-1):
    """caustica's pt and Mitsuba's volpath (the file's integrator) of one XML file, one render per seed."""
    scene = caustica.load_scene(path)
    ours = [caustica.render(scene, "pt", spp=spp, res=CMP_RES, seed=s, max_depth=max_depth).image for s in CMP_SEEDS]
    theirs_scene = mi.load_file(str(path), res=CMP_RES, spp=spp, max_depth=max_depth)
    assert "Volumetric" in str(theirs_scene.integrator())
    theirs = [np.array(mi.render(theirs_scene, spp=spp, seed=s), dtype=np.float32)[..., :3] for s in CMP_SEEDS]
    return ours, theirs


@pytest.mark.mitsuba
@pytest.mark.parametrize("max_depth", [-1, 3])
def test_media_scene_matches_mitsuba_volpath(mi, test_scenes_dir, max_depth):
    """Three media (the camera's haze, RGB fog, liquid in glass), null boundaries; max_depth = 3 checks
    that scattering in a medium counts as a bounce and crossing a null boundary does not (Mitsuba's depth)."""
    ours, theirs = media_renders(mi, test_scenes_dir / "media-glass.xml", CMP_SPP["media-glass"], max_depth)
    assert_images_agree(ours, theirs, label=f"media-glass, max_depth {max_depth}")


@pytest.mark.mitsuba
def test_fog_box_matches_mitsuba_volpath(mi):
    """The built-in cornell-diacaustic-fog: the light's cone and the sphere's focused beam in thin fog."""
    from caustica.scene import builtin_scene_path
    ours, theirs = media_renders(mi, builtin_scene_path("cornell-diacaustic-fog"), CMP_SPP["cornell-diacaustic-fog"])
    assert_images_agree(ours, theirs, label="cornell-diacaustic-fog")



def test_checkpoints_tell_media_apart():
    """A checkpoint's scene fingerprint covers the media: a resumed render cannot mix two fogs."""
    from caustica.checkpoint import scene_fingerprint
    a, b = furnace_media_scene("ball"), furnace_media_scene("ball")
    assert scene_fingerprint(a) == scene_fingerprint(b)
    assert scene_fingerprint(furnace_media_scene("ball", sigma_t="0.4, 0.8, 1.7")) != scene_fingerprint(a)
