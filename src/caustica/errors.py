"""The errors caustica reports to users: one clear line, never a traceback."""
from __future__ import annotations


class CausticaError(Exception):
    """Base of every error caused by the user's input; the CLI prints it and exits 2."""


class SceneError(CausticaError):
    """A scene file, element or mesh that cannot be loaded.

    The message names the file, the line and the element, and what is allowed.
    """


class ParameterError(CausticaError):
    """A render parameter out of range, misspelt, or asking for more memory than the machine has."""


class OutputError(CausticaError, OSError):
    """An output that cannot be written (a folder in the way, an input, a full disk, no permission).

    It is also an OSError, so code that handles I/O failures keeps working; nothing was replaced.
    """


class InterruptedAfterSaving(KeyboardInterrupt):
    """Ctrl-C arrived while a set of outputs was being renamed into place: the set was completed first."""
