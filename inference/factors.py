"""The factors of the variation model (paper section V) as pure error functions and GTSAM factors.

Variables: ``O`` (Pose3, object in world), ``W_t`` (Pose3, wrist in WORLD), ``J_t`` (13-vector, SAH joints),
and for constrained steps ``C_t`` (1-vector, the constraint value).

* f_1t, the demonstration factor over ``(O, W_t, J_t)`` (or ``(W_t, J_t)`` with O held fixed): error
  ``[Log(tau_r(t)^-1 O^-1 W_t), J_t - joints_r(t)]`` (19,), covariance ``Sigma_r(t) + Sigma_m(t)`` in
  ``[omega, v, joints]``. When the covariance couples wrist and joints it is one ``gtsam.CustomFactor`` with
  analytic Jacobians (:func:`demonstration_error`); when it is block diagonal it is GTSAM's own
  ``BetweenFactorPose3(O, W_t)`` plus ``PriorFactorVector(J_t)`` (same error, faster).
* f_2t, smoothness: ``BetweenFactorPose3(W_t, W_t+1, identity)`` and ``BetweenFactorVector(J_t, J_t+1, 0)``
  with the diagonal S_t of :meth:`VariationParams.smoothness_stds`.
* f_3t, the constraint ``C_t = phi(W_t, J_t)`` linearized at ``(W0, J0)``: error
  ``C_t - phi0 - G [Log(W0^-1 W_t), J_t - J0]`` with variance 1e-10 (the paper's stand-in for a delta);
  f_4t is a ``PriorFactorVector`` ``N(r_t, R_t)`` on ``C_t``. ``phi`` may be a vector (one signed distance
  per hand link), then ``C_t`` and ``r_t`` are vectors and ``G`` has one row per component.

Jacobians are with respect to GTSAM's right (body) perturbations ``T Exp(xi)``, ``xi = [omega, v]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import gtsam
import numpy as np

from assets.errors import InputError
from assets.q_layout import JOINTS, N_JOINTS, Q_DIM, TAN_POSE
from assets.se3 import retract

from .params import VariationParams

__all__ = [
    "demonstration_error",
    "demonstration_factors",
    "smoothness_factors",
    "linear_constraint_error",
    "constraint_factors",
    "constraint_gradient",
    "modeling_covariance",
    "is_block_diagonal",
]

FingertipMap = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
ConstraintFn = Callable[[np.ndarray, np.ndarray], "float | np.ndarray"]
ConstraintGradientFn = Callable[[np.ndarray, np.ndarray], "tuple[np.ndarray, np.ndarray]"]
"""``(T_world_wrist (4, 4), joints (13,)) -> (phi (m,), grad (m, 19))``, grad in the tangent of
:func:`constraint_gradient`: an analytic alternative to its central differences."""


def demonstration_error(
    O: gtsam.Pose3,
    W: gtsam.Pose3,
    J: np.ndarray,
    tau: gtsam.Pose3,
    joints_r: np.ndarray,
    jacobians: bool = False,
):
    """The f_1t error ``[Log(tau^-1 O^-1 W), J - joints_r]`` (19,) and optionally its Jacobians.

    With ``Z = tau^-1 O^-1 W`` and ``e = Log(Z)``: ``dE/dW = Jr^-1(e)`` and, since
    ``(O Exp(d))^-1 W = O^-1 W Exp(-Ad_{W^-1 O} d)``, ``dE/dO = -Jr^-1(e) Ad_{W^-1 O}``; ``dE/dJ = I``.

    Returns:
        ``e`` (19,), or ``(e, H_O (19, 6), H_W (19, 6), H_J (19, 13))`` with ``jacobians=True``.
    """
    O_inv_W = O.between(W)
    Z = tau.between(O_inv_W)
    e = np.concatenate([gtsam.Pose3.Logmap(Z), np.asarray(J, dtype=float) - joints_r])
    if not jacobians:
        return e
    Jr_inv = gtsam.Pose3.LogmapDerivative(Z)
    H_O = np.zeros((Q_DIM, 6), order="F")
    H_W = np.zeros((Q_DIM, 6), order="F")
    H_J = np.zeros((Q_DIM, N_JOINTS), order="F")
    H_W[TAN_POSE] = Jr_inv
    H_O[TAN_POSE] = -Jr_inv @ O_inv_W.inverse().AdjointMap()
    H_J[JOINTS] = np.eye(N_JOINTS)
    return e, H_O, H_W, H_J


def is_block_diagonal(cov: np.ndarray, rtol: float = 1e-12) -> bool:
    """True when the wrist-joint block of a 19x19 covariance is zero (relative to its largest entry)."""
    cov = np.asarray(cov)
    return bool(np.max(np.abs(cov[..., :6, 6:])) <= rtol * np.max(np.abs(cov)))


def demonstration_factors(
    key_o: int | None,
    key_w: int,
    key_j: int,
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    cov: np.ndarray,
    T_world_object: np.ndarray | None = None,
) -> list:
    """f_1t for one step: GTSAM factors tying ``(O, W_t, J_t)`` to ``tau_r(t)``.

    Args:
        key_o, key_w, key_j: GTSAM keys of O, W_t, J_t; ``key_o`` is unused when O is fixed.
        T_object_wrist: (4, 4) tau_r(t), the wrist in the object frame.
        joints: (13,) joints_r(t) [rad].
        cov: (19, 19) Sigma_r(t) + Sigma_m(t), ``[omega, v, joints]``, positive definite.
        T_world_object: (4, 4) if given, O is held fixed at this pose (the graph is conditioned on O) and
            the factor is unary in ``(W_t, J_t)`` with error ``[Log((O tau)^-1 W_t), J_t - joints_r]``.

    Returns:
        ``[CustomFactor]`` if ``cov`` couples wrist and joints, else GTSAM's own
        ``[BetweenFactorPose3 (O, W_t) or PriorFactorPose3 (W_t), PriorFactorVector (J_t)]``.
    """
    tau = gtsam.Pose3(np.asarray(T_object_wrist, dtype=float))
    joints_r = np.array(joints, dtype=float)
    cov = np.asarray(cov, dtype=float)
    fixed = T_world_object is not None
    P = gtsam.Pose3(np.asarray(T_world_object, dtype=float) @ tau.matrix()) if fixed else None
    if is_block_diagonal(cov):
        pose_noise = gtsam.noiseModel.Gaussian.Covariance(cov[:6, :6])
        pose = (
            gtsam.PriorFactorPose3(key_w, P, pose_noise)
            if fixed
            else gtsam.BetweenFactorPose3(key_o, key_w, tau, pose_noise)
        )
        return [
            pose,
            gtsam.PriorFactorVector(key_j, joints_r, gtsam.noiseModel.Gaussian.Covariance(cov[6:, 6:])),
        ]
    noise = gtsam.noiseModel.Gaussian.Covariance(cov)
    if fixed:
        H_J = np.zeros((Q_DIM, N_JOINTS), order="F")
        H_J[JOINTS] = np.eye(N_JOINTS)

        def error_fixed(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
            Z = P.between(values.atPose3(key_w))
            e = np.empty(Q_DIM)
            e[JOINTS] = values.atVector(key_j) - joints_r
            if H is None:
                e[TAN_POSE] = gtsam.Pose3.Logmap(Z)
                return e
            Jr_inv = np.zeros((6, 6), order="F")
            e[TAN_POSE] = gtsam.Pose3.Logmap(Z, Jr_inv)
            H_W = np.zeros((Q_DIM, 6), order="F")
            H_W[TAN_POSE] = Jr_inv
            H[0], H[1] = H_W, H_J
            return e

        return [gtsam.CustomFactor(noise, [key_w, key_j], error_fixed)]

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        O = values.atPose3(key_o)
        W = values.atPose3(key_w)
        J = values.atVector(key_j)
        if H is None:
            return demonstration_error(O, W, J, tau, joints_r)
        e, H[0], H[1], H[2] = demonstration_error(O, W, J, tau, joints_r, jacobians=True)
        return e

    return [gtsam.CustomFactor(noise, [key_o, key_w, key_j], error)]


def smoothness_factors(key_w0: int, key_w1: int, key_j0: int, key_j1: int, stds: np.ndarray) -> list:
    """f_2t: ``BetweenFactorPose3(W_t, W_t+1, I)`` and ``BetweenFactorVector(J_t, J_t+1, 0)``.

    Args:
        stds: (19,) S_t stds ``[omega (rad), v (m), joints (rad)]``.
    """
    stds = np.asarray(stds, dtype=float)
    return [
        gtsam.BetweenFactorPose3(
            key_w0, key_w1, gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(stds[TAN_POSE])
        ),
        gtsam.BetweenFactorVector(
            key_j0, key_j1, np.zeros(N_JOINTS), gtsam.noiseModel.Diagonal.Sigmas(stds[JOINTS])
        ),
    ]


def linear_constraint_error(
    C: np.ndarray,
    W: gtsam.Pose3,
    J: np.ndarray,
    W0: gtsam.Pose3,
    J0: np.ndarray,
    phi0,
    grad: np.ndarray,
    jacobians: bool = False,
):
    """f_3t error ``C - phi0 - G [Log(W0^-1 W), J - J0]`` (m,), optionally with Jacobians.

    ``phi0`` is a scalar or (m,) and ``grad`` (19,) or ``G`` (m, 19): one row per constraint (e.g. one per
    hand link near an obstacle).

    Returns:
        ``e`` (m,), or ``(e, H_C (m, m), H_W (m, 6), H_J (m, 13))``.
    """
    phi0 = np.atleast_1d(np.asarray(phi0, dtype=float))
    G = np.atleast_2d(np.asarray(grad, dtype=float))
    d = W0.between(W)
    xi = gtsam.Pose3.Logmap(d)
    e = np.asarray(C, dtype=float) - phi0 - G[:, TAN_POSE] @ xi - G[:, JOINTS] @ (np.asarray(J) - J0)
    if not jacobians:
        return e
    H_W = np.asfortranarray(-(G[:, TAN_POSE] @ gtsam.Pose3.LogmapDerivative(d)))
    return e, np.asfortranarray(np.eye(len(e))), H_W, np.asfortranarray(-G[:, JOINTS])


def constraint_factors(
    key_c: int,
    key_w: int,
    key_j: int,
    T_world_wrist0: np.ndarray,
    joints0: np.ndarray,
    phi0,
    grad: np.ndarray,
    r_t,
    R_std: float,
    delta_variance: float,
) -> list:
    """f_3t (linearized at ``(T_world_wrist0, joints0)``) and f_4t ``N(r_t, R_std^2 I)`` on ``C_t``.

    Args:
        phi0: the constraint value(s) at the linearization point, scalar or (m,).
        grad: (19,) or (m, 19) gradient(s) of phi in the tangent ``[omega, v, joints]`` there.
        r_t: the target(s), scalar or (m,); ``C_t`` is an m-vector.
    """
    W0 = gtsam.Pose3(np.asarray(T_world_wrist0, dtype=float))
    J0 = np.array(joints0, dtype=float)
    phi = np.atleast_1d(np.asarray(phi0, dtype=float))
    G = np.atleast_2d(np.asarray(grad, dtype=float))
    r = np.atleast_1d(np.asarray(r_t, dtype=float))
    m = len(phi)
    if G.shape != (m, Q_DIM) or r.shape != (m,):
        raise InputError(f"constraint factors: phi0 {phi.shape}, grad {G.shape} and r_t {r.shape} disagree")

    def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
        C = values.atVector(key_c)
        W = values.atPose3(key_w)
        J = values.atVector(key_j)
        if H is None:
            return linear_constraint_error(C, W, J, W0, J0, phi, G)
        e, H[0], H[1], H[2] = linear_constraint_error(C, W, J, W0, J0, phi, G, jacobians=True)
        return e

    delta = gtsam.noiseModel.Isotropic.Sigma(m, math.sqrt(delta_variance))
    return [
        gtsam.CustomFactor(delta, [key_c, key_w, key_j], error),
        gtsam.PriorFactorVector(key_c, r, gtsam.noiseModel.Isotropic.Sigma(m, R_std)),
    ]


def constraint_gradient(
    constraint_fn: ConstraintFn, T_world_wrist: np.ndarray, joints: np.ndarray, step: float
) -> tuple:
    """phi and its gradient in the tangent ``[omega, v, joints]`` by central differences.

    A scalar ``constraint_fn`` gives ``(phi0 float, grad (19,))``, a vector one (m,) gives
    ``(phi0 (m,), grad (m, 19))``. The wrist is perturbed on the right, ``T_world_wrist Exp(+-step e_i)``,
    as GTSAM's retract.
    """
    T = np.asarray(T_world_wrist, dtype=float)
    joints = np.asarray(joints, dtype=float)
    value = np.asarray(constraint_fn(T, joints), dtype=float)
    phi0 = np.atleast_1d(value)
    grad = np.zeros((len(phi0), Q_DIM))
    for i in range(Q_DIM):
        d = np.zeros(Q_DIM)
        d[i] = step
        plus = np.atleast_1d(
            np.asarray(constraint_fn(retract(T, d[TAN_POSE]), joints + d[JOINTS]), dtype=float)
        )
        minus = np.atleast_1d(
            np.asarray(constraint_fn(retract(T, -d[TAN_POSE]), joints - d[JOINTS]), dtype=float)
        )
        grad[:, i] = (plus - minus) / (2 * step)
    if not (np.all(np.isfinite(phi0)) and np.all(np.isfinite(grad))):
        raise InputError(f"constraint function returned a non-finite value (phi = {phi0.tolist()})")
    if value.ndim == 0:
        return float(phi0[0]), grad[0]
    return phi0, grad


def modeling_covariance(
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    grasp_type: str,
    params: VariationParams,
    fingertip_map: FingertipMap | None = None,
) -> np.ndarray:
    """Sigma_m(t) (T, 19, 19) in ``[omega, v, joints]``, with the joint floor added (paper section IV).

    Without ``params.sigma_m_std_config``: the isotropic fingertip covariance (12x12) is mapped to
    configuration space by ``fingertip_map`` (default: ``assets.sah.fingertip_jacobian`` and
    ``assets.sah.config_cov_from_fingertip_cov``, i.e. ``J+ cov J+^T``), then the wrist rotation and
    position variances are added on the ``[omega, v]`` diagonal. With it: ``diag(std^2)``. In both cases
    ``joint_floor_std^2`` is added to every joint's variance so that Sigma_r + Sigma_m is positive definite
    even in joint directions the fingertips do not see.

    Args:
        T_object_wrist: (T, 4, 4) tau_r; joints: (T, 13) [rad].
        fingertip_map: ``(T_object_wrist (T,4,4), joints (T,13), cov12 (12,12)) -> (T,19,19)``.
    """
    T_object_wrist = np.asarray(T_object_wrist, dtype=float)
    n = T_object_wrist.shape[0]
    if params.sigma_m_std_config is not None:
        cov = np.broadcast_to(np.diag(np.square(params.sigma_m_std_config)), (n, Q_DIM, Q_DIM)).copy()
    else:
        fingertip_std, wrist_pos_std, wrist_rot_std = params.modeling_stds(grasp_type)
        if fingertip_map is None:
            fingertip_map = _sah_fingertip_map
        cov = np.array(
            fingertip_map(T_object_wrist, np.asarray(joints, dtype=float), fingertip_std**2 * np.eye(12)),
            dtype=float,
        )
        if cov.shape != (n, Q_DIM, Q_DIM):
            raise InputError(f"fingertip map: expected shape {(n, 19, 19)}, found {cov.shape}")
        cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
        idx = np.arange(6)
        cov[:, idx, idx] += np.array([wrist_rot_std**2] * 3 + [wrist_pos_std**2] * 3)
    floor = math.radians(params.joint_floor_std_deg) ** 2
    idx = np.arange(Q_DIM)[JOINTS]
    cov[:, idx, idx] += floor
    return cov


def _sah_fingertip_map(T_object_wrist: np.ndarray, joints: np.ndarray, cov12: np.ndarray) -> np.ndarray:
    from assets import sah  # imported late: the SAH model is only needed for the default mapping

    return sah.config_cov_from_fingertip_cov(sah.fingertip_jacobian(T_object_wrist, joints), cov12)
