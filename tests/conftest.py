"""Fixtures shared by the test modules: synthetic trajectories, a stand-in fingertip map, the one
numerical-derivative helper of the Jacobian tests, a ham strategy built in code, and pybullet's penetration
depths of a hand trajectory in a scene.

``ham_top_down_model`` is the variation model of the direct transformation of a straight top-down
approach that ends at a hand-placed grasp of the ham can (``pbdgrasp.bench_fixtures.HAM_GRASP_Q``,
epsilon ~0.17): 15 cm above the grasp with the hand open, a minimum-jerk descent, the fingers pre-shaped
on the way; planner tests need neither a demonstration nor retargeting.
"""

import gtsam
import numpy as np
import pytest

from assets import sah
from assets.se3 import pose_from_q, q_from_pose, se3_exp, se3_inverse
from inference.solve import solve
from pbdgrasp import bench_fixtures as bench
from planning.scene import load_scene
from planning.world import World
from retarget.trajectory import Trajectory

H_STEP = 1e-6  # [rad, m] the numerical Jacobians' central-difference step


def _make_traj(n=5, coupled=True, seed=0, T_world_object=None, xi_path=None, cov_scale=0.01):
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)
    if xi_path is None:
        xi_path = np.zeros((n, 6))
        xi_path[:, 0] = 0.4 * s
        xi_path[:, 2] = -0.2 * s
        xi_path[:, 3] = 0.05 + 0.1 * (1 - s)
        xi_path[:, 5] = 0.25 * (1 - s)
    A = rng.normal(size=(n, 19, 6)) * cov_scale
    cov = A @ np.swapaxes(A, 1, 2)
    if not coupled:
        cov[:, :6, 6:] = cov[:, 6:, :6] = 0.0
    T_wo = se3_exp(np.array([0.1, -0.2, 0.5, 0.4, 0.0, 0.7])) if T_world_object is None else T_world_object
    return Trajectory(
        T_object_wrist=se3_exp(xi_path),
        joints=np.outer(s, np.linspace(0.1, 0.8, 13)),
        cov_retarget=cov,
        fingertip_rmse_mm=np.zeros(n),
        T_world_object_mean=T_wo,
        cov_object=np.diag([0.05] * 3 + [0.01] * 3) ** 2,
        dt_s=0.05,
        object="testobj",
        grasp_type="precision",
    )


def _standin_map(T_object_wrist, joints, cov12):
    """A fixed full-rank 12x19 'fingertip Jacobian': the same mapping J+ cov J+^T as assets.sah."""
    J = np.random.default_rng(0).normal(size=(12, 19))
    Jp = np.linalg.pinv(J)
    return np.broadcast_to(Jp @ cov12 @ Jp.T, (len(T_object_wrist), 19, 19)).copy()


def _numerical_jacobian(error_fn, values: gtsam.Values, key: int, h: float = H_STEP) -> np.ndarray:
    """Central-difference Jacobian of ``error_fn(values)`` w.r.t. the variable ``key`` (Pose3: retract)."""
    is_pose = True
    try:
        x0 = values.atPose3(key)
        dim = 6
    except RuntimeError:
        is_pose = False
        x0 = values.atVector(key)
        dim = x0.shape[0]
    cols = []
    for i in range(dim):
        d = np.zeros(dim)
        d[i] = h
        out = []
        for sign in (1.0, -1.0):
            v = gtsam.Values(values)
            v.update(key, x0.retract(sign * d) if is_pose else x0 + sign * d)
            out.append(np.asarray(error_fn(v), dtype=float))
        cols.append((out[0] - out[1]) / (2 * h))
    return np.stack(cols, axis=1)


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


def _ham_top_down_model(num_steps: int = 40):
    return solve(ham_top_down_trajectory(num_steps))


@pytest.fixture(scope="session")
def make_traj():
    """``make_traj(n=5, coupled=True, seed=0, ...)``: a synthetic :class:`Trajectory` with a random SPD
    Sigma_r (a test of the variation model)."""
    return _make_traj


@pytest.fixture(scope="session")
def standin_map():
    """A fixed full-rank 12 x 19 'fingertip Jacobian' mapping, ``(T, joints, cov12) -> (T, 19, 19)``."""
    return _standin_map


@pytest.fixture(scope="session")
def numerical_jacobian():
    """``numerical_jacobian(error_fn, values, key, h)``: central differences w.r.t. one GTSAM variable."""
    return _numerical_jacobian


@pytest.fixture(scope="session")
def ham_top_down_model():
    """``ham_top_down_model(num_steps=40)``: the ham strategy built in code (see the module docstring)."""
    return _ham_top_down_model


def _penetrations(scene, T_object_wrist, joints) -> list[dict[str, float]]:
    """Per step of ``(T (T, 4, 4) object-frame wrist poses, joints (T, 13))``, the deepest signed distance
    [m] of the hand to each scene body it penetrates (pybullet's ``World.hand_contacts``; by label)."""
    out = []
    with World(scene) as world:
        for T, J in zip(T_object_wrist, joints, strict=True):
            depth: dict[str, float] = {}
            for c in world.hand_contacts(np.r_[q_from_pose(scene.T_world_object @ T), J]):
                if c.distance_m < 0:
                    depth[c.other] = min(depth.get(c.other, 0.0), c.distance_m)
            out.append(depth)
    return out


@pytest.fixture(scope="session")
def penetrations():
    """``penetrations(scene, T_object_wrist, joints)``: per step, ``{body: deepest signed distance [m]}`` of
    the hand's penetrations (pybullet, an implementation independent of the variation model's)."""
    return _penetrations


@pytest.fixture(scope="session")
def wall_steps():
    """``wall_steps(scene, model)``: the steps whose mean penetrates a scene body other than the grasped
    object, by pybullet."""

    def steps(scene, model) -> list[int]:
        depths = _penetrations(scene, model.T_object_wrist_mean, model.joints_mean)
        return [t for t, d in enumerate(depths) if set(d) - {scene.object.name}]

    return steps
