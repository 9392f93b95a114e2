"""Reproducing the paper's Table I (section VIII): the strategy pipeline, the trials and their distribution.

For every row (a scene of the same name, :data:`pbdgrasp.paper.ROWS`):

1. the strategy: the scene's demonstration (``Scene.strategy``; the bottle uses the chips can's, the big
   cup the small cup's) is retargeted to the SAH with the collision term checked in the demonstrated
   object's obstacle-free scene, as ``pbdgrasp retarget`` does, and the variation model is solved with the
   row's scene (its object prior and the signed-distance constraints of its table and obstacles), as
   ``pbdgrasp infer --scene`` does. Both steps are cached under ``cache_dir`` by the SHA-256 of their
   inputs (demonstration file, scene, object and hand files, settings, the Python sources of the step,
   a format version), so a re-run computes nothing twice and an edited input or code is recomputed.
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

import ast
import contextlib
import dataclasses
import hashlib
import json
import logging
import os
import platform
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import assets
from assets.errors import InputError
from planning.grasp_planner import PLANNERS, PlanningSettings

from .paper import ROWS
from .results_db import (
    TrialRecord,
    finished_keys,
    insert_trial,
    load_trials,
    open_db,
    params_json,
    source_commit,
)

__all__ = [
    "Table1Config",
    "Strategy",
    "TrialTask",
    "RunSummary",
    "parse_names",
    "trial_rng",
    "prepare_strategy",
    "strategy_final_q",
    "make_tasks",
    "run_trial",
    "run_table1",
    "float_kernels",
]

log = logging.getLogger(__name__)

CACHE_VERSION = 1
"""Bump to invalidate every cached trajectory and model (a change of the pipeline's code)."""


@dataclass(frozen=True)
class Table1Config:
    """Settings of a Table I run (the paper's by default).

    Attributes:
        rows: Table I rows (scene names) in :data:`ROWS` order.
        planners: planners of :data:`planning.grasp_planner.PLANNERS`.
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
    db_path: Path = Path("results/table1.sqlite")
    cache_dir: Path = Path("results/cache")
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


# -- the strategy pipeline (cached) ------------------------------------------------------------------
def _sha256_file(path: str | os.PathLike) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _digest(parts: Iterable[str]) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p.encode())
        h.update(b"\0")
    return h.hexdigest()


_PACKAGE_ROOT = Path(__file__).resolve().parent.parent
#: The code each cached step runs. Retargeting checks d6 in a pybullet world, so the world's code is part
#: of its key too (it was not before 2026-12-01: an edit of world.py reused stale trajectories).
RETARGET_SOURCES = (
    "retarget",
    "pbdgrasp/strategy.py",
    "planning/world.py",
    "planning/scene.py",
    "planning/_pybullet.py",
)
#: Sources inside those folders that no cached step runs: the demonstration generator only writes the
#: demonstration files, whose contents are part of the retargeting key.
UNCACHED_SOURCES = ("assets/demonstrations/generate.py",)
MODEL_SOURCES = (
    "inference",
    "planning/world.py",
    "planning/scene.py",
    "planning/_pybullet.py",
    "pbdgrasp/strategy.py",
)


def float_kernels() -> str:
    """The floating-point kernels this process computes with: the machine and the two variables that pin
    numpy's and OpenBLAS's kernels (the Makefile sets them on x86-64). Part of every cache key: the
    retargeting's result depends on them (chips' MSE 856 mm^2 with AVX2 kernels, 988 with AVX-512)."""
    pins = (f"{k}={os.environ.get(k, '')}" for k in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES"))
    return " ".join([platform.machine(), *pins])


def _source_digest(entries: Sequence[str]) -> str:
    """SHA-256 of the Python sources a cached step runs (folders or files relative to the package root),
    each by its code (:func:`_code_digest`): an edit of a docstring, a comment or the layout recomputes
    nothing."""
    files: list[Path] = []
    for e in entries:
        p = _PACKAGE_ROOT / e
        files += sorted(p.rglob("*.py")) if p.is_dir() else [p]
    files = [f for f in files if f.relative_to(_PACKAGE_ROOT).as_posix() not in UNCACHED_SOURCES]
    return _digest(f"{f.relative_to(_PACKAGE_ROOT)}:{_code_digest(f)}" for f in files if f.is_file())


def _code_digest(path: Path) -> str:
    """SHA-256 of a Python file's syntax tree without docstrings (comments and layout are not in the tree);
    of its bytes if it does not parse. The tree's dump may differ between Python versions, which then
    recompute the cache once."""
    try:
        tree = ast.parse(path.read_bytes())
    except (SyntaxError, ValueError):
        return _sha256_file(path)
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (
            isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef)
            and body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            node.body = body[1:] or [ast.Pass()]
    return hashlib.sha256(ast.dump(tree).encode()).hexdigest()


def _scene_files(scene) -> list[Path]:
    """Every file a scene's geometry comes from: the YAML, its object, object obstacles and meshes."""

    def object_files(name: str) -> list[Path]:
        return [assets.object_urdf(name), assets.object_mesh(name), assets.object_collision_mesh(name)]

    files = [Path(scene.path), *object_files(scene.object.name)]
    for ob in scene.obstacles:
        if ob.type == "object":
            files += object_files(ob.name)
        elif ob.type == "mesh":
            files += [Path(ob.file)] + ([Path(ob.collision_file)] if ob.collision_file else [])
    return files + [assets.hand_urdf(scene.hand)]


@dataclass(frozen=True)
class Strategy:
    """The learned strategy of one row: its cached files and the retargeting error.

    Attributes:
        row: the Table I row (scene).
        demonstration: the demonstration used (``Scene.strategy``).
        trajectory_path: the cached ``.traj.npz`` (tau_r, Sigma_r(t)).
        model_path: the cached ``.model.npz`` (the marginals, with the row's scene prior and constraints).
        model_sha256: the model file's hash (keys the workers' planner cache).
        mse_mm2: the retargeting fingertip MSE, mean over steps of the per-step mean square [mm^2].
    """

    row: str
    demonstration: str
    trajectory_path: Path
    model_path: Path
    model_sha256: str
    mse_mm2: float


def prepare_strategy(
    row: str,
    cache_dir: str | os.PathLike,
    progress: bool | None = False,
    retarget_max_nfev: int | None = None,
) -> Strategy:
    """Demonstration -> retargeting -> inference for one row, each step cached by the hash of its inputs.

    Args:
        row: a Table I row (scene name).
        cache_dir: the cache folder (created if missing).
        progress: the retargeting's tqdm bar.
        retarget_max_nfev: see :class:`Table1Config`.

    Returns:
        The :class:`Strategy` with the cached file paths.
    """
    from inference import VariationParams
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration
    from retarget.retargeting import RetargetConfig
    from retarget.trajectory import Trajectory

    from .strategy import learn_in_scene, retarget_in_scene

    cache = Path(cache_dir)
    cache.mkdir(parents=True, exist_ok=True)
    scene = load_scene(row)
    demo_path = assets.demonstration_path(scene.strategy)
    demo = Demonstration.load(demo_path)
    demo_scene = load_scene(demo.object)
    config = RetargetConfig() if retarget_max_nfev is None else RetargetConfig(max_nfev=retarget_max_nfev)
    traj_key = _digest(
        [
            f"retarget v{CACHE_VERSION}",
            _source_digest(RETARGET_SOURCES),
            float_kernels(),
            _sha256_file(demo_path),
            repr(config),
        ]
        + [_sha256_file(assets.hand_urdf(h)) for h in ("sah", "human")]
        + [_sha256_file(f) for f in _scene_files(demo_scene)]
    )
    traj_path = cache / f"{scene.strategy}-{traj_key[:16]}.traj.npz"
    if not traj_path.is_file():
        log.info("retargeting %s (cache miss) -> %s", scene.strategy, traj_path)
        traj, _ = retarget_in_scene(demo, demo_scene, config, progress=bool(progress))
        traj.save(traj_path)
    traj = Trajectory.load(traj_path)
    params = VariationParams()
    model_key = _digest(
        [f"infer v{CACHE_VERSION}", _source_digest(MODEL_SOURCES), float_kernels(), _sha256_file(traj_path)]
        + [json.dumps(params.to_dict(), sort_keys=True), _sha256_file(assets.hand_urdf("sah"))]
        + [_sha256_file(f) for f in _scene_files(scene)]
    )
    model_path = cache / f"{row}-{model_key[:16]}.model.npz"
    if not model_path.is_file():
        log.info("inferring the variation model of %s (cache miss) -> %s", row, model_path)
        model = learn_in_scene(traj, scene, params)
        model.save(model_path)
    mse_mm2 = float(np.mean(np.asarray(traj.fingertip_rmse_mm) ** 2))
    return Strategy(row, scene.strategy, traj_path, model_path, _sha256_file(model_path), mse_mm2)


def strategy_final_q(strategy: Strategy) -> np.ndarray:
    """The strategy's mean final configuration (19,) in the row's world (for pictures)."""
    from assets.se3 import q_from_pose
    from inference.model import VariationModel
    from planning.scene import load_scene

    model = VariationModel.load(strategy.model_path)
    T_world_wrist = load_scene(strategy.row).T_world_object @ model.T_object_wrist_mean[-1]
    return np.concatenate([q_from_pose(T_world_wrist), model.joints_mean[-1]])


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
    grasp = {}
    if res.grasp is not None:
        grasp = {
            "closed_q": [float(x) for x in res.grasp.closed_q],
            "quality": float(res.grasp.quality),
            "contact_links": list(res.grasp.contact_links),
        }
    if res.success and len(res.path):
        grasp["q"] = [float(x) for x in res.path[-1]]
    return TrialRecord(
        row=task.row,
        planner=task.planner,
        trial=task.trial,
        seed=task.seed,
        success=bool(res.success),
        eta_s=float(elapsed),
        nodes=int(res.nodes),
        quality=float(res.quality),
        collision_checks=int(res.extra.get("collision_checks_total", res.collision_checks)),
        quality_evaluations=int(res.quality_evaluations),
        message=res.message,
        git_commit=task.git_commit,
        params_json=task.params_json,
        grasp_json=json.dumps(grasp),
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


def _check_params(conn, tasks_params: dict[tuple[str, str], str]) -> None:
    for (row, planner), pj in tasks_params.items():
        stored = {
            p for (p,) in conn.execute("SELECT DISTINCT params_json FROM trials WHERE row=? AND planner=?",
                                       (row, planner))
        }  # fmt: skip
        other = stored - {pj}
        if other:
            a, b = json.loads(next(iter(other))), json.loads(pj)
            diff = sorted(k for k in set(a) | set(b) if a.get(k) != b.get(k))
            raise InputError(
                f"the database holds {row}/{planner} trials run with other parameters ({', '.join(diff)}); "
                "use another --db, or the same settings to resume"
            )


class _Progress:
    """A tqdm bar over all trials with per-row success counts (learned/baseline) in the postfix."""

    def __init__(self, config: Table1Config, total: int, initial: int, records: list[TrialRecord]):
        from tqdm import tqdm

        self.counts = {r: {p: [0, 0] for p in config.planners} for r in config.rows}
        for rec in records:
            self._count(rec)
        disable = None if config.progress is None else not config.progress
        self.bar = tqdm(total=total, initial=initial, unit="trial", disable=disable, dynamic_ncols=True)
        self._postfix()

    def _count(self, rec: TrialRecord) -> None:
        c = self.counts.get(rec.row, {}).get(rec.planner)
        if c is not None:
            c[0] += int(rec.success)
            c[1] += 1

    def _postfix(self) -> None:
        text = " ".join(
            f"{row}:" + "/".join(f"{s}" for s, _ in per.values()) for row, per in self.counts.items()
        )
        self.bar.set_postfix_str(f"solved per row ({'/'.join(next(iter(self.counts.values())))}) {text}")

    def update(self, rec: TrialRecord) -> None:
        self._count(rec)
        self.bar.update(1)
        self._postfix()

    def close(self) -> None:
        self.bar.close()


def _quiet_dask() -> None:
    for name in ("distributed", "dask", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.WARNING)


@contextlib.contextmanager
def _dask_client(config: Table1Config):
    from distributed import Client, LocalCluster

    _quiet_dask()
    if config.scheduler:
        with Client(config.scheduler) as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=config.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.WARNING,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client


def run_table1(config: Table1Config, run_trials: bool = True) -> RunSummary:
    """Compute the strategies, run the unfinished trials and store each one as it completes.

    Args:
        config: the run's settings.
        run_trials: ``False`` only collects the stored trials (to report on a partial run).

    Returns:
        A :class:`RunSummary`; the report is :func:`pbdgrasp.report.write_report`'s job.

    Raises:
        InputError: the database holds trials of the requested rows run with other parameters.
    """
    start = time.perf_counter()
    strategies = {
        row: prepare_strategy(row, config.cache_dir, config.progress, config.retarget_max_nfev)
        for row in config.rows
    }
    strategy_time_s = time.perf_counter() - start
    commit = source_commit()
    conn = open_db(config.db_path)
    try:
        _check_params(
            conn,
            {
                (row, p): params_json(trial_params(config, strategies[row], p))
                for row in config.rows
                for p in config.planners
            },
        )
        wanted = {(r, p, t) for r in config.rows for p in config.planners for t in range(config.trials)}
        done = finished_keys(conn) & wanted
        tasks = make_tasks(config, strategies, done, commit) if run_trials else []
        previous = [r for r in load_trials(conn, list(config.rows)) if r.key() in wanted]
        progress = _Progress(config, len(wanted), len(done), previous)
        errors = 0
        workers = 0 if (config.workers == 0 and not config.scheduler) else config.workers
        try:
            if tasks and workers == 0:
                for task in tasks:
                    rec = run_trial(task)
                    insert_trial(conn, rec)
                    progress.update(rec)
            elif tasks:
                from distributed import as_completed

                with _dask_client(config) as client:
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
