"""The film of a multi-pass render: pass images summed in a fixed tree over the pass indices.

A pass's image is the mean of its own samples (float32, linear radiance).  Floating-point
addition is not associative, so a film whose bits must not depend on how passes were
grouped — between checkpoints, threads or machines (:mod:`caustica.cluster`) — needs one
order of additions fixed by the pass indices alone.  That order is a binary tree:

* a *block* is the float64 sum of the aligned passes [k·2^j, (k+1)·2^j), and a block of
  2^(j+1) passes is always (left block) + (right block) — pairwise summation;
* the film keeps the blocks of the binary decomposition of its passes, at most one per
  size; blocks of :data:`TRUNK_PASSES` passes are added, in pass order, into one running
  float64 ``trunk``, so a film holds at most log2(TRUNK_PASSES) + 1 images whatever the
  number of passes;
* the image is (trunk + blocks, left to right) / passes.

Whoever renders the passes [a, b) — this process one at a time, or a worker a whole
range — builds the same blocks, and :meth:`Film.merge` joins them exactly as adding the
passes one by one would: the same bits for any grouping.  A film of one pass returns that
pass's own float32 image (float64 and back is exact), so a one-pass render keeps the bits
of the one-shot renderer it replaces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Passes per trunk block: the tree's largest block (and the largest task of a distributed render).
TRUNK_PASSES = 64
#: Float64 images a film holds at most (trunk + one block per size below TRUNK_PASSES), for memory estimates.
MAX_FILM_IMAGES = TRUNK_PASSES.bit_length()
#: Memory per pixel a film can hold at most (float64 RGB images), for memory estimates.
FILM_BYTES_PER_PIXEL = MAX_FILM_IMAGES * 3 * 8

#: Memory per pixel of a render and its save, unless the method says otherwise (its
#: ``bytes_per_pixel``): the image, the camera pass's bookkeeping, the pass film's float64
#: sums and the EXR/PNG conversions.  Measured: the peak memory of a 1536 x 1536 render
#: less that of a 64 x 64 one is about 109 bytes per pixel for pt, pm and spm.
IMAGE_BYTES_PER_PIXEL = 112


@dataclass(frozen=True)
class Block:
    """The float64 sum of the passes [first, first + size), size a power of two and first a multiple of it."""
    first: int
    size: int
    sum: np.ndarray


def _push(blocks: list, block: Block) -> None:
    """Append ``block`` and join equal neighbours into their parent, as pairwise summation does."""
    blocks.append(block)
    while len(blocks) >= 2:
        left, right = blocks[-2], blocks[-1]
        if left.size != right.size or left.first % (2 * left.size) or left.size >= TRUNK_PASSES:
            break
        blocks[-2:] = [Block(left.first, 2 * left.size, left.sum + right.sum)]


@dataclass(frozen=True)
class Film:
    """The passes [start, end) summed: ``trunk`` (whole TRUNK_PASSES blocks, or None) and the blocks after it.

    Immutable: :meth:`add` and :meth:`merge` return a new film and never change an array
    the old one holds, so an interrupted pass leaves the last film whole.
    """
    shape: tuple
    start: int = 0
    end: int = 0
    trunk: np.ndarray | None = None
    blocks: tuple = ()
    #: A whole render's film (from pass 0, folding whole blocks into the trunk), or a worker's range.
    root: bool = True

    @staticmethod
    def empty(width: int, height: int) -> "Film":
        """A whole render's film, of no passes yet."""
        return Film((height, width, 3))

    @staticmethod
    def part(width: int, height: int, start: int) -> "Film":
        """A film for the passes from ``start`` on, to be merged into the whole render's (no trunk)."""
        return Film((height, width, 3), start, start, root=False)

    @property
    def passes(self) -> int:
        return self.end - self.start

    def add(self, pass_index: int, image: np.ndarray) -> "Film":
        """This film with pass ``pass_index``'s image added (passes must come in order)."""
        if pass_index != self.end:
            raise ValueError(f"film: pass {pass_index} added after pass {self.end - 1} (out of order)")
        image = np.asarray(image, np.float32)
        if image.shape != self.shape:
            raise ValueError(f"film: a {image.shape} pass image on a {self.shape} film")
        return self._with([Block(pass_index, 1, image.astype(np.float64))], pass_index + 1)

    def merge(self, other: "Film") -> "Film":
        """This film followed by ``other``, the passes [self.end, other.end): the bits of adding them one by one."""
        if other.start != self.end:
            raise ValueError(f"film: passes from {other.start} merged after pass {self.end - 1} (out of order)")
        if other.shape != self.shape:
            raise ValueError(f"film: a {other.shape} film merged into a {self.shape} film")
        if other.root:
            raise ValueError("film: only a part (Film.part) can be merged into another film")
        return self._with(list(other.blocks), other.end)

    def _with(self, new_blocks: list, end: int) -> "Film":
        blocks, trunk = list(self.blocks), self.trunk
        for b in new_blocks:
            _push(blocks, b)
            if self.root and blocks[0].size == TRUNK_PASSES:
                trunk = blocks[0].sum if trunk is None else trunk + blocks[0].sum
                blocks.pop(0)
        return Film(self.shape, self.start, end, trunk, tuple(blocks), self.root)

    def total(self) -> np.ndarray:
        """The float64 sum of the passes, in the tree's order."""
        parts = ([] if self.trunk is None else [self.trunk]) + [b.sum for b in self.blocks]
        if not parts:
            return np.zeros(self.shape, np.float64)
        out = parts[0]
        for p in parts[1:]:
            out = out + p
        return out

    def image(self) -> np.ndarray:
        """The mean of the passes (float32); pass 0's own image when there is one pass."""
        if self.passes == 0:
            return np.zeros(self.shape, np.float32)
        return (self.total() / self.passes).astype(np.float32)

    @property
    def nbytes(self) -> int:
        return sum(b.sum.nbytes for b in self.blocks) + (0 if self.trunk is None else self.trunk.nbytes)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"film_shape": np.asarray(self.shape), "film_range": np.asarray([self.start, self.end]),
               "film_blocks": np.asarray([[b.first, b.size] for b in self.blocks], np.int64).reshape(-1, 2)}
        for i, b in enumerate(self.blocks):
            out[f"film_block_{i}"] = b.sum
        if self.trunk is not None:
            out["film_trunk"] = self.trunk
        return out

    @staticmethod
    def from_arrays(arrays) -> "Film":
        """The whole render's film ``to_arrays`` saved, its structure checked (ValueError when damaged)."""
        shape = tuple(int(v) for v in arrays["film_shape"])
        start, end = (int(v) for v in arrays["film_range"])
        trunk = np.asarray(arrays["film_trunk"], np.float64) if "film_trunk" in arrays else None
        blocks = tuple(Block(int(f), int(s), np.asarray(arrays[f"film_block_{i}"], np.float64))
                       for i, (f, s) in enumerate(np.asarray(arrays["film_blocks"]).reshape(-1, 2)))
        film = Film(shape, start, end, trunk, blocks)
        film.check()
        return film

    def check(self) -> None:
        """ValueError unless trunk and blocks are the tree's for the passes [start, end)."""
        at = self.end - sum(b.size for b in self.blocks)     # where the trunk ends
        if self.start != 0 or (at != 0 if self.trunk is None else at <= 0 or at % TRUNK_PASSES) \
                or (self.trunk is not None and self.trunk.shape != self.shape):
            raise ValueError(f"film: its trunk and blocks do not make up the passes [{self.start}, {self.end})")
        rebuilt: list = []
        for b in self.blocks:
            if b.first != at or b.size < 1 or b.size & (b.size - 1) or b.first % b.size or b.sum.shape != self.shape:
                raise ValueError(f"film: a damaged block of passes [{b.first}, {b.first + b.size})")
            at += b.size
            _push(rebuilt, Block(b.first, b.size, b.sum))
        if len(rebuilt) != len(self.blocks) or (rebuilt and rebuilt[0].size >= TRUNK_PASSES):
            raise ValueError(f"film: its blocks are not the tree's for the passes [{self.start}, {self.end})")


@dataclass(frozen=True)
class PassSums:
    """The state of a render whose passes are independent: the film, and per-pixel integer counts summed.

    ``counts`` (int64, one per pixel, or None) adds exactly in any order; ``film`` adds in
    its tree.  A whole render's sums start at pass 0; a worker's part (:meth:`part`) at any
    pass, and :meth:`merge` joins it with the same bits as adding its passes one by one.
    """
    film: Film
    counts: np.ndarray | None = None

    @staticmethod
    def empty(width: int, height: int) -> "PassSums":
        return PassSums(Film.empty(width, height))

    @staticmethod
    def part(width: int, height: int, start: int) -> "PassSums":
        return PassSums(Film.part(width, height, start))

    @property
    def passes(self) -> int:
        return self.film.passes

    @property
    def end(self) -> int:
        return self.film.end

    def add(self, pass_index: int, image: np.ndarray, counts: np.ndarray | None = None) -> "PassSums":
        return PassSums(self.film.add(pass_index, image), _add_counts(self.counts, counts))

    def merge(self, part: "PassSums") -> "PassSums":
        return PassSums(self.film.merge(part.film), _add_counts(self.counts, part.counts))

    @property
    def nbytes(self) -> int:
        return self.film.nbytes + (0 if self.counts is None else self.counts.nbytes)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = self.film.to_arrays()
        if self.counts is not None:
            out["pixel_counts"] = self.counts
        return out

    @staticmethod
    def from_arrays(arrays) -> "PassSums":
        counts = np.asarray(arrays["pixel_counts"], np.int64) if "pixel_counts" in arrays else None
        return PassSums(Film.from_arrays(arrays), counts)


def _add_counts(a, b):
    if b is None:
        return a
    b = np.asarray(b, np.int64)
    return b.copy() if a is None else a + b
