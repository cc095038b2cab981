"""Photon mapping (method ``pm``, SPEC §2-3): power conservation of the photon tracer,
Russian roulette, the caustic map, agreement with the path tracer, determinism and
parameter checking.

Tolerances are derived, not tuned: a total over N independent photons is compared with
its expectation within 5 standard errors, the standard error being the sample standard
deviation of the per-photon contribution over sqrt(N) (with fixed seeds the tests are
deterministic; 5 sigma keeps a reseeded run from failing by chance).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

import caustica
from caustica.errors import ParameterError
from caustica.photons.records import CAUSTIC, EMPTY, INDIRECT, allocate_buffers
from caustica.photons import trace as trace_module
from caustica.photons.trace import TERMINATION_CAP, TERMINATION_ROULETTE, trace_caustic_photon_pass, trace_photon_pass
from caustica.sampling.rng import STREAM_CAUSTIC_PHOTON, STREAM_PHOTON
from caustica.tables import compile_scene
from caustica.scene.xml_loader import parse_scene_string

RHO = np.array([0.6, 0.5, 0.4])
SENSOR = """<sensor type="perspective"><float name="fov" value="60"/>
  <transform name="to_world"><lookat origin="0, 0, 4" target="0, 0, -1" up="0, 1, 0"/></transform>
  <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/></film></sensor>"""
WALLS = f"""<shape type="cube"><transform name="to_world"><scale value="5"/></transform>
  <boolean name="flip_normals" value="true"/>
  <bsdf type="diffuse"><rgb name="reflectance" value="{', '.join(map(str, RHO))}"/></bsdf></shape>"""
POINT_I = np.array([1.0, 2.0, 3.0])
POINT_BOX = f"""<?xml version="1.0"?><scene version="3.0.0">{SENSOR}{WALLS}
<emitter type="point"><point name="position" x="1" y="0.5" z="-0.3"/>
  <rgb name="intensity" value="{', '.join(map(str, POINT_I))}"/></emitter></scene>"""
# The area light's plate reflects like the walls on both sides, so every diffuse hit scales by ρ.
AREA_L = np.array([4.0, 3.0, 2.0])
AREA_BOX = f"""<?xml version="1.0"?><scene version="3.0.0">{SENSOR}{WALLS}
<shape type="rectangle"><transform name="to_world"><scale value="0.5"/><rotate x="1" angle="90"/>
  <translate x="0.5" y="4" z="1"/></transform>
  <bsdf type="twosided"><bsdf type="diffuse"><rgb name="reflectance" value="{', '.join(map(str, RHO))}"/></bsdf></bsdf>
  <emitter type="area"><rgb name="radiance" value="{', '.join(map(str, AREA_L))}"/></emitter></shape></scene>"""
BOXES = {"point": (POINT_BOX, 4.0 * math.pi * POINT_I),     # Φ = 4π I
         "area": (AREA_BOX, math.pi * AREA_L * 1.0)}        # Φ = π L A, A = 1 x 1


def xml_scene(text, name="test.xml"):
    return compile_scene(parse_scene_string(text, ".", None, name))


def trace(scene, n, mr, termination=TERMINATION_CAP, seed=5, threads=None):
    buf, _, _ = trace_photon_pass(scene, (seed, STREAM_PHOTON, n), (mr, termination), threads=threads)
    return buf


def per_photon_slot_power(buf, n, mr):
    """(n, mr + 1, 3) float64: the power photon i stored in its s-th record (0 where none)."""
    pw = buf.power.astype(np.float64).reshape(n, mr + 1, 3).copy()
    pw[buf.kind.reshape(n, mr + 1) == EMPTY] = 0.0
    return pw


N_BOX, MR_BOX = 60_000, 4


@pytest.fixture(scope="module", params=sorted(BOXES))
def closed_box(request):
    text, phi = BOXES[request.param]
    scene = xml_scene(text, f"box-{request.param}.xml")
    cap = trace(scene, N_BOX, MR_BOX, TERMINATION_CAP)
    rr = trace(scene, N_BOX, MR_BOX, TERMINATION_ROULETTE)
    return request.param, scene, phi, cap, rr


# ----------------------------------------------------------------------------- power conservation

def test_emitted_power_matches_light(closed_box):
    """Each photon leaves the light with Φ / N (the photons' powers sum to the light's power)."""
    kind, scene, phi, cap, _ = closed_box
    from caustica.photons.emission import emit_photon
    from caustica.sampling.rng import path_key
    total = np.zeros(3)
    for i in range(200):
        key = np.uint64(path_key(5, STREAM_PHOTON, i))   # (a uint64 comes back as a Python int)
        _, _, p, _ = emit_photon(scene.geometry, scene.lights, key, N_BOX)
        total += p
    np.testing.assert_allclose(total / 200 * N_BOX, phi, rtol=1e-9)


def test_cap_stored_power_per_bounce(closed_box):
    """termination=cap in a closed box: the record after b diffuse bounces carries Φ ρ^b / N exactly.

    Records of the first hit are direct light and are not stored, so a photon's slot s
    (s = 0 .. mr-1) holds the hit after s + 1 bounces; the last slot stays empty.  The
    expectation is exact; the only randomness is a photon lost to a numerical leak or a
    degenerate bounce, which the 5-standard-error band (from the per-photon sample
    variance, ≈ 0 here) would reveal.
    """
    kind, scene, phi, buf, _ = closed_box
    pw = per_photon_slot_power(buf, N_BOX, MR_BOX)
    counts = (buf.kind.reshape(N_BOX, MR_BOX + 1) != EMPTY).sum(axis=0)
    assert counts[MR_BOX] == 0
    assert np.all(buf.kind[buf.kind != EMPTY] == INDIRECT)
    for s in range(MR_BOX):
        b = s + 1
        expected = phi * RHO ** b
        total = pw[:, s].sum(axis=0)
        se = pw[:, s].std(axis=0, ddof=1) * math.sqrt(N_BOX)
        assert np.all(np.abs(total - expected) <= 5 * se + 1e-6 * expected), (kind, b, total, expected, se)
        assert counts[s] >= N_BOX * (1 - 1e-4), (kind, b, counts[s])   # (almost) no photon leaks


def test_roulette_same_expected_power_as_cap(closed_box):
    kind, scene, phi, cap, rr = closed_box
    pw = per_photon_slot_power(rr, N_BOX, MR_BOX)
    q = RHO.max()
    counts = (rr.kind.reshape(N_BOX, MR_BOX + 1) != EMPTY).sum(axis=0)
    for s in range(MR_BOX):
        b = s + 1
        expected = phi * RHO ** b
        total = pw[:, s].sum(axis=0)
        se = pw[:, s].std(axis=0, ddof=1) * math.sqrt(N_BOX)
        assert np.all(se > 0)
        assert np.all(np.abs(total - expected) <= 5 * se), (kind, b, total, expected, se)
        # survivors after b roulette games: N q^b, binomial
        p = q ** b
        assert abs(counts[s] - N_BOX * p) <= 5 * math.sqrt(N_BOX * p * (1 - p)), (kind, b, counts[s])
    # and the total over all bounces
    tot = pw.sum(axis=1)
    se = tot.std(axis=0, ddof=1) * math.sqrt(N_BOX)
    expected = phi * sum(RHO ** b for b in range(1, MR_BOX + 1))
    assert np.all(np.abs(tot.sum(axis=0) - expected) <= 5 * se)


def test_roulette_never_raises_a_photon_s_power(closed_box):
    """Roulette survives a bounce with the largest channel of its weight, so no channel of a photon's power grows:
    every record holds at most what the photon left its light with, Φ / N.  With the mean (0.5 here) the red of
    albedo 0.6 grew 1.2 times a bounce, and in a room of a strong colour its second moment without bound."""
    kind, _, phi, _, rr = closed_box
    stored = rr.kind != EMPTY
    assert stored.sum() > N_BOX
    assert np.all(rr.power[stored].astype(np.float64).max(axis=0) <= phi / N_BOX * (1 + 1e-6)), kind


def test_roulette_without_a_cap_keeps_every_record(closed_box, monkeypatch):
    """Roulette with a --max-bounces no path reaches: each photon keeps its first records in slots of its own and
    is traced again for the rest, which follow in photon order.  The records are bit for bit those of a block of
    slots per photon deep enough for every path (0.5 ** 160 of a path longer), in that order, for 1 or 2 threads;
    and they carry the box's power over every bounce, Φ Σ_b ρ^b = Φ ρ / (1 - ρ)."""
    kind, scene, phi, _, _ = closed_box
    n, mr, deep = 20_000, 1024, 160
    rules = (mr, TERMINATION_ROULETTE)
    buf, records, _ = trace_photon_pass(scene, (5, STREAM_PHOTON, n), rules, threads=2)
    one, _, _ = trace_photon_pass(scene, (5, STREAM_PHOTON, n), rules, threads=1)
    k = trace_module.fixed_slots(mr)
    assert records == buf.kind.shape[0] > n * k   # some paths were longer than their fixed slots
    monkeypatch.setattr(trace_module, "FIXED_SLOTS", deep)
    ref, _, _ = trace_photon_pass(scene, (5, STREAM_PHOTON, n), rules)
    assert ref.kind.shape[0] == n * deep   # no path made more than `deep` records
    slot = np.tile(np.arange(deep), n)
    head = (slot < k) & (ref.kind != EMPTY)
    tail = (slot >= k) & (ref.kind != EMPTY)
    for a, b, c in zip(buf, ref, one):
        np.testing.assert_array_equal(a[:n * k][buf.kind[:n * k] != EMPTY], b[head])
        np.testing.assert_array_equal(a[n * k:], b[tail])
        np.testing.assert_array_equal(a, c)
    assert np.all(buf.kind[n * k:] != EMPTY)
    per_photon = ref.power.astype(np.float64).reshape(n, deep, 3).sum(axis=1)
    se = per_photon.std(axis=0, ddof=1) * math.sqrt(n)
    expected = phi * RHO / (1 - RHO)
    assert np.all(np.abs(per_photon.sum(axis=0) - expected) <= 5 * se), (kind, per_photon.sum(0), expected, se)


BLACK_COATED_BOX = f"""<?xml version="1.0"?><scene version="3.0.0">{SENSOR}
<shape type="cube"><transform name="to_world"><scale value="5"/></transform>
  <boolean name="flip_normals" value="true"/>
  <bsdf type="roughplastic"><rgb name="diffuse_reflectance" value="0, 0, 0"/><float name="alpha" value="0.3"/></bsdf>
</shape>
<emitter type="point"><point name="position" x="1" y="0.5" z="-0.3"/>
  <rgb name="intensity" value="{', '.join(map(str, POINT_I))}"/></emitter></scene>"""


def test_roulette_keeps_a_black_based_coatings_reflection():
    """Rough plastic over a black base reflects only by its coating, a non-delta lobe.  Roulette there survives
    with the sample's largest weight, so the stored power after each bounce has the expectation cap gives it; a
    survival probability taken from the material's colour (0 here) ended every photon at the first bounce."""
    scene = xml_scene(BLACK_COATED_BOX, "black-coated-box.xml")
    n = 40_000
    cap = per_photon_slot_power(trace(scene, n, MR_BOX, TERMINATION_CAP), n, MR_BOX)
    rr = per_photon_slot_power(trace(scene, n, MR_BOX, TERMINATION_ROULETTE), n, MR_BOX)
    for s in range(MR_BOX - 1):
        a, b = cap[:, s].sum(axis=0), rr[:, s].sum(axis=0)
        se = math.sqrt(n) * np.hypot(cap[:, s].std(axis=0, ddof=1), rr[:, s].std(axis=0, ddof=1))
        assert np.all(a > 0) and np.all(se > 0), (s, a, se)
        assert np.all(np.abs(a - b) <= 5 * se), (s, a, b, se)


# ----------------------------------------------------------------------------- the caustic map

@pytest.fixture(scope="module")
def diacaustic():
    return caustica.load_scene("cornell-diacaustic")


@pytest.fixture(scope="module")
def catacaustic():
    return caustica.load_scene("cornell-catacaustic")


@pytest.fixture(scope="module")
def pyramid():
    return caustica.load_scene("cornell-pyramid")


def test_caustic_map_holds_only_lsd_records_on_diffuse_surfaces(diacaustic):
    s = diacaustic
    spheres = s.specular_bounding_spheres()
    assert spheres.shape == (1, 4)
    np.testing.assert_allclose(spheres[0], [4, 4, 2, 4], rtol=1e-8)   # the glass sphere itself
    n_c = 40_000
    buf = allocate_buffers(n_c, 1)
    trace_caustic_photon_pass(s, buf, 3, STREAM_CAUSTIC_PHOTON, n_c, spheres=spheres)
    keep = buf.kind != EMPTY
    assert keep.sum() > 0.1 * n_c
    assert np.all(buf.kind[keep] == CAUSTIC)
    p = buf.position[keep].astype(np.float64)
    # every record lies on one of the box's diffuse walls (never on the glass sphere)
    on_wall = ((np.abs(np.abs(p[:, 0]) - 10) < 1e-3) | (np.abs(p[:, 1]) < 1e-3)
               | (np.abs(p[:, 1] - 20) < 1e-3) | (np.abs(p[:, 2] + 10) < 1e-3)
               | ((np.abs(p[:, 1] - 19.99) < 1e-3) & (np.abs(p[:, 0]) <= 1.5) & (np.abs(p[:, 2]) <= 1.5)))  # the light's plate
    assert on_wall.all(), p[~on_wall][:5]
    # and the bulk of it is the focused spot on the floor below the sphere
    floor = np.abs(p[:, 1]) < 1e-3
    spot = floor & (np.hypot(p[:, 0] - 5, p[:, 2] - 2.5) < 2.5)
    pw = buf.power[keep].astype(np.float64).sum(axis=1)
    assert pw[spot].sum() > 0.7 * pw.sum()


def box_spheres(s):
    """What the caustic map aimed at before: the sphere about each specular shape's bounding box."""
    out = []
    for sh in s.specular_shapes():
        lo, hi = s.geometry.shape_box[sh, :3], s.geometry.shape_box[sh, 3:]
        out.append([*(0.5 * (lo + hi)), 0.5 * float(np.linalg.norm(hi - lo))])
    return np.array(out)


def stored_fraction(s, spheres, n, seed=3):
    buf = allocate_buffers(n, 1)
    trace_caustic_photon_pass(s, buf, seed, STREAM_CAUSTIC_PHOTON, n, spheres=spheres)
    return float((buf.kind != EMPTY).mean())


def test_caustic_spheres_are_tight_and_hold_their_shape(catacaustic):
    s = catacaustic
    (sphere,) = s.specular_bounding_spheres()
    g = s.geometry
    tri = np.nonzero(g.prim_shape == s.specular_shapes()[0])[0]
    v = np.concatenate([g.tri_p0[tri], g.tri_p0[tri] + g.tri_e1[tri], g.tri_p0[tri] + g.tri_e2[tri]])
    assert np.all(np.linalg.norm(v - sphere[:3], axis=1) <= sphere[3])
    # the half ring (radius 3.5, height 5): its ends are a diameter apart, so its minimal enclosing
    # sphere has the ring's axis point at mid-height as centre and radius sqrt(3.5^2 + 2.5^2)
    assert sphere[3] <= 1.01 * math.hypot(3.5, 2.5)
    assert sphere[3] < box_spheres(s)[0, 3]


def test_aimed_caustic_photons_hit_the_specular_object(diacaustic, catacaustic):
    """The fraction of aimed photons that reach the mirror / glass (and so store a record) rises with
    the tight sphere: about 31 % -> 97 % for the glass sphere (the box's sphere has radius 6.93, the
    glass 4); the half ring fills little of any sphere about it, 29 % -> 32 %."""
    n = 40_000
    tight = stored_fraction(diacaustic, diacaustic.specular_bounding_spheres(), n)
    box = stored_fraction(diacaustic, box_spheres(diacaustic), n)
    assert tight > 0.9 and box < 0.4, (tight, box)
    tight = stored_fraction(catacaustic, catacaustic.specular_bounding_spheres(), n)
    box = stored_fraction(catacaustic, box_spheres(catacaustic), n)
    se = math.sqrt(0.25 / n)                     # the standard error of a fraction is at most sqrt(1/4n)
    assert tight - box > 5 * math.sqrt(2) * se, (tight, box)


@pytest.mark.parametrize("scene_name", ["cornell-diacaustic", "cornell-catacaustic"])
def test_caustic_photons_carry_the_same_power_as_lsd_paths_of_the_global_pass(scene_name):
    """Aimed caustic photons are weighted by the aiming pdf: the L S+ D power they store equals,
    in expectation, the power of the CAUSTIC records of ordinary photons (SPEC §3: unbiased).
    This also shows the tight spheres hold the whole mirror / glass: a part outside them would
    lose its caustic power here."""
    s = caustica.load_scene(scene_name)
    n = 200_000
    g = trace(s, n, 1, seed=9)
    gpow = per_photon_slot_power(g, n, 1)
    gpow[g.kind.reshape(n, 2) != CAUSTIC] = 0.0
    x_g = gpow.sum(axis=1)
    c = allocate_buffers(n, 1)
    trace_caustic_photon_pass(s, c, 9, STREAM_CAUSTIC_PHOTON, n)
    x_c = c.power.astype(np.float64) * (c.kind != EMPTY)[:, None]
    tg, tc = x_g.sum(axis=0), x_c.sum(axis=0)
    se = np.sqrt(x_g.var(axis=0, ddof=1) * n + x_c.var(axis=0, ddof=1) * n)
    assert np.all(np.abs(tg - tc) <= 5 * se), (tg, tc, se)
    # the aimed photons are the better estimate: their standard error is much smaller
    assert np.all(x_c.std(axis=0) < 0.5 * x_g.std(axis=0))


def test_pm_c_global_map_leaves_out_caustic_paths(diacaustic):
    n, n_c = 20_000, 5_000
    pm = caustica.render(diacaustic, "pm", spp=1, res=8, seed=4, photons=n)
    pmc = caustica.render(diacaustic, "pm", spp=1, res=8, seed=4, photons=n, caustic_photons=n_c)
    buf = trace(diacaustic, n, 4, seed=4)                  # the same photons as the renders' global pass
    n_caustic = int((buf.kind == CAUSTIC).sum())
    n_all = int((buf.kind != EMPTY).sum())
    assert n_caustic > 0
    assert pm.stats["global_photons_stored"] == n_all
    assert pmc.stats["global_photons_stored"] == n_all - n_caustic
    assert pmc.stats["caustic_photons_emitted"] == n_c
    assert 0 < pmc.stats["caustic_photons_stored"] <= n_c
    assert pmc.stats["photons_emitted"] == n + n_c
    assert pmc.stats["photons_stored"] == pmc.stats["global_photons_stored"] + pmc.stats["caustic_photons_stored"]
    assert "note" not in pmc.stats


def test_no_specular_objects_no_caustic_map(pyramid):
    a = caustica.render(pyramid, "pm", spp=1, res=16, seed=2, photons=5000, caustic_photons=5000)
    b = caustica.render(pyramid, "pm", spp=1, res=16, seed=2, photons=5000)
    assert "caustic map was not built" in a.stats["note"]
    assert "caustic_photons_stored" not in a.stats
    assert a.stats["photons_emitted"] == 5000
    assert a.stats["global_photons_stored"] == b.stats["global_photons_stored"]
    np.testing.assert_array_equal(a.image, b.image)


def test_pm_c_image_mean_matches_pm(diacaustic):
    """The caustic map adds resolution, not energy.

    With the same seed, PM and PM+C share the camera samples and the global photons, so their
    difference isolates the caustic map against the global map's own L S+ D records; the
    noise of that paired difference is measured over 6 seeds and the mean difference must
    lie within 5 standard errors of 0 (measured: 0.01 standard errors).
    """
    d_img, rel_blk = [], []
    for seed in range(1, 7):
        a = caustica.render(diacaustic, "pm", spp=2, res=32, seed=seed, photons=40_000).image.astype(np.float64)
        b = caustica.render(diacaustic, "pm", spp=2, res=32, seed=seed, photons=40_000,
                            caustic_photons=40_000).image.astype(np.float64)
        d_img.append(b.mean() - a.mean())
        blk = lambda im: im.reshape(4, 8, 4, 8, 3).mean(axis=(1, 3, 4))
        rel_blk.append(np.abs(blk(b) / blk(a) - 1).max())
    d_img = np.array(d_img)
    assert abs(d_img.mean()) <= 5 * d_img.std(ddof=1) / math.sqrt(len(d_img)) + 1e-6, d_img
    # Blocks: the caustic map's own density gives its estimate another radius, i.e. another
    # blur of the caustic, which legitimately moves energy between neighbouring blocks (seen:
    # up to 3.7 paired standard errors in the caustic's block), so blocks get a relative
    # bound only (measured: 4.9 % at most).
    assert max(rel_blk) < 0.1


# ----------------------------------------------------------------------------- against the path tracer

def test_pm_agrees_with_pt_on_the_pyramid(pyramid):
    """PM (mr = 4) against pt with max_depth = mr + 2 (Mitsuba's depth: camera -> gather point ->
    mr diffuse vertices of the photon -> emitter), the same light paths.

    Pixels that see the emitter directly are left out (at low spp their antialiased edge
    dominates the image's noise and is the same quantity in both methods).
    Tolerances: image mean 3 % (the brief); 4x4 blocks (12x12 px, ≈ 5x5 scene units) 6 %:
    the k = 100 estimate has r ≈ 0.35 here (≈ 300 records per unit² for 200k photons), and
    where its disc crosses a wall's edge it underestimates by up to 1/2 (edge) or 3/4
    (corner); that band covers ≈ 2r / 5 ≈ 15 % of a block and indirect light is ≈ 40 % of
    it, so ≲ 3 % of bias, plus ≈ 1 % noise of pt and of the photons.  Measured: ≤ 2.6 %.
    """
    res, mr = 48, 4
    emit = caustica.render(pyramid, "pt", spp=64, res=res, seed=1, max_depth=1).image.max(axis=2) > 0
    mask = emit.copy()
    mask[1:] |= emit[:-1]; mask[:-1] |= emit[1:]; mask[:, 1:] |= emit[:, :-1]; mask[:, :-1] |= emit[:, 1:]
    ref = caustica.render(pyramid, "pt", spp=192, res=res, seed=1, max_depth=mr + 2).image.astype(np.float64)
    pm = caustica.render(pyramid, "pm", spp=4, res=res, seed=1, photons=200_000,
                         max_bounces=mr).image.astype(np.float64)
    keep = ~mask
    assert 0 < mask.sum() < 0.1 * mask.size
    rel = pm[keep].mean() / ref[keep].mean() - 1
    assert abs(rel) < 0.03, rel

    def blocks(im):
        w = np.where(keep[..., None], im, 0.0).reshape(4, 12, 4, 12, 3).sum(axis=(1, 3, 4))
        return w / keep.reshape(4, 12, 4, 12).sum(axis=(1, 3))
    rb = blocks(pm) / blocks(ref) - 1
    assert np.abs(rb).max() < 0.06, np.round(rb, 3)


# A corridor of two parallel mirrors (Mitsuba's default conductor reflects everything) ending in an emitting
# wall with a black BSDF: the camera looks down it at a slope, so every ray meets the mirrors 29-31 times
# before the wall, and every pixel sees the wall's radiance exactly.
CORRIDOR_L = np.array([1.0, 2.0, 3.0])
CORRIDOR = f"""<?xml version="1.0"?><scene version="3.0.0">
<sensor type="perspective"><float name="fov" value="2"/>
  <transform name="to_world"><lookat origin="0.2, 0, 0" target="1.2, 1.5, 0" up="0, 0, 1"/></transform>
  <film type="hdrfilm"><integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>
<bsdf type="conductor" id="mirror"/>
<shape type="rectangle"><transform name="to_world"><scale x="10" y="1"/><rotate x="1" angle="90"/>
  <translate x="10" y="0.5"/></transform><ref id="mirror"/></shape>
<shape type="rectangle"><transform name="to_world"><scale x="10" y="1"/><rotate x="1" angle="-90"/>
  <translate x="10" y="-0.5"/></transform><ref id="mirror"/></shape>
<shape type="rectangle"><transform name="to_world"><scale x="1" y="0.5"/><rotate y="1" angle="-90"/>
  <translate x="20"/></transform><bsdf type="diffuse"><rgb name="reflectance" value="0"/></bsdf>
  <emitter type="area"><rgb name="radiance" value="{', '.join(map(str, CORRIDOR_L))}"/></emitter></shape>
</scene>"""


@pytest.mark.parametrize("method, budget", [("pm", dict(spp=1, photons=2000)), ("spm", dict(spp=1, streams=200)),
                                            ("sppm", dict(passes=2)), ("pspm", dict(passes=2))])
def test_camera_paths_follow_long_mirror_chains(method, budget):
    """Every photon method's camera path reaches the corridor's end wall through its 29-31 mirror bounces, by
    default: each pixel is the wall's radiance.  (Their cap on a camera path's specular bounces was 16, and the
    image black; a diamond under an environment map rendered 8 % dark in sppm for the same reason.)"""
    scene = xml_scene(CORRIDOR, "corridor.xml")
    image = caustica.render(scene, method, seed=1, **budget).image
    np.testing.assert_allclose(image, np.broadcast_to(CORRIDOR_L, image.shape), rtol=1e-5)
    capped = caustica.render(scene, method, seed=1, max_specular_depth=28, **budget).image
    assert not capped.any()


# ----------------------------------------------------------------------------- determinism, parameters

def test_pm_deterministic_across_threads_and_seeds(diacaustic):
    kw = dict(spp=1, res=16, photons=8000, caustic_photons=4000)
    a = caustica.render(diacaustic, "pm", seed=3, threads=1, **kw)
    b = caustica.render(diacaustic, "pm", seed=3, threads=2, **kw)
    c = caustica.render(diacaustic, "pm", seed=4, threads=2, **kw)
    assert a.image.tobytes() == b.image.tobytes()
    for key in ("global_photons_stored", "caustic_photons_stored", "map_bytes"):
        assert a.stats[key] == b.stats[key]
    assert a.image.tobytes() != c.image.tobytes()
    # the buffers themselves, record by record
    s = diacaustic
    b1 = trace(s, 3000, 4, seed=8, threads=1)
    b2 = trace(s, 3000, 4, seed=8, threads=2)
    for x, y in zip(b1, b2):
        assert x.tobytes() == y.tobytes()


@pytest.mark.parametrize("params, match", [
    (dict(photon=100), "photon"),
    (dict(photons=-5), "photons"),
    (dict(photons=0), "photons"),
    (dict(caustic_photons=-1), "caustic"),
    (dict(filter="box"), "filter"),
    (dict(termination="never"), "termination"),
    (dict(radius=0.0), "radius"),
    (dict(k=0), "k"),
    (dict(max_bounces=0), "max-bounces"),
    (dict(photons=1.5), "photons"),
    (dict(assoc=3), "assoc"),
])
def test_pm_parameter_errors(diacaustic, params, match):
    with pytest.raises(ParameterError, match=match):
        caustica.render(diacaustic, "pm", spp=1, res=4, **params)
