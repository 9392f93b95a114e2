"""The keypoint fitter: the human hand model's wrist pose and 20 joints from 21 hand points a frame.

The points, their order and their file are :mod:`retarget.keypoints`; :mod:`retarget.keypoint_import`
turns a file into a demonstration with this fit. Steps:

1. **Checks** that the points are a right hand's in metres, in the 21-point order (below).
2. **Calibrate** the hand over all frames (:func:`calibrate_hand`): a scale from the six palm points
   (wrist, thumb CMC, four MCPs; Procrustes with one scale for all frames), then each of the 15 finger
   segments' length from the distance of its two end points, corrected for the noise's bias and shrunk
   towards the scaled model's length by its standard error (the data decide where they determine it).
3. **Per-frame fit** (:func:`fit_keypoints`): each frame's wrist pose and 20 joints within
   ``JOINT_LIMITS`` by ``scipy.optimize.least_squares``, analytic Jacobian, started from joints read off
   the points. Its residuals measure the keypoint noise sigma (per axis, 26 parameters a frame removed).
4. **Smoothed fit** of all frames at once, started there: keypoint residuals / sigma plus second
   differences (accelerations) of the joints, the wrist position and the wrist rotation matrix over
   :class:`KeypointFitConfig`'s prior accelerations; sparse analytic Jacobian. Noise-free points give a
   sigma near 0, so the smoothness then leaves the exact fit alone.
5. **Result** (:class:`KeypointFit`): the motion, the per-frame residuals, the measured noise and the
   standard deviations a single frame's fit would have.

The wrist is ``T_object_wrist``, rotations perturbed on the right, ``R = R_ref @ Exp(omega)``. The hand is
the demonstrator's (the scaled model): the file holds its wrist and joints, as glove and tracker would.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields

import numpy as np
import scipy.sparse as sp
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from assets import human_hand
from assets.errors import InputError
from assets.io import is_finite_number
from assets.kinematics import HandModel
from assets.se3 import make_pose, se3_inverse, skew, so3_exp

from .keypoints import (
    KEYPOINT_LINKS,
    KEYPOINT_NAMES,
    MODEL_SEGMENT_LENGTHS_M,
    PALM_POINTS,
    SEGMENTS,
    hand_keypoints,
    scaled_model,
    segment_vectors,
    transform_points,
)

__all__ = [
    "HandCalibration",
    "KeypointFitConfig",
    "KeypointFit",
    "calibrate_hand",
    "fit_keypoints",
    "SCALE_RANGE",
    "MAX_KEYPOINT_SIGMA_M",
]

#: A hand whose palm is outside these multiples of the model's is not in metres (or not a hand).
SCALE_RANGE = (0.5, 2.0)
#: A fit worse than this (per axis) means a wrong point order or not a hand [m] (tracker noise: 2-10 mm).
MAX_KEYPOINT_SIGMA_M = 0.015
_N = 26  # parameters a frame: omega (3), p (3), joints (20)
_FLEXIONS = [
    i for f in human_hand.FINGERS[1:] for i in human_hand.FINGER_JOINTS[f][1:]
]  # the 12 of the fingers


@dataclass(frozen=True)
class HandCalibration:
    """The demonstrator's hand: the model scaled, with measured finger segments.

    Attributes:
        scale: palm size over the model's (wrist, thumb CMC, MCPs).
        segment_lengths_m: (15,) [m] :data:`SEGMENTS` lengths used by the fit.
        segment_length_se_m: (15,) [m] their standard errors (prior and data combined).
        measured_weight: (15,) how much of each length is the data's (1) rather than the scaled model's (0).
    """

    scale: float
    segment_lengths_m: np.ndarray
    segment_length_se_m: np.ndarray
    measured_weight: np.ndarray

    def model(self) -> HandModel:
        return scaled_model(self.scale, self.segment_lengths_m)

    def header(self) -> dict:
        names = [f"{KEYPOINT_NAMES[a]}-{KEYPOINT_NAMES[b]}" for a, b in SEGMENTS]
        return {
            "scale": round(self.scale, 6),
            "segments": names,
            "segment_lengths_m": np.round(self.segment_lengths_m, 6).tolist(),
            "model_segment_lengths_m": np.round(MODEL_SEGMENT_LENGTHS_M, 6).tolist(),
            "segment_length_se_m": np.round(self.segment_length_se_m, 6).tolist(),
            "measured_weight": np.round(self.measured_weight, 4).tolist(),
        }


def _palm_alignment(p_object: np.ndarray):
    """R_object_wrist (T, 3, 3) by Kabsch of the model's palm points on the given ones, and both centred."""
    P = hand_keypoints(np.zeros(20))[list(PALM_POINTS)]
    P = P - P.mean(0)
    Y = p_object[:, list(PALM_POINTS)]
    Y = Y - Y.mean(1, keepdims=True)
    return np.stack([Rotation.align_vectors(y, P)[0].as_matrix() for y in Y]), Y, P


def calibrate_hand(p_object: np.ndarray, length_prior_rel_sigma: float = 0.1, path=None) -> HandCalibration:
    """Hand scale and segment lengths from all frames of keypoints (T, 21, 3) [m].

    The scale s minimises ``sum_t |Y_t - (s R_t P + c_t)|^2`` over the palm points (R_t by Kabsch,
    ``Rotation.align_vectors``). A segment's length from its end points' distances d_t: ``l^2 = mean(d^2)
    - 3 var(d)`` (isotropic noise adds 6 sigma^2 to d^2 and 2 sigma^2 to var d), standard error
    ``sqrt(var(d) / T)``, combined with the prior ``N(s l_model, (length_prior_rel_sigma s l_model)^2)``.

    Raises:
        InputError: the scale is outside :data:`SCALE_RANGE` (millimetres, or not a hand), or the palm
            points are not rigid to :data:`MAX_KEYPOINT_SIGMA_M` (another point order).
    """
    R, Y, P = _palm_alignment(p_object)
    s = float(np.einsum("tki,tij,kj->", Y, R, P) / (len(Y) * np.sum(P * P)))
    if not SCALE_RANGE[0] <= s <= SCALE_RANGE[1]:
        raise InputError(
            f"keypoints: the palm is {s:.4g} times the model's (expected {SCALE_RANGE[0]} to "
            f"{SCALE_RANGE[1]}): points must be in metres (millimetres?), in the 21-point order",
            path,
        )
    palm_sigma = np.sqrt(np.sum((Y - s * np.einsum("tij,kj->tki", R, P)) ** 2) / (len(Y) * 12))
    if palm_sigma > MAX_KEYPOINT_SIGMA_M:
        raise InputError(
            f"keypoints: points 0, 1, 5, 9, 13, 17 fit the model's palm (wrist, thumb CMC, MCPs) to "
            f"{palm_sigma * 1e3:.1f} mm per axis, more than {MAX_KEYPOINT_SIGMA_M * 1e3:.0f} mm: expected "
            f"the 21 points in the order {', '.join(KEYPOINT_NAMES)}",
            path,
        )
    d = np.linalg.norm(segment_vectors(p_object), axis=-1)
    m2, var = np.mean(d * d, 0), np.var(d, 0)
    measured = np.sqrt(np.maximum(m2 - 3.0 * var, 0.25 * m2))
    prior = s * MODEL_SEGMENT_LENGTHS_M
    prior_var = (length_prior_rel_sigma * prior) ** 2
    se2 = var / len(d)
    w = prior_var / (prior_var + se2)
    lengths = prior + w * (measured - prior)
    return HandCalibration(s, lengths, np.sqrt(w * se2), w)


@dataclass(frozen=True)
class KeypointFitConfig:
    """Settings of :func:`fit_keypoints`; the accelerations are the smoothness prior's standard deviations.

    Attributes:
        joint_accel_sigma_rad_s2: of each joint [rad/s^2] (a finger closing 1 rad in 1 s min-jerk: 6).
        wrist_accel_sigma_m_s2: of the wrist position [m/s^2].
        rotation_accel_sigma_s2: of the wrist rotation matrix's entries [1/s^2] (about rad/s^2).
        min_keypoint_sigma_m: floor of the measured keypoint noise that weighs the data [m].
        length_prior_rel_sigma: spread of real segment lengths around the scaled model's (relative).
        max_nfev: evaluations of each fit.
        ftol: ``least_squares``' ``ftol`` and ``xtol`` (1e-6: the cost to 6 digits; noise-free points still
            give the joints to 0.001 deg).
    """

    joint_accel_sigma_rad_s2: float = 30.0
    wrist_accel_sigma_m_s2: float = 3.0
    rotation_accel_sigma_s2: float = 20.0
    min_keypoint_sigma_m: float = 1e-4
    length_prior_rel_sigma: float = 0.1
    max_nfev: int = 100
    ftol: float = 1e-6

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if not (is_finite_number(v) and v > 0):
                raise InputError(f"{f.name}: expected a finite number > 0, found {v!r}")


@dataclass(frozen=True)
class KeypointFit:
    """The result of :func:`fit_keypoints`.

    Attributes:
        success, message: the smoothed fit's convergence (``least_squares``'s status).
        T_object_wrist: (T, 4, 4) wrist poses in the object frame [m].
        joints: (T, 20) [rad] within ``JOINT_LIMITS``.
        residual_rms_m: (T,) per frame, RMS over the 63 coordinates of fitted minus given points [m].
        residual_max_m: (T,) per frame, the largest point distance [m].
        sigma_m: keypoint noise per axis measured by the per-frame fit (26 parameters a frame removed) [m].
        frame_std: per-frame-fit standard deviations (medians over frames): ``position_m``,
            ``rotation_rad`` (body frame) and ``joints_rad`` (20,).
        calibration: the hand.
        nfev: evaluations of both fits.
        time_s: the fit's wall time [s].
    """

    success: bool
    message: str
    T_object_wrist: np.ndarray
    joints: np.ndarray
    residual_rms_m: np.ndarray
    residual_max_m: np.ndarray
    sigma_m: float
    frame_std: dict
    calibration: HandCalibration
    nfev: int = 0
    time_s: float = 0.0


def _initial_joints(k_wrist: np.ndarray) -> np.ndarray:
    """Joints (T, 20) read off points (T, 21, 3) in the wrist frame, not clipped: each finger's first
    segment in its knuckle frame gives the abduction (about -x) and first flexion (about y), each next
    segment's angle to the previous about that y the next flexion. Exact for the model's own points."""
    base = human_hand.model()
    knuckle = {j.child: j.T_parent_joint[:3, :3] for j in base.joints if j.parent == base.base_link}
    q = np.empty(k_wrist.shape[:-2] + (20,))
    for f, b in zip(human_hand.FINGERS, (1, 5, 9, 13, 17), strict=True):
        seg = np.einsum(
            "ji,...kj->...ki", knuckle[f"{f}_knuckle"], np.diff(k_wrist[..., b : b + 4, :], axis=-2)
        )
        u = seg[..., 0, :]
        abd = np.arctan2(u[..., 1], u[..., 2])
        y_axis = np.stack([np.zeros_like(abd), np.cos(abd), -np.sin(abd)], axis=-1)  # R_x(-abd) e_y
        angles = [abd, np.arctan2(u[..., 0], np.hypot(u[..., 1], u[..., 2]))]
        for i in (1, 2):
            a, c = seg[..., i - 1, :], seg[..., i, :]
            angles.append(np.arctan2(np.sum(np.cross(a, c) * y_axis, -1), np.sum(a * c, -1)))
        q[..., list(human_hand.FINGER_JOINTS[f])] = np.stack(angles, axis=-1)
    return q


def _right_jacobian(omega: np.ndarray) -> np.ndarray:
    """SO(3) right Jacobian (..., 3, 3): ``Exp(omega + d) = Exp(omega) Exp(Jr(omega) d)`` to first order."""
    th = np.linalg.norm(omega, axis=-1)[..., None, None]
    K = skew(omega)
    small = th < 1e-6
    t = np.where(small, 1.0, th)
    a = np.where(small, 0.5 - th**2 / 24.0, (1.0 - np.cos(t)) / t**2)
    b = np.where(small, 1.0 / 6.0 - th**2 / 120.0, (t - np.sin(t)) / t**3)
    return np.eye(3) - a * K + b * (K @ K)


def _keypoint_terms(
    model: HandModel, R_ref: np.ndarray, x: np.ndarray, y: np.ndarray, jacobian: bool = False
):
    """Residuals (T, 21, 3) [m] of frames x (T, 26) against points y, the rotations (T, 3, 3) and, with
    ``jacobian``, d residual / d x (T, 21, 3, 26)."""
    omega, p, q = x[:, :3], x[:, 3:6], x[:, 6:]
    R = R_ref @ so3_exp(omega)
    poses = model.fk(q)
    k = hand_keypoints(q, poses=poses)
    r = np.einsum("tij,tkj->tki", R, k) + p[:, None] - y
    if not jacobian:
        return r, R, None
    J = np.empty(r.shape + (_N,))
    J[..., :3] = -np.einsum("tij,tkjl,tlm->tkim", R, skew(k), _right_jacobian(omega))
    J[..., 3:6] = np.eye(3)
    for i, link in enumerate(KEYPOINT_LINKS):
        J[:, i, :, 6:] = R @ model.point_jacobian(q, link, poses)
    return r, R, J


def _problem(model, y, R_ref, sigma_m: float, dt_s: float, cfg: KeypointFitConfig, smooth: bool):
    """The residuals ``fun(v)`` and their sparse Jacobian ``jac(v)`` of all frames v = x.ravel(), x (T, 26):
    keypoint residuals / sigma_m and, if ``smooth``, the second differences of the joints and the wrist
    position (linear) and of the rotation matrices, each over its prior acceleration times dt^2."""
    n = len(y)
    n_kp, m = n * 63, max(n - 2, 0) if smooth else 0
    idx = np.r_[6:_N, 3:6]  # joints and position: linear terms
    w = (
        np.r_[np.full(20, 1.0 / cfg.joint_accel_sigma_rad_s2), np.full(3, 1.0 / cfg.wrist_accel_sigma_m_s2)]
        / dt_s**2
    )
    w_rot = 1.0 / (cfg.rotation_accel_sigma_s2 * dt_s**2)
    coef = np.array([1.0, -2.0, 1.0])
    t = np.arange(m)
    rows = [np.broadcast_to(np.arange(n_kp).reshape(n, 63, 1), (n, 63, _N))]
    cols = [np.broadcast_to((np.arange(n) * _N)[:, None, None] + np.arange(_N), (n, 63, _N))]
    rows.append(np.broadcast_to(n_kp + (t[:, None] * 23 + np.arange(23))[..., None], (m, 23, 3)))
    cols.append((t[:, None, None] + np.arange(3)) * _N + idx[:, None])
    lin_vals = np.broadcast_to(w[:, None] * coef, (m, 23, 3)).ravel()
    rows.append(
        np.broadcast_to(
            (n_kp + 23 * m + 9 * t)[:, None, None, None] + np.arange(9)[:, None, None], (m, 9, 3, 3)
        )
    )
    cols.append(
        np.broadcast_to((t[:, None, None, None] + np.arange(3)[:, None]) * _N + np.arange(3), (m, 9, 3, 3))
    )
    rows, cols = (np.concatenate([a.ravel() for a in v]) for v in (rows, cols))
    shape = (n_kp + 32 * m, n * _N)

    def fun(v):
        x = v.reshape(n, _N)
        r, R, _ = _keypoint_terms(model, R_ref, x, y)
        lin = (x[2:, idx] - 2 * x[1:-1, idx] + x[:-2, idx])[:m] * w
        rot = (R[2:] - 2 * R[1:-1] + R[:-2])[:m].reshape(m, 9) * w_rot
        return np.concatenate([r.ravel() / sigma_m, lin.ravel(), rot.ravel()])

    def jac(v):
        x = v.reshape(n, _N)
        _, R, J = _keypoint_terms(model, R_ref, x, y, jacobian=True)
        # column i of R is R e_i and d(R e_i) = -R [e_i]x Jr(omega) d omega; rows of vec(R) row-major
        dR = -np.einsum("tab,ibc,tcd->taid", R, skew(np.eye(3)), _right_jacobian(x[:, :3])).reshape(n, 9, 3)
        rot = w_rot * np.stack([coef[k] * dR[k : m + k] for k in range(3)], axis=2)
        return sp.csr_matrix(
            (np.concatenate([J.ravel() / sigma_m, lin_vals, rot.ravel()]), (rows, cols)), shape
        )

    return fun, jac


def _fit(model, y, R_ref, x0, sigma_m: float, dt_s: float, cfg: KeypointFitConfig, smooth: bool):
    """:func:`_problem` solved by ``least_squares`` from x0 (T, 26), joints bounded by ``JOINT_LIMITS``."""
    fun, jac = _problem(model, y, R_ref, sigma_m, dt_s, cfg, smooth)
    n = len(y)
    lo = np.tile(np.r_[np.full(6, -np.inf), human_hand.JOINT_LIMITS[:, 0]], n)
    hi = np.tile(np.r_[np.full(6, np.inf), human_hand.JOINT_LIMITS[:, 1]], n)
    return least_squares(
        fun, np.clip(x0.ravel(), lo, hi), jac, bounds=(lo, hi), method="trf", tr_solver="lsmr",
        x_scale="jac", max_nfev=cfg.max_nfev, ftol=cfg.ftol, xtol=cfg.ftol,
    )  # fmt: skip


def fit_keypoints(
    p_object: np.ndarray, rate_hz: float, config: KeypointFitConfig | None = None, path=None
) -> KeypointFit:
    """Fit the human hand's wrist pose and 20 joints to keypoints (T, 21, 3) [m, object frame] at
    ``rate_hz``: calibration, per-frame fit, smoothed fit (the module docstring's steps 2-4).

    Raises:
        InputError: the hand's scale is implausible, a left hand (the fingers read off the points bend
            backwards beyond the limits on average), or the model cannot explain the points (palm or fit
            residual over :data:`MAX_KEYPOINT_SIGMA_M` per axis: a wrong point order).
    """
    start = time.perf_counter()
    cfg = config or KeypointFitConfig()
    y = np.asarray(p_object, dtype=float)
    n = len(y)
    cal = calibrate_hand(y, cfg.length_prior_rel_sigma, path)
    model = cal.model()
    R_ref = _palm_alignment(y)[0]
    k_wrist = transform_points(se3_inverse(make_pose(R_ref, y[:, 0])), y)
    q0 = _initial_joints(k_wrist)
    bend = float(np.mean(q0[:, _FLEXIONS]))
    if bend < human_hand.JOINT_LIMITS[_FLEXIONS, 0].max():
        raise InputError(
            f"keypoints: the fingers bend backwards by {np.degrees(-bend):.0f} deg on average, beyond the "
            "model's hyperextension limit: a left hand (the model is a right one), or the fingers in "
            "reverse order?",
            path,
        )
    q0 = np.clip(q0, human_hand.JOINT_LIMITS[:, 0], human_hand.JOINT_LIMITS[:, 1])
    x0 = np.concatenate([np.zeros((n, 3)), y[:, 0], q0], axis=1)
    res = _fit(model, y, R_ref, x0, 1.0, 1.0 / rate_hz, cfg, smooth=False)
    nfev = res.nfev
    sigma = float(np.sqrt(2.0 * res.cost / (n * (63 - _N))))
    if sigma > MAX_KEYPOINT_SIGMA_M:
        raise InputError(
            f"keypoints: the hand model fits the points to {sigma * 1e3:.1f} mm per axis (more than "
            f"{MAX_KEYPOINT_SIGMA_M * 1e3:.0f} mm): expected a right hand's 21 points in the order "
            f"{', '.join(KEYPOINT_NAMES)}",
            path,
        )
    x = res.x.reshape(n, _N)
    J = _keypoint_terms(model, R_ref, x, y, jacobian=True)[2].reshape(n, 63, _N)
    cov_diag = np.diagonal(np.linalg.pinv(np.swapaxes(J, 1, 2) @ J), axis1=1, axis2=2)
    R_ref = R_ref @ so3_exp(x[:, :3])
    x[:, :3] = 0.0
    res = _fit(model, y, R_ref, x, max(sigma, cfg.min_keypoint_sigma_m), 1.0 / rate_hz, cfg, smooth=True)
    x = res.x.reshape(n, _N)
    r, R, _ = _keypoint_terms(model, R_ref, x, y)
    std = np.sqrt(np.median(cov_diag, axis=0)) * sigma
    return KeypointFit(
        success=bool(res.success),
        message=str(res.message),
        T_object_wrist=make_pose(R, x[:, 3:6]),
        joints=x[:, 6:].copy(),
        residual_rms_m=np.sqrt(np.mean(r.reshape(n, -1) ** 2, axis=1)),
        residual_max_m=np.linalg.norm(r, axis=-1).max(axis=1),
        sigma_m=sigma,
        frame_std={"position_m": std[3:6], "rotation_rad": std[:3], "joints_rad": std[6:]},
        calibration=cal,
        nfev=int(nfev + res.nfev),
        time_s=time.perf_counter() - start,
    )
