"""pybullet without its build-time banner.

pybullet writes "pybullet build time: ..." to the C-level stderr when it is imported and when a client
connects. That extra line would break the CLI's contract of exactly one ``error: ...`` line on stderr,
so both happen here with file descriptors 1 and 2 sent to /dev/null (C stdio flushed before they are
restored). Use ``from planning._pybullet import pb, connect_direct``.
"""

from __future__ import annotations

import ctypes
import os
import sys
from contextlib import contextmanager

__all__ = ["pb", "connect_direct"]


@contextmanager
def _c_output_silenced():
    for stream in (sys.stdout, sys.stderr):
        stream.flush()
    try:
        saved = [os.dup(1), os.dup(2)]
    except OSError:  # no usable descriptors: nothing to protect
        yield
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
        try:
            ctypes.CDLL(None).fflush(None)
        except (OSError, AttributeError):  # pragma: no cover - no libc symbols
            pass
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


with _c_output_silenced():
    import pybullet as pb


def connect_direct() -> int:
    """A new pybullet client in DIRECT mode (no GUI), without the banner."""
    with _c_output_silenced():
        return pb.connect(pb.DIRECT)
