"""Ray-tracing core: primitives against independent references, BVH against brute force.

References are written with numpy (linear solves, closed-form quadrics in world
space) so they share no code with the kernels under test.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from caustica.errors import SceneError
from caustica.geometry import primitives as pr
from caustica.geometry.bounds import enclosing_sphere, shape_bounding_sphere
from caustica.geometry.bvh import MAX_LEAF, STACK_SIZE, bvh_depth
from caustica.geometry.scene_geometry import (
    build_geometry, emitter_prims, intersect, intersect_brute_force, intersect_rays, occluded,
    sample_on_emitter, sample_on_primitive, surface_at,
)
from caustica.geometry.vec import offset_origin
from caustica.jit import borrowed, kernel
from caustica.scene import description as sd


# ---------------------------------------------------------------------------
# Scene fixtures
# ---------------------------------------------------------------------------

def camera():
    return sd.Camera(to_world=np.eye(4), fov_deg=40.0)


def desc_of(shapes):
    return sd.SceneDescription(camera=camera(), shapes=shapes, materials=[sd.Material(sd.DIFFUSE)])


def rectangle(to_world=np.eye(4), **kw):
    """Mitsuba's rectangle: [-1, 1]^2 in z = 0, front side +z, mapped by to_world."""
    p = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    p = p @ to_world[:3, :3].T + to_world[:3, 3]
    return sd.Shape(sd.MESH, kw.pop("material", 0),
                    mesh=sd.Mesh(p, np.array([[0, 1, 2], [2, 3, 0]])), **kw)


def soup(rng, n, spread=10.0, size=1.0):
    centres = rng.uniform(-spread, spread, (n, 1, 3))
    pos = (centres + rng.normal(0.0, size, (n, 3, 3))).reshape(-1, 3)
    return sd.Shape(sd.MESH, 0, mesh=sd.Mesh(pos, np.arange(3 * n).reshape(n, 3)), source="soup:1")


def rotation(rng):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.diag(r))


def similarity(rng, scale=None, centre=None):
    m = np.eye(4)
    s = rng.uniform(0.5, 3.0) if scale is None else scale
    m[:3, :3] = rotation(rng) * s
    m[:3, 3] = rng.uniform(-5, 5, 3) if centre is None else centre
    return m


def affine(rng):
    m = np.eye(4)
    m[:3, :3] = rng.uniform(-2, 2, (3, 3)) + 2.0 * np.eye(3)
    m[:3, 3] = rng.uniform(-5, 5, 3)
    return m


def mixed_scene(rng, n_tri=200):
    shapes = [soup(rng, n_tri, spread=8.0)]
    for kind in (sd.SPHERE, sd.DISK, sd.CYLINDER, sd.SPHERE, sd.DISK, sd.CYLINDER):
        shapes.append(sd.Shape(kind, 0, to_world=similarity(rng)))
        shapes.append(sd.Shape(kind, 0, to_world=affine(rng)))
    shapes.append(rectangle(similarity(rng)))
    return shapes


def random_rays(rng, n, box=12.0):
    o = rng.uniform(-box, box, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


def aimed_rays(rng, n, centre, spread=2.0, box=8.0):
    """Rays from random origins towards random points near ``centre`` (mostly hits)."""
    o = rng.uniform(-box, box, (n, 3))
    d = np.asarray(centre) + rng.normal(0.0, spread, (n, 3)) - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    return o, d


# ---------------------------------------------------------------------------
# Batch wrappers around the device functions
# ---------------------------------------------------------------------------

@kernel
def _tri_batch(p0, e1, e2, o, d):
    n = p0.shape[0]
    out = np.empty((n, 3))
    for i in range(n):
        t, b1, b2 = pr.intersect_triangle((p0[i, 0], p0[i, 1], p0[i, 2]), (e1[i, 0], e1[i, 1], e1[i, 2]),
                                          (e2[i, 0], e2[i, 1], e2[i, 2]), (o[i, 0], o[i, 1], o[i, 2]),
                                          (d[i, 0], d[i, 1], d[i, 2]), np.inf)
        out[i, 0] = t
        out[i, 1] = b1
        out[i, 2] = b2
    return out


@kernel
def _brute_batch(geom, o, d, tmax):
    geom = borrowed(geom)
    n = o.shape[0]
    prim = np.empty(n, dtype=np.int64)
    tt = np.empty(n)
    for i in range(n):
        p, t, b1, b2 = intersect_brute_force(geom, (o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]), tmax)
        prim[i] = p
        tt[i] = t
    return prim, tt


@kernel
def _occluded_batch(geom, o, d, tmax):
    geom = borrowed(geom)
    n = o.shape[0]
    out = np.empty(n, dtype=np.bool_)
    for i in range(n):
        out[i] = occluded(geom, (o[i, 0], o[i, 1], o[i, 2]), (d[i, 0], d[i, 1], d[i, 2]), tmax[i])
    return out


@kernel
def _surface_batch(geom, o, d):
    """Closest hit, then (prim, t, p, ng, ns) for each ray; rows of misses are left NaN."""
    geom = borrowed(geom)
    n = o.shape[0]
    prim = np.full(n, -1, dtype=np.int64)
    tt = np.full(n, np.nan)
    out = np.full((n, 9), np.nan)
    for i in range(n):
        oi = (o[i, 0], o[i, 1], o[i, 2])
        di = (d[i, 0], d[i, 1], d[i, 2])
        p, t, b1, b2 = intersect(geom, oi, di, np.inf)
        if p < 0:
            continue
        x, ng, ns = surface_at(geom, p, oi, di, t, b1, b2)
        prim[i] = p
        tt[i] = t
        for k in range(3):
            out[i, k] = x[k]
            out[i, 3 + k] = ng[k]
            out[i, 6 + k] = ns[k]
    return prim, tt, out


@kernel
def _rehit_batch(geom, p, ng, d):
    """Closest hit of rays leaving p (offset with vec.offset_origin) along d: prim, t, origin."""
    geom = borrowed(geom)
    n = p.shape[0]
    prim = np.empty(n, dtype=np.int64)
    tt = np.empty(n)
    org = np.empty((n, 3))
    for i in range(n):
        di = (d[i, 0], d[i, 1], d[i, 2])
        o = offset_origin((p[i, 0], p[i, 1], p[i, 2]), (ng[i, 0], ng[i, 1], ng[i, 2]), di)
        q, t, b1, b2 = intersect(geom, o, di, np.inf)
        prim[i] = q
        tt[i] = t
        for k in range(3):
            org[i, k] = o[k]
    return prim, tt, org


@kernel
def _sample_batch(geom, prim, u):
    geom = borrowed(geom)
    n = u.shape[0]
    out = np.empty((n, 6))
    for i in range(n):
        p, ng = sample_on_primitive(geom, prim, u[i, 0], u[i, 1])
        for k in range(3):
            out[i, k] = p[k]
            out[i, 3 + k] = ng[k]
    return out


@kernel
def _emitter_batch(geom, e, u):
    geom = borrowed(geom)
    n = u.shape[0]
    prim = np.empty(n, dtype=np.int64)
    for i in range(n):
        p, ng, q = sample_on_emitter(geom, e, u[i, 0], u[i, 1], u[i, 2])
        prim[i] = q
    return prim


def closest(geom, o, d, tmax=np.inf):
    prim, t, _, _ = intersect_rays(geom, np.ascontiguousarray(o), np.ascontiguousarray(d), tmax)
    return prim, t


# ---------------------------------------------------------------------------
# Primitives against independent references
# ---------------------------------------------------------------------------

def test_triangle_matches_linear_solve():
    rng = np.random.default_rng(0)
    n = 4000
    p0 = rng.normal(size=(n, 3))
    e1 = rng.normal(size=(n, 3))
    e2 = rng.normal(size=(n, 3))
    o = rng.normal(size=(n, 3)) * 3.0
    target = p0 + e1 * rng.uniform(-0.3, 1.0, (n, 1)) + e2 * rng.uniform(-0.3, 1.0, (n, 1))
    d = target - o
    d /= np.linalg.norm(d, axis=1)[:, None]
    got = _tri_batch(p0, e1, e2, o, d)
    # o + t d = p0 + b1 e1 + b2 e2  <=>  [-d e1 e2] (t b1 b2) = o - p0
    a = np.stack([-d, e1, e2], axis=2)
    tb = np.linalg.solve(a, (o - p0)[..., None])[..., 0]
    t, b1, b2 = tb.T
    inside = (b1 >= 0) & (b2 >= 0) & (b1 + b2 <= 1) & (t > 0)
    clear = np.minimum.reduce([np.abs(b1), np.abs(b2), np.abs(1 - b1 - b2)]) > 1e-9
    assert inside[clear].sum() > 1000 and (~inside[clear]).sum() > 1000
    np.testing.assert_array_equal(np.isfinite(got[:, 0])[clear], inside[clear])
    hit = inside & clear
    np.testing.assert_allclose(got[hit], tb[hit], rtol=1e-9, atol=1e-9)


def test_triangle_edges_are_watertight():
    """Rays through the shared diagonal of a rectangle (and its vertices) always hit."""
    geom = build_geometry(desc_of([rectangle()]))
    s = np.linspace(-1, 1, 201)
    pts = np.concatenate([np.stack([s, s, 0 * s], 1), np.array([[-1, -1, 0], [1, 1, 0], [0, 0, 0]])])
    o = pts + [0.0, 0.0, 1.0]
    d = np.tile([0.0, 0.0, -1.0], (len(o), 1))
    prim, t = closest(geom, o, d)
    assert np.all(prim >= 0)
    np.testing.assert_allclose(t, 1.0)


def _sphere_reference(o, d, c, r):
    f = o - c
    b = np.sum(f * d, axis=1)
    disc = b * b - (np.sum(f * f, axis=1) - r * r)
    sq = np.sqrt(np.maximum(disc, 0))
    t0, t1 = -b - sq, -b + sq
    t = np.where(t0 > 0, t0, np.where(t1 > 0, t1, np.inf))
    return np.where(disc >= 0, t, np.inf)


def test_sphere_matches_closed_form_and_hits_far_side_from_inside():
    rng = np.random.default_rng(1)
    c, r = np.array([1.0, -2.0, 0.5]), 2.5
    m = similarity(rng, scale=r, centre=c)  # rotation must not matter
    geom = build_geometry(desc_of([sd.Shape(sd.SPHERE, 0, to_world=m)]))
    o, d = random_rays(rng, 5000, box=6.0)
    o[:1000] = c + rng.uniform(-1, 1, (1000, 3)) * r / 2  # inside: must hit the far side
    prim, t = closest(geom, o, d)
    ref = _sphere_reference(o, d, c, r)
    np.testing.assert_array_equal(np.isfinite(t), np.isfinite(ref))
    np.testing.assert_allclose(t[np.isfinite(t)], ref[np.isfinite(ref)], rtol=1e-9)
    assert np.all(prim[:1000] == 0)
    # normals: outward, unit, at the exact hit point
    prim, t, s = _surface_batch(geom, o, d)
    hit = prim >= 0
    p, ng = s[hit, :3], s[hit, 3:6]
    np.testing.assert_allclose(np.linalg.norm(p - c, axis=1), r, rtol=1e-12)
    np.testing.assert_allclose(ng, (p - c) / r, atol=1e-9)


def test_ellipsoid_hit_point_and_normal():
    rng = np.random.default_rng(2)
    m = affine(rng)
    geom = build_geometry(desc_of([sd.Shape(sd.SPHERE, 0, to_world=m)]))
    o, d = aimed_rays(rng, 3000, m[:3, 3], box=12.0)
    prim, t, s = _surface_batch(geom, o, d)
    hit = prim >= 0
    assert hit.sum() > 300
    inv = np.linalg.inv(m)
    p, ng = s[hit, :3], s[hit, 3:6]
    loc = p @ inv[:3, :3].T + inv[:3, 3]
    np.testing.assert_allclose(np.linalg.norm(loc, axis=1), 1.0, atol=1e-10)
    grad = loc @ inv[:3, :3]  # gradient of |M^-1 x|^2 / 2: outward
    grad /= np.linalg.norm(grad, axis=1)[:, None]
    np.testing.assert_allclose(ng, grad, atol=1e-9)
    np.testing.assert_allclose(p, o[hit] + t[hit, None] * d[hit], atol=1e-8)


def test_disk_matches_plane_reference():
    rng = np.random.default_rng(3)
    m = affine(rng)
    geom = build_geometry(desc_of([sd.Shape(sd.DISK, 0, to_world=m)]))
    o, d = aimed_rays(rng, 5000, m[:3, 3], box=6.0)
    prim, t = closest(geom, o, d)
    n = np.linalg.inv(m[:3, :3]).T @ [0, 0, 1.0]
    n /= np.linalg.norm(n)
    c = m[:3, 3]
    tp = np.sum((c - o) * n, axis=1) / (d @ n)
    loc = (o + tp[:, None] * d - c) @ np.linalg.inv(m[:3, :3]).T
    r2 = np.sum(loc[:, :2] ** 2, axis=1)
    ref_hit = (tp > 0) & (r2 <= 1)
    clear = np.abs(r2 - 1) > 1e-9
    assert ref_hit.sum() > 200
    np.testing.assert_array_equal((prim >= 0)[clear], ref_hit[clear])
    np.testing.assert_allclose(t[ref_hit & clear], tp[ref_hit & clear], rtol=1e-9)


def _cylinder_reference(o, d, c, axis, r):
    """Open cylinder of radius r around c + z axis, z in [0, r] (similarity with scale r)."""
    f = o - c
    fp = f - np.outer(f @ axis, axis)
    dp = d - np.outer(d @ axis, axis)
    a = np.sum(dp * dp, axis=1)
    b = np.sum(fp * dp, axis=1)
    cc = np.sum(fp * fp, axis=1) - r * r
    disc = b * b - a * cc
    sq = np.sqrt(np.maximum(disc, 0))
    best = np.full(len(o), np.inf)
    for t in ((-b + sq) / a, (-b - sq) / a):
        z = (f + t[:, None] * d) @ axis
        ok = (disc >= 0) & (t > 0) & (z >= 0) & (z <= r)
        best = np.where(ok & (t < best), t, best)
    return best


def test_cylinder_matches_reference_and_normals_point_outward():
    rng = np.random.default_rng(4)
    r = 1.7
    m = similarity(rng, scale=r)
    geom = build_geometry(desc_of([sd.Shape(sd.CYLINDER, 0, to_world=m)]))
    o, d = random_rays(rng, 5000, box=6.0)
    o[:500] = m[:3, 3] + m[:3, 2] * 0.5 + rng.uniform(-0.5, 0.5, (500, 3))  # inside
    prim, t, s = _surface_batch(geom, o, d)
    ref = _cylinder_reference(o, d, m[:3, 3], m[:3, 2] / r, r)
    np.testing.assert_array_equal(np.isfinite(t), np.isfinite(ref))
    ok = np.isfinite(ref)
    np.testing.assert_allclose(t[ok], ref[ok], rtol=1e-9)
    p, ng = s[ok, :3], s[ok, 3:6]
    axis = m[:3, 2] / r
    radial = (p - m[:3, 3]) - np.outer((p - m[:3, 3]) @ axis, axis)
    np.testing.assert_allclose(ng, radial / r, atol=1e-9)


# ---------------------------------------------------------------------------
# BVH against brute force
# ---------------------------------------------------------------------------

def _check_against_brute_force(geom, o, d, tmax=np.inf):
    prim, t = closest(geom, o, d, tmax)
    bprim, bt = _brute_batch(geom, o, d, tmax)
    np.testing.assert_array_equal(t, bt)  # same primitive tests: bit-identical t
    same = prim == bprim
    assert np.all(same | (t == bt))  # a different prim only on an exact tie
    tm = np.full(len(o), tmax) if np.isinf(tmax) else np.minimum(np.where(prim >= 0, t, 1e3) * 1.5, 1e3)
    tm = np.where(np.arange(len(o)) % 2 == 0, tm, np.where(prim >= 0, t * 0.999, 1e3))
    occ = _occluded_batch(geom, o, d, tm)
    prim2, t2 = _brute_batch(geom, o, d, np.inf)
    np.testing.assert_array_equal(occ, (prim2 >= 0) & (t2 < tm))
    return prim


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 400),
       size=st.sampled_from([0.05, 0.5, 3.0]))
def test_bvh_equals_brute_force_on_triangle_soups(seed, n, size):
    rng = np.random.default_rng(seed)
    geom = build_geometry(desc_of([soup(rng, n, spread=8.0, size=size)]))
    o, d = random_rays(rng, 400)
    o[:50] = 0.0  # common origin
    d[50:100] = np.eye(3)[rng.integers(0, 3, 50)] * rng.choice([-1, 1], (50, 1))  # axis-parallel
    _check_against_brute_force(geom, o, d)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2 ** 32 - 1))
def test_bvh_equals_brute_force_on_mixed_scenes(seed):
    rng = np.random.default_rng(seed)
    geom = build_geometry(desc_of(mixed_scene(rng, n_tri=int(rng.integers(0, 300)))))
    o, d = random_rays(rng, 500)
    prim = _check_against_brute_force(geom, o, d)
    assert np.any(geom.prim_kind[prim[prim >= 0]] != pr.TRIANGLE)


def test_bvh_on_degenerate_input():
    """Coincident triangles (all centroids equal), axis-aligned flat ones, a single one, none."""
    rng = np.random.default_rng(5)
    same = np.tile(rng.normal(size=(1, 3, 3)), (50, 1, 1)).reshape(-1, 3)
    flat = rng.uniform(-5, 5, (300, 3, 3))
    flat[:, :, 2] = 1.0
    shapes = [sd.Shape(sd.MESH, 0, mesh=sd.Mesh(same, np.arange(150).reshape(50, 3))),
              sd.Shape(sd.MESH, 0, mesh=sd.Mesh(flat.reshape(-1, 3), np.arange(900).reshape(300, 3)))]
    geom = build_geometry(desc_of(shapes))
    o, d = random_rays(rng, 2000)
    _check_against_brute_force(geom, o, d)
    one = build_geometry(desc_of([rectangle()]))
    assert one.bvh_node.shape[0] >= 1
    empty = build_geometry(desc_of([]))
    prim, t = closest(empty, o[:5], d[:5], 7.0)
    assert np.all(prim == -1) and np.all(t == 7.0)


def test_bvh_structure():
    rng = np.random.default_rng(6)
    geom = build_geometry(desc_of(mixed_scene(rng, n_tri=3000)))
    node, box, order = geom.bvh_node, geom.bvh_box, geom.bvh_order
    assert sorted(order) == list(range(geom.n_prims))
    leaves = node[:, 1] > 0
    assert node[leaves, 1].max() <= MAX_LEAF
    assert bvh_depth(node) < STACK_SIZE
    # every primitive's box lies in its leaf's box; every child in its parent
    for k in np.nonzero(leaves)[0]:
        prims = order[node[k, 0]:node[k, 0] + node[k, 1]]
        tri = prims[geom.prim_kind[prims] == pr.TRIANGLE]
        j = geom.prim_index[tri]
        for v in (geom.tri_p0[j], geom.tri_p0[j] + geom.tri_e1[j], geom.tri_p0[j] + geom.tri_e2[j]):
            assert np.all(v >= box[k, :3] - 1e-12) and np.all(v <= box[k, 3:] + 1e-12)
    for k in np.nonzero(~leaves)[0]:
        for c in (k + 1, node[k, 0]):
            assert np.all(box[c, :3] >= box[k, :3]) and np.all(box[c, 3:] <= box[k, 3:])


def test_large_soup_builds():
    rng = np.random.default_rng(7)
    geom = build_geometry(desc_of([soup(rng, 100_000, spread=50.0, size=0.3)]))
    assert geom.n_prims == 100_000
    assert bvh_depth(geom.bvh_node) < STACK_SIZE
    o, d = random_rays(rng, 200, box=50.0)
    _check_against_brute_force(geom, o, d)


# ---------------------------------------------------------------------------
# Self-intersection and normals
# ---------------------------------------------------------------------------

def test_rays_leaving_a_surface_do_not_rehit_it():
    rng = np.random.default_rng(8)
    shapes = [sd.Shape(sd.SPHERE, 0, to_world=similarity(rng, scale=4.0, centre=[4.0, 4.0, 2.0])),
              sd.Shape(sd.SPHERE, 0, to_world=similarity(rng, scale=1e-2, centre=[-3.0, 1.0, 0.0])),
              sd.Shape(sd.CYLINDER, 0, to_world=similarity(rng, scale=3.0, centre=[-5.0, 0.0, -5.0])),
              sd.Shape(sd.DISK, 0, to_world=affine(rng)),
              sd.Shape(sd.SPHERE, 0, to_world=affine(rng)),
              rectangle(similarity(rng, scale=10.0, centre=[0.0, -3.0, 0.0])),
              soup(rng, 300, spread=8.0, size=2.0)]
    # far from the origin too: the offset must scale with |p|
    far = similarity(rng, scale=5.0, centre=[1e4, -2e4, 3e4])
    shapes.append(sd.Shape(sd.SPHERE, 0, to_world=far))
    shapes.append(rectangle(similarity(rng, scale=50.0, centre=[1e4, -2e4, 3e4 + 20])))
    geom = build_geometry(desc_of(shapes))
    o, d = random_rays(rng, 20000, box=10.0)
    targets = far[:3, 3] + rng.normal(size=(4000, 3)) * 8
    o[:4000] = far[:3, 3] + rng.normal(size=(4000, 3)) * 60
    d[:4000] = targets - o[:4000]
    d /= np.linalg.norm(d, axis=1)[:, None]
    prim, t, s = _surface_batch(geom, o, d)
    hit = prim >= 0
    p, ng = s[hit], s[hit, 3:6]
    p = p[:, :3]
    prim = prim[hit]
    n = len(p)
    # leave to both sides of the surface, including grazing directions
    new = rng.normal(size=(n, 3))
    new /= np.linalg.norm(new, axis=1)[:, None]
    graze = rng.random(n) < 0.2
    tang = new - np.sum(new * ng, axis=1)[:, None] * ng
    tang /= np.linalg.norm(tang, axis=1)[:, None]
    new[graze] = tang[graze] + 1e-3 * ng[graze] * np.sign(rng.normal(size=(graze.sum(), 1)))
    new /= np.linalg.norm(new, axis=1)[:, None]
    q, tq, org = _rehit_batch(geom, np.ascontiguousarray(p), np.ascontiguousarray(ng),
                              np.ascontiguousarray(new))
    rehit = q == prim
    kinds = geom.prim_kind[prim]
    # planar primitives can never be hit again
    assert not np.any(rehit & ((kinds == pr.TRIANGLE) | (kinds == pr.DISK)))
    # leaving a convex surface outward never re-hits it
    out = np.sum(new * ng, axis=1) > 0
    assert not np.any(rehit & out)
    # leaving a sphere inward (refraction) hits exactly its far side, never itself at t ~ 0
    for k in np.nonzero((kinds == pr.SPHERE) & ~out)[0]:
        m = shapes[geom.prim_shape[prim[k]]].to_world
        r = np.linalg.norm(m[:3, 0])
        if not np.allclose(m[:3, :3].T @ m[:3, :3], r * r * np.eye(3)):
            continue  # the ellipsoid
        ref = _sphere_reference(org[k:k + 1], new[k:k + 1], m[:3, 3], r)[0]
        if q[k] == prim[k]:
            np.testing.assert_allclose(tq[k], ref, rtol=1e-6)
        else:  # something else lies in between
            assert tq[k] <= ref * (1 + 1e-9)
    assert rehit.sum() > 100


def test_front_side_conventions_and_flip_normals():
    rng = np.random.default_rng(9)
    down = np.array([0.0, 0.0, -1.0])
    for flip in (False, True):
        sign = -1.0 if flip else 1.0
        shapes = [sd.Shape(sd.DISK, 0, to_world=np.eye(4), flip_normals=flip),
                  sd.Shape(sd.SPHERE, 0, to_world=similarity(rng, 1.0, [10.0, 0, 0]), flip_normals=flip),
                  sd.Shape(sd.CYLINDER, 0, to_world=similarity(rng, 1.0, [-10.0, 0, 0]), flip_normals=flip)]
        geom = build_geometry(desc_of(shapes))
        # disk seen from above and from below: ng is +z (or -z when flipped) either way
        o = np.array([[0.1, 0.2, 1.0], [0.1, 0.2, -1.0]])
        prim, t, s = _surface_batch(geom, o, np.array([down, -down]))
        np.testing.assert_allclose(s[:, 3:6], [[0, 0, sign]] * 2)
        np.testing.assert_allclose(s[:, 6:9], s[:, 3:6])
        for k, c in ((1, [10.0, 0, 0]), (2, None)):
            o, d = aimed_rays(rng, 2000, shapes[k].to_world[:3, 3], spread=1.0, box=12.0)
            prim, t, s = _surface_batch(geom, o, d)
            sel = prim == k
            assert sel.sum() > 10
            if c is not None:
                outward = s[sel, :3] - c
            else:
                m = shapes[2].to_world
                rel = s[sel, :3] - m[:3, 3]
                ax = m[:3, 2] / np.linalg.norm(m[:3, 2])
                outward = rel - np.outer(rel @ ax, ax)
            assert np.all(np.sum(outward * s[sel, 3:6], axis=1) * sign > 0)
    # rectangle (a mesh): +z, CCW winding
    geom = build_geometry(desc_of([rectangle()]))
    prim, t, s = _surface_batch(geom, np.array([[0.3, -0.2, -2.0]]), np.array([[0.0, 0.0, 1.0]]))
    np.testing.assert_allclose(s[0, 3:6], [0, 0, 1])


def test_shading_normals_interpolate_and_share_the_front_side():
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=float)
    nrm = np.array([[0, 0, 1], [1, 0, 1], [0, 0, -1]], dtype=float)  # n2 points to the back
    nrm[1] /= np.sqrt(2)
    geom = build_geometry(desc_of([sd.Shape(sd.MESH, 0, mesh=sd.Mesh(pos, np.array([[0, 1, 2]]), nrm))]))
    o = np.array([[0.2, 0.1, 1.0], [0.1, 0.8, 1.0]])
    prim, t, s = _surface_batch(geom, o, np.array([[0, 0, -1.0]] * 2))
    np.testing.assert_allclose(s[:, 3:6], [[0, 0, 1]] * 2)
    b = np.array([[0.7, 0.2, 0.1], [0.1, 0.1, 0.8]])  # barycentrics of the hits
    ref = b @ nrm
    ref /= np.linalg.norm(ref, axis=1)[:, None]
    ref[np.sum(ref * [0, 0, 1], axis=1) < 0] *= -1
    np.testing.assert_allclose(s[:, 6:9], ref, atol=1e-12)
    assert np.all(s[:, 8] > 0)


# ---------------------------------------------------------------------------
# Area sampling and the primitive / emitter tables
# ---------------------------------------------------------------------------

@pytest.mark.parametrize("kind", [sd.SPHERE, sd.DISK, sd.CYLINDER, "triangle"])
def test_area_sampling_is_uniform_and_on_the_surface(kind):
    rng = np.random.default_rng(10)
    if kind == "triangle":
        pos = rng.normal(size=(3, 3))
        shape = sd.Shape(sd.MESH, 0, mesh=sd.Mesh(pos, np.array([[0, 1, 2]])), emitter_radiance=(1, 1, 1))
        m = None
    else:
        m = affine(rng) if kind == sd.DISK else similarity(rng)
        shape = sd.Shape(kind, 0, to_world=m, emitter_radiance=(1, 1, 1))
    geom = build_geometry(desc_of([shape]))
    n = 200_000
    u = rng.random((n, 2))
    s = _sample_batch(geom, 0, u)
    p, ng = s[:, :3], s[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(ng, axis=1), 1.0)
    tol = 4.0 / math.sqrt(n)  # ~4 sigma for unit-variance quantities
    if kind == "triangle":
        e1, e2 = pos[1] - pos[0], pos[2] - pos[0]
        b = np.linalg.lstsq(np.stack([e1, e2], 1), (p - pos[0]).T, rcond=None)[0].T
        assert np.all(b >= -1e-12) and np.all(b.sum(1) <= 1 + 1e-12)
        np.testing.assert_allclose(b.mean(0), [1 / 3, 1 / 3], atol=tol)
        np.testing.assert_allclose((b ** 2).mean(0), [1 / 6, 1 / 6], atol=tol)  # E[b^2] = 1/6
        np.testing.assert_allclose(geom.prim_area[0], 0.5 * np.linalg.norm(np.cross(e1, e2)))
        return
    inv = np.linalg.inv(m)
    loc = p @ inv[:3, :3].T + inv[:3, 3]
    if kind == sd.SPHERE:
        np.testing.assert_allclose(np.linalg.norm(loc, axis=1), 1.0)
        np.testing.assert_allclose(loc.mean(0), 0.0, atol=tol)
        np.testing.assert_allclose(np.cov(loc.T), np.eye(3) / 3, atol=tol)
        np.testing.assert_allclose(ng, loc @ m[:3, :3].T / np.linalg.norm(m[:3, 0]) , atol=1e-9)
    elif kind == sd.DISK:
        np.testing.assert_allclose(loc[:, 2], 0.0, atol=1e-9)
        assert np.all(np.hypot(loc[:, 0], loc[:, 1]) <= 1 + 1e-12)
        np.testing.assert_allclose(loc[:, :2].mean(0), 0.0, atol=tol)
        np.testing.assert_allclose(np.cov(loc[:, :2].T), np.eye(2) / 4, atol=tol)
    else:
        np.testing.assert_allclose(np.hypot(loc[:, 0], loc[:, 1]), 1.0)
        assert np.all((loc[:, 2] >= 0) & (loc[:, 2] <= 1))
        np.testing.assert_allclose(loc.mean(0), [0, 0, 0.5], atol=tol)
        np.testing.assert_allclose(np.diag(np.cov(loc.T)), [0.5, 0.5, 1 / 12], atol=tol)


def test_analytic_areas():
    rng = np.random.default_rng(11)
    s = 2.5
    shapes = [sd.Shape(sd.SPHERE, 0, to_world=similarity(rng, s)),
              sd.Shape(sd.CYLINDER, 0, to_world=similarity(rng, s)),
              sd.Shape(sd.DISK, 0, to_world=np.diag([2.0, 3.0, 5.0, 1.0])),
              sd.Shape(sd.CYLINDER, 0, to_world=np.diag([1.0, 2.0, 3.0, 1.0])),
              sd.Shape(sd.SPHERE, 0, to_world=np.diag([1.0, 2.0, 3.0, 1.0]))]
    geom = build_geometry(desc_of(shapes))
    # ellipse perimeter (a=1, b=2) by fine numpy quadrature; ellipsoid (1,2,3) area 48.88214630
    phi = np.linspace(0, 2 * np.pi, 200_001)
    perim = np.trapezoid(np.hypot(np.sin(phi), 2 * np.cos(phi)), phi)
    np.testing.assert_allclose(geom.prim_area,
                               [4 * np.pi * s * s, 2 * np.pi * s * s, 6 * np.pi, 3 * perim, 48.88214630],
                               rtol=1e-8)


def test_primitive_and_emitter_tables():
    rng = np.random.default_rng(12)
    big = np.diag([3.0, 1.0, 1.0, 1.0])
    shapes = [rectangle(material=1),
              sd.Shape(sd.SPHERE, 0, to_world=similarity(rng, 2.0), emitter_radiance=(1, 2, 3)),
              rectangle(big, material=0, emitter_radiance=(5, 5, 5)),
              sd.Shape(sd.DISK, 1, to_world=np.diag([1.0, 2.0, 1.0, 1.0]), emitter_radiance=(1, 1, 1),
                       flip_normals=True)]
    geom = build_geometry(desc_of(shapes))
    np.testing.assert_array_equal(geom.prim_kind, [0, 0, 0, 0, pr.SPHERE, pr.DISK])
    np.testing.assert_array_equal(geom.prim_shape, [0, 0, 2, 2, 1, 3])
    np.testing.assert_array_equal(geom.prim_material, [1, 1, 0, 0, 0, 1])
    # emitters in scene order of their shapes: sphere (shape 1) = 0, big rectangle = 1, disk = 2
    np.testing.assert_array_equal(geom.prim_emitter, [-1, -1, 1, 1, 0, 2])
    np.testing.assert_array_equal(geom.emitter_shape, [1, 2, 3])
    np.testing.assert_allclose(geom.emitter_area, [16 * np.pi, 12.0, 2 * np.pi])
    table = emitter_prims(geom)
    np.testing.assert_array_equal(table[1][0], [2, 3])
    np.testing.assert_allclose(table[1][1].sum(), 12.0)
    counts = np.bincount(_emitter_batch(geom, 1, rng.random((20000, 3))), minlength=6)
    assert counts[2] + counts[3] == 20000 and abs(counts[2] - 10000) < 400


def test_stretched_emitter_on_a_curved_shape_is_an_error():
    for kind in (sd.SPHERE, sd.CYLINDER):
        shape = sd.Shape(kind, 0, to_world=np.diag([1.0, 2.0, 1.0, 1.0]), emitter_radiance=(1, 1, 1),
                         source="scene.xml:17")
        with pytest.raises(SceneError, match="scene.xml:17"):
            build_geometry(desc_of([shape]))
    singular = sd.Shape(sd.SPHERE, 0, to_world=np.diag([1.0, 0.0, 1.0, 1.0]), source="s.xml:3")
    with pytest.raises(SceneError, match="s.xml:3"):
        build_geometry(desc_of([singular]))
    bad = sd.Shape(sd.MESH, 0, mesh=sd.Mesh(np.zeros((3, 3)), np.array([[0, 1, 5]])), source="m.xml:9")
    with pytest.raises(SceneError, match="m.xml:9"):
        build_geometry(desc_of([bad]))


# ---------------------------------------------------------------------------
# Bounding spheres (what the caustic map aims at)
# ---------------------------------------------------------------------------

def canonical_points(kind, rng, n):
    """Points on Mitsuba's canonical sphere / disk / cylinder, including its extremes."""
    u = rng.normal(size=(n, 3))
    if kind == sd.SPHERE:
        return u / np.linalg.norm(u, axis=1)[:, None]
    phi = rng.uniform(0, 2 * np.pi, n)
    if kind == sd.DISK:
        r = np.sqrt(rng.uniform(0, 1, n))
        r[: n // 2] = 1.0                       # the rim is where the extremes are
        return np.stack([r * np.cos(phi), r * np.sin(phi), np.zeros(n)], axis=1)
    z = rng.uniform(0, 1, n)
    z[: n // 2] = np.round(z[: n // 2])         # the end circles
    return np.stack([np.cos(phi), np.sin(phi), z], axis=1)


@pytest.mark.parametrize("kind", [sd.SPHERE, sd.DISK, sd.CYLINDER])
def test_analytic_bounding_spheres_contain_the_shape_and_are_exact_for_similarities(kind):
    rng = np.random.default_rng(12)
    exact = {sd.SPHERE: 1.0, sd.DISK: 1.0, sd.CYLINDER: math.sqrt(1.25)}[kind]
    for m, scale in [(similarity(rng, 2.5), 2.5), (affine(rng), None), (affine(rng), None)]:
        geom = build_geometry(desc_of([sd.Shape(kind, 0, to_world=m)]))
        c, r = shape_bounding_sphere(geom, 0)
        p = canonical_points(kind, rng, 20_000) @ m[:3, :3].T + m[:3, 3]
        d = np.linalg.norm(p - c, axis=1)
        assert d.max() <= r, (kind, d.max(), r)
        box = geom.shape_box[0]
        assert r <= 0.5 * np.linalg.norm(box[3:] - box[:3]) * (1 + 1e-6)   # never worse than the box's sphere
        if scale is not None:
            assert r == pytest.approx(exact * scale, rel=1e-8)
        else:
            assert r <= 1.5 * d.max()       # a bound, but not a loose one


def test_mesh_bounding_sphere_holds_every_vertex_and_is_near_minimal():
    rng = np.random.default_rng(13)
    shape = soup(rng, 300)
    geom = build_geometry(desc_of([shape]))
    c, r = shape_bounding_sphere(geom, 0)
    assert np.linalg.norm(shape.mesh.positions - c, axis=1).max() <= r
    # points on a sphere of radius 3 (a tessellated ball): the minimal sphere is that sphere
    u = rng.normal(size=(5000, 3))
    u = 3.0 * u / np.linalg.norm(u, axis=1)[:, None] + [1.0, -2.0, 0.5]
    c, r = enclosing_sphere(u)
    assert 3.0 <= r <= 3.0 * 1.01
    np.testing.assert_allclose(c, [1.0, -2.0, 0.5], atol=0.05)
    # a cube's corners and inside: the minimal radius is the half-diagonal
    cube = np.concatenate([np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T,
                           rng.uniform(-1, 1, (1000, 3))])
    assert math.sqrt(3) <= enclosing_sphere(cube)[1] <= 1.01 * math.sqrt(3)
