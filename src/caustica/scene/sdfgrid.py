"""Mitsuba 3's ``sdfgrid`` shape (a signed distance field sampled on a regular grid) as a triangle mesh.

Mitsuba's conventions, which this module reproduces:

* the grid (a one-channel ``.vol`` file, values ``f[z, y, x]``) fills the unit cube [0, 1]³ before the shape's
  ``to_world``: grid point (i, j, k) sits at (i / (nx - 1), j / (ny - 1), k / (nz - 1)), so a voxel is the cell
  between eight neighbouring grid points;
* the distance between grid points is the trilinear interpolant F of the eight corner values of the voxel (clamped
  to the grid outside it), and the surface is F's zero level set inside the cube: a ray hits the first zero of F
  along it; nothing closes the surface where it meets the cube's faces;
* the geometric normal is the gradient of F (within the voxel holding the point), outward (towards F > 0);
* shading normals, the ``normals`` parameter: ``analytic``, the same gradient (so it jumps across voxel faces), or
  ``smooth`` (the default; Hansson-Söderlund, Evans and Akenine-Möller 2022): about the grid point nearest the hit
  point, each of the eight voxels sharing it gives a unit gradient, measured as the difference of F across that
  voxel along each axis at the point's other two coordinates; the eight are blended trilinearly by the point's
  position in the voxel-sized cell centred on that grid point (voxels with a negative index left out);
* no surface coordinates: (u, v) = (0, 0) everywhere.

Here the zero set becomes triangles at load: each voxel the surface crosses is cut into SUBDIVISIONS³ sub-cells,
each sub-cell into six tetrahedra (the Freudenthal split along its main diagonal, the same in every sub-cell, so
neighbouring cells share their faces' triangulations and the mesh is watertight), and each tetrahedron whose
corners' signs differ gets one or two triangles (marching tetrahedra).  A vertex is the zero of F on a tetrahedron
edge, solved to float precision on F itself (a sub-cell never straddles two voxels, so F is a polynomial of degree
at most 3 along the edge): every vertex lies on Mitsuba's surface, and only the flat facets between them depart
from it, by about h² κ / 8 for sub-cells of size h where the surface curves by κ.  Each vertex carries the shading
normal Mitsuba computes there (smooth: shared across voxels; analytic: one vertex per voxel, that voxel's
gradient); an even SUBDIVISIONS puts the half-voxel planes, where the smooth blend changes its eight voxels, on
sub-cell faces, so the barycentric interpolation of the vertex normals never spans a kink of Mitsuba's normal.

Refused (SceneError): fewer than 2 grid points along an axis (no voxel), nx != nz (Mitsuba 3 mixes those two
axes' resolutions when they differ: its voxel size and texture lookup read the (z, y, x) tensor shape as (x, y, z)),
a grid whose surface crosses no voxel (Mitsuba refuses it too), and a mesh too large for memory.
"""
from __future__ import annotations

import numpy as np

from ..errors import ParameterError, SceneError
from ..memory import check_budget
from .description import Mesh

#: Sub-cells per voxel along each axis (even: see the module's docstring).
SUBDIVISIONS = 4
#: Refused above this many triangles (about 200 bytes each in the scene's tables and BVH).
MAX_TRIANGLES = 1 << 26
#: Bytes per triangle counted against the memory budget: the scene's tables and BVH (about 200), and this
#: module's working arrays, about one vertex (~100 bytes of position, normal, key and uv) per triangle.
BYTES_PER_TRIANGLE = 300
#: Triangles per crossed voxel and per SUBDIVISIONS², used for the estimate checked before meshing: a surface
#: crossing a voxel meets about 1.5 S² sub-cells, each giving 2-6 triangles; 8 is above what smooth surfaces
#: give (the 40³ torus of Mitsuba's documentation: 6.6), so the estimate errs on the large side.
TRIANGLES_PER_VOXEL_FACTOR = 8
#: Voxels meshed together (bounds the working memory: a few tens of kB per voxel at SUBDIVISIONS = 4).
CHUNK = 2048
NORMAL_MODES = ("smooth", "analytic")

#: The six tetrahedra of a cube, each as its four corners (bit 0: +x, bit 1: +y, bit 2: +z), a chain from
#: corner 0 to corner 7 (each corner's bits contain the previous one's).
_TETS = np.array([[0, 1 << a, (1 << a) | (1 << b), 7]
                  for a, b in ((0, 1), (0, 2), (1, 0), (1, 2), (2, 0), (2, 1))], np.int64)
_BITS = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], np.int64)   # code -> (x, y, z)


def check_grid(data: np.ndarray) -> np.ndarray:
    """The (nz, ny, nx) float64 distances of a grid read by :func:`~caustica.scene.volume_files.read_grid`
    ((nz, ny, nx, channels)); SceneError for more than one channel, a grid without a voxel, or nx != nz."""
    if data.ndim != 4 or data.shape[3] != 1:
        raise SceneError(f"an sdfgrid takes a grid of 1 channel (the distance); this one has {data.shape[-1]}")
    nz, ny, nx = data.shape[:3]
    if min(nx, ny, nz) < 2:
        raise SceneError(f"an sdfgrid needs at least 2 grid points along each axis (one voxel); this grid has "
                         f"{nx} x {ny} x {nz}")
    if nx != nz:
        raise SceneError(f"an sdfgrid's grid must have as many points along x as along z (Mitsuba 3 mixes the two "
                         f"axes' resolutions when they differ); this grid has {nx} x {ny} x {nz}")
    return np.asarray(data[..., 0], np.float64)


def _corners(f: np.ndarray, vox: np.ndarray) -> np.ndarray:
    """(n, 8) corner values of voxels vox (n, 3) as (x, y, z), corner code bit 0 x, bit 1 y, bit 2 z."""
    x, y, z = vox[:, 0:1], vox[:, 1:2], vox[:, 2:3]
    return f[z + _BITS[None, :, 2], y + _BITS[None, :, 1], x + _BITS[None, :, 0]]


def _trilinear(c: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Trilinear interpolation of corner values c (n, 8) at local coordinates t (n, 3) in the voxel."""
    w = np.where(_BITS[None, :, :] == 1, t[:, None, :], 1.0 - t[:, None, :]).prod(axis=2)
    return (c * w).sum(axis=1)


def _trilinear_gradient(c: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The gradient (n, 3), in local voxel units, of the trilinear interpolant of c (n, 8) at t (n, 3)."""
    out = np.empty((len(c), 3))
    for axis in range(3):
        w = np.ones((len(c), 8))
        for other in range(3):
            if other == axis:
                w *= np.where(_BITS[None, :, other] == 1, 1.0, -1.0)
            else:
                w *= np.where(_BITS[None, :, other] == 1, t[:, None, other], 1.0 - t[:, None, other])
        out[:, axis] = (c * w).sum(axis=1)
    return out


def _sample(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """F at grid coordinates g (n, 3) (x, y, z), clamped to the grid as Mitsuba's texture lookup is."""
    n = np.array([f.shape[2], f.shape[1], f.shape[0]])
    g = np.clip(g, 0.0, n - 1)
    v = np.minimum(np.floor(g).astype(np.int64), n - 2)
    return _trilinear(_corners(f, v), g - v)


def _point_key(p: np.ndarray, res: np.ndarray) -> np.ndarray:
    """The index (int64) of points p (n, 3) (x, y, z) of a grid of res (x, y, z) points."""
    return (p[:, 2] * res[1] + p[:, 1]) * res[0] + p[:, 0]


def occupied_voxels(f: np.ndarray) -> np.ndarray:
    """(n, 3) (x, y, z) indices of the voxels holding some corner < 0 and some >= 0 (where the mesh has triangles)."""
    nz, ny, nx = f.shape
    neg = f < 0.0
    any_neg = np.zeros((nz - 1, ny - 1, nx - 1), bool)
    all_neg = np.ones((nz - 1, ny - 1, nx - 1), bool)
    for dz in (0, 1):
        for dy in (0, 1):
            for dx in (0, 1):
                corner = neg[dz:nz - 1 + dz, dy:ny - 1 + dy, dx:nx - 1 + dx]
                any_neg |= corner
                all_neg &= corner
    z, y, x = np.nonzero(any_neg & ~all_neg)
    return np.stack([x, y, z], axis=1).astype(np.int64)


def _solve_edges(c, a, b, fa, fb):
    """Parameters s in [0, 1] of F's zero on the segments a -> b (local voxel coordinates, (n, 3)) of voxels with
    corner values c, where fa < 0 <= fb or fb < 0 <= fa: the Illinois variant of regula falsi on F itself."""
    lo, hi = np.zeros(len(c)), np.ones(len(c))
    flo, fhi = fa.copy(), fb.copy()
    side = np.zeros(len(c), np.int64)
    s = np.where(fb == 0.0, 1.0, np.where(fa == 0.0, 0.0, 0.5))
    done = (fa == 0.0) | (fb == 0.0)
    for _ in range(60):
        live = ~done
        if not live.any():
            break
        i = np.nonzero(live)[0]
        denom = flo[i] - fhi[i]
        st = np.where(denom != 0.0, lo[i] + (hi[i] - lo[i]) * flo[i] / np.where(denom != 0.0, denom, 1.0),
                      0.5 * (lo[i] + hi[i]))
        st = np.clip(st, lo[i], hi[i])
        fs = _trilinear(c[i], a[i] + st[:, None] * (b[i] - a[i]))
        s[i] = st
        same_lo = (fs < 0.0) == (flo[i] < 0.0)
        # the Illinois step: halve the kept end's value when the same end is kept twice, so it converges on both sides
        j = i[same_lo]
        lo[j], flo[j] = st[same_lo], fs[same_lo]
        fhi[j] = np.where(side[j] == -1, 0.5 * fhi[j], fhi[j])
        side[j] = -1
        k = i[~same_lo]
        hi[k], fhi[k] = st[~same_lo], fs[~same_lo]
        flo[k] = np.where(side[k] == 1, 0.5 * flo[k], flo[k])
        side[k] = 1
        done[i] = (fs == 0.0) | (hi[i] - lo[i] <= 1e-12)
    return s


def _mesh_chunk(f, vox, S, analytic, res_sub):
    """Triangle records of the voxels vox (n, 3), each triangle facing F > 0: (edge keys (t, 3) (a vertex's edge
    of the whole sub-grid), vertex keys (t, 3) (the edge key, or with analytic normals the voxel and edge), vertex
    positions in grid coordinates (t, 3, 3), the voxel of each vertex (t, 3, 3))."""
    n = len(vox)
    c = _corners(f, vox)                                                    # (n, 8)
    k = np.arange(S + 1) / S
    # F at the (S + 1)³ sub-grid points of each voxel, [voxel, z, y, x]
    wx = np.stack([1.0 - k, k])                                             # [bit, k]
    P = np.einsum("nabc,ai,bj,ck->nkji", c.reshape(n, 2, 2, 2).transpose(0, 3, 2, 1), wx, wx, wx)
    # (the reshape gives [n, z, y, x] from codes z*4 + y*2 + x; transposed to [n, x, y, z] for the einsum)
    vals = np.stack([P[:, (cd >> 2) & 1:S + ((cd >> 2) & 1), (cd >> 1) & 1:S + ((cd >> 1) & 1),
                       cd & 1:S + (cd & 1)] for cd in range(8)], axis=-1)   # [n, z, y, x, code]
    inside = vals < 0.0
    mixed = inside.any(axis=-1) & ~inside.all(axis=-1)
    cn, cz, cy, cx = np.nonzero(mixed)
    cv = vals[cn, cz, cy, cx]                                               # (m, 8)
    cin = inside[cn, cz, cy, cx]
    cell = np.stack([cx, cy, cz], axis=1)                                   # sub-cell corner in the voxel
    tris_lo, tris_hi, tris_cell, tris_in0 = [], [], [], []
    for tet in _TETS:
        ins = cin[:, tet]                                                   # (m, 4)
        count = ins.sum(axis=1)
        # one corner apart (1 or 3 inside): a triangle on its three edges
        one = np.nonzero((count == 1) | (count == 3))[0]
        if len(one):
            lone = np.where(count[one, None] == 1, ins[one], ~ins[one]).argmax(axis=1)
            others = np.array([[j for j in range(4) if j != i] for i in range(4)])[lone]   # (q, 3)
            i0 = np.repeat(lone[:, None], 3, axis=1)
            lo, hi = np.minimum(i0, others), np.maximum(i0, others)
            tris_lo.append(tet[lo])
            tris_hi.append(tet[hi])
            tris_cell.append(one)
            tris_in0.append(ins[one, lo[:, 0]])
        # two and two: the quad on the four edges between them, as two triangles
        two = np.nonzero(count == 2)[0]
        if len(two):
            order = np.argsort(~ins[two], axis=1, kind="stable")            # inside corners first
            a, b, cc, d = order[:, 0], order[:, 1], order[:, 2], order[:, 3]
            quad = [(a, cc), (a, d), (b, d), (b, cc)]
            for e0, e1, e2 in ((0, 1, 2), (0, 2, 3)):
                pairs = [quad[e0], quad[e1], quad[e2]]
                lo = np.stack([np.minimum(p, q) for p, q in pairs], axis=1)
                hi = np.stack([np.maximum(p, q) for p, q in pairs], axis=1)
                tris_lo.append(tet[lo])
                tris_hi.append(tet[hi])
                tris_cell.append(two)
                tris_in0.append(ins[two, lo[:, 0]])
    if not tris_lo:
        return np.zeros((0, 3), np.int64), np.zeros((0, 3), np.int64), np.zeros((0, 3, 3)), np.zeros((0, 3, 3), np.int64)
    lo = np.concatenate(tris_lo)                                            # (t, 3) corner codes
    hi = np.concatenate(tris_hi)
    tc = np.concatenate(tris_cell)                                          # (t,) mixed-sub-cell index
    in0 = np.concatenate(tris_in0)                                          # edge 0's low end is inside
    t = len(tc)
    # each triangle vertex's edge: its ends in the voxel's sub-grid
    e_cell = np.repeat(tc, 3)
    e_lo, e_hi = lo.reshape(-1), hi.reshape(-1)
    local_lo = cell[e_cell] + _BITS[e_lo]                                   # in the voxel's sub-grid, (x, y, z)
    voxel = cn[e_cell]
    local_hi = cell[e_cell] + _BITS[e_hi]
    ukey_in, first, inverse = np.unique(_point_key(vox[voxel] * S + local_lo, res_sub) * 8 + (e_hi & ~e_lo),
                                        return_index=True, return_inverse=True)
    uv_ = voxel[first]
    a, b = local_lo[first] / S, local_hi[first] / S
    fa = cv[e_cell[first], e_lo[first]]
    fb = cv[e_cell[first], e_hi[first]]
    s = _solve_edges(c[uv_], a, b, fa, fb)
    # grid coordinates; a zero at an end (F exactly 0 at a sub-grid point) is that point exactly, and every edge
    # ending there gives the same vertex: its key is the point's (direction 0), not the edge's (1 to 7)
    upos = vox[uv_] + np.where(s[:, None] == 1.0, b, a + s[:, None] * (b - a))
    at_point = np.where(s == 0.0, 0, np.where(s == 1.0, 1, -1))
    point = np.where((at_point == 1)[:, None], local_hi[first], local_lo[first])
    ukey = np.where(at_point >= 0, _point_key(vox[uv_] * S + point, res_sub) * 8, ukey_in)
    pos = upos[inverse].reshape(t, 3, 3)
    keys = ukey[inverse].reshape(t, 3)
    if analytic:   # one vertex per voxel and edge (or point): the gradient jumps across voxel faces
        at = at_point[inverse]
        point = np.where((at == 1)[:, None], local_hi, local_lo)
        local = np.where(at >= 0, _point_key(point, np.array([S + 1] * 3)) * 8,
                         _point_key(local_lo, np.array([S + 1] * 3)) * 8 + (e_hi & ~e_lo))
        vindex = _point_key(vox[voxel], np.array([f.shape[2] - 1, f.shape[1] - 1, f.shape[0] - 1]))
        vkeys = (vindex * (S + 1) ** 3 * 8 + local).reshape(t, 3)
    else:
        vkeys = keys.copy()
    owner = (vox[voxel] if analytic else np.zeros((len(voxel), 3), np.int64)).reshape(t, 3, 3)
    # face F > 0: edge 0 runs from inside to outside (or back); the triangle's normal must point outward
    ends = np.stack([cell[tc] + _BITS[lo[:, 0]], cell[tc] + _BITS[hi[:, 0]]], axis=1)       # (t, 2, 3)
    out_dir = np.where(in0[:, None], ends[:, 1] - ends[:, 0], ends[:, 0] - ends[:, 1]).astype(np.float64)
    normal = np.cross(pos[:, 1] - pos[:, 0], pos[:, 2] - pos[:, 0])
    flip = (normal * out_dir).sum(axis=1) < 0.0
    keys[flip] = keys[flip][:, ::-1]
    vkeys[flip] = vkeys[flip][:, ::-1]
    pos[flip] = pos[flip][:, ::-1]
    owner[flip] = owner[flip][:, ::-1]
    return keys, vkeys, pos, owner


def smooth_normals(f: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Mitsuba's ``smooth`` shading normals (unnormalised, object space) at grid coordinates g (n, 3)."""
    res = np.array([f.shape[2], f.shape[1], f.shape[0]], np.float64)
    v111 = np.rint(g).astype(np.int64)
    v000 = v111 - 1
    blended = np.zeros_like(g)
    # a voxel's gradient along an axis is the difference of F across it along that axis at the point's other two
    # coordinates, so it depends on the voxel's index along that axis only: the eight voxels need F on three
    # planes per axis, and two differences
    step = np.empty((3, 2, len(g)))
    for axis in range(3):
        plane = []
        for offset in range(3):
            q = g.copy()
            q[:, axis] = v000[:, axis] + offset
            plane.append(_sample(f, q))
        step[axis, 0] = (plane[1] - plane[0]) * (res[axis] - 1.0)
        step[axis, 1] = (plane[2] - plane[1]) * (res[axis] - 1.0)
    valid = {}
    grads = {}
    for code in range(8):
        v = v000 + _BITS[code]
        ok = (v >= 0).all(axis=1)
        grad = np.stack([step[axis, _BITS[code, axis]] for axis in range(3)], axis=1)
        length = np.linalg.norm(grad, axis=1, keepdims=True)
        grads[code] = np.where(ok[:, None] & (length > 0.0), grad / np.where(length > 0.0, length, 1.0), 0.0)
        valid[code] = ok
    w = g - v111 + 0.5                                                     # (u, v, w) in the blend cell
    for axis in range(3):
        bit = 1 << axis
        low_codes = [cd for cd in range(8) if not cd & bit]
        high_codes = [cd for cd in range(8) if cd & bit]
        none_low = ~np.any([valid[cd] for cd in low_codes], axis=0)
        none_high = ~np.any([valid[cd] for cd in high_codes], axis=0)
        w[:, axis] = np.where(none_low, 1.0, w[:, axis])
        w[:, axis] = np.where(none_high, 0.0, w[:, axis])
    for code in range(8):
        weight = np.ones(len(g))
        for axis in range(3):
            weight *= w[:, axis] if code & (1 << axis) else 1.0 - w[:, axis]
        blended += weight[:, None] * grads[code]
    return blended


def analytic_normals(f: np.ndarray, g: np.ndarray, owner: np.ndarray) -> np.ndarray:
    """The gradient of F (object space) at grid coordinates g (n, 3), in the voxels owner (n, 3)."""
    res = np.array([f.shape[2], f.shape[1], f.shape[0]], np.float64)
    return _trilinear_gradient(_corners(f, owner), g - owner) * (res - 1.0)


def estimate_triangles(voxels: int, subdivisions: int = SUBDIVISIONS) -> int:
    """An estimate, on the large side, of the triangles :func:`sdf_mesh` makes for ``voxels`` crossed voxels."""
    return voxels * subdivisions ** 2 * TRIANGLES_PER_VOXEL_FACTOR


def sdf_mesh(f: np.ndarray, normals: str = "smooth", subdivisions: int = SUBDIVISIONS,
             what: str = "the sdfgrid") -> Mesh:
    """The object-space mesh (in the unit cube) of the zero set of the distances f (nz, ny, nx) (from
    :func:`check_grid`), with Mitsuba's ``normals`` ("smooth" or "analytic") as vertex normals, unnormalised
    (:func:`~caustica.scene.meshes.to_world_mesh` transforms and normalises them) and uv (0, 0).

    SceneError when no voxel holds the surface, or when the mesh would exceed MAX_TRIANGLES or the memory budget."""
    if normals not in NORMAL_MODES:
        raise SceneError(f"unknown normals mode {normals!r}; supported: {', '.join(NORMAL_MODES)}")
    if subdivisions < 2 or subdivisions % 2:
        raise ValueError("subdivisions must be even and at least 2")
    S = subdivisions
    vox = occupied_voxels(f)
    if len(vox) == 0:
        raise SceneError(f"{what}: its distances never change sign between neighbouring grid points: it has no "
                         f"surface (Mitsuba refuses such a grid too)")
    estimate = estimate_triangles(len(vox), S)
    if estimate > MAX_TRIANGLES:
        raise SceneError(f"{what}: its surface crosses {len(vox):,} voxels, which would make about {estimate:,} "
                         f"triangles ({S}³ sub-cells per voxel), more than the {MAX_TRIANGLES:,} allowed")
    try:
        check_budget(estimate * BYTES_PER_TRIANGLE, f"{what}: its mesh ({len(vox):,} voxels crossed, about "
                     f"{estimate:,} triangles)", "use a coarser grid")
    except ParameterError as exc:
        raise SceneError(str(exc)) from None
    res_sub = np.array([(f.shape[2] - 1) * S + 1, (f.shape[1] - 1) * S + 1, (f.shape[0] - 1) * S + 1], np.int64)
    analytic = normals == "analytic"
    keys, vkeys, pos, owner = [], [], [], []
    for start in range(0, len(vox), CHUNK):
        k, vk, p, o = _mesh_chunk(f, vox[start:start + CHUNK], S, analytic, res_sub)
        keys.append(k.reshape(-1))
        vkeys.append(vk.reshape(-1))
        pos.append(p.reshape(-1, 3))
        owner.append(o.reshape(-1, 3))
    keys, vkeys = np.concatenate(keys), np.concatenate(vkeys)
    pos, owner = np.concatenate(pos), np.concatenate(owner)
    # one position per vertex key (the voxels on either side of a face solve its edges alike, up to rounding), so
    # the triangles of neighbouring voxels meet exactly
    _, efirst, einverse = np.unique(keys, return_index=True, return_inverse=True)
    pos = pos[efirst][einverse.reshape(-1)]
    _, first, inverse = np.unique(vkeys, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    g = pos[first]
    triangles = inverse.reshape(-1, 3).astype(np.int64)
    # triangles with two coincident vertices (a grid value exactly 0 puts several edges' zeros on one point) have no
    # area; Mitsuba's surface has nothing there either
    gt = g[triangles]
    area2 = np.linalg.norm(np.cross(gt[:, 1] - gt[:, 0], gt[:, 2] - gt[:, 0]), axis=1)
    triangles = triangles[area2 > 0.0]
    used = np.zeros(len(g), bool)
    used[triangles.reshape(-1)] = True
    remap = np.cumsum(used) - 1
    triangles = remap[triangles]
    g = g[used]
    vowner = owner[first][used]
    n = analytic_normals(f, g, vowner) if analytic else smooth_normals(f, g)
    scale = 1.0 / np.array([f.shape[2] - 1, f.shape[1] - 1, f.shape[0] - 1], np.float64)
    return Mesh(positions=np.ascontiguousarray(g * scale), triangles=np.ascontiguousarray(triangles),
                normals=np.ascontiguousarray(n), uvs=np.zeros((len(g), 2)))
