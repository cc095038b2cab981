"""Checks of arrays read from disk (a checkpoint's): dtype, shape and the range a render writes."""
from __future__ import annotations

import numpy as np

from .errors import ParameterError


def require_array(arrays, name: str, dtype, shape: tuple, *, low=None, above=None, high=None) -> np.ndarray:
    """``arrays[name]`` if it has this dtype and shape and its values lie within the bounds given, else a
    ParameterError naming what is wrong (``low`` <= values, ``above`` < values, values <= ``high``)."""
    if name not in arrays:
        raise ParameterError(f"checkpoint: it has no {name}")
    a = arrays[name]
    if a.dtype != np.dtype(dtype) or a.shape != tuple(shape):
        raise ParameterError(f"checkpoint: its {name} is {a.dtype} of shape {a.shape}, this render needs "
                             f"{np.dtype(dtype)} of shape {tuple(shape)}")
    for bound, bad, word in ((low, lambda b: a < b, ">="), (above, lambda b: a <= b, ">"),
                             (high, lambda b: a > b, "<=")):
        if bound is not None and a.size and np.any(bad(bound)):
            raise ParameterError(f"checkpoint: its {name} has values out of range (a render writes {word} {bound:g})")
    return a
