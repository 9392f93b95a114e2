"""``pbdgrasp plan``: plan grasps in a scene with learned strategies, the baseline RRT or OMPL (paper VII).

Each trial is an independent query with its own generator spawned from ``--seed``; with ``-o`` every
finished trial is stored at once as a row of a SQLite results database (see :mod:`pbdgrasp.results_db`),
and trials already stored there are skipped, so an interrupted run resumes.
"""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from inference.model import VariationModel
from planning.planners import REGISTRY

NAME = "plan"
HELP = "plan grasps in a scene with learned strategies (or the baseline RRT, or OMPL's RRTConnect)"
ORDER = 50


def add_arguments(p) -> None:
    p.add_argument("--scene", required=True, help="scene name or YAML file")
    p.add_argument(
        "--model",
        action="append",
        required=True,
        metavar="M.model.npz",
        help="a learned strategy (repeat to superimpose several)",
    )
    p.add_argument(
        "--planner",
        default="learned",
        help="; ".join(f"{s.name}: {s.description}" for s in REGISTRY.values()).replace("%", "%%")
        + " (default learned)",
    )
    p.add_argument("--trials", type=int, default=1)
    p.add_argument("--time-limit-s", type=float, default=10.0)
    p.add_argument("--beta", type=float, default=0.05, help="probability of a uniform sample (learned)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("-o", "--output", metavar="RESULTS.sqlite", help="store each trial in this database")
    p.add_argument("--render", metavar="OUT.png", help="render the best grasp found")
    p.add_argument("--no-progress", action="store_true")


def run(args) -> int:
    from assets.errors import InputError
    from pbdgrasp.results_db import (
        finished_keys,
        insert_trial,
        open_db,
        params_json,
        record_from_plan,
        source_commit,
    )
    from planning.grasp_planner import GraspPlanner, PlanningSettings

    if args.trials < 1:
        raise InputError(f"--trials: expected a count >= 1, found {args.trials}")
    models = [VariationModel.load(m) for m in args.model]
    settings = PlanningSettings(planner=args.planner, beta=args.beta, time_limit_s=args.time_limit_s)
    params = {
        "scene": str(args.scene),
        "models": args.model,
        "settings": settings.__dict__,
        "seed": args.seed,
    }
    conn = open_db(args.output) if args.output else None
    done = finished_keys(conn) if conn else set()
    row = str(args.scene)
    seeds = np.random.SeedSequence(args.seed).spawn(args.trials)
    commit = source_commit()
    results = []
    best = None
    with GraspPlanner(args.scene, models) as planner:
        bar = tqdm(
            range(args.trials), desc=f"{row} {args.planner}", unit="trial", disable=args.no_progress or None
        )
        for trial in bar:
            if (row, args.planner, trial) in done:
                continue
            res = planner.plan(np.random.default_rng(seeds[trial]), settings)
            results.append(res)
            if res.success and (best is None or res.quality > best.quality):
                best = res
            if conn:
                insert_trial(
                    conn,
                    record_from_plan(
                        res,
                        row=row,
                        planner=args.planner,
                        trial=trial,
                        seed=int(seeds[trial].generate_state(1)[0]),
                        git_commit=commit,
                        params_json=params_json(params),
                    ),
                )
            bar.set_postfix(solved=f"{sum(r.success for r in results)}/{len(results)}")
        if args.render and best is not None:
            from assets.io import atomic_write
            from pbdgrasp.cli.render import png_bytes

            image = planner.world.render(best.grasp.closed_q)
            atomic_write(args.render, lambda f: f.write(png_bytes(image)))
    if not results:
        print(f"{row} {args.planner}: all {args.trials} trials already stored in {args.output}")
        return 0
    ok = [r for r in results if r.success]
    eta = np.median([r.eta_s for r in ok]) if ok else float("nan")
    print(
        f"{row} {args.planner}: {len(ok)}/{len(results)} solved, median ETA {eta:.2f} s, "
        f"mean nodes {np.mean([r.nodes for r in results]):.0f}, best quality "
        f"{max(r.quality for r in results):.3f}"
        + (f", best grasp rendered to {args.render}" if args.render and best is not None else "")
    )
    return 0
