"""Tinted glass: Mitsuba's ``specular_reflectance`` and ``specular_transmittance`` on dielectric, thindielectric and
roughdielectric (bsdfs/dielectric.py's ``tints``).  They scale the reflected and the transmitted light; the choice
between the two stays Fresnel's.

1. Against Mitsuba 3's own BSDFs (``scalar_rgb``): the weight of each branch a smooth glass samples, and a rough
   glass's f·|cos| and pdf at random direction pairs.
2. Every sample's weight is its branch's tint (the reflected one where it reflects), with the branch frequencies of
   clear glass.
3. tests/scenes/tinted-glass.xml (a smooth amber ball, a rough blue ball, a pane with a checkerboard transmittance,
   each with its own reflectance) against Mitsuba's path tracer: pt and every photon method (the caustics are the
   tinted ones), image mean within 2 % and every 4x4 block within 5 sigmas of both renderers' noise.
4. The loader reads both tints, a texture for the transmittance, and refuses a negative tint or a textured
   reflectance in one line (tests/test_glossy.py, test_thindielectric.py, test_textures.py).
"""
from __future__ import annotations

import math
import types

import numpy as np
import pytest

import caustica
from caustica import bsdfs
from caustica.scene.description import DIELECTRIC, GGX, ROUGHDIELECTRIC, THINDIELECTRIC, Material
from bsdfcompare import direction_pairs, mitsuba_f_pdf
from imagestats import assert_images_agree
from test_glossy import CAUSTIC_PHOTON_METHODS, bsdfs_camera_scale, draw, eval_many, incident

REFLECTANCE = (0.5, 0.8, 1.0)
TRANSMITTANCE = (0.95, 0.6, 0.2)
SCENE = __import__("pathlib").Path(__file__).parent / "scenes" / "tinted-glass.xml"


def table(kind, eta=1.5, alpha=0.3):
    """A one-material table of tinted glass, built as a scene's is (build_material_table)."""
    mat = Material(kind, TRANSMITTANCE, int_ior=eta, ext_ior=1.0, specular=REFLECTANCE, distribution=GGX,
                   alpha=alpha)
    return bsdfs.build_material_table(types.SimpleNamespace(materials=[mat]))


def mitsuba_glass(mi, kind, eta=1.5, alpha=0.3):
    props = {"type": kind, "int_ior": eta, "ext_ior": 1.0,
             "specular_reflectance": {"type": "rgb", "value": REFLECTANCE},
             "specular_transmittance": {"type": "rgb", "value": TRANSMITTANCE}}
    if kind == "roughdielectric":
        props.update(distribution="ggx", alpha=alpha)
    return mi.load_dict(props)


@pytest.mark.parametrize("kind", [DIELECTRIC, THINDIELECTRIC], ids=["dielectric", "thindielectric"])
def test_smooth_glass_branch_weights_match_mitsuba(mi, kind):
    """Mitsuba's sample with the lobe number 0 (reflection) and just under 1 (transmission): its weight is the
    branch's tint (times 1/eta² across a refraction, radiance mode); ours is the tint, and camera paths apply the
    1/eta² themselves.  Every one of our samples weighs its branch's tint exactly."""
    name = "dielectric" if kind == DIELECTRIC else "thindielectric"
    mats, theirs = table(kind), mitsuba_glass(mi, name)
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    for theta in (0.0, 40.0, 75.0):
        for below in (False, True):
            d = incident(theta, below)
            si.wi = mi.Vector3f(*(-np.array(d)))
            out = draw(mats, d, n=4_000, seed=3)
            refl = out[:, 12] == bsdfs.DELTA_REFLECTION
            assert np.all(out[:, 0] == 1.0)
            np.testing.assert_array_equal(out[refl, 4:7], np.broadcast_to(REFLECTANCE, (int(refl.sum()), 3)))
            np.testing.assert_array_equal(out[~refl, 4:7], np.broadcast_to(TRANSMITTANCE, (int((~refl).sum()), 3)))
            bs, w = theirs.sample(ctx, si, 0.0, mi.Point2f(0.5, 0.5))
            assert mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
            np.testing.assert_allclose(np.array(w), REFLECTANCE, rtol=1e-6)
            if float(bs.pdf) < 1.0:      # not total internal reflection
                bs, w = theirs.sample(ctx, si, 1.0 - 1e-7, mi.Point2f(0.5, 0.5))
                assert not mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection)   # thin: Mitsuba's Null lobe
                wt = out[~refl][0]
                wi = (wt[1], wt[2], wt[3])
                np.testing.assert_allclose(wi, np.array(bs.wo), atol=1e-6)
                eta = wt[13]         # the relative IOR crossed (1 through a thin sheet)
                np.testing.assert_allclose(np.array(TRANSMITTANCE) / eta ** 2, np.array(w), rtol=1e-5)
            # the branches' frequencies are clear glass's (Fresnel's), whatever the tints
            F = float(theirs.sample(ctx, si, 0.0, mi.Point2f(0.5, 0.5))[0].pdf)
            assert abs(refl.mean() - F) <= 5 * math.sqrt(F * (1 - F) / len(refl)) + 1e-12, (theta, below, F)


def test_rough_glass_values_match_mitsuba(mi):
    """f·|cos| (radiance mode) and the pdf of a tinted rough glass at random direction pairs, against Mitsuba 3's:
    the reflection carries specular_reflectance, the refraction specular_transmittance (GGX: float32 precision)."""
    mats, theirs = table(ROUGHDIELECTRIC), mitsuba_glass(mi, "roughdielectric")
    ctx, si = mi.BSDFContext(), mi.SurfaceInteraction3f()
    si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
    lobes = set()
    for wo, wi in direction_pairs():
        f_mi, pdf_mi = mitsuba_f_pdf(mi, theirs, ctx, si, wo, wi)
        d = tuple(-wo)
        out = np.zeros((1, 4))
        eval_many(mats, d, wi[None, :], out)
        np.testing.assert_allclose(out[0, :3] * bsdfs_camera_scale(mats, d, wi), f_mi, rtol=2e-4,
                                   atol=1e-6 * max(1.0, f_mi.max()))
        np.testing.assert_allclose(out[0, 3], pdf_mi, rtol=2e-4, atol=1e-6 * max(1.0, pdf_mi))
        if f_mi.max() > 0:
            lobes.add(bool(wo[2] * wi[2] > 0))
    assert lobes == {True, False}      # both lobes were compared


def test_rough_glass_sample_weights_carry_the_lobes_tints():
    """Each rough-glass sample weighs G1 times its lobe's tint: its weight divided by the tint is grey."""
    out = draw(table(ROUGHDIELECTRIC), incident(35.0), n=20_000, seed=4)
    ok = out[:, 0] == 1.0
    refl = ok & (out[:, 12] == bsdfs.GLOSSY_REFLECTION)
    trans = ok & (out[:, 12] == bsdfs.GLOSSY_TRANSMISSION)
    assert refl.sum() > 200 and trans.sum() > 2000
    for rows, tint in ((refl, REFLECTANCE), (trans, TRANSMITTANCE)):
        g1 = out[rows, 4:7] / np.array(tint)
        np.testing.assert_allclose(g1, np.broadcast_to(g1[:, :1], g1.shape), rtol=1e-12)
        assert np.all((g1 > 0) & (g1 <= 1.0 + 1e-12))


def test_loader_reads_the_tints(tmp_path):
    from caustica.scene import load_scene_file
    d = load_scene_file(SCENE)
    by_id = {s.id: d.materials[s.material] for s in d.shapes}
    assert (by_id["amber"].kind, by_id["amber"].rgb, by_id["amber"].specular) == \
        (DIELECTRIC, TRANSMITTANCE, REFLECTANCE)
    assert by_id["blue"].kind == ROUGHDIELECTRIC and by_id["blue"].specular == (0.6, 0.6, 0.6)
    assert by_id["blue"].rgb == (0.3, 0.5, 0.95)
    assert by_id["pane"].kind == THINDIELECTRIC and by_id["pane"].texture is not None
    assert by_id["pane"].specular == (1.0, 0.9, 0.3)


# --------------------------------------------------------------------------- the scene against Mitsuba 3

@pytest.fixture(scope="module")
def mitsuba_images(mi):
    """Mitsuba's path tracer on tests/scenes/tinted-glass.xml at 32 x 32: 4 seeds of 1024 spp."""
    scene = mi.load_file(str(SCENE), res=32, spp=1024)
    return [np.array(mi.render(scene, spp=1024, seed=s), dtype=np.float32)[..., :3] for s in (1, 2, 3, 4)]


@pytest.mark.parametrize("method, params", [("pt", {"spp": 512})] + CAUSTIC_PHOTON_METHODS)
def test_tinted_glass_scene_matches_mitsuba(mitsuba_images, method, params):
    """Each method's tinted caustics and reflections against Mitsuba's path tracer (roulette and mr = 64 for the
    photon methods: no depth truncation)."""
    scene = caustica.load_scene(SCENE)
    extra = {} if method == "pt" else {"termination": "roulette", "max_bounces": 64}
    ours = [caustica.render(scene, method, res=32, seed=s, **extra, **params).image for s in range(4)]
    assert_images_agree(ours, mitsuba_images, label=f"{method} tinted glass")
