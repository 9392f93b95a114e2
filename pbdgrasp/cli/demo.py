"""``pbdgrasp demo``: generate the synthetic human demonstrations (``assets/demonstrations/*.npz``), or
import a real one from hand-tracker keypoints (``pbdgrasp demo import KEYPOINTS.npz --object O -o D.npz``)."""

from __future__ import annotations

import logging
from pathlib import Path

import assets
from assets.errors import InputError

from ._args import float_in, output_dir, output_file, seed

NAME = "demo"
HELP = (
    "make human demonstrations: pbdgrasp demo generate --all | demo import KEYPOINTS.npz --object O -o D.npz"
)
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
    i = sub.add_parser(
        "import",
        help="fit the human hand model to 21 hand keypoints a frame (see assets/demonstrations/README.md)",
    )
    i.add_argument("keypoints", metavar="KEYPOINTS.npz", help="keypoints (T, 21, 3) [m] and rate_hz")
    i.add_argument("--object", required=True, help="the grasped object (pbdgrasp assets lists them)")
    i.add_argument("--grasp-type", choices=("precision", "power"), help="default: the object's")
    i.add_argument(
        "--rate-hz", type=float_in(1.0, 1000.0, "Hz"), default=20.0, help="output rate (default 20)"
    )
    i.add_argument(
        "-o", "--output", required=True, type=output_file(".npz"), metavar="DEMO.npz", help="file to write"
    )


def run(args) -> int:
    action = getattr(args, "demo_command", None)
    if action == "import":
        return _import(args)
    if action != "generate":
        raise InputError(
            "expected an action: pbdgrasp demo generate [--object O | --all] | "
            "demo import KEYPOINTS.npz --object O -o DEMO.npz"
        )
    from assets.demonstrations.generate import DEMONSTRATED_OBJECTS, generate, object_rng

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


def _import(args) -> int:
    from retarget.keypoint_import import import_keypoints

    out = Path(args.output)
    demo, fit = import_keypoints(args.keypoints, args.object, args.grasp_type, args.rate_hz)
    path = demo.save(out)
    status = "converged" if fit.success else "NOT converged"
    print(
        f"{demo.object}: {demo.num_steps} steps ({demo.duration_s:.2f} s, {demo.grasp_type}), hand scale "
        f"{fit.calibration.scale:.3f}, keypoint noise {fit.sigma_m * 1e3:.2f} mm per axis, residual "
        f"{fit.residual_rms_m.mean() * 1e3:.2f} mm RMS (worst point {fit.residual_max_m.max() * 1e3:.1f} "
        f"mm), {status} ({fit.nfev} evaluations, {fit.time_s:.1f} s) -> {path}"
    )
    return 0
