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


class RenderError(CausticaError):
    """A render whose image cannot be right (NaN or infinite pixels): refused rather than written as a success."""


class ClusterError(CausticaError):
    """A Dask cluster that failed during a render (a task that kills every worker, a lost scheduler).

    The message says how many passes were finished and where they were saved, if anywhere.
    """


#: How many characters of a user's value an error message repeats.
QUOTE_LIMIT = 40


def _cut(text: str, limit: int) -> tuple[str, str]:
    """(text cut to about limit characters, "" or " (N characters)" when it was cut)."""
    if len(text) <= limit:
        return text, ""
    return text[:limit - 11] + "..." + text[-8:], f" ({len(text):,} characters)"


def shorten(value, limit: int = QUOTE_LIMIT) -> str:
    """A user's value as an error message repeats it: at most about limit characters.

    A 5,000-digit number or a pasted paragraph becomes its start and end with its
    length, ``99999999999999999999999999999...99999999 (5,000 characters)``, so a
    message stays one readable line.
    """
    cut, length = _cut(str(value), limit)
    return cut + length


def quoted(value, limit: int = QUOTE_LIMIT) -> str:
    """:func:`shorten`, quoted like repr(): ``'1.x'``, ``'99999...99999999' (5,000 characters)``."""
    cut, length = _cut(str(value), limit)
    return repr(cut) + length


class OutputError(CausticaError, OSError):
    """An output that cannot be written (a folder in the way, an input, a full disk, no permission).

    It is also an OSError, so code that handles I/O failures keeps working; nothing was replaced.
    """


class InterruptedAfterSaving(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) arrived while a save was under way (a set of outputs being renamed into place, a
    checkpoint being written): the save was completed first.  ``signum`` is the signal that arrived."""

    def __init__(self, signum: int = 2, saved: str = "the outputs"):
        super().__init__(signum, saved)
        self.signum = int(signum)
        self.saved = saved
