"""Learned strategies built in code, so planner tests need neither a demonstration nor retargeting.

``ham_top_down_trajectory`` is the direct transformation of a straight top-down approach that ends at a
hand-placed grasp of the ham can (``pbdgrasp.bench.HAM_GRASP_Q``, epsilon ~0.17): 15 cm above
the grasp with the hand open, a minimum-jerk descent, the fingers pre-shaped on the way.
"""

import numpy as np

from assets import sah
from assets.se3 import pose_from_q, se3_inverse
from inference.solve import solve
from pbdgrasp import bench_fixtures as bench
from planning.scene import load_scene
from retarget.trajectory import Trajectory

HAM_GRASP_Q = np.array(bench.HAM_GRASP_Q)  # world frame of the "ham" scene


def ham_top_down_trajectory(num_steps: int = 40, rmse_mm: float = 6.5) -> Trajectory:
    scene = load_scene("ham")
    T_world_object = scene.T_world_object
    T_object_grasp = se3_inverse(T_world_object) @ pose_from_q(HAM_GRASP_Q)
    s = np.linspace(0.0, 1.0, num_steps)
    s = 10 * s**3 - 15 * s**4 + 6 * s**5
    T = np.repeat(T_object_grasp[None], num_steps, axis=0)
    T[:, 2, 3] += 0.15 * (1.0 - s)
    joints = (1.0 - s)[:, None] * sah.rest_joints() + s[:, None] * HAM_GRASP_Q[6:]
    cov = np.repeat((np.eye(19) * 1e-6)[None], num_steps, axis=0)
    return Trajectory(
        T,
        joints,
        cov,
        np.full(num_steps, rmse_mm),
        T_world_object,
        scene.cov_object,
        0.05,
        "ham",
        "precision",
    )


def ham_top_down_model(num_steps: int = 40):
    return solve(ham_top_down_trajectory(num_steps))
