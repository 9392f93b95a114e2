"""``pbdgrasp ceiling --scene S [--near MODEL] [--samples N] [--refine K] [--refine-iterations I] [--seed S]
[--workers W] [--json] [-o BEST.json]``: how well the SAH can hold the scene's object at all, before any
strategy, or near a strategy's last mean (:mod:`pbdgrasp.ceiling`)."""

from __future__ import annotations

import os

import numpy as np

from ._args import float_in, int_in, output_file, seed
from ._out import warn

NAME = "ceiling"
HELP = "random hand poses about a scene's object, closed and scored: how well the SAH can hold it at all"
ORDER = 46


def add_arguments(p) -> None:
    p.add_argument("--scene", required=True, help="scene name or YAML file")
    p.add_argument(
        "--near",
        metavar="MODEL",
        help="a strategy (.model.npz): draw its last marginal in the scene and refine within a trust region "
        "about its last mean, instead of poses about the whole object",
    )
    p.add_argument(
        "--near-position-mm",
        type=float_in(0.0, 200.0, "mm"),
        default=None,
        help="with --near: the trust region per axis of the last mean's wrist frame (default 25)",
    )
    p.add_argument(
        "--near-rotation-deg",
        type=float_in(0.0, 180.0, "deg"),
        default=None,
        help="with --near: the trust region's largest turn of the wrist (default 12)",
    )
    p.add_argument(
        "--samples",
        type=int_in(1, 10_000_000),
        default=None,
        help="poses sampled (default 100000; with --near, draws: 2000)",
    )
    p.add_argument("--refine", type=int_in(0, 1000), default=20, help="best valid poses refined (default 20)")
    p.add_argument(
        "--refine-iterations",
        type=int_in(0, 1_000_000),
        default=1_000,
        help="hill-climbing proposals per refined pose (default 1000; the refined best grows with it)",
    )
    p.add_argument(
        "--epsilon", type=float_in(0.0, 1.0, lo_open=True), default=0.05, help="quality of a valid grasp"
    )
    p.add_argument("--seed", type=seed, default=0, help="seed of the poses (default 0)")
    p.add_argument(
        "--workers",
        type=int_in(1, 256),
        default=None,
        help="worker processes closing the hand (Dask; the result does not depend on it; default: the cores)",
    )
    p.add_argument("--json", action="store_true", help="print the measurements as JSON")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    p.add_argument(
        "-o",
        "--output",
        type=output_file(".json"),
        metavar="BEST.json",
        help="write the most robust refined pose as a Q.json (see pbdgrasp quality --q)",
    )


def run(args) -> int:
    from assets.errors import InputError
    from inference.model import VariationModel
    from pbdgrasp.ceiling import CeilingConfig, grasp_ceiling
    from planning.qfile import save_q
    from planning.scene import load_scene

    scene = load_scene(args.scene)
    near = None
    if args.near is not None:
        near = VariationModel.load(args.near)
        if near.object != scene.object.name:
            warn(f"{args.near} was learned on {near.object!r}; the scene's object is {scene.object.name!r}")
    elif args.near_position_mm is not None or args.near_rotation_deg is not None:
        raise InputError("--near-position-mm and --near-rotation-deg need --near MODEL")
    region = {}
    if args.near_position_mm is not None:
        region["near_position_m"] = 1e-3 * args.near_position_mm
    if args.near_rotation_deg is not None:
        region["near_rotation_deg"] = args.near_rotation_deg
    samples = args.samples or (100_000 if near is None else 2_000)
    config = CeilingConfig(
        samples=samples,
        refine_best=args.refine,
        refine_iterations=args.refine_iterations,
        epsilon=args.epsilon,
        workers=(os.cpu_count() or 1) if args.workers is None else args.workers,
        **region,
    )
    rng = np.random.default_rng(args.seed)
    result = grasp_ceiling(scene, config, rng, progress=not args.no_progress, near=near)
    print(result.to_json() if args.json else result.summary())
    if args.output and result.most_robust is None:
        warn(f"no valid grasp among {samples} poses; -o {args.output} wrote nothing")
    elif args.output:
        save_q(args.output, np.asarray(result.refined_q[result.most_robust]))
    return 0
