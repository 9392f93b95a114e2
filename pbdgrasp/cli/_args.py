"""Argument types of the command line: ranged numbers, seeds and checked output paths (and ``--processes``,
which three commands share).

Each factory returns an ``argparse`` ``type=`` callable, so that a bad value is refused while the command
line is parsed, before any work, with one line saying the range and the unit (or what is wrong with the
path): ``error: pbdgrasp plan: argument --time-limit-s: expected a number in (0, 3600] s, found nan``.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

from assets.errors import InputError
from assets.io import check_output_dir, check_output_file

__all__ = ["int_in", "float_in", "seed", "output_file", "output_dir", "add_processes_argument", "MAX_SEED"]

MAX_SEED = 2**63 - 1
"""Seeds are non-negative integers below 2**63 (``numpy.random.SeedSequence`` takes any non-negative int;
the bound keeps them storable as SQLite integers)."""


def _unit(unit: str) -> str:
    return f" {unit}" if unit else ""


def int_in(lo: int, hi: int, unit: str = "") -> Callable[[str], int]:
    """An integer in ``[lo, hi]``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or not lo <= value <= hi:
            raise argparse.ArgumentTypeError(
                f"expected an integer in [{lo}, {hi}]{_unit(unit)}, found {text!r}"
            )
        return value

    parse.__name__ = "integer"
    return parse


def float_in(lo: float, hi: float, unit: str = "", *, lo_open: bool = False) -> Callable[[str], float]:
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` with ``lo_open``)."""
    shown = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]{_unit(unit)}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        ok = math.isfinite(value) and (lo < value if lo_open else lo <= value) and value <= hi
        if not ok:
            raise argparse.ArgumentTypeError(f"expected a number in {shown}, found {text!r}")
        return value

    parse.__name__ = "number"
    return parse


seed = int_in(0, MAX_SEED)
"""A run's seed: an integer in [0, 2**63 - 1]."""


def output_file(*suffixes: str) -> Callable[[str], str]:
    """A file to be written, checked by :func:`assets.io.check_output_file` (the value stays as given)."""

    def parse(text: str) -> str:
        try:
            check_output_file(text, suffixes)
        except InputError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
        return text

    parse.__name__ = "output file"
    return parse


def output_dir(text: str) -> str:
    """A directory to be written into, checked by :func:`assets.io.check_output_dir`."""
    try:
        check_output_dir(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return text


def add_processes_argument(p: argparse.ArgumentParser) -> None:
    """``--processes N``: the processes that close the hand at many draws (``retarget``, ``learn`` and
    ``inspect``; :class:`planning.closing_pool.ClosingPool`, whose default is the cores, at most 8)."""
    what = "processes closing the hand at the draws (default: the cores, at most 8; the same result on any)"
    p.add_argument("--processes", type=int_in(1, 256), default=None, metavar="N", help=what)
