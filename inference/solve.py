"""Solve the variation model in a scene: its constraint factors relinearized, the joint limits held, and the
marginals P(X_t | O = mu_o) (paper sections V-VI).

Constraints: ``phi = constraint_fn(T_world_wrist (4, 4), joints (13,))``, a scalar or a vector (e.g. the
signed distance of each hand link to the table and obstacles [m]), is evaluated at ``mu_o tau_r(t)``; its
components below ``activation_distance`` are active. A step with active components gets a vector
variable ``C_t``, a factor ``C_t = phi0 + G dx`` (the active rows of phi linearized at the current
estimate, by central differences or by a given ``constraint_gradient_fn``; variance
``constraint_delta_variance``) and a prior ``N(r_t, R_t)`` with ``r_t = phi(mu_o tau_r(t))`` clipped to
``[clearance, activation_distance]`` and ``R_t = constraint_std^2 I``; the clearance may differ per
component (``constraint_clearance_mm``).

Relinearization: linearize, solve by Gauss-Newton with a trust region (priors ``N(x0, trust_stds)`` tying
each constrained step to its linearization point ``x0``), move the linearization point by
``relinearization_damping`` of the way to the new means, and repeat until they move less than
``mean_tolerance`` (max-norm over all steps of the tangent change [rad, m]) or ``max_iterations`` solves.
Components that come below the activation distance on the way join the active set (it only grows, and a
grown set is solved once more before convergence is declared). The final solve drops the trust region, so
that the marginals are those of the paper's graph; the joint limits then go to their EP fixed point
(:mod:`inference.joint_limits`). Why each of these is there, and what it changed when measured, is in
docs/method.md.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import gtsam
import numpy as np

from assets.errors import InputError
from assets.io import require_finite, require_rotation, require_shape, require_spd
from assets.q_layout import JOINTS, Q_DIM, TAN_POSE
from assets.se3 import local, retract, se3_inverse
from retarget.trajectory import Trajectory

from .factors import ConstraintFn, ConstraintGradientFn, FingertipMap, constraint_gradient
from .graph import build_graph, factor_covariances, initial_values, key_c, key_j, key_w, means_of
from .joint_limits import JointLimitSites
from .model import VariationModel
from .params import VariationParams

__all__ = ["solve", "conditional_marginals"]

log = logging.getLogger(__name__)


def solve(
    traj: Trajectory,
    params: VariationParams | None = None,
    *,
    T_world_object: np.ndarray | None = None,
    cov_object: np.ndarray | None = None,
    constraint_fn: ConstraintFn | None = None,
    fingertip_map: FingertipMap | None = None,
    constraint_clearance_mm: float | Sequence[float] | None = None,
    constraint_gradient_fn: ConstraintGradientFn | None = None,
    joint_limits: np.ndarray | None = None,
) -> VariationModel:
    """Build the graph, solve it, and return the marginals P(X_t | O) as a :class:`VariationModel`.

    Args:
        traj: the retargeted trajectory tau_r with Sigma_r(t).
        params: defaults if None.
        T_world_object, cov_object: the object prior (4, 4), (6, 6) ``[omega, v]``; the trajectory's if None.
        constraint_fn: ``phi(T_world_wrist (4,4), joints (13,)) -> float or (m,)`` (e.g. signed distances
            [m]); None for no constraint factors.
        fingertip_map: the Sigma_m mapping of :func:`inference.factors.modeling_covariance`.
        constraint_clearance_mm: the clearance of each component of phi [mm] (a number for all, or one per
            component); default ``params.clearance_mm`` for all.
        constraint_gradient_fn: ``(T_world_wrist, joints) -> (phi (m,), grad (m, 19))``, the same phi with
            its gradient (e.g. from the contact normals); default central differences of ``constraint_fn``
            (``params.gradient_step``), 2 x 19 more evaluations of phi per constrained step.
        joint_limits: (13, 2) lower and upper joint limits [rad] (the SAH's: ``assets.sah.JOINT_LIMITS``),
            held by expectation propagation (:mod:`inference.joint_limits`); None: none, and the means may
            leave the limits.

    Raises:
        InputError: invalid object prior or a covariance that is not positive definite.
    """
    start = time.perf_counter()
    params = params or VariationParams()
    mu_o = traj.T_world_object_mean if T_world_object is None else T_world_object
    mu_o = require_finite("T_world_object", require_shape("T_world_object", mu_o, (4, 4)))
    require_rotation("T_world_object", mu_o[:3, :3])
    cov_o = traj.cov_object if cov_object is None else cov_object
    cov_o = require_spd("cov_object", require_shape("cov_object", cov_o, (6, 6)))
    n = traj.num_steps
    cov_f1 = factor_covariances(traj, params, fingertip_map)

    # constrained components per step: phi_i below the activation distance at tau_r or, as the means move,
    # at any linearization point (the active set only grows); targets r_i = phi_i(tau_r) clipped to
    # [clearance, activation]: keep the demonstrated distance, but at least the clearance
    act_m = params.activation_distance_mm * 1e-3
    clear_mm = params.clearance_mm if constraint_clearance_mm is None else constraint_clearance_mm
    clear_m = 1e-3 * np.asarray(clear_mm, dtype=float)
    if clear_m.ndim > 1 or not np.all(np.isfinite(clear_m)) or np.any(clear_m < 0):
        raise InputError(f"constraint_clearance_mm: expected finite numbers >= 0, found {clear_mm!r}")
    active: dict[int, np.ndarray] = {}
    phi_tau: list[np.ndarray] = []
    if constraint_fn is not None:
        T_world_wrist_tau = mu_o @ traj.T_object_wrist
        phi_tau = [
            _constraint_values(constraint_fn, T_world_wrist_tau[t], traj.joints[t], t) for t in range(n)
        ]
        if clear_m.ndim == 1 and clear_m.shape != phi_tau[0].shape:
            raise InputError(
                f"constraint_clearance_mm: {clear_m.size} clearances for {phi_tau[0].size} "
                "constraint components"
            )
        _grow_active(active, phi_tau, act_m)
    sites = JointLimitSites(joint_limits, n, params)

    def graph_at(lin: dict) -> gtsam.NonlinearFactorGraph:
        """P(X | O = mu_o) with the constraint factors linearized as in ``lin`` and the joint-limit sites."""
        return sites.add_to(build_graph(traj, params, cov_f1, mu_o, None, lin, fixed_object=True))

    values = initial_values(traj, mu_o, fixed_object=True)
    W_prev, J_prev = means_of(values, n)
    gn = gtsam.GaussNewtonParams()
    gn.setMaxIterations(params.gauss_newton_max_iterations)
    gn.setRelativeErrorTol(params.gauss_newton_relative_tolerance)
    gn.setAbsoluteErrorTol(0.0)
    iterations, converged = 0, not active
    grew = False
    lin: dict = {}
    for iterations in range(1, (params.max_iterations if active else 1) + 1):
        lin = {}
        for t, mask in active.items():
            if constraint_gradient_fn is None:
                phi0, grad = constraint_gradient(constraint_fn, W_prev[t], J_prev[t], params.gradient_step)
            else:
                phi0, grad = _constraint_gradient_values(constraint_gradient_fn, W_prev[t], J_prev[t], t)
            phi0, grad = np.atleast_1d(phi0)[mask], np.atleast_2d(grad)[mask]
            clear_t = np.broadcast_to(clear_m, mask.shape)[mask]
            r_t = np.clip(phi_tau[t][mask], clear_t, np.maximum(act_m, clear_t))
            lin[t] = (W_prev[t], J_prev[t], phi0, grad, r_t)
            if values.exists(key_c(t)):
                values.erase(key_c(t))  # its dimension grows with the active set
            values.insert(key_c(t), phi0)
        graph = graph_at(lin)
        if active:
            graph = _with_trust_region(graph, lin, params.trust_stds())
        values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
        W_new, J_new = means_of(values, n)
        if sites and active:  # one EP step per relinearization keeps the linearization points in the limits
            sites.update(graph, values)
        if active:
            dW = local(W_prev, W_new)
            moves = np.abs(np.concatenate([dW, J_new - J_prev], axis=1))  # (T, 19) [omega, v, joints]
            move = float(moves.max())
            if log.isEnabledFor(logging.DEBUG):
                t_max, i_max = np.unravel_index(int(np.argmax(moves)), moves.shape)
                log.debug("relinearization %d: means moved %.3g (step %d, tangent coordinate %d), %d "
                          "constraints", iterations, move, t_max, i_max,
                          sum(int(m.sum()) for m in active.values()))  # fmt: skip
            # damped update of the linearization point (damped loopy belief propagation): the closest-point
            # distances change their witness points, and undamped relinearization oscillates between them
            a = params.relinearization_damping
            W_prev, J_prev = retract(W_prev, a * dW), J_prev + a * (J_new - J_prev)
            if move < params.mean_tolerance and not grew:
                converged = True
                break
            phi_now = [_constraint_values(constraint_fn, W_prev[t], J_prev[t], t) for t in range(n)]
            grew = _grow_active(active, phi_now, act_m)
    if active:  # the final solve without the trust region, at the last linearization point
        graph = graph_at(lin)
        values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
    if not converged:
        log.warning("constraint relinearization did not converge in %d iterations", iterations)
    if sites:  # expectation propagation of the joint limits on the final graph, to its fixed point
        for _ in range(params.joint_limit_max_iterations):
            change = sites.update(graph, values)
            graph = graph_at(lin)
            values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
            if change < params.joint_limit_tolerance:
                break
        else:
            converged = False
            log.warning(
                "joint-limit propagation did not converge in %d iterations", params.joint_limit_max_iterations
            )

    T_object_wrist, joints, cov = conditional_marginals(graph, values, mu_o, n)
    return VariationModel(
        T_object_wrist_mean=T_object_wrist,
        joints_mean=joints,
        cov=cov,
        T_world_object_mean=mu_o,
        cov_object=cov_o,
        params=params,
        iterations=iterations,
        grasp_type=traj.grasp_type,
        object=traj.object,
        converged=converged,
        constrained=np.isin(np.arange(n), list(active)) | sites.steps(),
        source=traj,
        solve_time_s=time.perf_counter() - start,
    )


def _with_trust_region(
    graph: gtsam.NonlinearFactorGraph, linearizations: dict, stds: np.ndarray
) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with priors tying each constrained step to its linearization point."""
    out = gtsam.NonlinearFactorGraph(graph)
    wrist = gtsam.noiseModel.Diagonal.Sigmas(stds[TAN_POSE])
    joints = gtsam.noiseModel.Diagonal.Sigmas(stds[JOINTS])
    for t, (W0, J0, *_rest) in linearizations.items():
        out.add(gtsam.PriorFactorPose3(key_w(t), gtsam.Pose3(np.asarray(W0, dtype=float)), wrist))
        out.add(gtsam.PriorFactorVector(key_j(t), np.asarray(J0, dtype=float), joints))
    return out


def _constraint_values(constraint_fn: ConstraintFn, T_world_wrist: np.ndarray, joints: np.ndarray, t: int):
    phi = np.atleast_1d(np.asarray(constraint_fn(T_world_wrist, np.array(joints)), dtype=float))
    if phi.ndim != 1 or not np.all(np.isfinite(phi)):
        raise InputError(f"constraint function returned {phi.tolist()} at step {t}: expected finite values")
    return phi


def _constraint_gradient_values(
    gradient_fn: ConstraintGradientFn, T_world_wrist: np.ndarray, joints: np.ndarray, t: int
) -> tuple[np.ndarray, np.ndarray]:
    phi, grad = gradient_fn(T_world_wrist, np.array(joints))
    phi, grad = np.atleast_1d(np.asarray(phi, dtype=float)), np.atleast_2d(np.asarray(grad, dtype=float))
    if phi.ndim != 1 or grad.shape != (phi.size, Q_DIM):
        raise InputError(
            f"constraint gradient function at step {t}: expected phi (m,) and grad (m, 19), found shapes "
            f"{phi.shape} and {grad.shape}"
        )
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(grad))):
        raise InputError(f"constraint gradient function returned a non-finite value at step {t}")
    return phi, grad


def _grow_active(active: dict[int, np.ndarray], phi: list[np.ndarray], activation: float) -> bool:
    """Add the components with ``phi < activation`` (a distance [m]) to ``active`` (step -> bool mask); True
    if any was new."""
    grew = False
    for t, values in enumerate(phi):
        below = values < activation
        old = active.get(t, np.zeros(len(values), dtype=bool))
        if np.any(below & ~old):
            active[t] = old | below
            grew = True
    return grew


def conditional_marginals(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, mu_o: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P(X_t | O = mu_o) from the solved graph with O fixed (``build_graph(..., fixed_object=True)``).

    Returns:
        ``T_object_wrist`` (T, 4, 4) wrist means in the object frame, ``joints`` (T, 13) [rad] and ``cov``
        (T, 19, 19) ``[omega, v, joints]`` (the body-frame covariance is unchanged by the change of frame).
    """
    marginals = gtsam.Marginals(graph, values)
    cov = np.stack([marginals.jointMarginalCovariance([key_w(t), key_j(t)]).fullMatrix() for t in range(n)])
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    W, J = means_of(values, n)
    return se3_inverse(mu_o) @ W, J, cov
