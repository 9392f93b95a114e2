"""``pbdgrasp table1``: reproduce the paper's Table I (strategies, trials on Dask, SQLite, the report).

Everything a run writes goes to its run directory (``--run-dir``, default ``runs/table1``, or
``runs/table1-quick`` with ``--quick``): the database, the cached strategies and the report, unless
``--db``, ``--cache-dir`` or ``--report-dir`` say otherwise. The committed report in ``results/`` is
written only by ``make table1``, which passes those paths. A re-run with the same settings and database
skips the finished trials; a killed run resumes where it stopped; other settings are refused unless
``--new`` sets the old database aside.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from assets.errors import InputError

from ._args import float_in, int_in, output_dir, output_file, seed
from ._out import stage

NAME = "table1"
HELP = (
    "reproduce Table I: per row demonstration -> retarget -> infer, then planning trials (Dask) and a report"
)
ORDER = 80

QUICK = {"trials": 3, "rows": "ham,jam_hole", "planners": "learned", "retarget_max_nfev": 40}
"""The small run of ``--quick`` (a few minutes on two cores); options given explicitly still apply."""
FULL = {"trials": 100, "rows": None, "planners": "learned,baseline", "retarget_max_nfev": None}


def add_arguments(p) -> None:
    p.add_argument(
        "--quick",
        action="store_true",
        help=f"a small run to try it: {QUICK['trials']} trials of rows {QUICK['rows']}, planner "
        f"{QUICK['planners']}, coarse retargeting ({QUICK['retarget_max_nfev']} evaluations per step), in "
        "runs/table1-quick",
    )
    p.add_argument("--trials", type=int_in(1, 10_000), help="trials per row and planner (default 100)")
    p.add_argument("--rows", help="comma-separated Table I rows (default: all 11)")
    p.add_argument("--planners", help="comma-separated planners (default learned,baseline)")
    p.add_argument(
        "--time-limit-s", type=float_in(0, 3600, "s", lo_open=True), default=10.0, help="budget of one query"
    )
    p.add_argument("--beta", type=float_in(0, 1), default=0.05, help="uniform share of P(Y) (default 0.05)")
    p.add_argument(
        "--epsilon",
        type=float_in(0, 1, lo_open=True),
        default=0.05,
        help="quality threshold of a valid grasp (default 0.05; the L1 epsilon of unit forces is at most 1)",
    )
    g = p.add_mutually_exclusive_group()
    g.add_argument(
        "--workers",
        type=int_in(0, 256),
        default=None,
        help="worker processes of the embedded Dask cluster (default: one per core; 0: no Dask)",
    )
    g.add_argument("--scheduler", metavar="tcp://HOST:PORT",
                   help="an existing Dask scheduler (its workers must share this file system)")  # fmt: skip
    p.add_argument(
        "--run-dir",
        type=output_dir,
        help="the run's database, cache and report (default runs/table1; --quick: runs/table1-quick)",
    )
    p.add_argument(
        "--db", type=output_file(".sqlite", ".db"), help="results database (default RUN_DIR/table1.sqlite)"
    )
    p.add_argument(
        "--cache-dir", type=output_dir, help="cached trajectories and models (default RUN_DIR/cache)"
    )
    p.add_argument("--report-dir", type=output_dir, help="table1.md/.csv and the figures (default RUN_DIR)")
    p.add_argument(
        "--new",
        action="store_true",
        help="set an existing database aside (renamed *.bak) and start a new one",
    )
    p.add_argument("--no-renders", action="store_true", help="skip best_grasps.png")
    p.add_argument(
        "--report-only",
        action="store_true",
        help="build and run nothing: report what an existing database and the cached strategies hold",
    )
    p.add_argument("--seed", type=seed, default=0, help="the run's seed (trial streams are spawned from it)")
    p.add_argument("--no-progress", action="store_true", help="hide the progress bar and the stage lines")
    p.add_argument(
        "--retarget-max-nfev",
        type=int_in(1, 100_000),
        default=None,
        help="Rosenbrock evaluations per retargeting step (default: retargeting's own; fewer: quick tests)",
    )


def _resolve(args) -> None:
    """Fill the options left unset from --quick or the full run, and the paths from the run directory."""
    base = QUICK if args.quick else FULL
    for key, value in base.items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    run_dir = Path(args.run_dir or ("runs/table1-quick" if args.quick else "runs/table1"))
    args.db = args.db or str(run_dir / "table1.sqlite")
    args.cache_dir = args.cache_dir or str(run_dir / "cache")
    args.report_dir = args.report_dir or str(run_dir)
    if args.report_only and args.new:
        raise InputError("--new and --report-only: a report of a database just set aside would be empty")
    if args.report_only and not Path(args.db).is_file():
        raise InputError(f"--report-only: no such results database {args.db}")


def run(args) -> int:
    from pbdgrasp.cache import float_kernels, strategy_final_q
    from pbdgrasp.paper import ROWS
    from pbdgrasp.report import write_report
    from pbdgrasp.results_db import set_aside
    from pbdgrasp.table1 import Table1Config, parse_names, run_table1
    from planning.planners import PLANNERS

    _resolve(args)
    config = Table1Config(
        rows=parse_names(args.rows, ROWS, "--rows"),
        planners=parse_names(args.planners, PLANNERS, "--planners"),
        trials=args.trials,
        time_limit_s=args.time_limit_s,
        beta=args.beta,
        quality_threshold=args.epsilon,
        seed=args.seed,
        db_path=args.db,
        cache_dir=args.cache_dir,
        workers=(os.cpu_count() or 1) if args.workers is None else args.workers,
        scheduler=args.scheduler,
        progress=False if args.no_progress else None,
        retarget_max_nfev=args.retarget_max_nfev,
    )

    def say(line: str) -> None:
        stage(line, enabled=not args.no_progress)

    if args.new:
        backup = set_aside(config.db_path)
        if backup:
            say(f"the old database is kept as {backup}")
    summary = run_table1(config, run_trials=not args.report_only, on_stage=say)
    say(f"writing the report to {args.report_dir}")
    full = config.trials == 100 and len(config.rows) == len(ROWS)
    n_records = len(summary.records)
    expected = len(config.rows) * len(config.planners) * config.trials
    status = None
    if not full:
        status = (
            f"Reduced run: {config.trials} trials per row and planner, rows {', '.join(config.rows)} "
            "(the paper ran 100 trials per row); not the full Table I."
        )
    if n_records < expected:
        status = (status or "") + f" INCOMPLETE: {n_records} of {expected} trials stored."
    trial_time = sum(r.eta_s for r in summary.records)
    info = {
        "title": "reproduction" if full else "reproduction (reduced run)",
        "status": status,
        "settings": {
            "rows": ", ".join(config.rows),
            "planners": ", ".join(config.planners),
            "trials per row and planner": config.trials,
            "time limit per query": f"{config.time_limit_s:g} s",
            "beta": config.beta,
            "epsilon (quality threshold)": config.quality_threshold,
            "start nodes per trial": "100 collision-free draws of N(b_1, B_1)",
            "goal test": f"phi_o where an extension towards a last-step sample ended (its nearest node, "
            f"scored once, if its first step was blocked) within {config.settings('learned').goal_radius:g} "
            "steps of it",
            "retargeting": "default settings"
            if config.retarget_max_nfev is None
            else f"COARSE: at most {config.retarget_max_nfev} Rosenbrock evaluations per step",
            "seed": f"{config.seed} (trial streams SeedSequence(seed, spawn_key=(row, planner, trial)))",
            "git commit(s)": ", ".join(sorted({_short(r.git_commit) for r in summary.records})) or "—",
        },
        "run": {
            "this invocation": f"{summary.wall_time_s:.0f} s wall time ({summary.strategy_time_s:.0f} s "
            f"strategies), {summary.new_trials} new trials, {summary.skipped} resumed from the database, "
            f"{summary.errors} failed tasks, {summary.workers or 'no'} Dask worker(s)",
            "time inside the stored trials (sum)": f"{trial_time:.0f} s "
            f"(= {trial_time / max(summary.workers, 1) / 60:.1f} min on {max(summary.workers, 1)} worker(s))",
            "machine": f"{os.cpu_count()} cores; floating-point kernels: {float_kernels()}",
            "date": time.strftime("%Y-%m-%d %H:%M"),
        },
    }
    files = write_report(
        summary.records,
        config.rows,
        config.planners,
        args.report_dir,
        time_limit_s=config.time_limit_s,
        mse_mm2={r: s.mse_mm2 for r, s in summary.strategies.items()},
        info=info,
        renders=not args.no_renders,
        fallback_q={r: strategy_final_q(s) for r, s in summary.strategies.items()},
    )
    by_row = {}
    for r in summary.records:
        c = by_row.setdefault(r.row, {p: [0, 0] for p in config.planners})
        c[r.planner][0] += int(r.success)
        c[r.planner][1] += 1
    for row, c in by_row.items():
        print(f"{row}: " + ", ".join(f"{p} {s}/{n}" for p, (s, n) in c.items()))
    print(
        f"{summary.new_trials} new trials, {summary.skipped} resumed, {summary.errors} failed, "
        f"{summary.wall_time_s:.0f} s -> {config.db_path}; report: {', '.join(str(f) for f in files)}"
    )
    return 1 if summary.errors else 0


def _short(commit: str) -> str:
    """A commit's first 12 characters, keeping ``-dirty`` (a run of uncommitted sources)."""
    head, dirty, _ = commit.partition("-dirty")
    return head[:12] + dirty
