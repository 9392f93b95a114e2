"""The one definition of the SAH's 19-D configuration ``q`` and of its 19-D tangent.

``q`` (19,) = ``[p (3, m), r (3, rad), joints (13, rad)]``: the wrist position and rotation vector
(scaled axis) in the world or the object frame, then the 13 actuated SAH joints in :data:`JOINT_NAMES`
order (the four distal joints copy the middle ones and are not part of ``q``)::

    q[POS]     wrist position p (3,) [m]
    q[ROT]     wrist rotation vector r (3,) [rad]
    q[JOINTS]  joints (13,) [rad], JOINT_NAMES order
    q[POSE]    the wrist pose (6,) [p, r]

Covariances of a configuration live in GTSAM's Pose3 tangent instead, rotation first:
``xi`` (19,) = ``[omega (3, rad), v (3, m), joints (13, rad)]``, the wrist perturbed on the right,
``T = T_mean @ Exp(xi[TAN_POSE])`` (:func:`assets.se3.retract`)::

    xi[TAN_ROT]     omega (3,) [rad]
    xi[TAN_POS]     v (3,) [m], in the wrist (body) frame
    xi[TAN_POSE]    the Pose3 tangent (6,) [omega, v]
    xi[JOINTS]      joints (13,) [rad], the same slice as in q

Quaternions, where a library boundary needs them, are ``[x, y, z, w]`` everywhere (scipy's order;
:mod:`assets.se3`).
"""

from __future__ import annotations

__all__ = [
    "JOINT_NAMES",
    "N_JOINTS",
    "POSE_DIM",
    "Q_DIM",
    "POS",
    "ROT",
    "POSE",
    "JOINTS",
    "TAN_ROT",
    "TAN_POS",
    "TAN_POSE",
]

JOINT_NAMES: tuple[str, ...] = (
    "thumb_base", "thumb_abd", "thumb_prox", "thumb_mid",
    "index_abd", "index_prox", "index_mid",
    "middle_abd", "middle_prox", "middle_mid",
    "ring_abd", "ring_prox", "ring_mid",
)  # fmt: skip
"""The 13 actuated SAH joints, the order of every SAH joint vector and of ``q[JOINTS]``."""

N_JOINTS: int = len(JOINT_NAMES)
"""Actuated SAH joints in ``q`` (13)."""

POSE_DIM: int = 6
"""Entries of the wrist pose in ``q`` (position and rotation vector) and of its Pose3 tangent."""

Q_DIM: int = POSE_DIM + N_JOINTS
"""Entries of ``q`` and of its tangent."""

POS = slice(0, 3)
"""Wrist position in ``q`` [m]."""

ROT = slice(3, 6)
"""Wrist rotation vector in ``q`` [rad]."""

POSE = slice(0, POSE_DIM)
"""The wrist pose ``[p, r]`` in ``q``."""

JOINTS = slice(POSE_DIM, None)
"""The joints, in ``q`` and in its tangent alike [rad] (13 for the SAH; the same slice serves the
human hand's 6 + 20 entries in the pybullet world)."""

TAN_ROT = slice(0, 3)
"""Rotation ``omega`` in the tangent [rad] (GTSAM's Pose3 order: rotation first)."""

TAN_POS = slice(3, 6)
"""Translation ``v`` in the tangent [m], wrist (body) frame."""

TAN_POSE = slice(0, POSE_DIM)
"""The Pose3 tangent ``[omega, v]`` of the wrist."""
