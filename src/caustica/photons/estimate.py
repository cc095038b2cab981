"""The radiance estimate from a photon map (SPEC §3, eq. 2 of the paper).

At a diffuse point x with normal n the k nearest records within R that arrived on
the same side (dot(n_record, n) > kdtree.FACING_COS = 1/64) are gathered; r is the distance of the
farthest one used, or R when fewer than k are found, and

    L(x) = f_r · Σ_p W(d_p, r) Φ_p,    f_r = ρ / π,

where W is the filter kernel normalised to integrate to 1 over the disc of radius r
(:mod:`caustica.photons.density_filters`).  This function returns Σ W Φ (irradiance-like, W/m²); the caller applies f_r.

At the diffuse lobes beside a glossy one (pplastic, principled, principledthin: the camera path takes the glossy
one apart) and at a diffuse lobe under a map nothing is Lambertian to take out of the sum: there each record is
weighted by the value of the lobes the point holds at its own direction (:func:`caustica.bsdfs.eval_photon`),

    L(x, ω_o) = Σ_p W(d_p, r) f(ω_o, ω_p) Φ_p,

and the sum is the radiance itself (``bsdf``; pbrt-v4's SPPM weights its photons so, by the whole BSDF).
"""
from __future__ import annotations

from ..bsdfs import eval_photon, split_record_weight
from ..jit import kernel
from .density_filters import filter_weight
from .kdtree import KdTree, knn
from .records import MIN_RECORD_DEPTH


@kernel(inline=True)
def none_admitted(max_depth, k_camera):
    """Whether a camera path of k_camera segments may gather no record at all under ``max_depth`` (None: never):
    the k-nearest search would visit every record within its radius for nothing."""
    if max_depth is None:
        return False
    return max_depth - k_camera < MIN_RECORD_DEPTH


@kernel
def flux_density(pmap, at, estimate, scratch, bsdf, split=None):
    """Σ_p W(d_p, r) Φ_p over the k nearest same-side records (RGB, W/m²), and the number of them.

    ``at`` = (p, n, (max_depth, k)): the point, its normal for the same-side test, and the records it may take:
    those of at most max_depth - k segments from their light, k the camera path's segments to p (every record
    with max_depth None: a separate compilation, the search as it was).  ``estimate`` = (k, r_max, filter);
    ``scratch`` = the search's (indices, squared distances).
    With ``bsdf`` = (mats, m, d, ng, ns, uv) (a point that evaluates its BSDF, as
    :func:`caustica.photons.grid.grid_range_sum` takes it) each term is weighted by material m's f(d, -record
    direction): Σ_p W f Φ_p, the radiance towards -d.  With ``bsdf`` None, the plain sum: a separate compilation in
    which Numba prunes the other branch, so the Lambertian points' loop is what it was.  With ``split`` = the diffuse
    lobe's factor A of a roughplastic's split point (m's) too, the records are caustic records carrying its factor
    B, each weighted by :func:`caustica.bsdfs.split_record_weight` (A + f_glossy / B) instead."""
    p, n, (max_depth, k_camera) = at
    k, r_max, filt = estimate
    scratch_idx, scratch_d2 = scratch
    if pmap.position.shape[0] == 0 or k <= 0 or none_admitted(max_depth, k_camera):
        return (0.0, 0.0, 0.0), 0
    tree = KdTree(pmap.tree_points, pmap.tree_index, pmap.tree_axis)
    count, r2 = knn(tree, (pmap.normal, pmap.tree_normal_bounds, (pmap.depth, max_depth, k_camera)), p, n, k, r_max,
                    scratch)
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    if count == 0 or r2 <= 0.0:
        return (0.0, 0.0, 0.0), count
    if bsdf is not None:
        for j in range(count):
            i = scratch_idx[j]
            wi = (-float(pmap.direction[i, 0]), -float(pmap.direction[i, 1]), -float(pmap.direction[i, 2]))
            if split is not None:
                f, f_scale = split_record_weight(bsdf[0], bsdf[1], bsdf[2], bsdf[3], bsdf[4], wi, split), 1.0
            else:
                f, f_scale = eval_photon(bsdf[0], bsdf[1], bsdf[2], bsdf[3], bsdf[4], bsdf[5], wi)
            w = filter_weight(filt, scratch_d2[j], r2) * f_scale
            s0 += w * f[0] * pmap.power[i, 0]
            s1 += w * f[1] * pmap.power[i, 1]
            s2 += w * f[2] * pmap.power[i, 2]
        return (s0, s1, s2), count
    for j in range(count):
        i = scratch_idx[j]
        w = filter_weight(filt, scratch_d2[j], r2)
        s0 += w * pmap.power[i, 0]
        s1 += w * pmap.power[i, 1]
        s2 += w * pmap.power[i, 2]
    return (s0, s1, s2), count
