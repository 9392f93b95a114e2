"""The bench's inference measurements (:mod:`pbdgrasp.bench`): the variation model without a scene (GTSAM's
marginals beside the dense inverse of the information matrix) and each Table I row's model in its scene
with the final grasp chosen again there (docs/performance.md).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path

import gtsam
import numpy as np

from assets.q_layout import Q_DIM

from .bench_fixtures import synthetic_trajectory, timed
from .scene_grasp import SceneGraspConfig, adapt_final_grasp

__all__ = ["bench_inference", "bench_scene_inference"]

log = logging.getLogger(__name__)


def _dense_marginals(graph, values, n: int) -> np.ndarray:
    """(T, 19, 19) marginals of (W_t, J_t) from the dense inverse of the information matrix."""
    from inference.graph import key_j, key_w

    order = gtsam.Ordering()
    for t in range(n):
        order.push_back(key_w(t))
        order.push_back(key_j(t))
    info = graph.linearize(values).hessian(order)[0]
    cov = np.linalg.inv(info)
    idx = np.arange(n)[:, None] * Q_DIM + np.arange(Q_DIM)
    return cov[idx[:, :, None], idx[:, None, :]]


def bench_inference(
    sizes=(25, 50, 100, 200), repeats: int = 3, rng: np.random.Generator | None = None
) -> dict:
    """Graph + solve + marginals per T, gtsam vs dense marginals (no scene).

    Returns:
        ``{"rows": [{T, solve_ms, marginals_ms, dense_ms, dense_over_gtsam, max_rel_diff}]}``.
    """
    from inference.graph import build_graph, factor_covariances, initial_values
    from inference.params import VariationParams
    from inference.solve import conditional_marginals, solve

    rng = rng or np.random.default_rng(0)
    params = VariationParams()
    rows = []
    for n in sizes:
        traj = synthetic_trajectory(n, rng)
        solve_s, model = timed(lambda traj=traj: solve(traj, params), repeats)
        mu_o = traj.T_world_object_mean
        graph = build_graph(traj, params, factor_covariances(traj, params), mu_o, None, fixed_object=True)
        values = gtsam.GaussNewtonOptimizer(graph, initial_values(traj, mu_o, fixed_object=True)).optimize()
        marg_s, (_, _, cov_g) = timed(
            lambda g=graph, v=values, n=n, mu=mu_o: conditional_marginals(g, v, mu, n), repeats
        )
        dense_s, cov_d = timed(lambda g=graph, v=values, n=n: _dense_marginals(g, v, n), repeats)
        rel = float(np.max(np.abs(cov_g - cov_d)) / np.max(np.abs(cov_d)))
        rows.append(
            {
                "T": n,
                "solve_ms": 1e3 * solve_s,
                "marginals_ms": 1e3 * marg_s,
                "dense_ms": 1e3 * dense_s,
                "dense_over_gtsam": dense_s / marg_s,
                "max_rel_diff": rel,
            }
        )
    return {"rows": rows}


def bench_scene_inference(
    rows: Sequence[str],
    trajectory_of: Callable,
    cache_dir: Path | None,
    scene_grasp: SceneGraspConfig,
) -> dict:
    """Per row, the variation model in the row's scene (:func:`pbdgrasp.scene_model.learn_in_scene`): the
    solve's wall time with the scene's distance fields built (their build time apart), its LM iterations,
    convergence and constrained steps; then the final grasp chosen again in the scene
    (:func:`pbdgrasp.scene_grasp.adapt_final_grasp`, as Table I builds its models): its wall time and
    whether it kept a re-solved model.

    Args:
        rows: scene names.
        trajectory_of: ``row -> Trajectory``, e.g. the row's retargeted strategy.
        cache_dir: the distance fields' cache is ``cache_dir / "fields"`` (None: in memory only).
        scene_grasp: the final grasp's settings.
    """
    from inference.params import VariationParams
    from planning.scene import load_scene
    from planning.scene_fields import scene_fields

    from .scene_model import learn_in_scene

    params = VariationParams()
    fields_dir = None if cache_dir is None else cache_dir / "fields"
    out = {}
    for row in rows:
        traj = trajectory_of(row)
        scene = load_scene(row)
        fields_s, _ = timed(lambda scene=scene: scene_fields(scene, fields_dir), 1)
        solve_s, model = timed(
            lambda traj=traj, scene=scene: learn_in_scene(traj, scene, params, fields_dir), 1
        )
        grasp_s, adapted = timed(
            lambda m=model, scene=scene: adapt_final_grasp(m, scene, params, fields_dir, scene_grasp), 1
        )
        out[row] = {
            "T": int(model.num_steps),
            "solve_s": solve_s,
            "fields_s": fields_s,
            "iterations": int(model.iterations),
            "converged": bool(model.converged),
            "constrained_steps": int(np.sum(model.constrained)),
            "scene_grasp_s": grasp_s,
            "scene_grasp_kept": bool(adapted.source.meta["scene_grasp"]["kept"]),
        }
        log.info("bench scene inference %s: %s", row, out[row])
    return out
