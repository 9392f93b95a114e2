"""The variation model's factor graph (paper section V): its keys, its factors' covariances, the graph and
its starting point.

The graph is P(O) P(X_1..X_T | O): an SE(3) prior O ~ N(mu_o, Sigma_o) (``PriorFactorPose3``), per step
the demonstration factor f_1t tying (O, W_t, J_t) to tau_r(t) with Sigma_r(t) + Sigma_m(t), the
smoothness factors f_2t between consecutive steps and, for the steps in ``constrained``, the clearance
factor f_3t/f_4t (:func:`inference.factors.clearance_factor`). With ``fixed_object`` the object is
held at mu_o: the graph of P(X | O = mu_o), whose ``gtsam.Marginals`` are the conditional marginals
(equal to the Schur complement of the full graph's joint covariance; tests compare both). Variables:
``W_t`` wrist pose in the world frame (``Pose3``), ``J_t`` the 13 joints (vector)
(no constraint variables: the clearance factor is the paper's f_3t/f_4t pair with C_t marginalized out).
"""

from __future__ import annotations

import gtsam
import numpy as np

from assets.errors import InputError
from retarget.trajectory import Trajectory

from .clearance import ClearanceFn
from .factors import (
    FingertipMap,
    clearance_factors,
    demonstration_factors,
    modeling_covariance,
    smoothness_factors,
)
from .params import VariationParams

__all__ = [
    "key_o",
    "key_w",
    "key_j",
    "configuration_weights",
    "factor_covariances",
    "build_graph",
    "initial_values",
    "means_of",
]


def key_o() -> int:
    """GTSAM key of the object pose O."""
    return gtsam.symbol("o", 0)


def key_w(t: int) -> int:
    """GTSAM key of the wrist pose W_t (world frame)."""
    return gtsam.symbol("w", t)


def key_j(t: int) -> int:
    """GTSAM key of the joints J_t."""
    return gtsam.symbol("j", t)


def configuration_weights(
    traj: Trajectory,
    params: VariationParams,
    clearance: ClearanceFn | None,
    T_world_object: np.ndarray,
) -> np.ndarray:
    """(T,) the scene's weight in [0, 1]: of the ``configuration`` map in Sigma_m(t) for ``fingertip_cov_map:
    by_scene`` (:mod:`inference.params`): ``clip(-m_t / by_scene_depth_mm, 0, 1)``, then the largest over
    ``by_scene_steps`` steps either side, with ``m_t`` [m] the smallest margin of tau_r(t) placed at
    ``T_world_object`` to the table and the obstacles (``clearance.environment_only()`` where the
    clearance has it, else all its rows). Zeros without a clearance."""
    n = traj.num_steps
    if clearance is None:
        return np.zeros(n)
    environment = getattr(clearance, "environment_only", None)
    margins_of = environment() if environment is not None else clearance
    T_world_object = np.asarray(T_world_object, dtype=float)
    margins = margins_of(T_world_object, T_world_object @ traj.T_object_wrist, np.asarray(traj.joints))
    m = margins.min(axis=-1) if margins.shape[-1] else np.full(n, np.inf)
    weight = np.clip(-m / (params.by_scene_depth_mm * 1e-3), 0.0, 1.0)
    k = params.by_scene_steps
    return np.array([weight[max(0, t - k) : t + k + 1].max() for t in range(n)])


def factor_covariances(
    traj: Trajectory,
    params: VariationParams,
    fingertip_map: FingertipMap | None = None,
    configuration_weight: np.ndarray | None = None,
) -> np.ndarray:
    """Sigma_r(t) + Sigma_m(t) (T, 19, 19), checked positive definite; ``configuration_weight`` (T,) as
    :func:`inference.factors.modeling_covariance`'s (``by_scene``: :func:`configuration_weights`).

    Raises:
        InputError: the sum is not positive definite at some step (raise ``joint_floor_std_deg``).
    """
    cov = np.asarray(traj.cov_retarget) + modeling_covariance(
        traj.T_object_wrist, traj.joints, traj.grasp_type, params, fingertip_map, configuration_weight
    )
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    eig_min = np.linalg.eigvalsh(cov).min(axis=-1)
    if not np.all(eig_min > 0):
        t = int(np.argmin(eig_min))
        raise InputError(
            f"Sigma_r + Sigma_m at step {t} is not positive definite (smallest eigenvalue "
            f"{eig_min[t]:.3g}); raise joint_floor_std_deg or give sigma_m_std_config"
        )
    return cov


def build_graph(
    traj: Trajectory,
    params: VariationParams,
    cov_f1: np.ndarray,
    T_world_object: np.ndarray,
    cov_object: np.ndarray | None,
    clearance: ClearanceFn | None = None,
    constrained=(),
    fixed_object: bool = False,
) -> gtsam.NonlinearFactorGraph:
    """The factor graph P(O) P(X_1..X_T | O) (and the clearance factors of the ``constrained`` steps).

    Args:
        traj: tau_r and Sigma_r.
        params: parameters (smoothness, constraint noise).
        cov_f1: (T, 19, 19) Sigma_r + Sigma_m (:func:`factor_covariances`).
        T_world_object: (4, 4) mu_o. cov_object: (6, 6) Sigma_o ``[omega, v]``.
        clearance: the margins of the clearance factors; constrained: the steps that get one.
        fixed_object: hold O fixed at ``T_world_object`` (the graph of P(X | O = mu_o); no O variable, no
            prior, ``cov_object`` unused).
    """
    graph = gtsam.NonlinearFactorGraph()
    T_world_object = np.asarray(T_world_object, dtype=float)
    if not fixed_object:
        graph.add(
            gtsam.PriorFactorPose3(
                key_o(),
                gtsam.Pose3(T_world_object),
                gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov_object, dtype=float)),
            )
        )
    stds = params.smoothness_stds()
    n = traj.num_steps
    for t in range(n):
        for f in demonstration_factors(
            key_o(),
            key_w(t),
            key_j(t),
            traj.T_object_wrist[t],
            traj.joints[t],
            cov_f1[t],
            T_world_object if fixed_object else None,
        ):
            graph.add(f)
        if t + 1 < n:
            for f in smoothness_factors(key_w(t), key_w(t + 1), key_j(t), key_j(t + 1), stds):
                graph.add(f)
    std_m = params.constraint_std_mm * 1e-3
    steps = [(key_w(t), key_j(t)) for t in constrained]
    if steps:
        fixed = T_world_object if fixed_object else None
        smoothing_m = params.hinge_smoothing_mm * 1e-3
        for f in clearance_factors(key_o(), steps, clearance, std_m, smoothing_m, fixed):
            graph.add(f)
    return graph


def initial_values(traj: Trajectory, T_world_object: np.ndarray, fixed_object: bool = False) -> gtsam.Values:
    """The starting point ``O = mu_o, W_t = mu_o tau_r(t), J_t = joints_r(t)`` (no O if ``fixed_object``)."""
    values = gtsam.Values()
    if not fixed_object:
        values.insert(key_o(), gtsam.Pose3(T_world_object))
    T_world_wrist = T_world_object @ traj.T_object_wrist
    for t in range(traj.num_steps):
        values.insert(key_w(t), gtsam.Pose3(T_world_wrist[t]))
        values.insert(key_j(t), np.array(traj.joints[t]))
    return values


def means_of(values: gtsam.Values, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The wrist poses W_t (T, 4, 4), world frame, and the joints J_t (T, 13) [rad] held by ``values``."""
    W = np.stack([values.atPose3(key_w(t)).matrix() for t in range(n)])
    J = np.stack([values.atVector(key_j(t)) for t in range(n)])
    return W, J
