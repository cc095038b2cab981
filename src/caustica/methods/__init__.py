"""Rendering methods, registered by name: a new method is a new module, not an edit here.

A method is a class with ``name``, ``summary``, ``params`` (a tuple of
:class:`~caustica.methods.params.Param`), ``progressive`` (whether it takes several
passes) and the pass as its unit of work:

* ``new_state(scene, settings)`` — the state before the first pass (``state.passes == 0``);
* ``run_pass(scene, settings, state, progress)`` — one pass: ``(new state, pass stats)``,
  never changing the old state (so an interrupt cannot leave half a pass behind);
* ``image(scene, settings, state)`` — the image the state holds;
* ``final_stats(scene, settings, state)`` — what the sidecar adds after the last pass;
* progressive methods also ``state_from_arrays`` (checkpoints; ``state.to_arrays()``)
  and may offer ``aovs`` (names) with ``aov(scene, settings, state, name)``;
* optionally ``scene_defaults(description)`` — the parameters a scene file's
  ``<integrator>`` sets (a value given when rendering wins): :func:`scene_params`.

:mod:`caustica.driver` runs the passes (count, time budget, progress, checkpoints,
Ctrl-C); one-shot methods (pm, spm) are the one-pass case.  Every module of this
package except the shared ones (:data:`_SHARED`) is imported on first use and registers
its method with :func:`register`: adding a method is adding a file.
"""
from __future__ import annotations

import importlib
import pkgutil

from ..errors import ParameterError

_REGISTRY: dict[str, type] = {}
#: Modules of this package that hold shared machinery, not a method.
_SHARED = frozenset({"independent", "params", "photon_common", "progressive"})


def register(cls):
    _REGISTRY[cls.name] = cls
    return cls


def _load_all():
    """Import every method module of this package (discovery: a new file is a new method)."""
    for info in pkgutil.iter_modules(__path__):
        if info.name not in _SHARED:
            importlib.import_module(f"{__name__}.{info.name}")


def available() -> dict[str, type]:
    _load_all()
    return dict(_REGISTRY)


def get(name: str):
    methods = available()
    if name not in methods:
        raise ParameterError(f"unknown method '{name}'; available: {', '.join(sorted(methods))}")
    return methods[name]


def scene_params(cls, description, given: dict) -> dict:
    """The parameters a render of method ``cls`` runs with before defaults: the scene's
    ``<integrator>`` settings the method reads (``cls.scene_defaults``), overridden by those
    ``given`` (None = not given)."""
    given = {k: v for k, v in given.items() if v is not None}
    defaults = getattr(cls, "scene_defaults", None)
    return {**(defaults(description) if defaults else {}), **given}
