"""The ``pbdgrasp`` command line.

Each subcommand is a module of this package that defines ``NAME`` (the subcommand), ``HELP`` (one line),
``ORDER`` (its place in ``--help``), ``add_arguments(parser)`` and ``run(args) -> int``. Modules are
found automatically, so adding a subcommand touches no shared file.

Errors: bad input (:class:`assets.errors.InputError`) prints one line ``error: ...`` and exits 2; so do
argument errors, which include every range check and output-path check of :mod:`pbdgrasp.cli._args`
(made while parsing, before any work). ``--debug`` shows the traceback instead. A reader that closes the
output early (``pbdgrasp assets | head -1``) ends the command quietly with status 141, as SIGPIPE would.

Every command runs BLAS (OpenBLAS under numpy and scipy) on one thread: its matrices are small, and the
extra threads only spin-wait on the core that pybullet's closings, a
:class:`~planning.closing_pool.ClosingPool`'s worker or a Dask worker needs (docs/performance.md).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import pkgutil
import sys

from threadpoolctl import threadpool_limits

from assets.errors import InputError

__all__ = ["main", "build_parser"]


class _Parser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line ``error: ...`` and exit status 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        sys.stderr.write(f"error: {self.prog}: {message}\n")
        raise SystemExit(2)


def _commands():
    mods = []
    for info in pkgutil.iter_modules(__path__):
        if info.name.startswith("_"):
            continue
        mod = importlib.import_module(f"{__name__}.{info.name}")
        if hasattr(mod, "NAME") and hasattr(mod, "run"):
            mods.append(mod)
    return sorted(mods, key=lambda m: (getattr(m, "ORDER", 100), m.NAME))


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="pbdgrasp", description=__doc__.splitlines()[0])
    parser.add_argument("--debug", action="store_true", help="show tracebacks and debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for mod in _commands():
        p = sub.add_parser(mod.NAME, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``pbdgrasp`` console script; returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # an argument error (one line already printed) or --help
        return exc.code if isinstance(exc.code, int) else 2
    logging.basicConfig(
        level=logging.DEBUG if args.debug else logging.WARNING, format="%(levelname)s %(name)s: %(message)s"
    )
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    threadpool_limits(limits=1, user_api="blas")
    try:
        status = int(args._run(args) or 0)
        sys.stdout.flush()  # inside the try: a reader gone is caught here, not at the interpreter's exit
        return status
    except InputError as exc:
        if args.debug:
            raise
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)  # always one line
        return 2
    except KeyboardInterrupt:
        print("error: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (``| head``): stop quietly, as a Unix tool does
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 141  # 128 + SIGPIPE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
