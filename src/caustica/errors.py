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


#: How many characters of a user's value an error message repeats.
QUOTE_LIMIT = 40


def quoted(value, limit: int = QUOTE_LIMIT) -> str:
    """A user's value as an error message shows it: quoted like repr(), cut to about limit characters.

    A 5,000-digit number or a pasted paragraph is shown as its start and end with its
    length, ``'9999999999999999999999999999...99999999' (5,000 characters)``, so a message stays one line.
    """
    text = str(value)
    if len(text) <= limit:
        return repr(text)
    head, tail = text[:limit - 11], text[-8:]
    return f"{(head + '...' + tail)!r} ({len(text):,} characters)"
