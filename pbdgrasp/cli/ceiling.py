"""``pbdgrasp ceiling --scene S [--samples N] [--refine K] [--refine-iterations I] [--seed S] [--workers W]
[--json] [-o BEST.json]``: how well the SAH can hold the scene's object at all, before any strategy
(:mod:`pbdgrasp.ceiling`)."""

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
        "--samples", type=int_in(1, 10_000_000), default=100_000, help="poses sampled (default 100000)"
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
    from pbdgrasp.ceiling import CeilingConfig, grasp_ceiling
    from planning.qfile import save_q
    from planning.scene import load_scene

    scene = load_scene(args.scene)
    config = CeilingConfig(
        samples=args.samples,
        refine_best=args.refine,
        refine_iterations=args.refine_iterations,
        epsilon=args.epsilon,
        workers=(os.cpu_count() or 1) if args.workers is None else args.workers,
    )
    result = grasp_ceiling(scene, config, np.random.default_rng(args.seed), progress=not args.no_progress)
    print(result.to_json() if args.json else result.summary())
    if args.output and result.most_robust is None:
        warn(f"no valid grasp among {args.samples} poses; -o {args.output} wrote nothing")
    elif args.output:
        save_q(args.output, np.asarray(result.refined_q[result.most_robust]))
    return 0
