"""Rigid-body helpers, vectorized over leading dimensions, in GTSAM's conventions.

Conventions used everywhere in pbdgrasp:

* ``T_a_b`` (..., 4, 4) is the pose of frame b in frame a and maps points of b into a:
  ``p_a = T_a_b @ p_b``; compose only when inner frames match, ``T_a_c = T_a_b @ T_b_c``.
* The 19-D hand configuration is ``q = [p (3, m), r (3, rad), joints (13, rad)]``: the wrist position
  and its rotation vector (scaled axis, the paper's orientation) in the world (or object) frame, then
  the SAH joints in :data:`assets.sah.JOINT_NAMES` order. See :func:`pose_from_q`.
* Covariances of poses use GTSAM's Pose3 tangent ``xi = [omega (3, rad), v (3, m)]`` in the body frame
  with right perturbation ``T = T_mean @ Exp(xi)`` (:func:`retract`); ``Exp`` is the full SE(3)
  exponential, equal to ``gtsam.Pose3.Expmap`` and, in GTSAM's default build, ``Pose3.retract``.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from .q_layout import POS, ROT

__all__ = [
    "skew",
    "so3_exp",
    "so3_log",
    "se3_exp",
    "se3_log",
    "se3_inverse",
    "retract",
    "local",
    "make_pose",
    "pose_from_q",
    "q_from_pose",
    "quat_from_rotvec",
    "quat_of_rotvec",
    "rotvec_from_quat",
    "slerp_rotvec",
    "quat_rows_from_matrix",
    "quat_rows_exp",
    "quat_rows_mul",
    "quat_rows_rotate",
    "pose_rows_compose",
    "rotvec_rows_from_quat",
]

_SMALL = 1e-8


def skew(v: np.ndarray) -> np.ndarray:
    """The cross-product matrix of ``v`` (..., 3) -> (..., 3, 3)."""
    v = np.asarray(v, dtype=float)
    z = np.zeros(v.shape[:-1])
    return np.stack(
        [
            np.stack([z, -v[..., 2], v[..., 1]], -1),
            np.stack([v[..., 2], z, -v[..., 0]], -1),
            np.stack([-v[..., 1], v[..., 0], z], -1),
        ],
        -2,
    )


def so3_exp(omega: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from rotation vectors ``omega`` (..., 3) [rad] (scipy's
    ``Rotation.from_rotvec``; one vector in plain floats with scipy's arithmetic, bit for bit)."""
    omega = np.asarray(omega, dtype=float)
    if omega.shape == (3,):
        return _so3_exp_one(*omega.tolist())
    flat = omega.reshape(-1, 3)
    return Rotation.from_rotvec(flat).as_matrix().reshape(omega.shape[:-1] + (3, 3))


def so3_log(R: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) [rad], angle in [0, pi], from rotation matrices (..., 3, 3).

    Through the unit quaternion by Shepperd's method (the largest of w, x, y, z first, as scipy's
    ``Rotation.from_matrix``), without scipy's per-call checks: the wrist conversions are a hot path.
    """
    R = np.asarray(R, dtype=float)
    if R.shape == (3, 3):
        return _so3_log_one(R.tolist())
    m = R.reshape(-1, 3, 3)
    d = np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=-1)
    tr = d.sum(axis=-1)
    k = np.argmax(np.concatenate([d, tr[:, None]], axis=-1), axis=-1)  # 0-2: x, y or z largest; 3: w
    q = np.empty((len(m), 4))  # x, y, z, w
    q[:, 0] = m[:, 2, 1] - m[:, 1, 2]
    q[:, 1] = m[:, 0, 2] - m[:, 2, 0]
    q[:, 2] = m[:, 1, 0] - m[:, 0, 1]
    q[:, 3] = 1.0 + tr
    for i in range(3):  # rows where x, y or z is the largest component
        rows = k == i
        if not np.any(rows):
            continue
        j, l = (i + 1) % 3, (i + 2) % 3
        mi = m[rows]
        qi = np.empty((len(mi), 4))
        qi[:, i] = 1.0 - tr[rows] + 2.0 * mi[:, i, i]
        qi[:, j] = mi[:, j, i] + mi[:, i, j]
        qi[:, l] = mi[:, l, i] + mi[:, i, l]
        qi[:, 3] = mi[:, l, j] - mi[:, j, l]
        q[rows] = qi
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q = np.where(q[:, 3:] < 0.0, -q, q)
    s = np.linalg.norm(q[:, :3], axis=-1)
    angle = 2.0 * np.arctan2(s, q[:, 3])
    scale = np.where(s > _SMALL, angle / np.where(s > _SMALL, s, 1.0), 2.0 / q[:, 3])
    out = q[:, :3] * scale[:, None]
    return out.reshape(R.shape[:-2] + (3,))


def _so3_exp_one(x: float, y: float, z: float) -> np.ndarray:
    """:func:`so3_exp` of one vector: scipy's quaternion (its series below 1e-3 rad), then its matrix."""
    a = math.sqrt(x * x + y * y + z * z)
    if a <= 1e-3:
        a2 = a * a
        s = 0.5 - a2 / 48 + a2 * a2 / 3840
    else:
        s = math.sin(a / 2) / a
    x, y, z, w = s * x, s * y, s * z, math.cos(a / 2)
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return np.array(
        [
            [x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw)],
            [2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw)],
            [2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2],
        ]
    )


def _so3_log_one(m: list) -> np.ndarray:
    """:func:`so3_log` of one matrix (nested lists) in plain floats, the same arithmetic."""
    tr = m[0][0] + m[1][1] + m[2][2]
    diag = (m[0][0], m[1][1], m[2][2], tr)
    k = diag.index(max(diag))
    if k == 3:
        q = [m[2][1] - m[1][2], m[0][2] - m[2][0], m[1][0] - m[0][1], 1.0 + tr]
    else:
        j, l = (k + 1) % 3, (k + 2) % 3
        q = [0.0] * 4
        q[k] = 1.0 - tr + 2.0 * m[k][k]
        q[j] = m[j][k] + m[k][j]
        q[l] = m[l][k] + m[k][l]
        q[3] = m[l][j] - m[j][l]
    n = math.sqrt(sum(x * x for x in q))
    sign = -1.0 if q[3] < 0.0 else 1.0
    x, y, z, w = (sign * v / n for v in q)
    s = math.sqrt(x * x + y * y + z * z)
    scale = 2.0 * math.atan2(s, w) / s if s > _SMALL else 2.0 / w
    return np.array([x * scale, y * scale, z * scale])


def _coefficients(theta: np.ndarray):
    """A = sin t / t, B = (1 - cos t) / t^2, C = (t - sin t) / t^3 with Taylor series near 0."""
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    t2 = theta * theta
    A = np.where(small, 1 - t2 / 6 + t2 * t2 / 120, np.sin(t) / t)
    B = np.where(small, 0.5 - t2 / 24 + t2 * t2 / 720, (1 - np.cos(t)) / (t * t))
    C = np.where(small, 1 / 6 - t2 / 120 + t2 * t2 / 5040, (t - np.sin(t)) / (t * t * t))
    return A, B, C


def se3_exp(xi: np.ndarray) -> np.ndarray:
    """SE(3) exponential of ``xi = [omega, v]`` (..., 6) -> (..., 4, 4), as ``gtsam.Pose3.Expmap``."""
    xi = np.asarray(xi, dtype=float)
    omega, v = xi[..., :3], xi[..., 3:]
    theta = np.linalg.norm(omega, axis=-1)
    A, B, C = _coefficients(theta)
    K = skew(omega)
    K2 = K @ K
    eye = np.eye(3)
    R = eye + A[..., None, None] * K + B[..., None, None] * K2
    V = eye + B[..., None, None] * K + C[..., None, None] * K2
    T = np.zeros(xi.shape[:-1] + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = np.einsum("...ij,...j->...i", V, v)
    T[..., 3, 3] = 1.0
    return T


def se3_log(T: np.ndarray) -> np.ndarray:
    """SE(3) logarithm (..., 4, 4) -> ``[omega, v]`` (..., 6), the inverse of :func:`se3_exp`."""
    T = np.asarray(T, dtype=float)
    omega = so3_log(T[..., :3, :3])
    theta = np.linalg.norm(omega, axis=-1)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    # V^-1 = I - K/2 + D K^2 with D = (1 - A / (2 B)) / t^2
    A, B, _ = _coefficients(theta)
    D = np.where(small, 1 / 12 + theta**2 / 720, (1 - A / (2 * B)) / (t * t))
    K = skew(omega)
    Vinv = np.eye(3) - 0.5 * K + D[..., None, None] * (K @ K)
    v = np.einsum("...ij,...j->...i", Vinv, T[..., :3, 3])
    return np.concatenate([omega, v], axis=-1)


def se3_inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of rigid transforms (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", Rt, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


def retract(T: np.ndarray, xi: np.ndarray) -> np.ndarray:
    """Right (body) perturbation ``T @ Exp(xi)``, GTSAM's ``Pose3.retract``; broadcasts."""
    return np.asarray(T, dtype=float) @ se3_exp(xi)


def local(T_a: np.ndarray, T_b: np.ndarray) -> np.ndarray:
    """Body-frame difference ``Log(T_a^-1 T_b)`` (..., 6), GTSAM's ``T_a.localCoordinates(T_b)``."""
    return se3_log(se3_inverse(T_a) @ np.asarray(T_b, dtype=float))


def make_pose(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homogeneous transforms (..., 4, 4) from rotations (..., 3, 3) and translations (..., 3)."""
    R = np.asarray(R, dtype=float)
    p = np.asarray(p, dtype=float)
    shape = np.broadcast_shapes(R.shape[:-2], p.shape[:-1])
    T = np.zeros(shape + (4, 4))
    T[..., :3, :3] = R
    T[..., :3, 3] = p
    T[..., 3, 3] = 1.0
    return T


def pose_from_q(q: np.ndarray) -> np.ndarray:
    """Wrist pose (..., 4, 4) from configurations ``q`` (..., >=6): position then rotation vector."""
    q = np.asarray(q, dtype=float)
    return make_pose(so3_exp(q[..., ROT]), q[..., POS])


def q_from_pose(T: np.ndarray) -> np.ndarray:
    """The first six entries of ``q`` (..., 6), ``[p (m), rotation vector (rad)]``, from poses (..., 4, 4)."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([T[..., :3, 3], so3_log(T[..., :3, :3])], axis=-1)


def quat_from_rotvec(r: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) ``[x, y, z, w]`` (scipy's order) from rotation vectors (..., 3)."""
    r = np.asarray(r, dtype=float)
    theta = np.linalg.norm(r, axis=-1, keepdims=True)
    half = 0.5 * theta
    # sin(theta/2)/theta with its Taylor series near 0
    k = np.where(theta < 1e-6, 0.5 - theta**2 / 48.0, np.sin(half) / np.where(theta < 1e-6, 1.0, theta))
    return np.concatenate([k * r, np.cos(half)], axis=-1)


def quat_of_rotvec(x: float, y: float, z: float) -> tuple[float, float, float, float]:
    """The unit quaternion ``(x, y, z, w)`` (pybullet's and scipy's order) of one rotation vector [rad], in
    plain floats: ~10x cheaper than :func:`quat_from_rotvec` on a single vector (the planner's hot path)."""
    x, y, z = float(x), float(y), float(z)
    theta = math.sqrt(x * x + y * y + z * z)
    k = 0.5 - theta * theta / 48.0 if theta < 1e-6 else math.sin(0.5 * theta) / theta
    return (x * k, y * k, z * k, math.cos(0.5 * theta))


def rotvec_from_quat(quat: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3), angle in [0, pi], from quaternions (..., 4) ``[x, y, z, w]``."""
    quat = np.asarray(quat, dtype=float)
    quat = np.where(quat[..., 3:] < 0, -quat, quat)
    v = quat[..., :3]
    s = np.linalg.norm(v, axis=-1, keepdims=True)
    theta = 2.0 * np.arctan2(s, quat[..., 3:])
    k = np.where(s < 1e-12, 2.0 / np.maximum(quat[..., 3:], 1e-300), theta / np.where(s < 1e-12, 1.0, s))
    return k * v


def slerp_rotvec(r_a: np.ndarray, r_b: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Rotation vectors (n, 3) along the geodesic from ``r_a`` (3,) to ``r_b`` (3,) at fractions ``s`` (n,).

    ``R(s) = R_a Exp(s Log(R_a^T R_b))``: the shortest rotation path, as scipy's ``Slerp``, in plain
    numpy (scipy's per-call overhead dominates the planner's single-edge interpolations).
    """
    qa = quat_from_rotvec(r_a)
    qb = quat_from_rotvec(r_b)
    dot = float(qa @ qb)
    if dot < 0:
        qb, dot = -qb, -dot
    s = np.atleast_1d(np.asarray(s, dtype=float))[:, None]
    if dot > 1.0 - 1e-12:
        q = qa + s * (qb - qa)
    else:
        omega = np.arccos(min(dot, 1.0))
        q = (np.sin((1.0 - s) * omega) * qa + np.sin(s * omega) * qb) / np.sin(omega)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return rotvec_from_quat(q)


# -- unit quaternions [x, y, z, w] and vectors as rows, (4, n) and (3, n): the sampler's fast path --------
def quat_rows_from_matrix(R: np.ndarray) -> np.ndarray:
    """(4, m) quaternion rows [x, y, z, w] from rotation matrices (m, 3, 3)."""
    return np.ascontiguousarray(Rotation.from_matrix(R).as_quat().T)


def _cross_rows(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def quat_rows_exp(omega: np.ndarray) -> np.ndarray:
    """(4, n) quaternion rows [x, y, z, w] of rotation vectors (3, n) [rad]."""
    theta = np.sqrt(omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2)
    small = theta < 1e-6
    s = np.where(small, 0.5 - theta * theta / 48.0, np.sin(0.5 * theta) / np.where(small, 1.0, theta))
    return np.concatenate([omega * s, np.cos(0.5 * theta)[None]])


def quat_rows_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The products ``a * b`` (4, n) of quaternion rows [x, y, z, w]."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ]
    )


def quat_rows_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R(q) v = v + 2 w (u x v) + 2 u x (u x v), u the vector part; q (4, n) [x, y, z, w], v (3, n)."""
    u = q[:3]
    uv = _cross_rows(u, v)
    return v + 2.0 * (q[3] * uv + _cross_rows(u, uv))


def pose_rows_compose(quat: np.ndarray, p: np.ndarray, xi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(quat, p) @ Exp(xi)`` for xi = [omega, v] (6, n), quat (4, n) [x, y, z, w], p (3, n) [m]: SE(3)
    Exp's ``V(omega) v``, then rotate (the right perturbation of :func:`retract`)."""
    omega, v = xi[:3], xi[3:]
    theta2 = omega[0] ** 2 + omega[1] ** 2 + omega[2] ** 2
    theta = np.sqrt(theta2)
    small = theta < 1e-4
    t = np.where(small, 1.0, theta)
    B = np.where(small, 0.5 - theta2 / 24.0, (1.0 - np.cos(t)) / (t * t))
    C = np.where(small, 1.0 / 6.0 - theta2 / 120.0, (t - np.sin(t)) / (t * t * t))
    wv = _cross_rows(omega, v)
    trans = v + B * wv + C * _cross_rows(omega, wv)
    return quat_rows_mul(quat, quat_rows_exp(omega)), p + quat_rows_rotate(quat, trans)


def rotvec_rows_from_quat(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (3, n), angle in [0, pi], from unit quaternion rows (4, n) [x, y, z, w]."""
    sign = np.where(q[3] < 0, -1.0, 1.0)
    w = q[3] * sign
    u = q[:3]
    s = np.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
    small = s < 1e-8
    angle = 2.0 * np.arctan2(s, w)
    scale = np.where(small, 2.0 / np.maximum(w, 1e-300), angle / np.where(small, 1.0, s)) * sign
    return u * scale
