"""Photon records and photon maps, as structures of arrays.

A photon record is what a photon leaves at a diffuse surface (SPEC §3): position,
incoming direction (pointing towards the surface), power RGB (W) and the surface
normal on the side the photon arrived from.  Records are float32: the map's memory
is what the paper's Tables 2 and 3 compare, and float32 is ample for positions in
a 20-unit box.

A :class:`PhotonMap` is the records plus the kd-tree over their positions; the
stream records of SPM become a PhotonMap too (leading position, normal, the
stream's energy E_i as power), so one estimator serves every method.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..features import specialisable, specialised
from .kdtree import KdTree, build_kdtree, memory_bytes as tree_bytes, normal_bounds

# Record kinds in the tracing buffers.
EMPTY = 0
INDIRECT = 1   # arrived after at least one diffuse bounce: light -> ... -> D -> ... -> here
CAUSTIC = 2    # arrived through mirrors, glass and glossy surfaces only: light -> (S|G)+ -> here
# Volume photons (a scattering event in a medium; photons/trace.py), with the same two histories.
VOLUME_INDIRECT = 3
VOLUME_CAUSTIC = 4


#: The shallowest surface record a traced path makes: light -> the first scattering event -> the record (direct
#: light is not stored; shadow rays carry it).
MIN_RECORD_DEPTH = 2


class PhotonMap(NamedTuple):
    """Records plus the kd-tree's arrays, flat (Numba's parallel loops refuse nested tuples)."""
    tree_points: np.ndarray
    tree_index: np.ndarray
    tree_axis: np.ndarray
    tree_normal_bounds: np.ndarray  # int8 (n, 6): kdtree.normal_bounds of ``normal``
    position: np.ndarray   # float32[n, 3]
    direction: np.ndarray  # float32[n, 3], incoming, towards the surface
    power: np.ndarray      # float32[n, 3], W
    normal: np.ndarray     # float32[n, 3], on the side the photon came from
    depth: np.ndarray      # uint16[n]: segments from the light to the record (TraceBuffers.depth), which a
    #                        render's max_depth limits at the gather

    @property
    def tree(self) -> KdTree:
        return KdTree(self.tree_points, self.tree_index, self.tree_axis)

    @property
    def count(self) -> int:
        return self.position.shape[0]

    def record_bytes(self) -> int:
        """Bytes of the records themselves (position, direction, power, normal, depth)."""
        return sum(a.nbytes for a in (self.position, self.direction, self.power, self.normal, self.depth))

    def memory_bytes(self) -> int:
        """Records plus the kd-tree's own arrays and normal bounds: what the map costs in memory."""
        return self.record_bytes() + tree_bytes(self.tree) + self.tree_normal_bounds.nbytes


def build_photon_map_with_order(position, direction, power, normal, depth) -> tuple[PhotonMap, np.ndarray]:
    """The photon map, its records stored in kd-tree order, and ``order``: record j was input ``order[j]``.

    Storing the records in the tree's own order makes the k-nearest search read
    normals and powers sequentially instead of jumping through an index (a third of
    the search time on a 200k-photon map); the tree's index is then the identity.
    """
    position = np.asarray(position, dtype=np.float32)
    tree = build_kdtree(position.astype(np.float64))
    order = tree.index

    def f32(a):
        return np.ascontiguousarray(np.asarray(a, dtype=np.float32)[order])

    tree = KdTree(tree.points, np.arange(order.shape[0], dtype=np.int64), tree.axis)
    normal = f32(normal)
    pmap = PhotonMap(tree.points, tree.index, tree.axis, normal_bounds(tree, normal), f32(position),
                     f32(direction), f32(power), normal,
                     np.ascontiguousarray(np.asarray(depth, dtype=np.uint16)[order]))
    return pmap, order


def build_photon_map(position, direction, power, normal, depth=None) -> PhotonMap:
    """The photon map of these records (stored in kd-tree order; see :func:`build_photon_map_with_order`).
    ``depth``: each record's segments from its light; None for records made without a path (a test's), which then
    count as the shallowest a traced path makes (:data:`MIN_RECORD_DEPTH`)."""
    if depth is None:
        depth = np.full(len(position), MIN_RECORD_DEPTH, np.uint16)
    return build_photon_map_with_order(position, direction, power, normal, depth)[0]


def empty_photon_map() -> PhotonMap:
    z = np.zeros((0, 3), np.float32)
    return build_photon_map(z, z, z, z)


@specialisable
class TraceBuffers(NamedTuple):
    """Photon records as structures of arrays.  Tracing writes path i into slots of its own, [i*m, (i+1)*m), so
    threads need no atomics (:func:`caustica.photons.trace.trace_photon_pass` appends the rest of a longer path
    after every path's slots)."""
    position: np.ndarray
    direction: np.ndarray
    power: np.ndarray
    normal: np.ndarray
    kind: np.ndarray       # int8: EMPTY, INDIRECT or CAUSTIC
    depth: np.ndarray      # uint16: the segments of the photon's path from its light to the record (Mitsuba's
    #                        depth: 2 after one bounce; a stream's split photon counts its stream's path too),
    #                        saturating


SLOT_BYTES = 4 * 3 * 4 + 1 + 2
#: The deepest record :attr:`TraceBuffers.depth` tells apart (deeper ones read as this).
MAX_RECORD_DEPTH = 65535


def allocate_buffers(n_paths: int, slots_per_path: int) -> TraceBuffers:
    n = n_paths * slots_per_path
    return TraceBuffers(np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32),
                        np.zeros((n, 3), np.float32), np.zeros((n, 3), np.float32),
                        np.zeros(n, np.int8), np.zeros(n, np.uint16))


def no_records() -> TraceBuffers:
    """A buffer of no slots whose type says so (no record kind: :mod:`caustica.features`), for a pass that stores
    nothing there: the code that would write to it is dropped from its kernels before typing
    (:func:`caustica.photons.streams.may_split`)."""
    v = np.zeros((0, 3), np.float32)
    return specialised(TraceBuffers, 0)(v, v, v, v, np.zeros(0, np.int8), np.zeros(0, np.uint16))


def map_from_buffers(buf: TraceBuffers, kinds: tuple[int, ...]) -> PhotonMap:
    """The photon map of the records whose kind is in ``kinds`` (in path order: deterministic)."""
    keep = np.isin(buf.kind, np.asarray(kinds, np.int8))
    return build_photon_map(buf.position[keep], buf.direction[keep], buf.power[keep], buf.normal[keep],
                            buf.depth[keep])
