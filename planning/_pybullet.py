"""pybullet, imported once without its build-time banner (it writes to the C-level stdout on import).

Import it as ``from planning._pybullet import pb`` so that CLI output (and ``--json``) stays clean.
"""

from __future__ import annotations

import os
import sys


def _quiet_import():
    sys.stdout.flush()
    try:
        saved = os.dup(1)
    except OSError:  # no usable stdout: nothing to protect
        import pybullet

        return pybullet
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        import pybullet
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)
    return pybullet


pb = _quiet_import()

__all__ = ["pb"]
