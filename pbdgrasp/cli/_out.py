"""What the command line says besides its results: warnings and the stages of long work (on stderr).

A warning is one line ``warning: ...``; a stage line ``pbdgrasp: ...`` says what a long step is doing
(building strategies, fields, solving), so that no command is silent for more than a few seconds.
"""

from __future__ import annotations

import sys

__all__ = ["warn", "stage"]


def warn(message: str) -> None:
    """Print one line ``warning: <message>`` on stderr."""
    print(f"warning: {' '.join(message.split())}", file=sys.stderr, flush=True)


def stage(message: str, *, enabled: bool | None = None) -> None:
    """Print one line ``pbdgrasp: <message>`` on stderr (``enabled=None``: only when stderr is a
    terminal, as tqdm's bars)."""
    if enabled is None:
        enabled = sys.stderr.isatty()
    if enabled:
        print(f"pbdgrasp: {message}", file=sys.stderr, flush=True)
