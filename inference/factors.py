"""The factors of the variation model (paper section V) as pure error functions and GTSAM factors.

Variables: ``O`` (Pose3, object in world), ``W_t`` (Pose3, wrist in WORLD), ``J_t`` (13-vector, SAH joints).

* f_1t, the demonstration factor over ``(O, W_t, J_t)`` (or ``(W_t, J_t)`` with O held fixed): error
  ``[Log(tau_r(t)^-1 O^-1 W_t), J_t - joints_r(t)]`` (19,), covariance ``Sigma_r(t) + Sigma_m(t)`` in
  ``[omega, v, joints]``. When the covariance couples wrist and joints it is one ``gtsam.CustomFactor`` with
  analytic Jacobians (:func:`demonstration_error`); when it is block diagonal it is GTSAM's own
  ``BetweenFactorPose3(O, W_t)`` plus ``PriorFactorVector(J_t)`` (same error, faster).
* f_2t, smoothness: ``BetweenFactorPose3(W_t, W_t+1, identity)`` and ``BetweenFactorVector(J_t, J_t+1, 0)``
  with the diagonal S_t of :meth:`VariationParams.smoothness_stds`.
* f_3t/f_4t, the constraint: one ``gtsam.CustomFactor`` per constrained step over ``(O, W_t, J_t)`` (or
  ``(W_t, J_t)``), a hinge on the clearance margins of :mod:`inference.clearance` with the small std R_t
  (:func:`clearance_factors`, evaluated for all steps at once); GTSAM's optimizer relinearizes it.

Jacobians are with respect to GTSAM's right (body) perturbations ``T Exp(xi)``, ``xi = [omega, v]``.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import gtsam
import numpy as np

from assets.errors import InputError
from assets.q_layout import JOINTS, N_JOINTS, Q_DIM, TAN_POSE

from .clearance import ClearanceFn
from .params import VariationParams

__all__ = [
    "demonstration_error",
    "demonstration_factors",
    "smoothness_factors",
    "clearance_error",
    "HINGE_CUTOFF",
    "ClearanceBatch",
    "clearance_factor",
    "clearance_factors",
    "modeling_covariance",
    "is_block_diagonal",
]

FingertipMap = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


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


HINGE_CUTOFF = 10.0
"""Beyond ``HINGE_CUTOFF`` smoothing lengths the smooth hinge is below 5e-5 of one and set to zero."""


def clearance_error(margins: np.ndarray, smoothing_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The smooth hinge of the clearance margins and its slope.

    ``e(m) = -s softplus(-m / s)`` with ``s = smoothing_m``: ``m`` deep inside the violated side (m << -s),
    zero far on the free side, differentiable everywhere (slope ``sigmoid(-m / s)`` in (0, 1)); so the
    information a row adds, and the marginals, change continuously as a sphere nears the clearance (a
    plain hinge ``min(m, 0)`` switches them on and off, and the joint-limit propagation then cycles).
    Zero (and slope zero) beyond ``HINGE_CUTOFF * s``.

    Returns:
        ``(e (m,) [m], de/dm (m,))``.
    """
    m = np.asarray(margins, dtype=float)
    x = -m / smoothing_m
    softplus = np.maximum(x, 0.0) + np.log1p(np.exp(-np.abs(x)))
    on = m < HINGE_CUTOFF * smoothing_m
    slope = np.where(on, 0.5 * (1.0 + np.tanh(0.5 * x)), 0.0)  # sigmoid(x), stable
    return np.where(on, -smoothing_m * softplus, 0.0), slope


class ClearanceBatch:
    """Evaluates a clearance function for every step of a graph in one vectorized call.

    GTSAM asks each step's clearance factor for its error (and Jacobians) one at a time, always with the
    whole ``gtsam.Values`` of the graph. The first factor of a pass finds its inputs changed, evaluates all
    steps whose variables are in those values at once and keeps the results; the other factors of the pass
    find theirs unchanged and read them. A result is reused only for bit-identical inputs, so this changes
    what is computed per call, never the values GTSAM sees.

    Args:
        clearance: ``(T_world_object, T_world_wrist, joints, jacobians) -> rows`` or ``(rows, H_O, H_W,
            H_J)``, batched over leading axes: the margins (:class:`inference.clearance.HandClearance`) or
            rows made from them (the hinges of :func:`clearance_factors`).
        steps: per step ``(key_w, key_j)``.
        key_o: the key of O, or None with ``T_world_object`` given (O fixed there).
    """

    def __init__(self, clearance: ClearanceFn, steps, key_o: int | None, T_world_object=None):
        self.clearance = clearance
        self.steps = [tuple(s) for s in steps]
        self.key_o = key_o
        self.T_world_object = None if T_world_object is None else np.asarray(T_world_object, dtype=float)
        self._cache: dict[int, tuple] = {}

    def _inputs(self, values: gtsam.Values, i: int):
        key_w, key_j = self.steps[i]
        return values.atPose3(key_w).matrix(), values.atVector(key_j)

    def _object(self, values: gtsam.Values) -> np.ndarray:
        return self.T_world_object if self.key_o is None else values.atPose3(self.key_o).matrix()

    def evaluate(self, i: int, values: gtsam.Values, jacobians: bool) -> tuple:
        """Step ``i``'s ``margins`` (m,) or ``(margins, H_O, H_W, H_J)`` at ``values``."""
        O = self._object(values)
        W, J = self._inputs(values, i)
        hit = self._cache.get(i)
        if (
            hit is not None
            and (hit[4] is not None or not jacobians)
            and np.array_equal(hit[0], O)
            and np.array_equal(hit[1], W)
            and np.array_equal(hit[2], J)
        ):
            return hit[3] if not jacobians else (hit[3], *hit[4])
        present = [k for k, (kw, kj) in enumerate(self.steps) if values.exists(kw) and values.exists(kj)]
        inputs = [self._inputs(values, k) for k in present]
        Ws, Js = np.stack([w for w, _ in inputs]), np.stack([j for _, j in inputs])
        out = self.clearance(O, Ws, Js, jacobians=jacobians)
        margins = out[0] if jacobians else out
        self._cache = {
            k: (O, Ws[n], Js[n], margins[n], tuple(H[n] for H in out[1:]) if jacobians else None)
            for n, k in enumerate(present)
        }
        hit = self._cache[i]
        return hit[3] if not jacobians else (hit[3], *hit[4])


def clearance_factors(
    key_o: int | None,
    steps,
    clearance: ClearanceFn,
    std_m: float,
    smoothing_m: float,
    T_world_object: np.ndarray | None = None,
) -> list[gtsam.CustomFactor]:
    """f_3t/f_4t of the given steps: per step a hinge on the clearance margins of ``(O, W_t, J_t)``,
    Gaussian, std ``std_m``; the steps share one :class:`ClearanceBatch`.

    The paper ties a constraint variable ``C_t = phi(X_t)`` (variance ~0) to a prior ``N(r_t, R_t)``;
    with ``C_t`` marginalized out that is a Gaussian factor ``N(phi(X_t); r_t, R_t)``. Here ``phi`` is the
    margin vector of ``clearance`` (:mod:`inference.clearance`), ``r_t`` its clearance (margin 0) and the
    factor one-sided: per row the smooth hinge of :func:`clearance_error`, ~``min(margin, 0)``, so that a
    row acts only where the clearance is (nearly) violated. GTSAM relinearizes it at every iteration of its
    optimizer.

    Args:
        key_o: GTSAM key of O; unused when ``T_world_object`` is given.
        steps: per step ``(key_w, key_j)``, the keys of W_t and J_t.
        clearance: the margins and their Jacobians, batched over leading axes.
        std_m: the std of each row [m] (the paper's R_t).
        smoothing_m: the hinge's smoothing length [m]; ``clearance.active_margin_m`` must be at least
            ``HINGE_CUTOFF`` times it.
        T_world_object: (4, 4) if given, O is held fixed there and the factors are over ``(W_t, J_t)``.
    """
    if not (np.isfinite(std_m) and std_m > 0):
        raise InputError(f"clearance factor: std must be > 0, found {std_m!r}")
    if not (np.isfinite(smoothing_m) and smoothing_m > 0):
        raise InputError(f"clearance factor: smoothing must be > 0, found {smoothing_m!r}")
    if clearance.active_margin_m < HINGE_CUTOFF * smoothing_m:
        raise InputError(
            f"clearance factor: the clearance function's active margin {clearance.active_margin_m!r} m is "
            f"below the hinge's cutoff {HINGE_CUTOFF * smoothing_m!r} m"
        )
    noise = gtsam.noiseModel.Isotropic.Sigma(clearance.dim, float(std_m))
    fixed = T_world_object is not None

    def hinged(T_world_object, T_world_wrist, joints, jacobians: bool = False):
        """The hinge of every step's margins, and its Jacobians, in one vectorized evaluation."""
        out = clearance(T_world_object, T_world_wrist, joints, jacobians=jacobians)
        if not jacobians:
            return clearance_error(out, smoothing_m)[0]
        e, slope = clearance_error(out[0], smoothing_m)
        return e, *(slope[..., None] * H for H in out[1:])

    batch = ClearanceBatch(hinged, steps, None if fixed else key_o, T_world_object)

    def make(i: int) -> gtsam.CustomFactor:
        def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
            if H is None:
                return batch.evaluate(i, values, False)
            e, H_O, H_W, H_J = batch.evaluate(i, values, True)
            blocks = (H_W, H_J) if fixed else (H_O, H_W, H_J)
            for k, block in enumerate(blocks):
                H[k] = np.asfortranarray(block)
            return e

        keys = list(batch.steps[i]) if fixed else [key_o, *batch.steps[i]]
        return gtsam.CustomFactor(noise, keys, error)

    return [make(i) for i in range(len(batch.steps))]


def clearance_factor(
    key_o: int | None,
    key_w: int,
    key_j: int,
    clearance: ClearanceFn,
    std_m: float,
    smoothing_m: float,
    T_world_object: np.ndarray | None = None,
) -> gtsam.CustomFactor:
    """The clearance factor of one step (:func:`clearance_factors` of ``[(key_w, key_j)]``)."""
    return clearance_factors(key_o, [(key_w, key_j)], clearance, std_m, smoothing_m, T_world_object)[0]


def modeling_covariance(
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    grasp_type: str,
    params: VariationParams,
    fingertip_map: FingertipMap | None = None,
    configuration_weight: np.ndarray | None = None,
) -> np.ndarray:
    """Sigma_m(t) (T, 19, 19) in ``[omega, v, joints]``, with the joint floor added (paper section IV).

    Without ``params.sigma_m_std_config``: the isotropic fingertip covariance (12x12) is mapped to
    configuration space by ``fingertip_map`` (default: ``assets.sah.fingertip_jacobian`` and
    ``assets.sah.config_cov_from_fingertip_cov`` through ``params.fingertip_cov_map``, i.e.
    ``J+ cov J+^T``; with ``by_scene`` the blend ``w_t C_configuration + (1 - w_t) C_finger_joints`` of
    the two maps, ``w = configuration_weight`` (T,) in [0, 1], zeros if None), then the wrist rotation and
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
        cov12 = fingertip_std**2 * np.eye(12)
        if fingertip_map is None:
            w = np.zeros(n) if configuration_weight is None else np.asarray(configuration_weight, float)
            if w.shape != (n,) or not np.all((w >= 0) & (w <= 1)):
                raise InputError(f"configuration_weight: expected {n} numbers in [0, 1]")
            cov = _sah_fingertip_map(
                T_object_wrist, np.asarray(joints, dtype=float), cov12, params.fingertip_cov_map, w
            )
        else:
            cov = np.array(fingertip_map(T_object_wrist, np.asarray(joints, dtype=float), cov12), dtype=float)
        if cov.shape != (n, Q_DIM, Q_DIM):
            raise InputError(f"fingertip map: expected shape {(n, 19, 19)}, found {cov.shape}")
        cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
        idx = np.arange(6)
        cov[:, idx, idx] += np.array([wrist_rot_std**2] * 3 + [wrist_pos_std**2] * 3)
    floor = math.radians(params.joint_floor_std_deg) ** 2
    idx = np.arange(Q_DIM)[JOINTS]
    cov[:, idx, idx] += floor
    return cov


def _sah_fingertip_map(
    T_object_wrist: np.ndarray, joints: np.ndarray, cov12: np.ndarray, through: str, weight: np.ndarray
) -> np.ndarray:
    from assets import sah  # imported late: the SAH model is only needed for the default mapping

    J = sah.fingertip_jacobian(T_object_wrist, joints)
    if through != "by_scene":
        return sah.config_cov_from_fingertip_cov(J, cov12, through=through)
    joints_only = sah.config_cov_from_fingertip_cov(J, cov12, through="finger_joints")
    if not weight.any():
        return joints_only
    coupled = sah.config_cov_from_fingertip_cov(J, cov12, through="configuration")
    w = weight[:, None, None]
    return w * coupled + (1.0 - w) * joints_only
