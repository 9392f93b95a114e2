"""``pbdgrasp demo``: generate the synthetic human demonstrations (``assets/demonstrations/*.npz``)."""

from __future__ import annotations

import logging
from pathlib import Path

import assets
from assets.errors import InputError

from ._args import output_dir, seed

NAME = "demo"
HELP = "generate (regenerate) the human demonstrations: pbdgrasp demo generate --all"
ORDER = 10

log = logging.getLogger(__name__)


def add_arguments(p) -> None:
    sub = p.add_subparsers(dest="demo_command", metavar="ACTION")
    g = sub.add_parser("generate", help="generate demonstration files")
    which = g.add_mutually_exclusive_group(required=True)
    which.add_argument("--object", help="one demonstrated object")
    which.add_argument("--all", action="store_true", help="all demonstrated objects")
    g.add_argument("--seed", type=seed, default=0, help="seed of the sensor noise (default 0)")
    g.add_argument(
        "-o",
        "--output",
        type=output_dir,
        default=str(assets.ROOT / "demonstrations"),
        help="output directory (default: the shipped assets/demonstrations)",
    )


def run(args) -> int:
    from assets.demonstrations.generate import DEMONSTRATED_OBJECTS, generate, object_rng

    if getattr(args, "demo_command", None) != "generate":
        raise InputError("expected an action: pbdgrasp demo generate [--object O | --all]")
    if args.object is not None and args.object not in DEMONSTRATED_OBJECTS:
        raise InputError(
            f"--object: no demonstration strategy for {args.object!r}; "
            f"valid names: {', '.join(DEMONSTRATED_OBJECTS)}"
        )
    names = DEMONSTRATED_OBJECTS if args.all else (args.object,)
    out = Path(args.output)
    for name in names:
        demo, report = generate(name, object_rng(name, args.seed), seed=args.seed)
        path = demo.save(out / f"{name}.npz")
        print(
            f"{name}: {demo.num_steps} steps ({demo.duration_s:.2f} s, {demo.grasp_type}), fingertip gaps "
            f"{', '.join(f'{g:+.2f}' for g in report.tip_gap_mm)} mm, max penetration "
            f"{report.max_penetration_mm:.2f} mm (trajectory {report.max_penetration_trajectory_mm:.2f} mm), "
            f"{report.virtual_fingers} -> {path}"
        )
    return 0
