"""Heterogeneous media (Mitsuba 3's ``heterogeneous`` with ``gridvolume`` and ``constvolume``).

1. A constant grid renders as the equivalent homogeneous medium: the same image within the noise of both
   (tests/imagestats.py), RGB coefficients so that the majorant's null collisions carry per-channel weights.
2. The trackers against quadrature: ratio tracking's mean transmittance, and delta tracking's weight of the
   flights that pass, through an RGB grid (trilinear, nearest, repeated), equal exp(-integral of sigma_t) per
   channel computed with SciPy's own interpolation of the grid (Mitsuba's convention: voxel i at (i + 1/2) / n,
   clamped); the majorant grid bounds sigma_t wherever a ray reads it.
3. A box of smoke made from a synthetic .vol (a density gradient, an RGB albedo grid) under an area light, against
   Mitsuba 3's volpath (scalar_rgb), image mean within 2 % and block means within both renders' noise.
4. Bad input: a missing, foreign, truncated or too large .vol, a negative density, a wrong channel count, each one
   line with the file and line from the CLI (exit 2).
5. Bits: the homogeneous fog keeps its pinned image with the heterogeneous code compiled in.
6. The photon methods: pm and spm render the constant grid as the homogeneous medium (the same estimator in expectation,
   its kernel's bias included); the progressive ones (sppm, pspm), consistent, render the box of smoke and the
   homogeneous medium with an albedo grid as ``pt`` does.
7. The default volume radius in a scene with grid media: at most half the grids' finest voxel, not below a quarter of
   the default it replaces; a radius the user sets is taken as it is.

Tolerances come from the estimators' own statistics (standard errors over seeds or samples), 5 sigma.
"""
from __future__ import annotations

import hashlib
import math

import numpy as np
import pytest
from scipy.ndimage import map_coordinates

import caustica
from caustica.jit import borrowed, kernel
from caustica.media import MediumTable
from caustica.scene import parse_scene_string
from caustica.scene.volume_files import write_grid
from caustica.tables import compile_scene
from caustica.scene.description import NEAREST, TRILINEAR, Volume
from caustica.volumes import delta_tracking, majorant_grid, ratio_tracking, ratio_tracking_steps
from imagestats import N_SIGMA, assert_images_agree

RES = 16
SEEDS = (1, 2, 3, 4)


def sensor(res=RES, spp=16):
    return f"""<sensor type="perspective"><float name="fov" value="40"/>
        <transform name="to_world"><lookat origin="0, 1.2, 4.5" target="0, 0.3, 0" up="0, 1, 0"/></transform>
        <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="box"/></film>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler></sensor>"""


def box_scene(medium: str, res=RES, spp=16) -> str:
    """A null-bounded box [-1, 1] x [0.1, 2.1] x [-1, 1] holding ``medium`` (a <medium> named interior), above a
    grey floor (a box standing on the floor would share its face: which of two coincident surfaces a ray meets is
    up to rounding), under a square area light."""
    return f"""<scene version="3.0.0">
        <integrator type="volpath"/>
        {sensor(res, spp)}
        <shape type="cube"><transform name="to_world"><translate y="1.1"/></transform>
            <bsdf type="null"/>{medium}</shape>
        <shape type="rectangle"><transform name="to_world"><scale value="4"/><rotate x="1" angle="-90"/></transform>
            <bsdf type="diffuse"><rgb name="reflectance" value="0.5"/></bsdf></shape>
        <shape type="rectangle"><transform name="to_world"><scale value="0.6"/><rotate x="1" angle="90"/>
            <translate x="0.4" y="3"/></transform>
            <emitter type="area"><rgb name="radiance" value="8, 7, 6"/></emitter></shape>
    </scene>"""


#: The box's unit cube -> [-1, 1] x [0.1, 2.1] x [-1, 1].
BOX_LO = (-1.0, 0.1, -1.0)
BOX_TO_WORLD = '<transform name="to_world"><scale value="2"/><translate x="-1" y="0.1" z="-1"/></transform>'


def grid_medium(sigma_file, albedo, scale=1.0, extra="") -> str:
    return f"""<medium type="heterogeneous" name="interior"><float name="scale" value="{scale}"/>
        <volume type="gridvolume" name="sigma_t"><string name="filename" value="{sigma_file}"/>{BOX_TO_WORLD}{extra}
        </volume>{albedo}<phase type="hg"><float name="g" value="0.3"/></phase></medium>"""


def load(text, base_dir):
    return compile_scene(parse_scene_string(text, base_dir=base_dir))


def renders(scene, spp, res=RES):
    return [caustica.render(scene, "pt", spp=spp, res=res, seed=s, threads=2).image for s in SEEDS]


# --------------------------------------------------------------------------- 1. a constant grid

SIGMA = (0.5, 1.0, 2.0)
ALBEDO = (0.9, 0.6, 0.3)


def test_a_constant_grid_renders_as_the_homogeneous_medium(tmp_path):
    write_grid(tmp_path / "const.vol", np.broadcast_to(np.float32(SIGMA), (3, 4, 5, 3)) / 2.0)
    albedo = f'<rgb name="albedo" value="{", ".join(map(str, ALBEDO))}"/>'
    hetero = load(box_scene(grid_medium("const.vol", albedo, scale=2.0)), tmp_path)
    homo = load(box_scene(f"""<medium type="homogeneous" name="interior"><rgb name="sigma_t"
        value="{", ".join(map(str, SIGMA))}"/>{albedo}<phase type="hg"><float name="g" value="0.3"/></phase>
        </medium>"""), tmp_path)
    assert type(hetero.media) is MediumTable and type(homo.media) is not MediumTable   # every kind vs homogeneous
    assert_images_agree(renders(hetero, 64), renders(homo, 64), label="constant grid vs homogeneous")


# --------------------------------------------------------------------------- 2. the trackers

N_GRID = (40, 5, 20)   # nx, ny, nz: more voxels than majorant cells along x and z


def gradient_grid():
    """An RGB grid, (nz, ny, nx, 3): densities rising along x, y and z at different rates per channel."""
    nx, ny, nz = N_GRID
    z, y, x = np.meshgrid((np.arange(nz) + 0.5) / nz, (np.arange(ny) + 0.5) / ny, (np.arange(nx) + 0.5) / nx,
                          indexing="ij")
    return np.stack([0.2 + 2.0 * x, 1.0 + y * z, 0.1 + 3.0 * x * (1 - y)], axis=-1).astype(np.float32)


def optical_depth(data, o, d, s, mode, n=20001):
    """Per channel, the integral of sigma_t over [0, s] of o + t d (world = the box), by the trapezoid rule on
    SciPy's interpolation of the grid (index = unit-cube coordinate x n - 1/2, edges clamped or wrapped round)."""
    t = np.linspace(0.0, s, n)
    p = np.asarray(o)[None, :] + t[:, None] * np.asarray(d)[None, :]
    unit = (p - np.array(BOX_LO)) / 2.0
    inside = np.all((unit >= 0.0) & (unit <= 1.0), axis=1)   # the medium exists inside its box only
    nz, ny, nx = data.shape[:3]
    idx = np.stack([unit[:, 2] * nz - 0.5, unit[:, 1] * ny - 0.5, unit[:, 0] * nx - 0.5])
    if mode == "nearest":
        idx = np.floor(idx + 0.5)
    sig = np.stack([map_coordinates(data[..., c], idx, order=0 if mode == "nearest" else 1,
                                    mode="grid-wrap" if mode == "repeat" else "nearest")
                    for c in range(3)], axis=1) * inside[:, None]
    return np.trapezoid(sig, t, axis=0) if hasattr(np, "trapezoid") else np.trapz(sig, t, axis=0)


@kernel
def _track_many(media, ray, s, n, delta):
    """n estimates of the transmittance over [0, s]: ratio tracking's, or delta tracking's weight of a flight
    that passes s (0 for one that scatters first)."""
    media = borrowed(media)
    out = np.zeros((n, 3))
    for i in range(n):
        if delta:
            _, scattered, w, _ = delta_tracking(media, 0, ray, s, np.uint64(i * 7919 + 1), 0)
            if scattered:
                w = (0.0, 0.0, 0.0)
        else:
            w = ratio_tracking(media, 0, ray, s, np.uint64(i * 7919 + 1))
        out[i, 0] = w[0]
        out[i, 1] = w[1]
        out[i, 2] = w[2]
    return out


@pytest.mark.parametrize("mode", ["trilinear", "nearest", "repeat"])
@pytest.mark.parametrize("delta", [False, True], ids=["ratio", "delta"])
def test_tracked_transmittance_matches_quadrature(tmp_path, mode, delta):
    """(repeat: within half a voxel of its faces the grid blends its first and last voxels.)"""
    data = gradient_grid()
    write_grid(tmp_path / "grad.vol", data)
    extra = {"trilinear": "", "nearest": '<string name="filter_type" value="nearest"/>',
             "repeat": '<string name="wrap_mode" value="repeat"/>'}[mode]
    scene = load(box_scene(grid_medium("grad.vol", '<float name="albedo" value="0.8"/>', extra=extra)), tmp_path)
    for o, target in (((-1.5, 1.0, 0.0), (1.5, 1.0, 0.0)), ((-0.9, 0.1, -0.8), (0.7, 1.9, 0.95)),
                      ((0.2, 2.5, 0.3), (0.1, -0.4, -0.2))):
        seg = np.subtract(target, o)
        s = float(np.linalg.norm(seg))
        d = tuple(seg / s)
        est = _track_many(scene.media, (tuple(map(float, o)), d), s, 40000, delta)
        want = np.exp(-optical_depth(data, o, d, s, mode))
        se = est.std(axis=0, ddof=1) / math.sqrt(len(est))
        assert np.all(np.abs(est.mean(axis=0) - want) <= N_SIGMA * se + 1e-4), (o, est.mean(axis=0), want, se)


@kernel
def _walked_and_tracked(media, ray, s, key, xs, size):
    """At each distance xs[i] <= s: (the estimate read from one walk of [0, s] in arrays of ``size``, ratio tracking's
    own from the same numbers), as the beam estimate reads each photon's T."""
    media = borrowed(media)
    steps = (np.empty(size), np.empty((size, 3)))
    n, ended = ratio_tracking_steps(media, 0, ray, s, key, steps)
    out = np.zeros((xs.shape[0], 2, 3))
    for i in range(xs.shape[0]):
        j = np.searchsorted(steps[0][:n], xs[i])
        if j == n and not ended:
            w = ratio_tracking(media, 0, ray, xs[i], key)
        elif j == 0:
            w = (1.0, 1.0, 1.0)
        else:
            w = (steps[1][j - 1, 0], steps[1][j - 1, 1], steps[1][j - 1, 2])
        t = ratio_tracking(media, 0, ray, xs[i], key)
        for c in range(3):
            out[i, 0, c] = w[c]
            out[i, 1, c] = t[c]
    return out, n, ended


@pytest.mark.parametrize("size", [1024, 3], ids=["walked", "arrays-full"])
def test_one_walk_of_a_segment_gives_each_distance_ratio_tracking_s_estimate(tmp_path, size):
    """The beam estimate walks a segment once and reads each photon's T at its distance: the same collisions from the
    same numbers, so the same estimate as ratio tracking to that distance, bit for bit (at random distances: a
    distance that falls on a collision to the last bit could round either way); past a walk whose arrays filled up,
    ratio tracking itself."""
    data = gradient_grid() * 4.0   # dense: many collisions along the segment
    write_grid(tmp_path / "grad.vol", data)
    scene = load(box_scene(grid_medium("grad.vol", '<float name="albedo" value="0.8"/>')), tmp_path)
    o, target = np.array([-1.5, 0.6, -0.7]), np.array([1.4, 1.8, 0.9])
    s = float(np.linalg.norm(target - o))
    ray = (tuple(map(float, o)), tuple((target - o) / s))
    xs = np.random.default_rng(5).uniform(-0.1, s, 4000)
    for key in range(1, 41):
        out, n, ended = _walked_and_tracked(scene.media, ray, s, np.uint64(key * 7919), xs, size)
        assert (ended and n > 3) if size > 3 else (not ended and n == 3)   # dense enough to fill 3 every time
        assert np.array_equal(out[:, 0], out[:, 1])


@pytest.mark.parametrize("mode", ["trilinear", "nearest"])
def test_the_majorant_grid_bounds_sigma_t_wherever_a_ray_reads_it(mode):
    """Each cell's majorant is at least sigma_t at every point of the cell, and beyond the unit cube at every point
    whose cell index is clamped to it (the walk's convention), for a grid of more voxels than cells on two axes."""
    rng = np.random.default_rng(5)
    data = rng.gamma(0.5, 2.0, size=(33, 7, 20, 3)).astype(np.float32)   # (nz, ny, nx, channels)
    vol = Volume(data, np.eye(4), NEAREST if mode == "nearest" else TRILINEAR)
    maj = majorant_grid(vol)
    cz, cy, cx = maj.shape
    assert (cz, cy, cx) == (16, 7, 16) and maj.max() == data.max()
    p = rng.uniform(-0.2, 1.2, size=(200000, 3))
    idx = np.stack([p[:, 2] * 33 - 0.5, p[:, 1] * 7 - 0.5, p[:, 0] * 20 - 0.5])
    if mode == "nearest":
        idx = np.floor(idx + 0.5)
    value = np.max([map_coordinates(data[..., c], idx, order=0 if mode == "nearest" else 1, mode="nearest")
                    for c in range(3)], axis=0)
    cell = [np.clip(np.floor(p[:, a] * n), 0, n - 1).astype(int) for a, n in ((2, cz), (1, cy), (0, cx))]
    assert np.all(value <= maj[cell[0], cell[1], cell[2]] * (1 + 1e-6))


# --------------------------------------------------------------------------- 3. against Mitsuba 3

MI_RES, MI_SPP = 32, 128


def smoke_files(folder):
    """A density gradient (rising with height, thinning towards the box's sides) and an RGB albedo grid."""
    nx, ny, nz = 8, 12, 8
    z, y, x = np.meshgrid((np.arange(nz) + 0.5) / nz, (np.arange(ny) + 0.5) / ny, (np.arange(nx) + 0.5) / nx,
                          indexing="ij")
    write_grid(folder / "smoke.vol", (0.2 + 1.5 * y) * (1.0 - 0.8 * np.abs(x - 0.5)))
    write_grid(folder / "albedo.vol", np.stack([0.9 - 0.3 * y, 0.5 + 0.4 * x, 0.8 * np.ones_like(z)], axis=-1))


@pytest.mark.mitsuba
@pytest.mark.parametrize("kind", ["smoke", "homogeneous-textured"])
def test_a_box_of_smoke_matches_mitsuba_volpath(mi, tmp_path, kind):
    """smoke: the density gradient and RGB albedo grid; homogeneous-textured: Mitsuba's homogeneous medium with a
    <volume> albedo (the grid tiled twice across the box, wrap_mode repeat), which fills the box."""
    smoke_files(tmp_path)
    albedo = f'<volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>{BOX_TO_WORLD}' \
             f'</volume>'
    medium = grid_medium("smoke.vol", albedo, scale=1.5)
    if kind == "homogeneous-textured":
        medium = """<medium type="homogeneous" name="interior"><float name="sigma_t" value="0.8"/>
            <volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>
            <string name="wrap_mode" value="repeat"/><transform name="to_world"><translate y="0.1"/></transform>
            </volume></medium>"""
    text = box_scene(medium, res=MI_RES, spp=MI_SPP)
    (tmp_path / "smoke.xml").write_text(text)
    ours = renders(caustica.load_scene(tmp_path / "smoke.xml"), MI_SPP, res=MI_RES)
    theirs_scene = mi.load_file(str(tmp_path / "smoke.xml"))
    theirs = [np.array(mi.render(theirs_scene, spp=MI_SPP, seed=s), dtype=np.float32)[..., :3] for s in SEEDS]
    assert_images_agree(ours, theirs, label="box of smoke vs Mitsuba volpath")


# --------------------------------------------------------------------------- 4. bad input

def _scene_file(tmp_path, medium):
    """The box scene without its integrator (a volpath integrator under a photon method prints a note)."""
    path = tmp_path / "scene.xml"
    path.write_text(box_scene(medium).replace('<integrator type="volpath"/>', ""))
    return path


def _refused(cli, tmp_path, scene, *args):
    out = tmp_path / "out"
    code, _, err = cli("render", scene, "--res", "8", "--spp", "1", "-q", "-o", out / "x.exr", *args)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("caustica: error: "), err
    assert "Traceback" not in err and not out.exists()
    return lines[0]


def _header(nx, ny, nz, channels, magic=b"VOL", version=3):
    return magic + bytes([version]) + np.array([1, nx, ny, nz, channels], "<i4").tobytes() + \
        np.array([0, 0, 0, 1, 1, 1], "<f4").tobytes()


@pytest.mark.parametrize("case, words", [
    ("missing", ("nothere.vol", "not found")),
    ("magic", ("not a Mitsuba .vol file",)),
    ("truncated", ("truncated", "4 x 4 x 4 voxels x 1 channels")),
    ("negative", ("negative value (-0.5)",)),
    ("channels", ("2 channels", "1 (grey) or 3 (RGB)")),
    ("memory", ("GB", "more than the", "coarser grid")),
])
def test_bad_grid_files_are_one_line_with_file_and_line(cli, tmp_path, case, words):
    grid = tmp_path / "grid.vol"
    if case == "magic":
        grid.write_bytes(b"PNG" + bytes(100))
    elif case == "truncated":
        grid.write_bytes(_header(4, 4, 4, 1) + bytes(4 * 60))
    elif case == "negative":
        write_grid(grid, np.full((2, 2, 2), -0.5))
    elif case == "channels":
        grid.write_bytes(_header(2, 2, 2, 2) + bytes(4 * 16))
    elif case == "memory":
        grid.write_bytes(_header(1 << 15, 1 << 15, 1 << 15, 3) + bytes(64))
    name = "nothere.vol" if case == "missing" else "grid.vol"
    line = _refused(cli, tmp_path, _scene_file(tmp_path, grid_medium(name, "")))
    assert "scene.xml:" in line, line
    for w in words:
        assert w in line, (w, line)


def test_a_grid_of_the_wrong_channel_count_names_its_element(cli, tmp_path):
    write_grid(tmp_path / "grid.vol", np.ones((2, 2, 2, 3)))
    line = _refused(cli, tmp_path, _scene_file(tmp_path, grid_medium("grid.vol", "").replace(
        'name="sigma_t"', 'name="density"')))
    assert "name=\"sigma_t\" or name=\"albedo\"" in line, line


# --------------------------------------------------------------------------- 5. bits

def test_the_homogeneous_fog_keeps_its_bits_with_the_heterogeneous_code_compiled():
    from test_bit_pins import CASES, load_pins
    scene_name, method, kw = CASES["pt-fog"]
    scene = caustica.load_scene(scene_name)
    assert type(scene.media) is not MediumTable   # compiled without the heterogeneous code by default
    scene.media = MediumTable(*scene.media)       # every kind of medium compiled
    image = np.ascontiguousarray(caustica.render(scene, method=method, seed=3, threads=2, **kw).image, np.float32)
    assert hashlib.sha256(image.tobytes()).hexdigest()[:20] == load_pins()["pt-fog"]


# --------------------------------------------------------------------------- 6. the photon methods

#: k above any count within the radius: every estimate a fixed-radius one, linear in the photons' powers, so that the
#: two media's differently distributed photons give the same expectation (a k-nearest radius would not)
FIXED_RADIUS = dict(k=5000, radius=0.15)
#: enough photons and samples that an image mean's spread over the seeds is 0.7 % (measured over 24), so the two
#: sides' means over 4 seeds differ by 0.5 % (one sigma), well inside the comparison's 2 %
PM_KW = dict(termination="roulette", photons=40000, caustic_photons=0, max_bounces=32, spp=64, **FIXED_RADIUS)
#: spm's streams likewise.  Its image mean's spread over seeds at 16 camera samples was 0.94 % in the grid against
#: 0.52 % in the homogeneous medium (64,000 streams, 30 seeds), and 0.50 % against 0.51 % at 64: the tracked
#: transmittance and in-scatter of the camera side add noise that more streams do not take away, more samples do
SPM_KW = dict(termination="roulette", streams=64000, max_bounces=32, spp=64, **FIXED_RADIUS)


@pytest.mark.parametrize("method, params", [("pm", PM_KW), ("spm", SPM_KW)])
def test_the_one_shot_methods_render_a_constant_grid_as_the_homogeneous_medium(tmp_path, method, params):
    """Delta tracking for the photons' (and streams') flights and the roulette's albedo (read from the albedo grid:
    the row holds none), ratio tracking along the camera's segments, the in-scatter distance drawn as in the
    homogeneous medium: in expectation the homogeneous medium's estimate, bias of the beam kernel included."""
    write_grid(tmp_path / "const.vol", np.broadcast_to(np.float32(SIGMA), (3, 4, 5, 3)) / 2.0)
    write_grid(tmp_path / "albedo.vol", np.broadcast_to(np.float32(ALBEDO), (2, 2, 2, 3)))
    albedo = f'<volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>{BOX_TO_WORLD}' \
             f'</volume>'
    hetero = load(box_scene(grid_medium("const.vol", albedo, scale=2.0)), tmp_path)
    homo = load(box_scene(f"""<medium type="homogeneous" name="interior"><rgb name="sigma_t"
        value="{", ".join(map(str, SIGMA))}"/><rgb name="albedo" value="{", ".join(map(str, ALBEDO))}"/>
        <phase type="hg"><float name="g" value="0.3"/></phase></medium>"""), tmp_path)
    assert type(hetero.media) is MediumTable and type(homo.media) is not MediumTable
    images = [[caustica.render(scene, method, seed=s, res=RES, threads=2, **params).image for s in SEEDS]
              for scene in (hetero, homo)]
    assert_images_agree(*images, label=f"{method}: constant grid vs homogeneous")


@pytest.fixture(scope="module")
def smoke_scenes(tmp_path_factory):
    """The two media of section 3 in the box, and pt's renders of each (4 seeds)."""
    folder = tmp_path_factory.mktemp("smoke")
    smoke_files(folder)
    albedo = f'<volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>{BOX_TO_WORLD}' \
             f'</volume>'
    media = {"smoke": grid_medium("smoke.vol", albedo, scale=1.5),
             "homogeneous-textured": """<medium type="homogeneous" name="interior"><float name="sigma_t" value="0.8"/>
                <volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>
                <string name="wrap_mode" value="repeat"/><transform name="to_world"><translate y="0.1"/></transform>
                </volume></medium>"""}
    out = {}
    for kind, medium in media.items():
        scene = load(box_scene(medium), folder)
        out[kind] = scene, [caustica.render(scene, "pt", spp=1024, seed=100 + s, threads=2).image for s in SEEDS]
    return out


@pytest.mark.parametrize("kind", ["smoke", "homogeneous-textured"])
@pytest.mark.parametrize("method, params", [
    ("sppm", dict(termination="roulette", photons=2000, caustic_photons=0, max_bounces=32)),
    ("pspm", dict(termination="roulette", streams=300, assoc=4, stream_radius=1.0, max_bounces=32,
                  estimator="photons"))])
def test_the_progressive_photon_methods_render_heterogeneous_media_as_pt(smoke_scenes, kind, method, params):
    scene, pt = smoke_scenes[kind]
    ours = [caustica.render(scene, method, passes=128, seed=s, threads=2, **params).image for s in SEEDS]
    assert_images_agree(ours, pt, label=f"{method} vs pt, {kind}")


# --------------------------------------------------------------------------- 7. the default volume radius

def _varying(shape):
    """A grid of ``shape`` whose values change along every axis of more than one voxel."""
    return (1.0 + np.arange(math.prod(shape)) % 7).reshape(shape).astype(np.float32)


def _layered_scene(tmp_path, shape, to_world=BOX_TO_WORLD, albedo_shape=None, data=None, unused=""):
    """The box holding a grid of ``shape`` (nz, ny, nx) voxels (``data``, else :func:`_varying`) placed by
    ``to_world``, with an albedo grid of ``albedo_shape`` voxels (on the box) or a constant albedo; ``unused``: a
    <medium> declared beside it that nothing refers to."""
    write_grid(tmp_path / "layers.vol", _varying(shape) if data is None else data)
    albedo = '<rgb name="albedo" value="0.9"/>'
    if albedo_shape is not None:
        write_grid(tmp_path / "albedo.vol", _varying(albedo_shape) / 8.0)
        albedo = f'<volume type="gridvolume" name="albedo"><string name="filename" value="albedo.vol"/>' \
                 f'{BOX_TO_WORLD}</volume>'
    medium = f"""<medium type="heterogeneous" name="interior"><volume type="gridvolume" name="sigma_t">
        <string name="filename" value="layers.vol"/>{to_world}</volume>{albedo}</medium>"""
    return load(box_scene(medium).replace("<integrator", unused + "<integrator", 1), tmp_path)


def test_the_finest_voxel_is_read_from_every_grid_of_every_medium_in_use(tmp_path):
    """Along each axis on which a grid's values change, its to_world column over the voxel count; the albedo grid's
    voxels count too; a grid constant along an axis has no voxels there, a constant grid or a homogeneous medium none
    at all, and a medium nothing refers to does not count."""
    from caustica.methods.photon_common import finest_voxel
    assert finest_voxel(_layered_scene(tmp_path, (4, 16, 1)).description) == pytest.approx(2.0 / 16)
    assert finest_voxel(_layered_scene(tmp_path, (4, 2, 1), albedo_shape=(1, 1, 40)).description) \
        == pytest.approx(2.0 / 40)
    rotated = '<transform name="to_world"><scale x="3" y="1" z="2"/><rotate y="1" angle="30"/></transform>'
    assert finest_voxel(_layered_scene(tmp_path, (8, 1, 10), to_world=rotated).description) \
        == pytest.approx(min(3.0 / 10, 2.0 / 8))
    along_y = np.broadcast_to(_varying((1, 4, 1)), (30, 4, 20)).copy()   # changes along y only
    assert finest_voxel(_layered_scene(tmp_path, (30, 4, 20), data=along_y).description) == pytest.approx(2.0 / 4)
    assert finest_voxel(_layered_scene(tmp_path, (1, 1, 1)).description) == math.inf
    assert finest_voxel(_layered_scene(tmp_path, (3, 4, 5), data=np.ones((3, 4, 5), np.float32)).description) \
        == math.inf
    homogeneous = load(box_scene('<medium type="homogeneous" name="interior"/>'), tmp_path)
    assert finest_voxel(homogeneous.description) == math.inf
    write_grid(tmp_path / "fine.vol", _varying((1, 1, 200)))
    unused = f"""<medium type="heterogeneous" id="spare"><volume type="gridvolume" name="sigma_t">
        <string name="filename" value="fine.vol"/>{BOX_TO_WORLD}</volume></medium>"""
    scene = _layered_scene(tmp_path, (4, 16, 1), unused=unused)
    assert len(scene.description.media) == 2 and finest_voxel(scene.description) == pytest.approx(2.0 / 16)


@pytest.mark.parametrize("shape, expected", [((1, 16, 1), 0.5 * 2.0 / 16),   # half a voxel: below the default
                                             ((1, 4, 1), None),               # coarse voxels: the default
                                             ((1, 160, 1), "floor")])         # fine voxels: a quarter of the default
def test_the_default_volume_radius_is_limited_by_the_voxels(tmp_path, shape, expected):
    """The beam estimate takes the photons within its radius of a camera ray, so across a voxel boundary it counts
    photons scattered where the grid is denser than along the ray (docs/media.md: a layered grid and the corpus's
    16³ grids)."""
    scene = _layered_scene(tmp_path, shape)
    box = scene.geometry.scene_box
    default = 0.01 * float(np.linalg.norm(box[3:] - box[:3]))   # RADIUS_FRACTION and VOLUME_RADIUS_FRACTION of it
    want = default if expected is None else (0.25 * default if expected == "floor" else expected)
    sppm = caustica.render(scene, "sppm", passes=1, res=4, photons=100, caustic_photons=0).stats
    pm = caustica.render(scene, "pm", res=4, photons=100, caustic_photons=0, spp=1).stats
    assert sppm["initial_volume_radius"] == pytest.approx(want) and pm["volume_radius"] == pytest.approx(want)
    set_sppm = caustica.render(scene, "sppm", passes=1, res=4, photons=100, caustic_photons=0, volume_radius=0.3)
    set_pm = caustica.render(scene, "pm", res=4, photons=100, caustic_photons=0, spp=1, volume_radius=0.3)
    assert set_sppm.stats["initial_volume_radius"] == 0.3 and set_pm.stats["volume_radius"] == 0.3
