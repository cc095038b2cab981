"""Rendering methods, registered by name: a new method is a new module, not an edit here.

A method is a class with ``name``, ``summary``, ``params`` (a tuple of
:class:`~caustica.methods.params.Param`) and ``render(scene, settings, progress)``
returning ``(image, stats)``.  Modules register themselves with :func:`register`.
"""
from __future__ import annotations

import importlib

from ..errors import ParameterError

_REGISTRY: dict[str, type] = {}
_MODULES = ("pt", "pm", "spm")


def register(cls):
    _REGISTRY[cls.name] = cls
    return cls


def _load_all():
    for mod in _MODULES:
        try:
            importlib.import_module(f"{__name__}.{mod}")
        except ModuleNotFoundError as exc:  # a method not written yet
            if exc.name != f"{__name__}.{mod}":
                raise


def available() -> dict[str, type]:
    _load_all()
    return dict(_REGISTRY)


def get(name: str):
    methods = available()
    if name not in methods:
        raise ParameterError(f"unknown method '{name}'; available: {', '.join(sorted(methods))}")
    return methods[name]
