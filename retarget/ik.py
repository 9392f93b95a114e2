"""Robust per-finger inverse kinematics of the SAH (the paper's section IV, footnote 1).

Each SAH finger is an abduction joint (axis -x of the finger's knuckle frame, positive towards the
thumb side) and three flexions about the knuckle's y axis at 0, L1 and L1 + L2 along its z axis, the
last one coupled 1:1 to the middle one. In the knuckle frame at zero abduction a fingertip is at

    p = (X, Z sin a, Z cos a),   X + iZ = i (L1 e^{-i t1} + L2 e^{-i (t1 + t2)} + L3 e^{-i (t1 + 2 t2)})

so the distance ``r = |p|`` to the knuckle depends on the middle angle t2 alone:
``r^2 = A + B cos t2 + C (2 cos^2 t2 - 1)``, a quadratic in ``cos t2`` that is monotone on the joint
range. The solver is closed-form: abduction from the direction of p in the y-z plane, t2 from r, t1
from the angle of (X, Z). Robustness as the paper's footnote: a target farther (or nearer) than the
finger can reach is moved along the ray from the knuckle onto the reachable distance, and angles
outside their limits are cut off; when anything was cut, the tip goes to the reachable point nearest the
original target. That search is exact in abduction and proximal flexion for a given middle angle (with
``theta = t1 + phi(t2)`` the tip is ``r(t2) (sin theta, cos theta sin a, cos theta cos a)``, and the best
``(a, theta)`` in the limits is among a few closed-form candidates) and a zoomed grid over the middle
angle, so it finds the global nearest point of the non-convex workspace to ~0.01 deg in t2.

The thumb's base rotation (opposition) is not solved: it is taken from the seed (default: the rest
pose's 90 deg) and IK solves abduction, proximal and middle flexion in the knuckle frame it gives.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from assets import sah
from assets.errors import InputError
from assets.se3 import skew

__all__ = [
    "THUMB_BASE",
    "FingerGeometry",
    "finger_geometry",
    "finger_ik",
    "hand_ik",
    "finger_fk_local",
    "fingertips",
]

_GRID_T2 = 64  # middle-joint values of the nearest-point search over the joint range
_ZOOM_POINTS = 33  # values per zoom, over two grid cells about the best one so far
_ZOOMS = 2  # zooms: the middle angle to (range / 63) / 16^2, about 0.006 deg
_UNIT_GRID = np.linspace(0.0, 1.0, _GRID_T2)
_UNIT_ZOOM = np.linspace(-1.0, 1.0, _ZOOM_POINTS)
THUMB_BASE = sah.JOINT_NAMES.index("thumb_base")
"""Index of the thumb's opposition joint in the 13 joints: the IK keeps it from the seed."""
_FLEXION = [list(sah.FINGER_JOINTS[f])[-3:] for f in sah.FINGERS]  # abd, prox, mid of each finger


@dataclass(frozen=True)
class FingerGeometry:
    """What the IK needs of one finger, read from the URDF.

    Attributes:
        finger: the finger name.
        lengths_m: (3,) L1, L2, L3: knuckle -> mid joint -> distal joint -> tip [m].
        limits: (3, 2) [rad] of abduction, proximal and middle flexion.
        T_parent_knuckle0: (4, 4) the knuckle frame at zero abduction in the abduction joint's parent
            (the wrist for index/middle/ring, the thumb module for the thumb).
        T_wrist_module_origin: (4, 4) the thumb base joint frame at zero (thumb only, else identity).
        module_axis: (3,) the thumb base axis (thumb only, else zeros).
        reach_m: (2,) smallest and largest knuckle-to-tip distance over the middle-joint range [m].
    """

    finger: str
    lengths_m: np.ndarray
    limits: np.ndarray
    T_parent_knuckle0: np.ndarray
    T_wrist_module_origin: np.ndarray
    module_axis: np.ndarray
    reach_m: tuple[float, float] = (0.0, np.inf)


@lru_cache(maxsize=4)
def finger_geometry(finger: str) -> FingerGeometry:
    """The :class:`FingerGeometry` of an SAH finger (cached).

    Raises:
        InputError: unknown finger name.
    """
    if finger not in sah.FINGERS:
        raise InputError(f"unknown SAH finger {finger!r}; valid names: {', '.join(sah.FINGERS)}")
    joints = {j.name: j for j in sah.model().joints}
    lengths = []
    for name in (f"{finger}_mid", f"{finger}_dist", f"{finger}_tip_joint"):
        t = joints[name].T_parent_joint
        if np.abs(t[:3, :3] - np.eye(3)).max() > 1e-12 or np.abs(t[:2, 3]).max() > 1e-12:
            raise RuntimeError(f"sah.urdf: joint {name} is not a pure offset along z; the IK assumes it")
        lengths.append(t[2, 3])
    idx = [sah.JOINT_NAMES.index(f"{finger}_{s}") for s in ("abd", "prox", "mid")]
    T_origin, axis = np.eye(4), np.zeros(3)
    if finger == "thumb":
        T_origin, axis = joints["thumb_base"].T_parent_joint, joints["thumb_base"].axis
    g = FingerGeometry(
        finger,
        np.array(lengths),
        sah.JOINT_LIMITS[idx].copy(),
        joints[f"{finger}_abd"].T_parent_joint,
        T_origin,
        axis,
    )
    r = [float(np.linalg.norm(finger_fk_local(g, np.array([[0.0, 0.0, t]]))[0])) for t in g.limits[2]]
    return replace(g, reach_m=(min(r), max(r)))


def _T_wrist_knuckle0(g: FingerGeometry, thumb_base: np.ndarray) -> np.ndarray:
    """(N, 4, 4) knuckle frame at zero abduction in the wrist frame."""
    if g.finger != "thumb":
        return np.broadcast_to(g.T_parent_knuckle0, thumb_base.shape + (4, 4))
    K = skew(g.module_axis)
    th = thumb_base[:, None, None]
    R = np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * (K @ K)
    T_rot = np.zeros(thumb_base.shape + (4, 4))
    T_rot[:, :3, :3] = R
    T_rot[:, 3, 3] = 1.0
    return g.T_wrist_module_origin @ T_rot @ g.T_parent_knuckle0


@lru_cache(maxsize=1024)
def _knuckle0(finger: str, thumb_base: float) -> np.ndarray:
    """(4, 4) a finger's knuckle frame at zero abduction in the wrist frame (the thumb at ``thumb_base``);
    cached: a retargeting step moves the thumb's base rarely."""
    if finger != "thumb":
        return finger_geometry(finger).T_parent_knuckle0
    T = _T_wrist_knuckle0(finger_geometry(finger), np.array([thumb_base]))[0]
    T.setflags(write=False)
    return T


def _knuckle_frames(thumb_base: float) -> np.ndarray:
    """(4, 4, 4) the four fingers' :func:`_knuckle0` frames, :data:`assets.sah.FINGERS` order."""
    return np.stack([_knuckle0(f, float(thumb_base)) for f in sah.FINGERS])


def finger_fk_local(g: FingerGeometry, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tip in the knuckle frame at zero abduction and its Jacobian.

    Args:
        g: the finger.
        v: (N, 3) abduction, proximal, middle [rad] (distal = middle).

    Returns:
        p (N, 3) [m] and J (N, 3, 3) = dp / dv.
    """
    return _tip_local(g.lengths_m, v)


def _tip_local(lengths_m: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`finger_fk_local` with the lengths (3,) of one finger or (N, 3), one finger per row."""
    L1, L2, L3 = lengths_m[..., 0], lengths_m[..., 1], lengths_m[..., 2]
    a, t1, t2 = v[:, 0], v[:, 1], v[:, 2]
    s1, c1 = np.sin(t1), np.cos(t1)
    s12, c12 = np.sin(t1 + t2), np.cos(t1 + t2)
    s122, c122 = np.sin(t1 + 2 * t2), np.cos(t1 + 2 * t2)
    X = L1 * s1 + L2 * s12 + L3 * s122
    Z = L1 * c1 + L2 * c12 + L3 * c122
    dX2 = L2 * c12 + 2 * L3 * c122
    dZ2 = -L2 * s12 - 2 * L3 * s122
    sa, ca = np.sin(a), np.cos(a)
    n = v.shape[0]
    p = np.empty((n, 3))
    p[:, 0], p[:, 1], p[:, 2] = X, Z * sa, Z * ca
    J = np.empty((n, 3, 3))
    J[:, 0, 0], J[:, 0, 1], J[:, 0, 2] = 0.0, Z, dX2
    J[:, 1, 0], J[:, 1, 1], J[:, 1, 2] = Z * ca, -X * sa, dZ2 * sa
    J[:, 2, 0], J[:, 2, 1], J[:, 2, 2] = -Z * sa, -X * ca, dZ2 * ca
    return p, J


@dataclass(frozen=True)
class _Rows:
    """Per-row finger geometry for a batch that mixes fingers: lengths (N, 3), limits lo, hi (N, 3),
    and reach r_min, r_max (N,)."""

    lengths_m: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    r_min: np.ndarray
    r_max: np.ndarray

    def take(self, rows: np.ndarray) -> _Rows:
        return _Rows(*(a[rows] for a in (self.lengths_m, self.lo, self.hi, self.r_min, self.r_max)))


@lru_cache(maxsize=8)
def _rows_of(fingers: tuple[str, ...]) -> _Rows:
    """The :class:`_Rows` of one row per finger name (cached; the SAH's four fingers in one batch)."""
    gs = [finger_geometry(f) for f in fingers]
    return _Rows(
        np.stack([g.lengths_m for g in gs]),
        np.stack([g.limits[:, 0] for g in gs]),
        np.stack([g.limits[:, 1] for g in gs]),
        np.array([g.reach_m[0] for g in gs]),
        np.array([g.reach_m[1] for g in gs]),
    )


def _closed_form(rows: _Rows, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clipped closed-form solution (N, 3) and a mask of the rows where something was clipped."""
    L = rows.lengths_m
    L1, L2, L3 = L[:, 0], L[:, 1], L[:, 2]
    r = np.linalg.norm(p, axis=-1)
    r_c = np.clip(r, rows.r_min, rows.r_max)
    moved = np.abs(r_c - r) > 1e-12
    safe = np.where(r > 1e-12, r, 1.0)
    p = np.where(moved[:, None], p * (r_c / safe)[:, None], p)
    on_knuckle = np.stack([np.zeros_like(r), np.zeros_like(r), rows.r_min], axis=-1)
    p = np.where((r <= 1e-12)[:, None], on_knuckle, p)
    # abduction: the branch with Z > 0 or Z < 0 whose angle is smaller
    rho = np.hypot(p[:, 1], p[:, 2])
    a_pos = np.arctan2(p[:, 1], p[:, 2])
    a_neg = np.arctan2(-p[:, 1], -p[:, 2])
    use_pos = np.abs(a_pos) <= np.abs(a_neg)
    a = np.where(use_pos, a_pos, a_neg)
    Z = np.where(use_pos, rho, -rho)
    X = p[:, 0]
    # middle angle from the distance: 2C c^2 + B c + (A - C - r^2) = 0
    A = L1 * L1 + L2 * L2 + L3 * L3
    B = 2 * (L1 * L2 + L2 * L3)
    C = 2 * L1 * L3
    disc = np.maximum(B * B - 8 * C * (A - C - r_c * r_c), 0.0)
    c = (-B + np.sqrt(disc)) / (4 * C)
    t2 = np.arccos(np.clip(c, -1.0, 1.0))
    phi = np.arctan2(L2 * np.sin(t2) + L3 * np.sin(2 * t2), L1 + L2 * np.cos(t2) + L3 * np.cos(2 * t2))
    t1 = np.arctan2(X, Z) - phi
    t1 = (t1 + np.pi) % (2 * np.pi) - np.pi
    v = np.stack([a, t1, t2], axis=-1)
    v_c = np.clip(v, rows.lo, rows.hi)
    clipped = moved | np.any(np.abs(v_c - v) > 1e-12, axis=-1)
    return v_c, clipped


def _finger_plane(lengths_m: np.ndarray, t2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Knuckle-to-tip distance r(t2) and the angle phi(t2) of the tip from the proximal link, (N, M)."""
    L1, L2, L3 = (lengths_m[:, k, None] for k in range(3))
    u = L1 + L2 * np.cos(t2) + L3 * np.cos(2 * t2)
    w = L2 * np.sin(t2) + L3 * np.sin(2 * t2)
    return np.hypot(u, w), np.arctan2(w, u)


@dataclass(frozen=True)
class _Target:
    """What :func:`_best_at` needs of the targets (N, 3): the abduction candidates ``a`` (N, 4), the
    amplitude ``c = rho cos(a - a*)`` (N, 4) of the cos theta term, the sinusoid's peak value ``R`` and
    angle ``beta`` (N, 4), ``q_x`` and ``|q|^2`` (N,)."""

    a: np.ndarray
    c: np.ndarray
    R: np.ndarray
    beta: np.ndarray
    qx: np.ndarray
    q2: np.ndarray

    @classmethod
    def of(cls, rows: _Rows, q: np.ndarray) -> _Target:
        lo, hi = rows.lo[:, :1], rows.hi[:, :1]
        qx, rho, a_star = q[:, 0], np.hypot(q[:, 1], q[:, 2]), np.arctan2(q[:, 1], q[:, 2])
        a = np.stack([lo[:, 0], hi[:, 0], a_star, a_star + np.pi], axis=-1)  # the ends, a*, a* + pi
        a = (a - lo) % (2 * np.pi) + lo
        a = np.where(a <= hi, a, lo)  # a* or a* + pi out of range: an end instead
        c = rho[:, None] * np.cos(a - a_star[:, None])
        qxc = np.broadcast_to(qx[:, None], c.shape)
        return cls(a, c, np.hypot(qxc, c), np.arctan2(qxc, c), qx, (q * q).sum(axis=1))


def _best_at(rows: _Rows, q: _Target, t2: np.ndarray, angles: bool) -> tuple[np.ndarray, ...]:
    """The nearest tip to the targets for each fixed middle angle ``t2`` (N, M), exactly.

    With theta = t1 + phi(t2) the tip is ``r(t2) (sin theta, cos theta sin a, cos theta cos a)``, so
    ``|tip - q|^2 = |q|^2 + r^2 - 2 r f`` with ``f = q_x sin theta + rho cos(a - a*) cos theta``
    (``rho, a*``: the target's polar coordinates in the y-z plane). For a fixed ``a``, f is a sinusoid of
    theta whose maximum over an interval is its peak, if inside, or an end; f's maximum over theta is
    convex in ``c = rho cos(a - a*)``, so over the abduction interval it is at an extreme of c: an end,
    a*, or a* + pi (:class:`_Target`). Returns the squared distances (N, M) and, with ``angles``, the
    abduction and proximal angles (N, M).
    """
    r, phi = _finger_plane(rows.lengths_m, t2)  # (N, M)
    th0 = rows.lo[:, 1, None] + phi
    th1 = rows.hi[:, 1, None] + phi
    qx, c = q.qx[:, None, None], q.c[:, None, :]
    f0 = qx * np.sin(th0)[..., None] + c * np.cos(th0)[..., None]  # (N, M, 4)
    f1 = qx * np.sin(th1)[..., None] + c * np.cos(th1)[..., None]
    off = (q.beta[:, None, :] - th0[..., None]) % (2 * np.pi)
    inside = off <= (rows.hi[:, 1] - rows.lo[:, 1])[:, None, None]
    f = np.where(inside, q.R[:, None, :], np.maximum(f0, f1))
    d2 = q.q2[:, None] + r * r - 2 * r * f.max(axis=-1)
    if not angles:
        return (d2,)
    n, m = t2.shape
    k = np.argmax(f, axis=-1)
    i, j = np.arange(n)[:, None], np.arange(m)[None, :]
    theta = np.where(inside, th0[..., None] + off, np.where(f0 >= f1, th0[..., None], th1[..., None]))
    return d2, q.a[i, k], theta[i, j, k] - phi


def _nearest_reachable(rows: _Rows, target: np.ndarray) -> np.ndarray:
    """The joint values (N, 3) within the limits whose tip is nearest ``target`` (N, 3).

    Exact in abduction and proximal flexion for each middle angle (:func:`_best_at`); the middle angle by
    a grid over its range (:data:`_GRID_T2` points), zoomed :data:`_ZOOMS` times about the best point.
    """
    q = _Target.of(rows, target)
    lo2, hi2 = rows.lo[:, 2, None], rows.hi[:, 2, None]
    t2 = lo2 + (hi2 - lo2) * _UNIT_GRID
    cell = (hi2 - lo2) / (_GRID_T2 - 1)
    n = np.arange(len(target))
    for _ in range(_ZOOMS):
        (d2,) = _best_at(rows, q, t2, angles=False)
        t2 = np.clip(t2[n, np.argmin(d2, axis=1)][:, None] + cell * _UNIT_ZOOM, lo2, hi2)
        cell = 2 * cell / (_ZOOM_POINTS - 1)
    d2, a, t1 = _best_at(rows, q, t2, angles=True)
    k = np.argmin(d2, axis=1)
    return np.clip(np.stack([a[n, k], t1[n, k], t2[n, k]], axis=-1), rows.lo, rows.hi)


def _solve_rows(rows: _Rows, p_local: np.ndarray) -> np.ndarray:
    """Closed form, then the nearest reachable point of the clipped rows: (N, 3) targets -> (N, 3) joints."""
    v, clipped = _closed_form(rows, p_local)
    if np.any(clipped):
        v[clipped] = _nearest_reachable(rows.take(clipped), p_local[clipped])
    return v


def finger_ik(finger: str, p_wrist: np.ndarray, seed: np.ndarray | None = None) -> np.ndarray:
    """Joint values of one finger placing its tip at (or as near as it can to) ``p_wrist``.

    Args:
        finger: one of :data:`assets.sah.FINGERS`.
        p_wrist: (3,) or (N, 3) [m] fingertip targets in the wrist frame.
        seed: (k,) or (N, k) [rad] current values of the finger's joints
            (``sah.FINGER_JOINTS[finger]``); only the thumb uses it, for its fixed base rotation
            (default: :func:`assets.sah.rest_joints`). The closed form needs no other seed.

    Returns:
        (N, k) [rad] values of ``sah.FINGER_JOINTS[finger]`` (thumb: base, abd, prox, mid; others: abd,
        prox, mid), inside the joint limits; the distal joint follows the mid one.

    Raises:
        InputError: unknown finger, wrong shapes or non-finite input.
    """
    g = finger_geometry(finger)
    p = np.asarray(p_wrist, dtype=float)
    if p.ndim == 1:
        p = p[None]
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"finger_ik: p_wrist must have shape (3,) or (N, 3), found {np.shape(p_wrist)}")
    if not np.all(np.isfinite(p)):
        raise InputError("finger_ik: p_wrist has non-finite values")
    n = p.shape[0]
    k = len(sah.FINGER_JOINTS[finger])
    if finger == "thumb":
        if seed is None:
            base = np.full(n, sah.rest_joints()[0])
        else:
            s = np.asarray(seed, dtype=float)
            if s.shape not in ((k,), (n, k)):
                raise InputError(f"finger_ik: seed must have shape ({k},) or ({n}, {k}), found {s.shape}")
            base = np.broadcast_to(s[..., 0], (n,)).astype(float)
        base = np.clip(base, *sah.JOINT_LIMITS[0])
    else:
        base = np.zeros(n)
    T = _T_wrist_knuckle0(g, base)
    p_local = np.einsum("nji,nj->ni", T[..., :3, :3], p - T[..., :3, 3])
    rows = _rows_of((finger,)).take(np.zeros(n, dtype=int))
    v = _solve_rows(rows, p_local)
    return np.concatenate([base[:, None], v], axis=-1) if finger == "thumb" else v


def hand_ik(p_wrist_tips: np.ndarray, seed_joints: np.ndarray) -> np.ndarray:
    """IK of all four fingers.

    Args:
        p_wrist_tips: (4, 3) [m] fingertip targets in the wrist frame, :data:`assets.sah.FINGERS` order.
        seed_joints: (13,) [rad]; its thumb base value is kept.

    Returns:
        (13,) [rad] joint values inside the limits.
    """
    p = np.asarray(p_wrist_tips, dtype=float)
    seed = np.asarray(seed_joints, dtype=float)
    if p.shape != (4, 3) or seed.shape != (13,):
        raise InputError(f"hand_ik: expected (4, 3) targets and a (13,) seed, found {p.shape}, {seed.shape}")
    if not np.all(np.isfinite(p)):
        raise InputError("hand_ik: the targets have non-finite values")
    out = seed.copy()
    thumb_base = np.clip(seed[THUMB_BASE], *sah.JOINT_LIMITS[THUMB_BASE])
    T = _knuckle_frames(thumb_base)
    p_local = np.einsum("nji,nj->ni", T[..., :3, :3], p - T[..., :3, 3])
    v = _solve_rows(_rows_of(sah.FINGERS), p_local)
    out[THUMB_BASE] = thumb_base
    for i, idx in enumerate(_FLEXION):
        out[idx] = v[i]
    return out


def fingertips(joints: np.ndarray) -> np.ndarray:
    """The four fingertips (4, 3) [m] in the wrist frame at joints (13,) [rad]: the IK's own forward
    kinematics (:func:`finger_fk_local` in each knuckle frame), equal to
    :func:`assets.sah.fingertip_positions` to ~1e-16 m and several times cheaper for one configuration
    (the retargeting objective's hot path)."""
    q = np.asarray(joints, dtype=float)
    T = _knuckle_frames(q[THUMB_BASE])
    p_local, _ = _tip_local(_rows_of(sah.FINGERS).lengths_m, q[_FLEXION])
    return np.einsum("nij,nj->ni", T[:, :3, :3], p_local) + T[:, :3, 3]
