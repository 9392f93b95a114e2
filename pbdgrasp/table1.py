"""Reproducing the paper's Table I (section VIII): the strategy pipeline, the trials and their distribution.

For every row (a scene of the same name, :data:`pbdgrasp.paper.ROWS`):

1. the strategy: the scene's demonstration (``Scene.strategy``; the bottle uses the chips can's, the big
   cup the small cup's) is retargeted to the SAH with the collision term checked in the demonstrated
   object's obstacle-free scene, as ``pbdgrasp retarget`` does, and the variation model is solved with the
   row's scene (its object prior and the signed-distance constraints of its table and obstacles), as
   ``pbdgrasp infer --scene`` does; both steps cached by the hash of their inputs
   (:mod:`pbdgrasp.cache`).
2. the trials: ``trials`` planning queries per planner, each with its own generator
   ``np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(row index in ROWS, planner index in
   PLANNERS, trial)))``, so results do not depend on the number of workers or on the order they run in.

Trials are Dask tasks (:mod:`distributed`): an embedded ``LocalCluster`` (one single-threaded worker
process per core by default) or an existing cluster given by its scheduler address (its workers must see
the same file system: they load the ``.model.npz`` files by path). Each worker process builds and keeps
its own :class:`~planning.grasp_planner.GraspPlanner` per row (one pybullet client per world, never shared
between processes). The coordinating process writes each finished trial to the SQLite results database
(:mod:`pbdgrasp.results_db`) as it completes, so a run killed at any moment resumes where it stopped.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assets.errors import InputError
from planning.grasp_planner import PlanningSettings
from planning.planners import PLANNERS

from .cache import Strategy, prepare_strategy
from .paper import ROWS
from .results_db import (
    TrialRecord,
    check_params,
    finished_keys,
    insert_trial,
    load_trials,
    open_db,
    params_json,
    record_from_plan,
    source_commit,
)
from .workers import TrialProgress, check_scheduler, dask_client

__all__ = [
    "Table1Config",
    "TrialTask",
    "RunSummary",
    "parse_names",
    "trial_rng",
    "make_tasks",
    "run_trial",
    "run_table1",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Table1Config:
    """Settings of a Table I run (the paper's by default).

    Attributes:
        rows: Table I rows (scene names) in :data:`ROWS` order.
        planners: planners of :data:`planning.planners.PLANNERS`.
        trials: planning queries per row and planner (the paper: 100).
        time_limit_s: budget of one query [s]; a failed query costs all of it.
        beta: probability of the uniform strategy in P(Y) (the paper: 0.05).
        quality_threshold: epsilon, phi_o >= it is a valid grasp (the paper: 0.05).
        seed: the run's seed; trial streams are spawned from it (see the module docstring).
        db_path: the SQLite results database.
        cache_dir: where trajectories and models are cached.
        workers: worker processes of the embedded cluster; 0 runs the trials in this process (no Dask).
        scheduler: address of an existing Dask scheduler (``tcp://host:port``); overrides ``workers``.
        progress: show a tqdm bar (``None``: only on a terminal).
        retarget_max_nfev: Rosenbrock evaluations per retargeting step (``None``: the default of
            :class:`retarget.retargeting.RetargetConfig`); fewer make a quick, coarser strategy (tests).
    """

    rows: tuple[str, ...] = ROWS
    planners: tuple[str, ...] = ("learned", "baseline")
    trials: int = 100
    time_limit_s: float = 10.0
    beta: float = 0.05
    quality_threshold: float = 0.05
    seed: int = 0
    db_path: Path = Path("runs/table1/table1.sqlite")
    cache_dir: Path = Path("runs/table1/cache")
    workers: int = field(default_factory=lambda: os.cpu_count() or 1)
    scheduler: str | None = None
    progress: bool | None = None
    retarget_max_nfev: int | None = None

    def __post_init__(self):
        bad = [r for r in self.rows if r not in ROWS]
        if bad or not self.rows:
            raise InputError(f"rows: unknown {bad or '(none)'}; valid: {', '.join(ROWS)}")
        bad = [p for p in self.planners if p not in PLANNERS]
        if bad or not self.planners:
            raise InputError(f"planners: unknown {bad or '(none)'}; valid: {', '.join(PLANNERS)}")
        if self.trials < 1:
            raise InputError(f"trials: expected a positive number, found {self.trials}")
        if self.workers < 0:
            raise InputError(f"workers: expected >= 0, found {self.workers}")
        if self.retarget_max_nfev is not None and self.retarget_max_nfev < 1:
            raise InputError(f"retarget_max_nfev: expected a positive number, found {self.retarget_max_nfev}")
        if self.seed < 0:
            raise InputError(f"seed: expected >= 0, found {self.seed}")
        # validates time_limit_s, beta and quality_threshold the way the planner does
        self.settings("learned")
        object.__setattr__(self, "rows", tuple(r for r in ROWS if r in self.rows))
        object.__setattr__(self, "db_path", Path(self.db_path))
        object.__setattr__(self, "cache_dir", Path(self.cache_dir))

    def settings(self, planner: str) -> PlanningSettings:
        """The planning settings of one query of ``planner``."""
        return PlanningSettings(
            planner=planner,
            beta=self.beta,
            time_limit_s=self.time_limit_s,
            quality_threshold=self.quality_threshold,
        )


def parse_names(text: str | None, valid: Sequence[str], what: str) -> tuple[str, ...]:
    """A comma-separated list of names checked against ``valid`` (``None`` or empty: all of them)."""
    if not text:
        return tuple(valid)
    names = tuple(n.strip() for n in text.split(",") if n.strip())
    bad = [n for n in names if n not in valid]
    if bad or not names:
        raise InputError(f"{what}: unknown {', '.join(bad) or '(none)'}; valid: {', '.join(valid)}")
    return tuple(dict.fromkeys(names))


def trial_rng(seed: int, row: str, planner: str, trial: int) -> np.random.Generator:
    """The generator of one trial: ``SeedSequence(seed, spawn_key=(ROWS index, PLANNERS index, trial))``."""
    key = (ROWS.index(row), PLANNERS.index(planner), int(trial))
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# -- trials ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class TrialTask:
    """One planning query, everything a worker needs (picklable)."""

    row: str
    planner: str
    trial: int
    seed: int
    model_path: str
    model_sha256: str
    settings: PlanningSettings
    git_commit: str
    params_json: str

    def key(self) -> tuple[str, str, int]:
        return (self.row, self.planner, self.trial)


def trial_params(config: Table1Config, strategy: Strategy, planner: str) -> dict:
    """The parameters stored with every trial of (row, planner); a resume must match them."""
    s = config.settings(planner)
    return {
        "row": strategy.row,
        "planner": planner,
        "seed": config.seed,
        "strategy": strategy.demonstration,
        "model_sha256": strategy.model_sha256,
        "settings": dataclasses.asdict(s),
        "seed_scheme": "SeedSequence(seed, spawn_key=(ROWS.index(row), PLANNERS.index(planner), trial))",
    }


def make_tasks(
    config: Table1Config, strategies: dict[str, Strategy], done: set[tuple[str, str, int]], commit: str
) -> list[TrialTask]:
    """The unfinished trials, trial-major (every row advances together, so a partial run covers all rows)."""
    tasks = []
    for trial in range(config.trials):
        for row in config.rows:
            st = strategies[row]
            for planner in config.planners:
                if (row, planner, trial) in done:
                    continue
                tasks.append(
                    TrialTask(
                        row=row,
                        planner=planner,
                        trial=trial,
                        seed=config.seed,
                        model_path=str(st.model_path.resolve()),
                        model_sha256=st.model_sha256,
                        settings=config.settings(planner),
                        git_commit=commit,
                        params_json=params_json(trial_params(config, st, planner)),
                    )
                )
    return tasks


_PLANNER_CACHE: dict = {}
"""Per-process cache of GraspPlanners keyed by (row, model hash): each Dask worker process owns its own."""


def _planner(row: str, model_path: str, model_sha256: str):
    from inference.model import VariationModel
    from planning.grasp_planner import GraspPlanner

    key = (row, model_sha256)
    gp = _PLANNER_CACHE.get(key)
    if gp is None:
        gp = GraspPlanner(row, [VariationModel.load(model_path)])
        _PLANNER_CACHE[key] = gp
    return gp


def run_trial(task: TrialTask) -> TrialRecord:
    """Run one planning query (in a worker process) and return its record."""
    gp = _planner(task.row, task.model_path, task.model_sha256)
    rng = trial_rng(task.seed, task.row, task.planner, task.trial)
    start = time.perf_counter()
    res = gp.plan(rng, task.settings)
    elapsed = time.perf_counter() - start
    return record_from_plan(
        res,
        row=task.row,
        planner=task.planner,
        trial=task.trial,
        seed=task.seed,
        git_commit=task.git_commit,
        params_json=task.params_json,
        eta_s=elapsed,
    )


# -- the run -----------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunSummary:
    """What one invocation of :func:`run_table1` did.

    Attributes:
        strategies: per row.
        new_trials: trials run now; skipped: trials found finished in the database.
        errors: trials whose task raised (not stored; a re-run retries them).
        wall_time_s: of this invocation, strategies included; strategy_time_s: of the strategies alone.
        workers: worker processes used (0: in this process).
        records: the stored trials of the requested rows, planners and trial numbers.
    """

    strategies: dict[str, Strategy]
    new_trials: int
    skipped: int
    errors: int
    wall_time_s: float
    strategy_time_s: float
    workers: int
    records: list[TrialRecord]


_RESUME_HINT = "use --new to start a fresh database (the old one is kept), another --db, or the same settings"


def _expected_params(config: Table1Config, strategies: dict[str, Strategy] | None) -> dict:
    """Per (row, planner), the run's trial parameters (without strategies: with an empty model hash)."""
    from planning.scene import load_scene

    out = {}
    for row in config.rows:
        st = strategies[row] if strategies else Strategy(row, load_scene(row).strategy, Path(), Path(), "", 0)
        for p in config.planners:
            out[(row, p)] = params_json(trial_params(config, st, p))
    return out


def run_table1(
    config: Table1Config, run_trials: bool = True, on_stage: Callable[[str], None] | None = None
) -> RunSummary:
    """Compute the strategies, run the unfinished trials and store each one as it completes.

    The database is opened and checked first (:func:`pbdgrasp.results_db.open_db`), and the stored
    trials' settings are compared with the run's before the strategies are built, their models' hashes
    after.

    Args:
        config: the run's settings.
        run_trials: ``False`` builds nothing and runs nothing: it collects the stored trials of an existing
            database and the cached strategies (to report on a run).
        on_stage: called with one line per strategy step that is computed (cache misses) and per phase.

    Returns:
        A :class:`RunSummary`; the report is :func:`pbdgrasp.report.write_report`'s job.

    Raises:
        InputError: the database is not a results database or is locked; it holds trials of the requested
            rows run with other parameters; with ``run_trials=False``, the database or a strategy is
            missing.
    """
    start = time.perf_counter()
    say = on_stage or (lambda _line: None)
    conn = open_db(config.db_path, create=run_trials)
    try:
        if run_trials and config.scheduler:
            check_scheduler(config.scheduler)
        check_params(conn, _expected_params(config, None), _RESUME_HINT, ignore=("model_sha256",))
        say(f"strategies of {len(config.rows)} row(s) (cached in {config.cache_dir})")
        strategies = {
            row: prepare_strategy(
                row,
                config.cache_dir,
                config.progress,
                config.retarget_max_nfev,
                build=run_trials,
                on_stage=say,
            )
            for row in config.rows
        }
        strategy_time_s = time.perf_counter() - start
        commit = source_commit()
        check_params(conn, _expected_params(config, strategies), _RESUME_HINT)
        wanted = {(r, p, t) for r in config.rows for p in config.planners for t in range(config.trials)}
        done = finished_keys(conn) & wanted
        tasks = make_tasks(config, strategies, done, commit) if run_trials else []
        previous = [r for r in load_trials(conn, list(config.rows)) if r.key() in wanted]
        errors = 0
        workers = 0 if (config.workers == 0 and not config.scheduler) else config.workers
        if tasks:
            where = config.scheduler or (f"{workers} Dask worker(s)" if workers else "this process")
            say(f"planning {len(tasks)} trials ({len(done)} already stored in {config.db_path}) on {where}")
        progress = TrialProgress(config, len(wanted), len(done), previous)
        try:
            if tasks and workers == 0:
                for task in tasks:
                    rec = run_trial(task)
                    insert_trial(conn, rec)
                    progress.update(rec)
            elif tasks:
                from distributed import as_completed

                with dask_client(config.workers, config.scheduler) as client:
                    if config.scheduler:
                        workers = len(client.scheduler_info().get("workers", {}))
                    futures = [client.submit(run_trial, t, pure=False, key=f"trial-{t.row}-{t.planner}-"
                                             f"{t.trial}-{t.model_sha256[:8]}") for t in tasks]  # fmt: skip
                    for fut in as_completed(futures):
                        try:
                            rec = fut.result()
                        except Exception as exc:  # a crashed trial is logged, not stored: resume retries it
                            errors += 1
                            log.error("trial %s failed: %s: %s", fut.key, type(exc).__name__, exc)
                            continue
                        finally:
                            fut.release()
                        insert_trial(conn, rec)
                        progress.update(rec)
        finally:
            progress.close()
        records = [r for r in load_trials(conn, list(config.rows)) if r.key() in wanted]
    finally:
        conn.close()
    return RunSummary(
        strategies=strategies,
        new_trials=len(tasks) - errors,
        skipped=len(done),
        errors=errors,
        wall_time_s=time.perf_counter() - start,
        strategy_time_s=strategy_time_s,
        workers=workers,
        records=records,
    )
