"""Fixtures of the bench and the tests: a hand-placed ham grasp, a synthetic trajectory, and learned
strategies (by the real pipeline from the Table I cache, or built in code for the quick mode).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from assets.q_layout import JOINTS, Q_DIM

__all__ = ["HAM_GRASP_Q", "quick_model", "strategy_model", "synthetic_trajectory", "timed"]

#: A hand-placed grasp of the ham can from above in the ``ham`` scene (epsilon ~0.17), q (19,) [m, rad];
#: the grasp of ``tests/test_autograsp.py``. The ham can (10 x 5.5 x 8 cm) stands upright at the origin;
#: the fingers point down (hand z ~ world -z, tilted 25 deg towards -y), the palm faces +y (tilted 24 deg
#: down); the opposed thumb (base 86 deg) is on the +y face, index and middle on the -y face (the ring
#: passes beyond the can's end), low on the can. Fingers pre-flexed 0/10 deg, thumb 18/10 deg.
HAM_GRASP_Q = (-0.0293, 0.0485, 0.2687, 2.1136, 1.9704, -0.543,
               1.5019, 0.0, 0.3152, 0.1745, 0.0, 0.0006, 0.1745,
               0.0, 0.0006, 0.1745, 0.0, 0.0006, 0.1745)  # fmt: skip


def timed(fn, repeats: int) -> tuple[float, object]:
    """Median wall time [s] of ``repeats`` calls of ``fn()`` and the last result."""
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def synthetic_trajectory(num_steps: int, rng: np.random.Generator):
    """A smooth T-step top-down approach on the ham scene with degenerate rank-6 Sigma_r(t).

    Returns:
        A :class:`retarget.trajectory.Trajectory` (T steps, precision grasp, the ham scene's prior).
    """
    from assets import sah
    from assets.se3 import pose_from_q, se3_inverse
    from planning.scene import load_scene
    from retarget.trajectory import Trajectory

    scene = load_scene("ham")
    q = np.array(HAM_GRASP_Q)
    T_object_grasp = se3_inverse(scene.T_world_object) @ pose_from_q(q)
    s = np.linspace(0.0, 1.0, num_steps)
    s = 10 * s**3 - 15 * s**4 + 6 * s**5
    T = np.repeat(T_object_grasp[None], num_steps, axis=0)
    T[:, 2, 3] += 0.15 * (1.0 - s)
    joints = (1.0 - s)[:, None] * sah.rest_joints() + s[:, None] * q[JOINTS]
    A = rng.normal(size=(num_steps, Q_DIM, 6)) * 0.003
    cov = A @ np.swapaxes(A, 1, 2)
    return Trajectory(
        T,
        joints,
        cov,
        np.full(num_steps, 6.5),
        scene.T_world_object,
        scene.cov_object,
        0.05,
        "ham",
        "precision",
    )


def strategy_model(scene_name: str, cache_dir: Path, max_nfev: int):
    """The learned strategy of a scene by the real pipeline, from the Table I cache.

    :func:`pbdgrasp.cache.prepare_strategy` with ``max_nfev`` Rosenbrock evaluations per retargeting
    step: the scene's demonstration retargeted in the demonstrated object's own scene, solved with the
    scene's object prior and constraints, each step cached by the hash of its inputs.

    Returns:
        ``(VariationModel, info dict)`` with the model file, the wall time of this call (about 0 on a
        cache hit) and the retargeting and solve times recorded when the strategy was built.
    """
    from inference.model import VariationModel
    from retarget.trajectory import Trajectory

    from .cache import prepare_strategy

    t0 = time.perf_counter()
    strategy = prepare_strategy(scene_name, cache_dir, retarget_max_nfev=max_nfev)
    elapsed = time.perf_counter() - t0
    model = VariationModel.load(strategy.model_path)
    traj = Trajectory.load(strategy.trajectory_path)
    info = {
        "model": str(strategy.model_path),
        "prepare_s": elapsed,
        "retarget_s": float(traj.meta.get("retarget_time_s", float("nan"))),
        "infer_s": float(model.solve_time_s),
        "retarget_rmse_mm": float(traj.meta.get("rmse_mm", float("nan"))),
        "retarget_mse_mm2": strategy.mse_mm2,
    }
    return model, info


def quick_model():
    """A ham strategy built in code: a 30-step top-down approach to :data:`HAM_GRASP_Q`, small Sigma_r."""
    from inference.solve import solve
    from retarget.trajectory import Trajectory

    traj = synthetic_trajectory(30, np.random.default_rng(0))
    cov = np.repeat((np.eye(Q_DIM) * 1e-6)[None], traj.num_steps, axis=0)
    traj = Trajectory(
        traj.T_object_wrist, traj.joints, cov, traj.fingertip_rmse_mm, traj.T_world_object_mean,
        traj.cov_object, traj.dt_s, traj.object, traj.grasp_type,
    )  # fmt: skip
    return solve(traj)
