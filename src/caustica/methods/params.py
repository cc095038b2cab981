"""Method parameters: declared once, with defaults, checked on every render.

Each method declares a tuple of :class:`Param`.  :func:`resolve` fills defaults,
converts types and refuses unknown names (with the nearest spelling) and values
out of range — a misspelt parameter stops the run instead of being ignored, as
pbrt's ``ReportUnused`` and Mitsuba's unused-property check do.

Every integer has an upper bound the kernels can honour (``max``, by default
:data:`caustica.limits.INT_MAX`); every float must be finite.  The common render
settings (spp, image size, seed, threads) are Params too and pass through the
same :func:`resolve`.  What :func:`resolve` returns is a :class:`Settings`: read by
attribute (``settings.alpha``), immutable, so a method reads exactly what was checked.
"""
from __future__ import annotations

import difflib
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..errors import ParameterError, quoted, shorten
from ..limits import INT_MAX, MAX_SEED, MAX_SPP, MAX_THREADS


@dataclass(frozen=True)
class Param:
    name: str            # Python / JSON name (CLI: --name-with-dashes)
    type: type           # int, float, str or bool
    default: Any
    help: str
    check: Callable[[Any], bool] | None = None
    allowed: str = ""    # what check accepts, for messages
    choices: tuple = ()
    max: int | None = None   # largest int allowed (None: INT_MAX); see caustica.limits
    scratch: int = 0     # bytes each worker thread allocates per unit of the value (memory check)
    option: str = ""     # how messages name it, when not --name (e.g. "--res width")

    @property
    def flag(self) -> str:
        return self.option or "--" + self.name.replace("_", "-")

    @property
    def upper(self) -> int | None:
        """The largest value allowed, for ints; None for other types."""
        if self.type is not int:
            return None
        return INT_MAX if self.max is None else self.max

    def describe_range(self) -> str:
        """What values are allowed, e.g. '>= 1 and <= 64' (empty when anything goes)."""
        parts = [self.allowed] if self.allowed else []
        if self.upper is not None:
            parts.append(f"<= {self.upper:,}")
        elif self.type is float and not self.allowed.startswith(("between", "at least", "0 or between")):
            # (a range with two ends says so already)
            parts.append("finite")
        return " and ".join(parts)


def positive(x) -> bool:
    return x > 0


#: Radii in scene units: the estimates divide by a radius's square (an area) and cube (a volume), which
#: must stay normal float64 numbers: (1e-100)^3 = 1e-300 and (1e100)^3 = 1e300.  A radius outside would
#: underflow to 0 (an image of NaN) or overflow to infinity.
RADIUS_MIN = 1e-100
RADIUS_MAX = 1e100
RADIUS_ALLOWED = f"between {RADIUS_MIN:g} and {RADIUS_MAX:g} (square and cube stay normal float64 numbers)"


def in_radius_range(x) -> bool:
    """A radius whose square and cube are normal float64 numbers (see RADIUS_MIN, RADIUS_MAX)."""
    return RADIUS_MIN <= x <= RADIUS_MAX


def zero_or_in_radius_range(x) -> bool:
    return x == 0 or in_radius_range(x)


def non_negative(x) -> bool:
    return x >= 0


def _did_you_mean(name: str, names) -> str:
    close = difflib.get_close_matches(name, names, n=1)
    return f" (did you mean '{close[0]}'?)" if close else ""


class Settings(Mapping):
    """A render's settings after :func:`resolve`: each value has its parameter's type and passed its checks.

    Read by attribute (``settings.radius``); a name only some methods have is read with ``settings.get(name)``.
    Immutable: :meth:`replace` gives a changed copy.  A mapping too (``dict(settings)``, ``**settings``; JSON
    through ``dict(settings)`` or :func:`caustica.imageio.to_jsonable`), and picklable, so Dask tasks and
    checkpoints take it as they took a dict.  It equals a dict (or another Settings) with the same values.
    """

    __slots__ = ("_owner", "_values")

    def __init__(self, owner: str, values: Mapping[str, Any]):
        object.__setattr__(self, "_owner", owner)   # the method (or "common") whose parameters these are
        object.__setattr__(self, "_values", dict(values))

    def __getattr__(self, name: str):
        if name.startswith("_"):   # the slots themselves (unset while unpickling): no lookup in the values
            raise AttributeError(name)
        try:
            return self._values[name]
        except KeyError:
            raise self._unknown(name) from None

    def _unknown(self, name: str) -> AttributeError:
        return AttributeError(f"method '{self._owner}' has no setting '{name}'{_did_you_mean(name, self._values)}")

    def __setattr__(self, name, value):
        raise AttributeError(f"settings are read-only; use settings.replace({name}=...)")

    def __getitem__(self, name: str):
        return self._values[name]

    def __iter__(self):
        return iter(self._values)

    def __len__(self) -> int:
        return len(self._values)

    def __reduce__(self):
        return Settings, (self._owner, self._values)

    def __dir__(self):
        return sorted(set(super().__dir__()) | set(self._values))   # completion offers the settings

    def __repr__(self) -> str:
        return f"Settings({self._owner!r}, {self._values!r})"

    def replace(self, **changes) -> Settings:
        """A copy with ``changes``, which must name settings this one has (values not checked again)."""
        for name in changes:
            if name not in self._values:
                raise self._unknown(name)
        return Settings(self._owner, {**self._values, **changes})

    def merged(self, other: Mapping[str, Any]) -> Settings:
        """These settings and ``other``'s (another :func:`resolve`'s, e.g. the common ones) in one."""
        return Settings(self._owner, {**self._values, **other})


def resolve(method: str, specs: tuple[Param, ...], given: dict[str, Any]) -> Settings:
    """Defaults + given values, converted and checked; unknown names are an error."""
    by_name = {p.name: p for p in specs}
    out = {p.name: p.default for p in specs}
    for name, value in given.items():
        if value is None:
            continue
        spec = by_name.get(name)
        if spec is None:
            raise ParameterError(
                f"method '{method}' has no parameter '{name}'{_did_you_mean(name, by_name)}; "
                f"its parameters: {', '.join(sorted(by_name))}")
        try:
            if isinstance(value, (bool, np.bool_)) != (spec.type is bool) and not isinstance(value, str):
                raise TypeError   # True is an int to Python, not a count or a radius to a user; 5 is not a bool
            if spec.type is bool and isinstance(value, str):
                words = {"1": True, "true": True, "yes": True, "on": True,
                         "0": False, "false": False, "no": False, "off": False}
                if value.lower() not in words:
                    raise ValueError
                value = words[value.lower()]
            elif spec.type is int and isinstance(value, float) and not value.is_integer():
                raise ValueError
            else:
                value = spec.type(value)
        except (TypeError, ValueError, OverflowError):
            raise ParameterError(f"{spec.flag}: {quoted(value)} is not a valid {spec.type.__name__}") from None
        if spec.choices and value not in spec.choices:
            raise ParameterError(f"{spec.flag}: {quoted(value)} is not one of {', '.join(map(str, spec.choices))}")
        if ((spec.check is not None and not spec.check(value))
                or (spec.upper is not None and value > spec.upper)
                or (spec.type is float and not math.isfinite(value))):
            raise ParameterError(f"{spec.flag}: {shorten(value)} is out of range; allowed: {spec.describe_range()}")
        out[name] = value
    return Settings(method, out)


#: Mitsuba volpath's treatment of a thindielectric (pt and the photon methods; a scene's volpath or volpathmis
#: integrator sets it).
NULL_THIN_PARAM = Param(
    "null_thin_dielectric", bool, False, "thindielectric's straight-on transmission is Mitsuba volpath's null event: "
    "not counted in max_depth, and shadow rays pass it with 1 - R (a scene's volpath integrator sets it; else a "
    "crossing is a bounce and blocks shadow rays, as Mitsuba's path)")

#: Settings every method takes (``caustica.render``'s own keywords), next to its own parameters, with the bounds of caustica.limits.
COMMON_PARAMS = (
    Param("spp", int, None, "samples per pixel", positive, ">= 1", max=MAX_SPP),
    Param("width", int, None, "image width", positive, ">= 1", option="--res width"),
    Param("height", int, None, "image height", positive, ">= 1", option="--res height"),
    Param("seed", int, 0, "random seed", non_negative, ">= 0", max=MAX_SEED),
    Param("threads", int, None, "worker threads", positive, ">= 1", max=MAX_THREADS),
)
COMMON = tuple(p.name for p in COMMON_PARAMS)
