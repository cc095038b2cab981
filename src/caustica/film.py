"""The film of a multi-pass render: per-pass images summed in pass order.

A pass's image is the mean of its own samples (float32, linear radiance).  The film
adds pass images into a float64 sum strictly in pass order, so the final bits depend
only on which passes were rendered — not on threads, on how passes were grouped
between checkpoints, or on which machine rendered which pass: whoever renders a
pass hands its image to the one film, which adds it when its turn comes.  A film
of one pass returns that pass's image unchanged, so a one-pass render has exactly
the bits of the one-shot renderer it replaces.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Film:
    """``passes`` pass images summed (float64 H×W×3); ``first`` keeps pass 0's own float32 image."""
    sum: np.ndarray
    passes: int = 0
    first: np.ndarray | None = None

    @staticmethod
    def empty(width: int, height: int) -> "Film":
        return Film(np.zeros((height, width, 3), np.float64), 0, None)

    def add(self, pass_index: int, image: np.ndarray) -> "Film":
        """This film with pass ``pass_index``'s image added (passes must come in order)."""
        if pass_index != self.passes:
            raise ValueError(f"film: pass {pass_index} added after {self.passes} passes (out of order)")
        image = np.asarray(image, np.float32)
        if image.shape != self.sum.shape:
            raise ValueError(f"film: a {image.shape} pass image on a {self.sum.shape} film")
        return Film(self.sum + image, self.passes + 1, image if self.passes == 0 else None)

    def image(self) -> np.ndarray:
        """The mean of the passes (float32); pass 0's own image when there is one pass."""
        if self.passes == 0:
            return np.zeros(self.sum.shape, np.float32)
        if self.passes == 1 and self.first is not None:
            return self.first
        return (self.sum / self.passes).astype(np.float32)

    def to_arrays(self) -> dict[str, np.ndarray]:
        out = {"film_sum": self.sum, "film_passes": np.asarray(self.passes)}
        if self.first is not None:
            out["film_first"] = self.first
        return out

    @staticmethod
    def from_arrays(arrays) -> "Film":
        first = arrays["film_first"] if "film_first" in arrays else None
        return Film(np.asarray(arrays["film_sum"], np.float64), int(arrays["film_passes"]), first)
