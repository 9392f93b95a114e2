"""The one error type for bad input, shared by every package.

``assets`` is the bottom of the dependency stack (assets <- retarget <- inference <- planning), so the
typed exception that every loader and validator raises lives here. The CLI turns it into one line
``error: ...`` and exit status 2; anything else is a bug.
"""

from __future__ import annotations

from os import PathLike

__all__ = ["InputError"]


class InputError(ValueError):
    """Bad input: a malformed file, a non-finite value, an unknown name, an impossible request.

    Args:
        message: what was wrong, what was expected and what was found.
        path: the file the problem is in, if any; it is prefixed to the message.
    """

    def __init__(self, message: str, path: str | PathLike | None = None):
        self.path = None if path is None else str(path)
        self.reason = message
        super().__init__(message if path is None else f"{path}: {message}")
