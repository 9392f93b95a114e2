"""The Schunk Anthropomorphic Hand (SAH): joint order, limits, forward kinematics, fingertip Jacobian.

The model is ``assets/hands/sah/sah.urdf`` (see its README for frames, sources and simplifications).
The wrist frame is the URDF base link: +z along the middle finger, +y towards the thumb/index side,
+x out of the palm (the side the fingers flex towards). The 13 actuated joints, in the order used by
every 13-vector and by ``q[JOINTS]``, are :data:`assets.q_layout.JOINT_NAMES` (re-exported here); the
four distal joints copy the middle ones 1:1 (:func:`expand_mimic`).

Tangent convention of :func:`fingertip_jacobian`: 19 columns ``[omega (3), v (3), 13 joints]``, the
wrist pose perturbed on the right, ``T_object_wrist @ Exp(xi)`` (:func:`assets.se3.retract`), as
GTSAM's Pose3 and as the 19x19 configuration covariances.
"""

from __future__ import annotations

from functools import lru_cache
from types import MappingProxyType

import numpy as np

import assets
from assets.q_layout import Q_DIM

from .kinematics import HandModel, collision_radius, load_hand_model
from .q_layout import JOINT_NAMES, TAN_POS, TAN_ROT
from .se3 import skew

__all__ = [
    "JOINT_NAMES",
    "URDF_JOINT_NAMES",
    "FINGERS",
    "FINGER_JOINTS",
    "JOINT_LIMITS",
    "TIP_LINKS",
    "FINGERTIP_RADII_M",
    "BASE_LINKS",
    "SELF_COLLISION_EXCLUDED_PAIRS",
    "model",
    "expand_mimic",
    "fk",
    "fingertip_positions",
    "fingertip_positions_in",
    "rest_joints",
    "clip_joints",
    "fingertip_jacobian",
    "fingertip_marginals",
    "FINGERTIP_COV_MAPS",
    "config_cov_from_fingertip_cov",
]

FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring")

FINGER_JOINTS = MappingProxyType(
    {f: tuple(i for i, n in enumerate(JOINT_NAMES) if n.startswith(f + "_")) for f in FINGERS}
)
"""finger -> indices into the 13-vector.

thumb (0, 1, 2, 3), index (4, 5, 6), middle (7, 8, 9), ring (10, 11, 12).
"""

URDF_JOINT_NAMES: tuple[str, ...] = JOINT_NAMES + tuple(f"{f}_dist" for f in FINGERS)
"""The 13 actuated joints then the 4 distal mimic joints (thumb, index, middle, ring)."""

TIP_LINKS: tuple[str, ...] = tuple(f"{f}_tip" for f in FINGERS)
"""Fingertip frames (end of each distal phalanx), :data:`FINGERS` order."""

FINGERTIP_RADII_M: tuple[float, ...] = tuple(
    collision_radius(assets.hand_urdf("sah"), f"{f}_distal") for f in FINGERS
)
"""Radius [m] of each distal phalanx's collision capsule (the fingertip pad), :data:`FINGERS` order."""

BASE_LINKS: tuple[str, ...] = tuple(f"{f}_knuckle" for f in FINGERS)
"""The link at each finger's abduction/flexion centre (MCP), :data:`FINGERS` order."""

SELF_COLLISION_EXCLUDED_PAIRS: tuple[tuple[str, str], ...] = ()
"""Non-adjacent link pairs that touch by construction and must be excluded from self-collision checks.

Empty: in the shipped URDF no non-adjacent pair touches at any joint values by construction (the thumb
module ends 2 mm short of the thumb's proximal phalanx; the palm ends 4 mm below the knuckles).
Parent-child pairs are excluded by pybullet itself; the knuckle links carry no collision shape.
"""

_MID = np.array([JOINT_NAMES.index(f"{f}_mid") for f in FINGERS])


@lru_cache(maxsize=1)
def model() -> HandModel:
    """The parsed SAH URDF (cached)."""
    return load_hand_model(str(assets.hand_urdf("sah")))


def _limits() -> np.ndarray:
    m = model()
    if m.joint_names != JOINT_NAMES:
        raise RuntimeError(f"sah.urdf actuated joints {m.joint_names} differ from JOINT_NAMES")
    return m.limits.copy()


JOINT_LIMITS: np.ndarray = _limits()
"""(13, 2) [rad] lower and upper limits, read from the URDF."""
JOINT_LIMITS.setflags(write=False)


def expand_mimic(joints: np.ndarray) -> np.ndarray:
    """The 17 URDF joint values (:data:`URDF_JOINT_NAMES`) from the 13 actuated ones.

    Args:
        joints: (..., 13) [rad].

    Returns:
        (..., 17) [rad], the distal joints equal to the mid ones.
    """
    joints = np.asarray(joints, dtype=float)
    return np.concatenate([joints, joints[..., _MID]], axis=-1)


def fk(joints: np.ndarray) -> dict[str, np.ndarray]:
    """Link poses ``T_wrist_link`` (..., 4, 4) for joints (..., 13) [rad]; distal joints copy the mids."""
    return model().fk(joints)


def fingertip_positions(joints: np.ndarray) -> np.ndarray:
    """Fingertip positions in the wrist frame, (..., 13) -> (..., 4, 3) [m], :data:`FINGERS` order."""
    poses = fk(joints)
    return np.stack([poses[t][..., :3, 3] for t in TIP_LINKS], axis=-2)


def fingertip_positions_in(T_frame_wrist: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Fingertip positions (..., 4, 3) [m] in a frame from ``T_frame_wrist`` (..., 4, 4), joints (..., 13)."""
    T = np.asarray(T_frame_wrist, dtype=float)
    p = fingertip_positions(joints)
    return np.einsum("...ij,...kj->...ki", T[..., :3, :3], p) + T[..., None, :3, 3]


def rest_joints() -> np.ndarray:
    """The open rest pose (13,) [rad]: thumb opposed (90 deg), every finger flexed 10/10 deg, no abduction.

    Free of self-collision (tested in pybullet).
    """
    d = np.deg2rad
    q = np.zeros(len(JOINT_NAMES))
    q[0] = d(90.0)
    for f in FINGERS:
        q[JOINT_NAMES.index(f"{f}_prox")] = d(10.0)
        q[JOINT_NAMES.index(f"{f}_mid")] = d(10.0)
    return q


def clip_joints(joints: np.ndarray) -> np.ndarray:
    """Joint values (..., 13) cut to :data:`JOINT_LIMITS`."""
    return np.clip(np.asarray(joints, dtype=float), JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1])


def fingertip_jacobian(T_object_wrist: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Analytic Jacobian of the four fingertip positions in the object frame.

    Args:
        T_object_wrist: (..., 4, 4) wrist pose in the object frame.
        joints: (..., 13) [rad].

    Returns:
        (..., 12, 19): rows thumb xyz, index xyz, middle xyz, ring xyz [m]; columns the wrist tangent
        ``[omega (3) rad, v (3) m]`` of ``T_object_wrist @ Exp(xi)`` (body frame, right perturbation),
        then the 13 joints [rad] (a mid joint's column includes its distal mimic).
    """
    T = np.asarray(T_object_wrist, dtype=float)
    joints = np.asarray(joints, dtype=float)
    batch = np.broadcast_shapes(T.shape[:-2], joints.shape[:-1])
    T = np.broadcast_to(T, batch + (4, 4))
    joints = np.broadcast_to(joints, batch + (13,))
    m = model()
    poses = m.fk(joints)
    R = T[..., None, :3, :3]  # (..., 1, 3, 3)
    J = np.zeros(batch + (4, 3, Q_DIM))
    p_wrist = np.stack([poses[t][..., :3, 3] for t in TIP_LINKS], axis=-2)  # (..., 4, 3)
    # d/dxi of R (Exp(xi) p) at 0 = R [-skew(p) | I]
    J[..., TAN_ROT] = -R @ skew(p_wrist)
    J[..., TAN_POS] = np.broadcast_to(R, batch + (4, 3, 3))
    for k, t in enumerate(TIP_LINKS):
        J[..., k, :, 6:] = T[..., :3, :3] @ m.point_jacobian(joints, t, poses)
    return J.reshape(batch + (12, Q_DIM))


def fingertip_marginals(
    T_object_wrist_mean: np.ndarray, joints_mean: np.ndarray, cov: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The fingertips' Gaussian marginals of configuration marginals, linearized: ``J cov J^T``.

    Args:
        T_object_wrist_mean: (T, 4, 4) wrist means in the object frame.
        joints_mean: (T, 13) [rad].
        cov: (T, 19, 19) ``[omega, v, joints]`` (the body tangent of :func:`fingertip_jacobian`).

    Returns:
        means (T, 4, 3) [m] and covariances (T, 4, 3, 3) [m^2] of the fingertips in the object frame,
        :data:`FINGERS` order (the 3x3 diagonal blocks; the cross-finger terms are dropped).
    """
    mean = fingertip_positions_in(T_object_wrist_mean, joints_mean)
    J = fingertip_jacobian(T_object_wrist_mean, joints_mean)  # (T, 12, 19)
    full = J @ np.asarray(cov, dtype=float) @ np.swapaxes(J, -1, -2)
    blocks = np.stack([full[..., 3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(len(FINGERS))], axis=-3)
    return mean, 0.5 * (blocks + np.swapaxes(blocks, -1, -2))


FINGERTIP_COV_MAPS = ("configuration", "finger_joints")
"""How :func:`config_cov_from_fingertip_cov` realises a fingertip covariance in the configuration."""


def config_cov_from_fingertip_cov(
    J: np.ndarray, cov_tips: np.ndarray, rcond: float = 1e-10, through: str = "configuration"
) -> np.ndarray:
    """Map a fingertip covariance into the 19-D configuration tangent: ``J+ cov J+^T``.

    Args:
        J: (..., 12, 19) from :func:`fingertip_jacobian`.
        cov_tips: (..., 12, 12) [m^2] covariance of the stacked fingertip positions.
        rcond: relative cut-off of small singular values in the pseudo-inverse.
        through: ``"configuration"``: the pseudo-inverse of the whole Jacobian, so the wrist and the
            joints share the fingertip variation (the minimum-norm configuration change per fingertip
            change, which couples them); ``"finger_joints"``: the pseudo-inverse of the joint columns
            alone, the wrist held, so the fingertips vary by the fingers' own joints and the wrist rows
            and columns stay zero (a wrist variance is then stated on its own).

    Returns:
        (..., 19, 19) in ``[omega, v, 13 joints]``; rank <= 12, degenerate by design (the paper's Sigma_r).

    Raises:
        InputError: an unknown ``through``.
    """
    J = np.asarray(J, dtype=float)
    if through == "configuration":
        Jp = np.linalg.pinv(J, rcond=rcond)
    elif through == "finger_joints":
        Jp = np.zeros(J.shape[:-2] + (Q_DIM, J.shape[-2]))
        Jp[..., 6:, :] = np.linalg.pinv(J[..., 6:], rcond=rcond)
    else:
        raise assets.InputError(
            f"through: expected one of {', '.join(FINGERTIP_COV_MAPS)}, found {through!r}"
        )
    cov = Jp @ np.asarray(cov_tips, dtype=float) @ np.swapaxes(Jp, -1, -2)
    return 0.5 * (cov + np.swapaxes(cov, -1, -2))
