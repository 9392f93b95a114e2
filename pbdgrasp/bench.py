"""``pbdgrasp bench``: the speed of every stage, measured in one process (docs/performance.md).

Each measurement is a function returning a plain ``dict`` (JSON-ready); :func:`run_bench` runs them all
and :func:`pbdgrasp.cli.bench.format_table` prints them. Timings use ``time.perf_counter`` and report the
median of repeats unless said otherwise; they are figures of this machine (:func:`machine_info`), never
asserted in tests.

* inference: graph + Gauss-Newton + all conditional marginals of a synthetic T-step trajectory
  (:func:`inference.solve.solve`), and the marginals alone by ``gtsam.Marginals`` beside the dense
  reference (the information matrix at the solution, ``hessian`` with an explicit ordering, inverted by
  numpy), with the largest relative difference of the two as a check;
* scene inference: per Table I row, the variation model in the row's scene (clearance factors on the SAH's
  sphere cover and the scene's distance fields, LM, joint limits): solve time, iterations, convergence,
  and the time of choosing the final grasp again in the scene (quick mode: the in-code ham approach in the
  ham scene, a few draws). These two live in :mod:`pbdgrasp.bench_inference`;
* samples per second of the mixture P(Y) (:class:`inference.sampler.MixtureSampler`, beta = 0.05);
* collision: configurations (uniform in the ham scene's bounds) and edges (between consecutive P(Y) draws
  of the ham strategy) checked per second;
* quality: epsilon from four tetrahedral contacts (us) and a close-and-score at a hand-placed ham grasp (ms);
* retargeting: seconds per step of the whole ham demonstration, as a Table I build retargets it;
* planning: per scene and planner, success rate, median ETA of the solved trials, nodes, collision checks,
  the ratios learned/OMPL and learned/baseline of the median ETAs, and the share of planning time spent in
  pybullet collision checks and in the quality (phi_o); the rest is our own overhead (sampling, nearest
  neighbours, bookkeeping). The learned strategies come from the real pipeline (demonstration ->
  retargeting with ``retarget_max_nfev`` -> variation model with the scene's prior and signed-distance
  constraints), cached under ``cache_dir`` as the Table I runner caches them. Quick mode plans on the ham
  scene only, with a strategy built in code (a top-down approach to the hand-placed grasp). This part lives
  in :mod:`pbdgrasp.bench_planning`;
* peak memory: ``resource.getrusage(RUSAGE_SELF).ru_maxrss``.
"""

from __future__ import annotations

import importlib.metadata
import logging
import os
import platform
import resource
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.q_layout import Q_DIM
from planning.closing_pool import default_processes

from .bench_fixtures import HAM_GRASP_Q, quick_model, synthetic_trajectory, timed
from .bench_inference import bench_inference, bench_scene_inference
from .bench_planning import PLANNING_SCENES, bench_planning
from .cache import prepare_trajectory
from .paper import ROWS
from .scene_grasp import SceneGraspConfig

__all__ = [
    "BenchConfig",
    "machine_info",
    "bench_inference",
    "bench_sampler",
    "bench_collision",
    "bench_quality",
    "bench_retargeting",
    "bench_planning",
    "peak_memory",
    "run_bench",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class BenchConfig:
    """Settings of one bench run.

    Attributes:
        quick: tiny settings (seconds): small sizes, ham planning only with a strategy built in code.
        trials: planning trials per scene and planner.
        seed: the run's seed; every measurement gets its own spawned generator.
        time_limit_s: budget of one planning query [s].
        cache_dir: where the planning strategies are cached.
        retarget_max_nfev: Rosenbrock evaluations per step when building the planning strategies.
        models: ``(scene, model path)`` pairs: use these strategies instead of building them (e.g. the
            full-budget ones of ``pbdgrasp table1``'s cache).
    """

    quick: bool = False
    trials: int = 3
    seed: int = 0
    time_limit_s: float = 10.0
    cache_dir: Path = Path("results/cache/bench")
    retarget_max_nfev: int = 100
    models: tuple[tuple[str, str], ...] = ()

    def __post_init__(self):
        bad = [scene for scene, _ in self.models if scene not in PLANNING_SCENES]
        if bad:
            raise InputError(f"models: unknown scenes {bad}; valid: {', '.join(PLANNING_SCENES)}")
        if self.trials < 1:
            raise InputError(f"trials: expected a count >= 1, found {self.trials}")
        if self.seed < 0:
            raise InputError(f"seed: expected >= 0, found {self.seed}")
        if not self.time_limit_s > 0:
            raise InputError(f"time_limit_s: expected > 0, found {self.time_limit_s}")
        if self.retarget_max_nfev < 1:
            raise InputError(f"retarget_max_nfev: expected >= 1, found {self.retarget_max_nfev}")
        object.__setattr__(self, "cache_dir", Path(self.cache_dir))


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


def machine_info() -> dict:
    """Platform, Python, CPU count and the CPU model name from ``/proc/cpuinfo``."""
    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.lower().startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "platform": platform.platform(),
        "python": platform.python_version(),
        "cpu_count": os.cpu_count(),
        "cpu_model": model,
        "gtsam": _version("gtsam"),
        "pybullet": _version("pybullet"),
        "numpy": np.__version__,
    }


def bench_sampler(
    model, n: int = 1_000_000, repeats: int = 3, rng: np.random.Generator | None = None
) -> dict:
    """Samples per second of P(Y) with one learned strategy and beta = 0.05."""
    from inference.sampler import MixtureSampler
    from planning.scene import load_scene

    rng = rng or np.random.default_rng(0)
    lo, hi = load_scene("ham").bounds_array
    mixture = MixtureSampler([model], lo, hi, 0.05)
    dt, _ = timed(lambda: mixture.sample(n, rng), repeats)
    dt_ref, _ = timed(lambda: rng.standard_normal((n, Q_DIM)), repeats)  # the machine's speed, for reference
    return {"n": n, "samples_per_s": n / dt, "numpy_normals_19d_per_s": n / dt_ref}


def bench_collision(
    model, n_configs: int = 2000, n_edges: int = 200, rng: np.random.Generator | None = None
) -> dict:
    """Configurations and edges checked per second in the ham scene.

    Configurations are uniform in the scene's wrist bounds and joint limits; edges join consecutive draws
    of P(Y) (beta = 0.05) of ``model``, the planner's typical query.
    """
    from assets.sah import JOINT_LIMITS
    from inference.sampler import MixtureSampler
    from planning.collision import CollisionChecker
    from planning.world import World

    rng = rng or np.random.default_rng(0)
    with World("ham") as world:
        checker = CollisionChecker(world)
        lo, hi = world.scene.bounds_array
        mixture = MixtureSampler([model], lo, hi, 1.0, JOINT_LIMITS)
        qs = mixture.sample(n_configs, rng).q
        t0 = time.perf_counter()
        free = sum(checker.is_free(q) for q in qs)
        dt_q = time.perf_counter() - t0
        ys = MixtureSampler([model], lo, hi, 0.05, JOINT_LIMITS).sample(n_edges + 1, rng).q
        checks0 = checker.checks
        t0 = time.perf_counter()
        for a, b in zip(ys[:-1], ys[1:], strict=True):
            checker.is_edge_free(a, b)
        dt_e = time.perf_counter() - t0
        points = checker.checks - checks0
    return {
        "configs_per_s": n_configs / dt_q,
        "us_per_config": 1e6 * dt_q / n_configs,
        "free_fraction": free / n_configs,
        "edges_per_s": n_edges / dt_e,
        "configs_per_edge": points / n_edges,
    }


def bench_quality(repeats_epsilon: int = 200, repeats_close: int = 20) -> dict:
    """epsilon from four tetrahedral contacts (us) and a close-and-score at :data:`HAM_GRASP_Q` (ms)."""
    from planning.autograsp import HandCloser
    from planning.grasp_quality import epsilon_l1
    from planning.world import World

    p = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float) / np.sqrt(3.0) * 0.04
    normals = -p / np.linalg.norm(p, axis=1, keepdims=True)
    eps_s, eps = timed(lambda: epsilon_l1(p, normals, 0.6, np.zeros(3), 0.04), repeats_epsilon)
    with World("ham") as world:
        closer = HandCloser(world)
        close_s, res = timed(lambda: closer.close(np.array(HAM_GRASP_Q)), repeats_close)
    return {
        "epsilon_us": 1e6 * eps_s,
        "epsilon_tetrahedron": float(eps),
        "close_and_score_ms": 1e3 * close_s,
        "ham_grasp_quality": float(res.quality),
        "closing_steps": int(res.steps),
    }


def bench_retargeting(
    num_steps: int | None = None, max_nfev: int | None = None, demo_name: str = "ham"
) -> dict:
    """Seconds per step of retargeting a demonstration as a Table I build does it (:func:`retarget_in_scene`,
    d6 with the penetration depth): all its steps, or its first ``num_steps`` (the quick bench). The per-step
    search (``s_per_step``) and the refined final grasp, once per demonstration (``final_grasp_s``), are
    timed apart; ``total_s`` is both; ``closing_processes``: the processes that close the final grasp's
    draws (:class:`~planning.closing_pool.ClosingPool`'s default)."""
    from pbdgrasp.strategy import retarget_in_scene
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration
    from retarget.retargeting import RetargetConfig

    demo = Demonstration.load(demo_name)
    if num_steps is not None:
        demo = demo.first_steps(num_steps)
    n = demo.num_steps
    config = RetargetConfig() if max_nfev is None else RetargetConfig(max_nfev=max_nfev)
    t0 = time.perf_counter()
    _, res = retarget_in_scene(demo, load_scene(demo.object), config)
    dt = time.perf_counter() - t0
    final_s = float(res.meta.get("final_grasp", {}).get("time_s", 0.0))
    return {
        "demonstration": demo_name,
        "steps": n,
        "max_nfev": config.max_nfev,
        "s_per_step": (dt - final_s) / n,
        "final_grasp_s": final_s,
        "closing_processes": default_processes(),
        "total_s": dt,
        "mean_nfev": float(np.mean(res.nfev)),
        "collision_checks": int(np.sum(res.n_collision_checks)),
        "rmse_mm": float(res.rmse_mm),
    }


def peak_memory() -> dict:
    """Peak resident memory of this process (``ru_maxrss``, KiB on Linux) [MiB]."""
    return {"peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}


def run_bench(config: BenchConfig = BenchConfig(), progress=None) -> dict:
    """Every measurement of the module docstring, in one process; a JSON-ready dict.

    Args:
        config: :class:`BenchConfig`.
        progress: optional ``callable(str)`` told the name of each section as it starts.
    """
    say = progress or (lambda _name: None)
    rngs = np.random.default_rng(np.random.SeedSequence(config.seed)).spawn(5)
    q = config.quick
    out = {"machine": machine_info(), "config": {k: str(v) for k, v in asdict(config).items()}}
    say("inference")
    out["inference"] = bench_inference((25, 50) if q else (25, 50, 100, 200), 1 if q else 3, rngs[0])
    model = quick_model()
    say("scene inference")
    if q:  # the in-code top-down ham approach, in the ham scene
        rows, trajectory_of = ("ham",), lambda _row: synthetic_trajectory(30, np.random.default_rng(0))
    else:  # the rows' retargeted strategies

        def trajectory_of(row: str):
            from retarget.trajectory import Trajectory

            path = prepare_trajectory(row, config.cache_dir, retarget_max_nfev=config.retarget_max_nfev)
            return Trajectory.load(path)

        rows = ROWS
    quick_grasp = SceneGraspConfig(probe_draws=16, candidates=2, draws=4, accept_draws=8, resolves=1)
    fields, grasp = (None, quick_grasp) if q else (config.cache_dir, SceneGraspConfig())
    out["scene_inference"] = bench_scene_inference(rows, trajectory_of, fields, grasp)
    say("sampler")
    out["sampler"] = bench_sampler(model, 100_000 if q else 1_000_000, 1 if q else 3, rngs[1])
    say("collision")
    out["collision"] = bench_collision(model, 200 if q else 2000, 20 if q else 200, rngs[2])
    say("quality")
    out["quality"] = bench_quality(20 if q else 200, 2 if q else 20)
    say("retargeting")
    out["retargeting"] = bench_retargeting(2, max_nfev=30) if q else bench_retargeting()
    say("planning")
    out["planning"] = bench_planning(config, rngs[4])
    out["memory"] = peak_memory()
    return out
