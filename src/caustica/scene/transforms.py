"""4x4 matrices for Mitsuba's ``<transform>`` operations.

Mitsuba applies the children of a ``<transform>`` in document order, each new
operation multiplied on the left (``M = op @ M``), so ``<scale/><translate/>``
scales first.  The functions here build the individual operations from the
(already ``$``-substituted) XML attributes; they raise :class:`ValueError` with a
short message, which the XML loader turns into a :class:`~caustica.errors.SceneError`
naming the file and line.

Every number read here is checked finite and within :data:`MAX_ABS_FLOAT` (float32's
range: the image is float32, and a value beyond it overflows long before it is useful),
and every matrix a scene uses passes :func:`check_transform`.
"""
from __future__ import annotations

import math
import re

import numpy as np

from ..errors import quoted

#: The operations allowed inside ``<transform>``, in the order of the docs.
TRANSFORM_OPS = ("translate", "rotate", "scale", "matrix", "lookat")

_SPLIT = re.compile(r"[,\s]+")

#: The largest magnitude a number in a scene may have: float32's largest finite value
#: (about 3.4e38).  The image is float32, and geometry beyond it overflows in the kernels.
MAX_ABS_FLOAT = float(np.finfo(np.float32).max)
_RANGE = f"±{MAX_ABS_FLOAT:.3g} (float32's range, which the image uses)"

#: A transform whose smallest singular value is below this fraction of its largest
#: squashes space flat (a zero scale, or a scale so small that float64 cannot tell it from zero).
MIN_SINGULAR_RATIO = 1e-12

#: float32's smallest normal number: a transform that shrinks everything below it is degenerate too.
MIN_SCALE = float(np.finfo(np.float32).tiny)


def check_finite(value: float, what: str) -> float:
    """value if it is finite and within ±MAX_ABS_FLOAT; ValueError naming `what` otherwise."""
    if not math.isfinite(value):
        raise ValueError(f"{what} is not a finite number")
    if abs(value) > MAX_ABS_FLOAT:
        raise ValueError(f"{what} is out of range: numbers in a scene must lie within {_RANGE}")
    return value


def parse_floats(text: str, what: str = "value") -> list[float]:
    """Split "1, 2 3" (commas and/or spaces, as Mitsuba) into finite floats within ±MAX_ABS_FLOAT."""
    parts = [p for p in _SPLIT.split(text.strip()) if p]
    out = []
    for p in parts:
        try:
            v = float(p)
        except ValueError:
            raise ValueError(f"{what}={quoted(text)} is not a number") from None
        out.append(check_finite(v, f"{what}={quoted(text)}"))
    return out


def parse_float(text: str, what: str = "value") -> float:
    vals = parse_floats(text, what)
    if len(vals) != 1:
        raise ValueError(f"{what}={quoted(text)} must be a single number")
    return vals[0]


#: The range of an ``<integer>`` in a scene: int32, which every size and count in the kernels fits.
INT32_MAX = 2**31 - 1
_INTEGER = re.compile(r"[+-]?[0-9]+")


def parse_int(text: str, what: str = "value") -> int:
    """An integer within ±INT32_MAX; ValueError for anything else (without converting 5,000 digits)."""
    t = text.strip()
    if not _INTEGER.fullmatch(t):
        raise ValueError(f"{what}={quoted(text)} is not an integer")
    digits = t.lstrip("+-").lstrip("0")
    if len(digits) > len(str(INT32_MAX)) or int(digits or "0") > INT32_MAX:
        raise ValueError(f"{what}={quoted(text)} is out of range: integers in a scene must lie within "
                         f"±{INT32_MAX:,} (int32)")
    return int(t)


def check_transform(m: np.ndarray) -> np.ndarray:
    """m if it is a usable 4x4 affine transform; ValueError saying what is wrong otherwise.

    Usable: every entry finite and within ±MAX_ABS_FLOAT, the last row (0, 0, 0, 1)
    (caustica's shapes and camera are affine; Mitsuba's are too), and the 3x3 part not
    degenerate: its singular values all above MIN_SINGULAR_RATIO times the largest and
    above MIN_SCALE.
    The one check for every transform: shapes, the sensor, emitters, and the matrices a
    shape's own parameters (radius, center, p0/p1) add.
    """
    m = np.asarray(m, dtype=np.float64)
    if not np.all(np.isfinite(m)):
        raise ValueError("the transform is not finite")
    big = float(np.abs(m).max())
    if big > MAX_ABS_FLOAT:
        raise ValueError(f"the transform has an entry of {big:.3g}, beyond {_RANGE}")
    if not np.array_equal(m[3], [0.0, 0.0, 0.0, 1.0]):
        raise ValueError(f"the transform's last row is {tuple(float(c) for c in m[3])}, not (0, 0, 0, 1): "
                         f"projective transforms are not supported")
    sv = np.linalg.svd(m[:3, :3], compute_uv=False)
    if not sv[-1] > max(MIN_SINGULAR_RATIO * sv[0], MIN_SCALE):
        raise ValueError(f"the transform is degenerate (a zero scale?): its scales (singular values) are "
                         f"{', '.join(f'{v:.3g}' for v in sv)}; the smallest must exceed "
                         f"{MIN_SINGULAR_RATIO:g} x the largest and {MIN_SCALE:.3g} (float32's smallest normal)")
    return m


def xyz_from_attrs(attrs: dict[str, str], default: float, allow_uniform: bool = False) -> np.ndarray:
    """A 3-vector from ``value="x, y, z"`` or ``x= y= z=`` attributes (missing ones = default).

    allow_uniform: a single number in ``value`` applies to all three components
    (``<scale value="2"/>``).
    """
    if "value" in attrs:
        if any(k in attrs for k in "xyz"):
            raise ValueError("give either value= or x/y/z, not both")
        vals = parse_floats(attrs["value"])
        if len(vals) == 1 and allow_uniform:
            vals = vals * 3
        if len(vals) != 3:
            raise ValueError(f"value={quoted(attrs['value'])} must have 3 components")
        return np.array(vals, dtype=np.float64)
    return np.array([parse_float(attrs[k], k) if k in attrs else default for k in "xyz"],
                    dtype=np.float64)


def translate(v) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = np.asarray(v, dtype=np.float64)
    return m


def scale(v) -> np.ndarray:
    v = np.broadcast_to(np.asarray(v, dtype=np.float64), (3,))
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg: float) -> np.ndarray:
    """Right-handed rotation by angle_deg degrees about an axis (Rodrigues), as Mitsuba 3 builds it.

    An axis of length 1 (within 1e-3, which allows hand-typed "0.707, 0.707, 0") is normalised.
    Mitsuba 3 does not normalise any other axis: its matrix is then Rodrigues' formula with the
    axis as given, which is not a rotation (it scales and shears); so is this one, so that a scene
    renders as in Mitsuba.  A zero axis is an error.
    """
    a = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(a)
    if n == 0.0:
        raise ValueError("the rotation axis is zero; give an axis such as x=\"1\"")
    x, y, z = a / n if abs(n - 1.0) <= 1e-3 else a
    t = math.radians(angle_deg)
    c, s = math.cos(t), math.sin(t)
    C = 1.0 - c
    m = np.eye(4)
    m[:3, :3] = [
        [x * x * C + c, x * y * C - z * s, x * z * C + y * s],
        [x * y * C + z * s, y * y * C + c, y * z * C - x * s],
        [x * z * C - y * s, y * z * C + x * s, z * z * C + c],
    ]
    return m


def look_at(origin, target, up) -> np.ndarray:
    """Mitsuba's look-at: columns [left, new_up, dir, origin], camera looks along +z."""
    origin = np.asarray(origin, dtype=np.float64)
    d = np.asarray(target, dtype=np.float64) - origin
    if np.linalg.norm(d) == 0.0:
        raise ValueError("lookat: origin and target coincide")
    d = d / np.linalg.norm(d)
    left = np.cross(np.asarray(up, dtype=np.float64), d)
    if np.linalg.norm(left) < 1e-12:
        raise ValueError("lookat: up is parallel to the viewing direction (or zero)")
    left = left / np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0] = left
    m[:3, 1] = new_up
    m[:3, 2] = d
    m[:3, 3] = origin
    return m


def coordinate_system(n) -> tuple[np.ndarray, np.ndarray]:
    """Two tangents completing the unit vector n to a frame (Mitsuba's coordinate_system,
    Duff et al. 2017), so shapes built from a direction match Mitsuba's orientation."""
    nx, ny, nz = (float(c) for c in n)
    sign = 1.0 if math.copysign(1.0, nz) > 0 else -1.0
    a = -1.0 / (sign + nz)
    b = nx * ny * a
    s = np.array([nx * nx * a * sign + 1.0, b * sign, -nx * sign])
    t = np.array([b, sign + ny * ny * a, -ny])
    return s, t


def to_frame(n) -> np.ndarray:
    """The matrix with columns [s, t, n]: maps local +z onto n (Mitsuba's Transform4f::to_frame)."""
    s, t = coordinate_system(n)
    m = np.eye(4)
    m[:3, 0] = s
    m[:3, 1] = t
    m[:3, 2] = np.asarray(n, dtype=np.float64)
    return m


def op_matrix(op: str, attrs: dict[str, str]) -> np.ndarray:
    """The 4x4 matrix of one ``<transform>`` child element given its attributes.

    Raises ValueError (unknown op, unknown or missing attribute, bad number).
    """
    allowed = {
        "translate": {"x", "y", "z", "value"},
        "rotate": {"x", "y", "z", "value", "angle"},
        "scale": {"x", "y", "z", "value"},
        "matrix": {"value"},
        "lookat": {"origin", "target", "up"},
    }
    if op not in allowed:
        raise ValueError(f"unknown transform operation <{op}>; supported: {', '.join(TRANSFORM_OPS)}")
    extra = sorted(set(attrs) - allowed[op])
    if extra:
        raise ValueError(f"unknown attribute(s) {', '.join(extra)}; supported: "
                         f"{', '.join(sorted(allowed[op]))}")
    if op == "translate":
        return translate(xyz_from_attrs(attrs, 0.0))
    if op == "scale":
        return scale(xyz_from_attrs(attrs, 1.0, allow_uniform=True))
    if op == "rotate":
        if "angle" not in attrs:
            raise ValueError("rotate needs angle= (degrees)")
        return rotate(xyz_from_attrs(attrs, 0.0), parse_float(attrs["angle"], "angle"))
    if op == "matrix":
        if "value" not in attrs:
            raise ValueError("matrix needs value= with 16 (or 9) numbers, row-major")
        vals = parse_floats(attrs["value"])
        if len(vals) == 16:
            return np.array(vals, dtype=np.float64).reshape(4, 4)
        if len(vals) == 9:
            m = np.eye(4)
            m[:3, :3] = np.array(vals).reshape(3, 3)
            return m
        raise ValueError(f"matrix needs 16 (or 9) numbers, got {len(vals)}")
    # lookat: Mitsuba requires all three points.
    vec = {}
    for k in ("origin", "target", "up"):
        if k not in attrs:
            raise ValueError(f"lookat needs {k}=")
        v = parse_floats(attrs[k], k)
        if len(v) != 3:
            raise ValueError(f"{k}={quoted(attrs[k])} must have 3 components")
        vec[k] = v
    return look_at(vec["origin"], vec["target"], vec["up"])


def compose(ops: list[np.ndarray]) -> np.ndarray:
    """Ops in document order -> one matrix (each new op on the left).

    Many large scales can overflow float64; the result is then not finite, which
    :func:`check_transform` reports, so the overflow itself stays silent.
    """
    m = np.eye(4)
    with np.errstate(over="ignore", invalid="ignore"):
        for op in ops:
            m = op @ m
    return m


def transform_points(m: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply the affine 4x4 m to (n, 3) points."""
    return p @ m[:3, :3].T + m[:3, 3]


def transform_normals(m: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Apply m to (n, 3) normals (inverse transpose), renormalised."""
    inv_t = np.linalg.inv(m[:3, :3]).T
    out = n @ inv_t.T
    lengths = np.linalg.norm(out, axis=1, keepdims=True)
    lengths[lengths == 0.0] = 1.0
    return out / lengths
