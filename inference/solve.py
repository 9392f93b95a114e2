"""Solve the variation model in a scene: its clearance factors, the joint limits held, and the marginals
P(X_t | O = mu_o) (paper sections V-VI).

Constraints: a clearance function (:mod:`inference.clearance`) gives the margins of the hand at
``(mu_o, W_t, J_t)``; every step gets a clearance factor (:func:`inference.factors.clearance_factors`, a
smooth hinge with std ``constraint_std_mm``; its rows act only where a margin is near or below zero). The
graph is solved by GTSAM's Levenberg-Marquardt, which relinearizes every factor at each iteration, until
the relative decrease of the error is below ``relative_error_tolerance`` (GTSAM's ``checkConvergence``)
or ``max_iterations`` iterations. The joint limits then go to their expectation-propagation fixed point
(:mod:`inference.joint_limits`), each update followed by a warm-started solve; the solves ahead of an
update stop at the looser ``site_solve_tolerance`` (the sites move the optimum anyway), the one after the
last update goes on to ``relative_error_tolerance``, and the marginals are taken at that point. With
``params.clearance_sites`` (off by default) the clearance rows get expectation-propagation sites in the
same loop (:mod:`inference.clearance_sites`), so that the marginals, not only the means, clear the scene.
What each choice changed when measured is in docs/method.md.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

import gtsam
import numpy as np

from assets.io import require_finite, require_rotation, require_shape, require_spd
from assets.se3 import se3_inverse
from retarget.trajectory import Trajectory

from .clearance import ClearanceFn
from .clearance_sites import ClearanceSites
from .contact import contact_factors, contact_plan
from .factors import FingertipMap
from .graph import (
    build_graph,
    configuration_weights,
    factor_covariances,
    initial_values,
    key_j,
    key_o,
    key_w,
    means_of,
)
from .joint_limits import JointLimitSites
from .model import VariationModel
from .params import VariationParams
from .sweep import backward_sweep, penetrating_steps

__all__ = ["solve", "optimize", "conditional_marginals"]

log = logging.getLogger(__name__)


def solve(
    traj: Trajectory,
    params: VariationParams | None = None,
    *,
    T_world_object: np.ndarray | None = None,
    cov_object: np.ndarray | None = None,
    clearance: ClearanceFn | None = None,
    fingertip_map: FingertipMap | None = None,
    joint_limits: np.ndarray | None = None,
    on_iteration: Callable[[float], None] | None = None,
    demonstrated: ClearanceFn | None = None,
) -> VariationModel:
    """Build the graph, solve it, and return the marginals P(X_t | O) as a :class:`VariationModel`.

    Args:
        traj: the retargeted trajectory tau_r with Sigma_r(t).
        params: defaults if None.
        T_world_object, cov_object: the object prior (4, 4), (6, 6) ``[omega, v]``; the trajectory's if None.
        clearance: the clearance margins of the scene (:class:`inference.clearance.HandClearance`); None
            for no clearance factors.
        fingertip_map: the Sigma_m mapping of :func:`inference.factors.modeling_covariance`.
        joint_limits: (13, 2) lower and upper joint limits [rad] (the SAH's: ``assets.sah.JOINT_LIMITS``),
            held by expectation propagation (:mod:`inference.joint_limits`); None: none, and the means may
            leave the limits.
        on_iteration: called after every optimizer iteration with the graph's error (progress reports).
        demonstrated: ``clearance`` with the trajectory's own object in place of the scene's, where the
            scene grasps another object: the held contacts are the demonstrated ones
            (:func:`inference.contact.contact_plan`).

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
    scene_weight = None  # by_scene: the scene chooses Sigma_m's map per step (params.py); zeros without one
    if params.fingertip_cov_map == "by_scene":
        scene_weight = configuration_weights(traj, params, clearance, mu_o)
    cov_f1 = factor_covariances(traj, params, fingertip_map, scene_weight)
    sites = JointLimitSites(joint_limits, n, params)
    clearance_sites = ClearanceSites(clearance, n, mu_o, params)
    constrained = range(n) if clearance is not None else ()

    base = build_graph(traj, params, cov_f1, mu_o, None, clearance, constrained, fixed_object=True)
    contacts = contact_plan(traj, params, clearance, mu_o, demonstrated)
    if contacts is not None:  # the demonstrated contacts held at the grasp (inference.contact)
        for f in contact_factors(contacts, key_o(), [(key_w(t), key_j(t)) for t in range(n)], mu_o):
            base.add(f)
        log.info("solve: %d contact rows on %d steps", contacts.num_rows, len(contacts.steps))

    def graph_at() -> gtsam.NonlinearFactorGraph:  # the same factors (and their clearance cache) + the sites
        return clearance_sites.add_to(sites.add_to(gtsam.NonlinearFactorGraph(base)))

    values = initial_values(traj, mu_o, fixed_object=True)
    graph = graph_at()
    ep = bool(sites or clearance_sites)
    # ahead of expectation propagation the solves stop at the looser tolerance; the last one goes on
    loose = max(params.relative_error_tolerance, params.site_solve_tolerance) if ep else None
    values, iterations, converged = optimize(
        graph, values, params, on_iteration=on_iteration, tolerance=loose
    )
    stuck = None
    if clearance is not None and params.backward_sweep:
        stuck = penetrating_steps(clearance, mu_o, values, n)
    if stuck is not None and stuck.any():  # a start from the grasp backwards (inference.sweep)
        sweep_start = backward_sweep(traj, params, cov_f1, mu_o, clearance, values)
        swept, its, swept_converged = optimize(
            graph, sweep_start, params, on_iteration=on_iteration, tolerance=loose
        )
        iterations += its
        fewer = int(penetrating_steps(clearance, mu_o, swept, n).sum())
        log.info("solve: %d steps penetrate from tau_r, %d from the backward sweep", stuck.sum(), fewer)
        if fewer < stuck.sum():
            values, converged = swept, swept_converged
    if ep:  # expectation propagation, each update followed by a warm-started solve
        settled = False
        for _ in range(params.joint_limit_max_iterations):
            change_j = change_c = 0.0
            if clearance_sites:
                covs = _step_covariances(graph, values, n)
                change_c = clearance_sites.update(values, covs)
                if sites:
                    change_j = sites.update(graph, values, covs[:, np.arange(6, 19), np.arange(6, 19)])
            else:
                change_j = sites.update(graph, values)
            graph = graph_at()
            values, its, converged = optimize(
                graph, values, params, warm=True, on_iteration=on_iteration, tolerance=loose
            )
            iterations += its
            settled = change_j < params.joint_limit_tolerance and change_c < params.clearance_site_tolerance
            if settled:
                break
        if not settled:
            log.warning(
                "expectation propagation did not converge in %d updates", params.joint_limit_max_iterations
            )
        loose_converged = converged
        values, its, converged = optimize(graph, values, params, warm=True, on_iteration=on_iteration)
        iterations += its
        converged = converged and loose_converged and settled
    if not converged:
        log.warning("the variation model's solve did not converge (%d iterations)", iterations)

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
        constrained=np.isin(np.arange(n), list(constrained)) | sites.steps() | clearance_sites.steps(),
        source=traj,
        solve_time_s=time.perf_counter() - start,
    )


def optimize(
    graph: gtsam.NonlinearFactorGraph,
    values: gtsam.Values,
    params: VariationParams,
    warm: bool = False,
    on_iteration: Callable[[float], None] | None = None,
    tolerance: float | None = None,
) -> tuple[gtsam.Values, int, bool]:
    """GTSAM's Levenberg-Marquardt from ``values`` until the relative decrease of the error is below
    ``tolerance`` (default ``params.relative_error_tolerance``; or the error is zero).

    With ``warm`` (a start next to the solution, after a joint-limit site update) Gauss-Newton steps are
    tried first, one error evaluation each; one that increases the error by more than the tolerance hands
    over to Levenberg-Marquardt from the point before it.

    Returns:
        The solution, the iterations taken and whether it converged within ``params.max_iterations``.
    """
    report = on_iteration or (lambda _error: None)
    tol = params.relative_error_tolerance if tolerance is None else tolerance
    iterations = 0
    if warm:
        gn = gtsam.GaussNewtonOptimizer(graph, values, gtsam.GaussNewtonParams())
        error = gn.error()
        while iterations < params.max_iterations:
            previous = gtsam.Values(gn.values())  # a copy: the optimizer replaces its own
            gn.iterate()
            iterations += 1
            new_error = gn.error()
            report(new_error)
            if not new_error <= error:  # an increase (or NaN): back to the last point
                if new_error - error <= tol * error:
                    return previous, iterations, True  # at the minimum, up to the tolerance
                values = previous  # LM from there
                break
            if gtsam.checkConvergence(tol, 0.0, 0.0, error, new_error):
                return gtsam.Values(gn.values()), iterations, True
            error, values = new_error, gtsam.Values(gn.values())
    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(params.max_iterations)
    lm.setRelativeErrorTol(tol)
    lm.setAbsoluteErrorTol(0.0)
    lm.setErrorTol(0.0)
    lm.setUseFixedLambdaFactor(False)  # Nielsen's lambda update: 30-40 % fewer error evaluations here
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, values, lm)
    error = optimizer.error()
    while iterations < params.max_iterations:
        optimizer.iterate()
        iterations += 1
        new_error = optimizer.error()
        report(new_error)
        if gtsam.checkConvergence(tol, 0.0, 0.0, error, new_error):
            return optimizer.values(), iterations, True
        error = new_error
    return optimizer.values(), iterations, False


def conditional_marginals(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, mu_o: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P(X_t | O = mu_o) from the solved graph with O fixed (``build_graph(..., fixed_object=True)``).

    Returns:
        ``T_object_wrist`` (T, 4, 4) wrist means in the object frame, ``joints`` (T, 13) [rad] and ``cov``
        (T, 19, 19) ``[omega, v, joints]`` (the body-frame covariance is unchanged by the change of frame).
    """
    cov = _step_covariances(graph, values, n)
    W, J = means_of(values, n)
    return se3_inverse(mu_o) @ W, J, cov


def _step_covariances(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, n: int) -> np.ndarray:
    """(T, 19, 19) the marginal covariances of ``(W_t, J_t)``, ``[omega, v, joints]``, symmetrized."""
    marginals = gtsam.Marginals(graph, values)
    cov = np.stack([marginals.jointMarginalCovariance([key_w(t), key_j(t)]).fullMatrix() for t in range(n)])
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))
