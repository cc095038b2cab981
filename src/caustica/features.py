"""What a scene's tables hold, written into their types, so kernels compile only the code a scene can reach.

Every light path dispatches on kinds: a material's BSDF, an emitter's kind.  Compiled for every kind, the photon
and camera loops carry the code of all of them: the paper's diacaustic scene (diffuse walls, a glass sphere, an area
light) compiled its spm render in 80 CPU s that way, 53 s with its own kinds (docs/results.md, 2026-12-04).

So a table built for a scene is an instance of a *specialised* subclass of its named tuple, :func:`specialised`
(base, features), whose class attribute ``FEATURES`` is a bit set: bit c set when rows of kind (or feature) code c
may occur.  The class is part of the Numba type of the tuple, so each feature set compiles (and caches) its own
kernels, and :func:`has` (table, c) is a compile-time constant in them: ``if has(mats, PLASTIC) and kind == PLASTIC:``
leaves nothing in the compiled loop when the scene has no plastic: :class:`caustica.jit.FoldFeatureTests` folds
the test to a constant before typing wherever the table's type follows from the kernel's arguments, so Numba's
dead-branch pruning drops the branch and the callees only it reaches are never compiled.  The arithmetic of the
code kept is the same, so the images are bit for bit those of the code compiled for every kind (the bit pins and
tests/test_features.py hold it).  A table of the base class (built by hand, in tests) holds every feature.

A pass's buffers may be typed the same way: a stream pass that cannot split gets a split buffer of no record kind
(:func:`caustica.photons.records.no_records`), so that :func:`caustica.photons.streams.may_split` folds to False.

Each feature set compiles its kernels once more, so :func:`caustica.tables.specialise` rounds a scene's materials and
lights up to one of two sets each, and :func:`caustica.media.medium_features` its media to one of three.
"""
from __future__ import annotations

from numba import types
from numba.extending import intrinsic

#: Every feature: the base classes' (unspecialised) set.
ALL = (1 << 62) - 1

_BASES: dict[str, type] = {}
_CLASSES: dict[tuple[str, int], type] = {}


def bits(*codes: int) -> int:
    """The feature set holding exactly ``codes`` (kind or feature codes)."""
    out = 0
    for c in codes:
        out |= 1 << int(c)
    return out


def specialisable(base: type) -> type:
    """Class decorator: a named tuple of scene tables that :func:`specialised` may subclass."""
    _BASES[base.__name__] = base
    return base


def specialised(base: type, features: int) -> type:
    """The subclass of named tuple ``base`` whose instances hold (at most) ``features`` (bit c: kind or feature c)."""
    base = _BASES[getattr(base, "_specialised_base", base.__name__)]
    features &= ALL
    if features == ALL:
        return base
    key = (base.__name__, features)
    if key not in _CLASSES:
        name = f"{base.__name__}__{features:x}"
        cls = type(base)(name, (base,), {"__slots__": (), "FEATURES": features, "_specialised_base": base.__name__,
                                        "__module__": __name__, "__qualname__": name,
                                        "__reduce__": _reduce})
        _CLASSES[key] = cls
    return _CLASSES[key]


def features_of(table) -> int:
    """The feature bits a table (or its class) may hold."""
    cls = table if isinstance(table, type) else type(table)
    return getattr(cls, "FEATURES", ALL)


def _reduce(self):
    """Pickle an instance by its base class and features (a Dask worker rebuilds the class)."""
    return _rebuild, (_BASES[self._specialised_base], self.FEATURES, tuple(self))


def _rebuild(base, features, fields):
    return specialised(base, features)(*fields)


def __getattr__(name: str):
    """``caustica.features.<Base>__<hex>``: a specialised class by name, as pickle (Numba's cache index) finds it."""
    base, sep, hexa = name.rpartition("__")
    if sep and base in _BASES:
        try:
            return specialised(_BASES[base], int(hexa, 16))
        except ValueError:
            pass
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def guarded_by(*codes: int):
    """Decorator for a kernel ``f(table, ...)`` that is False whenever ``table`` holds none of ``codes`` (its body is
    ``(has(table, c1) or ...) and ...``): a call to it is then folded to False before typing, as a ``has`` test is
    (:class:`caustica.jit.FoldFeatureTests`), so that ``if f(table, ...):`` drops its branch and the callees only that
    branch reaches are never compiled.  (A kernel is compiled apart and inlined by LLVM only, so the ``has`` inside it
    cannot prune its caller's branch.)  Put it above ``@kernel``."""
    mask = bits(*codes)

    def mark(f):
        f.feature_guard = mask
        return f
    return mark


@intrinsic
def has(typingctx, table, code):
    """Whether ``table``'s type says it may hold kind (or feature) ``code``: a constant, so a branch under
    ``if has(table, code)`` compiles to nothing when it does not.  ``code`` must be a constant."""
    if not isinstance(code, types.IntegerLiteral):
        return None
    present = bool(features_of(getattr(table, "instance_class", object)) >> code.literal_value & 1)

    def codegen(context, builder, signature, args):
        return context.get_constant(types.boolean, present)

    return types.boolean(table, code), codegen
