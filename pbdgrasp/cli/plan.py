"""``pbdgrasp plan``: plan grasps in a scene with learned strategies, the baseline RRT or OMPL (paper VII).

Each trial is an independent query with its own generator spawned from ``--seed``; with ``-o`` every
finished trial is stored at once as a row of a SQLite results database (see :mod:`pbdgrasp.results_db`),
and trials already stored there are skipped, so an interrupted run resumes. The database remembers the
run's parameters (scene, models by content hash, planner settings, seed) and refuses other ones unless
``--new`` sets it aside. The best grasp's configuration (the last node of the best solved path) is
written as ``<database stem>.Q.json`` beside the database, or to ``--best-q``, for ``pbdgrasp quality``
and ``render``.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from assets.errors import InputError
from inference.model import VariationModel
from planning.planners import REGISTRY

from ._args import float_in, int_in, output_file, seed
from ._out import warn

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
    p.add_argument("--trials", type=int_in(1, 10_000), default=1, help="planning queries (default 1)")
    p.add_argument(
        "--time-limit-s", type=float_in(0, 3600, "s", lo_open=True), default=10.0, help="budget of one query"
    )
    p.add_argument(
        "--beta", type=float_in(0, 1), default=0.05, help="probability of a uniform sample (learned; 0.05)"
    )
    p.add_argument("--seed", type=seed, default=0)
    p.add_argument(
        "-o",
        "--output",
        type=output_file(".sqlite", ".db"),
        metavar="RESULTS.sqlite",
        help="store each trial",
    )
    p.add_argument("--new", action="store_true", help="set an existing -o database aside (*.bak), start anew")
    p.add_argument(
        "--best-q",
        type=output_file(".json"),
        metavar="Q.json",
        help="write the best grasp's q (default with -o: beside the database)",
    )
    p.add_argument(
        "--render", type=output_file(".png"), metavar="OUT.png", help="render the best grasp found"
    )
    p.add_argument("--no-progress", action="store_true")


def _best_q_path(args) -> Path | None:
    if args.best_q:
        return Path(args.best_q)
    if args.output:
        db = Path(args.output)
        return db.with_name(db.name.rsplit(".", 1)[0] + ".Q.json")
    return None


def run(args) -> int:
    from assets.io import check_output_file
    from pbdgrasp.results_db import check_params, load_trials, open_db, params_json, set_aside
    from planning.grasp_planner import PlanningSettings
    from planning.qfile import save_q

    if args.new and not args.output:
        raise InputError("--new: expected -o DATABASE (there is no database to start anew)")
    best_q_path = _best_q_path(args)
    if best_q_path is not None:
        check_output_file(best_q_path, (".json",))
    models = [VariationModel.load(m) for m in args.model]
    settings = PlanningSettings(planner=args.planner, beta=args.beta, time_limit_s=args.time_limit_s)
    row = str(args.scene)
    params = {
        "scene": row,
        "models_sha256": [_sha256(m) for m in args.model],
        "settings": settings.__dict__,
        "seed": args.seed,
    }
    conn = None
    if args.output:
        if args.new and (backup := set_aside(args.output)):
            print(f"the old database is kept as {backup}", file=sys.stderr)
        conn = open_db(args.output)
        check_params(
            conn,
            {(row, args.planner): params_json(params)},
            "use --new to start the database afresh (the old one is kept), another -o, or the same settings",
        )
    try:
        results, best = _run_trials(args, models, settings, params, conn, row)
        stored = load_trials(conn, [row]) if conn else []
    finally:
        if conn:
            conn.close()
    best_q = _best_q(results, stored, args.planner, best)
    said = []
    if best_q_path is not None and best_q is not None:
        save_q(best_q_path, best_q)
        said.append(f"best grasp's q -> {best_q_path}")
    if args.render:
        if best is None:
            warn(f"no trial of this invocation was solved; --render {args.render} wrote nothing")
        else:
            from assets.io import atomic_write
            from pbdgrasp.cli.render import png_bytes
            from planning.world import World

            with World(args.scene) as world:
                image = world.render(best.grasp.closed_q)
            atomic_write(args.render, lambda f: f.write(png_bytes(image)))
            said.append(f"best grasp rendered to {args.render}")
    if not results:
        print(f"{row} {args.planner}: all {args.trials} trials already stored in {args.output}"
              + "".join(f"; {x}" for x in said))  # fmt: skip
        return 0
    ok = [r for r in results if r.success]
    eta = np.median([r.eta_s for r in ok]) if ok else float("nan")
    print(
        f"{row} {args.planner}: {len(ok)}/{len(results)} solved, median ETA {eta:.2f} s, "
        f"mean nodes {np.mean([r.nodes for r in results]):.0f}, best quality "
        f"{max(r.quality for r in results):.3f}" + "".join(f"; {x}" for x in said)
    )
    return 0


def _sha256(path: str) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _run_trials(args, models, settings, params, conn, row):
    """The trials not yet stored; each stored as soon as it ends. Returns the new results and the best."""
    from pbdgrasp.results_db import finished_keys, insert_trial, params_json, record_from_plan, source_commit
    from planning.grasp_planner import GraspPlanner

    done = finished_keys(conn) if conn else set()
    seeds = np.random.SeedSequence(args.seed).spawn(args.trials)
    commit = source_commit()
    results, best = [], None
    with GraspPlanner(args.scene, models) as planner:
        scene_object = planner.world.scene.object.name
        for m, path in zip(models, args.model, strict=True):
            if m.object != scene_object:
                warn(f"{path} was learned on {m.object!r}; the scene's object is {scene_object!r}")
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
    return results, best


def _best_q(results, stored, planner: str, best) -> np.ndarray | None:
    """The best solved grasp's pre-closing q: of the database's trials if there is one, else of this
    invocation's."""
    import json

    solved = [r for r in stored if r.planner == planner and r.success]
    if solved:
        top = max(solved, key=lambda r: r.quality)
        q = json.loads(top.grasp_json).get("q")
        return None if q is None else np.asarray(q, dtype=float)
    if best is not None and len(best.path):
        return np.asarray(best.path[-1], dtype=float)
    return None
