"""Fixtures shared by the test modules: synthetic trajectories, a stand-in fingertip map, the one
numerical-derivative helper of the Jacobian tests, a ham strategy built in code, and pybullet's penetration
depths of a hand trajectory in a scene.

``ham_top_down_model`` is the variation model of the direct transformation of a straight top-down
approach that ends at a hand-placed grasp of the ham can (``pbdgrasp.bench_fixtures.HAM_GRASP_Q``,
epsilon ~0.17): 15 cm above the grasp with the hand open, a minimum-jerk descent, the fingers pre-shaped
on the way; planner tests need neither a demonstration nor retargeting.

BLAS runs on one thread, as in the ``pbdgrasp`` command (:mod:`pbdgrasp.cli`).
"""

import gtsam
import numpy as np
import pytest
import scipy.linalg  # noqa: F401 - loads scipy's BLAS, so that the limit below reaches it too
from threadpoolctl import threadpool_limits

from assets import sah
from assets.se3 import pose_from_q, q_from_pose, se3_exp, se3_inverse
from inference.solve import solve
from pbdgrasp import bench_fixtures as bench
from planning.scene import load_scene
from planning.world import World
from retarget.trajectory import Trajectory

threadpool_limits(limits=1, user_api="blas")

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


def _dense_joint_chain(traj, params, extra, full=False):
    """Means (n, 13) and covariances of the joints' linear-Gaussian chain (block-diagonal f_1t, smoothness
    S_t), solved densely with numpy, with extra scalar priors ``extra[(t, i)] = [(value, variance), ...]``
    on J_t,i: the per-step blocks (n, 13, 13), or with ``full`` the whole (13 n, 13 n) covariance, index
    ``13 t + i`` for J_t,i."""
    from inference import factor_covariances

    n = traj.num_steps
    cov_f1 = factor_covariances(traj, params)
    D = np.linalg.inv(np.diag(params.smoothness_stds()[6:] ** 2))
    Lam, eta = np.zeros((13 * n, 13 * n)), np.zeros(13 * n)
    for t in range(n):
        P = np.linalg.inv(cov_f1[t][6:, 6:])
        Lam[13 * t : 13 * t + 13, 13 * t : 13 * t + 13] += P
        eta[13 * t : 13 * t + 13] += P @ traj.joints[t]
    for t in range(n - 1):
        a, b = slice(13 * t, 13 * t + 13), slice(13 * t + 13, 13 * t + 26)
        Lam[a, a] += D
        Lam[b, b] += D
        Lam[a, b] -= D
        Lam[b, a] -= D
    for (t, i), priors in extra.items():
        for value, variance in priors:
            Lam[13 * t + i, 13 * t + i] += 1.0 / variance
            eta[13 * t + i] += value / variance
    cov = np.linalg.inv(Lam)
    mean = (cov @ eta).reshape(n, 13)
    if full:
        return mean, cov
    return mean, np.stack([cov[13 * t : 13 * t + 13, 13 * t : 13 * t + 13] for t in range(n)])


@pytest.fixture(scope="session")
def dense_joint_chain():
    return _dense_joint_chain


class _Planes:
    """A toy clearance function: margins ``n_k . p - b_k`` of the wrist position p [m] (rows k), or, with
    ``joint_rows``, ``slope_k (J[i_k] - w_k)`` of single joints; analytic Jacobians; batched over leading
    axes like :class:`inference.clearance.HandClearance`."""

    def __init__(self, normals=(), offsets=(), joint_rows=()):
        self.normals = np.asarray(normals, dtype=float).reshape(-1, 3)
        self.offsets = np.asarray(offsets, dtype=float)
        self.joint_rows = list(joint_rows)  # (joint index, slope, wall)
        self.dim = len(self.normals) + len(self.joint_rows)
        self.active_margin_m = np.inf  # every margin exact, with its Jacobian

    def __call__(self, T_world_object, T_world_wrist, joints, jacobians=False):
        p, R = T_world_wrist[..., :3, 3], T_world_wrist[..., :3, :3]
        rows = [k * (joints[..., i] - w) for i, k, w in self.joint_rows]
        margins = np.concatenate(
            [p @ self.normals.T - self.offsets, np.stack(rows, -1) if rows else p[..., :0]], -1
        )
        if not jacobians:
            return margins
        batch = margins.shape[:-1]
        H_W, H_J = np.zeros(batch + (self.dim, 6)), np.zeros(batch + (self.dim, 13))
        H_W[..., : len(self.normals), 3:] = self.normals @ R  # a body twist v moves p by R v
        for r, (i, k, _) in enumerate(self.joint_rows):
            H_J[..., len(self.normals) + r, i] = k
        return margins, np.zeros(batch + (self.dim, 6)), H_W, H_J


@pytest.fixture(scope="session")
def planes():
    """The toy clearance class :class:`_Planes`."""
    return _Planes


@pytest.fixture(scope="session")
def ep_exact():
    """Variation parameters under which the joint-limit sites are exact: steps independent (no smoothness
    coupling), no joint floor, a tight tolerance."""
    from inference.params import VariationParams

    return VariationParams(
        sigma_m_std_config=[0.02] * 6 + list(np.linspace(0.02, 0.08, 13)),
        smoothness_std_config=[1e3] * 19,  # steps independent: one site per joint and step, EP exact
        joint_floor_std_deg=0.0,
        joint_limit_tolerance=1e-12,
        joint_limit_max_iterations=500,
    )


@pytest.fixture(scope="session")
def independent_joints_traj():
    """``independent_joints_traj(make_traj, joints, n=2)``: n steps at the joint values ``joints`` (13,),
    no retargeting covariance; with ``ep_exact`` every joint's f_1t is an independent N(joints_i,
    sigma_i^2)."""
    import dataclasses

    def traj(make_traj, joints, n=2):
        plain = make_traj(n=n, coupled=False, seed=3)
        return dataclasses.replace(plain, joints=np.tile(joints, (n, 1)), cov_retarget=np.zeros((n, 19, 19)))

    return traj
