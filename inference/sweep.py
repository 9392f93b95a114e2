"""A collision-free start for the variation model's solve: each step reached from the one after it.

Levenberg-Marquardt from tau_r can stop with a link inside a thin obstacle: where tau_r passes a finger
through a wall, the spheres on either side of the wall's mid-plane are pushed out on opposite sides and the
solve ends between them (ham on an arc, step 48: the index finger 13-31 mm inside a 20 mm wall). The
backward sweep solves the last step alone (its f_1t and its clearance factor, from tau_r), then every
earlier step alone with the step after it held where the sweep put it (the smoothness factor f_2t as a
prior) and starting there, so a hand that is clear of the scene at the grasp leaves it the way it came,
its links pushed out of the obstacles from the side they are on. :func:`inference.solve.solve` solves the
whole graph again from this start when its first solution penetrates the scene and keeps it if it
penetrates at fewer steps.
"""

from __future__ import annotations

import gtsam
import numpy as np

from assets.q_layout import JOINTS, TAN_POSE
from retarget.trajectory import Trajectory

from .clearance import ClearanceFn
from .factors import clearance_factors, demonstration_factors
from .graph import key_j, key_o, key_w, means_of
from .params import VariationParams

__all__ = ["backward_sweep", "penetrating_steps"]


def backward_sweep(
    traj: Trajectory,
    params: VariationParams,
    cov_f1: np.ndarray,
    T_world_object: np.ndarray,
    clearance: ClearanceFn,
    start: gtsam.Values,
) -> gtsam.Values:
    """The sweep's values of ``W_t, J_t`` for every step (module docstring), the last step from ``start``.

    Args:
        traj: tau_r; cov_f1: (T, 19, 19) the f_1t covariances; T_world_object: (4, 4) O, held fixed.
        clearance: the margins of the clearance factors; start: values holding ``W_{T-1}, J_{T-1}``.
    """
    n = traj.num_steps
    smooth = params.smoothness_stds()
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(smooth[TAN_POSE])
    joint_noise = gtsam.noiseModel.Diagonal.Sigmas(smooth[JOINTS])
    std_m, smoothing_m = params.constraint_std_mm * 1e-3, params.hinge_smoothing_mm * 1e-3
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(params.max_iterations)
    lm.setRelativeErrorTol(params.relative_error_tolerance)
    lm.setAbsoluteErrorTol(0.0)
    out = gtsam.Values()
    W, J = start.atPose3(key_w(n - 1)), start.atVector(key_j(n - 1))
    for t in reversed(range(n)):
        kw, kj = key_w(t), key_j(t)
        graph = gtsam.NonlinearFactorGraph()
        for f in demonstration_factors(
            key_o(), kw, kj, traj.T_object_wrist[t], traj.joints[t], cov_f1[t], T_world_object
        ):
            graph.add(f)
        for f in clearance_factors(None, [(kw, kj)], clearance, std_m, smoothing_m, T_world_object):
            graph.add(f)
        if t + 1 < n:  # f_2t with the next step held: a prior at its pose and joints
            graph.add(gtsam.PriorFactorPose3(kw, W, pose_noise))
            graph.add(gtsam.PriorFactorVector(kj, J, joint_noise))
        values = gtsam.Values()
        values.insert(kw, W)
        values.insert(kj, J)
        values = gtsam.LevenbergMarquardtOptimizer(graph, values, lm).optimize()
        W, J = values.atPose3(kw), values.atVector(kj)
        out.insert(kw, W)
        out.insert(kj, J)
    return out


PENETRATION_M = 2e-3
"""A step whose spheres penetrate the scene or each other by more than this [m] counts as penetrating."""


def penetrating_steps(clearance: ClearanceFn, T_world_object: np.ndarray, values: gtsam.Values, n: int):
    """(T,) bool: the steps whose hand penetrates by more than :data:`PENETRATION_M` at ``values``
    (:meth:`inference.clearance.HandClearance.penetration`), or None for a clearance that cannot tell."""
    penetration = getattr(clearance, "penetration", None)
    if penetration is None:
        return None
    W, J = means_of(values, n)
    return penetration(T_world_object, W, J) < -PENETRATION_M
