"""The human hand model of the demonstrations: 20 joints, fingertip forward kinematics.

The model is ``assets/hands/human/human.urdf`` (see its README). Same wrist frame as the SAH: +z along
the middle finger, +y towards the thumb, +x out of the palm (the side the fingers flex towards); a
RIGHT hand. Joint order (every 20-vector): thumb_cmc_abd, thumb_cmc_flex, thumb_mcp, thumb_ip, then
for index, middle, ring, little: ``<f>_abd``, ``<f>_mcp``, ``<f>_pip``, ``<f>_dip``. Positive abduction
turns a finger towards +y (the thumb side); positive flexion closes it towards +x.
"""

from __future__ import annotations

from types import MappingProxyType

import numpy as np

import assets

from .kinematics import HandModel, collision_radius, load_hand_model

__all__ = [
    "JOINT_NAMES",
    "FINGERS",
    "FINGER_JOINTS",
    "JOINT_LIMITS",
    "TIP_LINKS",
    "FINGERTIP_RADII_M",
    "SELF_COLLISION_EXCLUDED_PAIRS",
    "model",
    "fk",
    "fingertip_positions",
]

FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")

# The palm capsule overlaps the little finger's and the thumb's first segments by construction (they are
# soft tissue in a real hand); pybullet only excludes parent-child pairs itself.
SELF_COLLISION_EXCLUDED_PAIRS: tuple[tuple[str, str], ...] = (
    ("wrist", "little_proximal"),
    ("wrist", "thumb_metacarpal"),
)

JOINT_NAMES: tuple[str, ...] = ("thumb_cmc_abd", "thumb_cmc_flex", "thumb_mcp", "thumb_ip") + tuple(
    f"{f}_{j}" for f in FINGERS[1:] for j in ("abd", "mcp", "pip", "dip")
)
"""The 20 joints, the order of every human-hand joint vector."""

FINGER_JOINTS = MappingProxyType(
    {f: tuple(i for i, n in enumerate(JOINT_NAMES) if n.startswith(f + "_")) for f in FINGERS}
)
"""finger -> indices into the 20-vector (4 each, in chain order)."""

TIP_LINKS: tuple[str, ...] = tuple(f"{f}_tip" for f in FINGERS)
"""Fingertip frames (end of each distal segment), :data:`FINGERS` order."""

FINGERTIP_RADII_M: tuple[float, ...] = tuple(
    collision_radius(assets.hand_urdf("human"), f"{f}_distal") for f in FINGERS
)
"""Radius [m] of each distal phalanx's collision capsule (the fingertip pad), :data:`FINGERS` order."""


def model() -> HandModel:
    """The parsed human-hand URDF (cached)."""
    return load_hand_model(str(assets.hand_urdf("human")))


def _limits() -> np.ndarray:
    m = model()
    if m.joint_names != JOINT_NAMES:
        raise RuntimeError(f"human.urdf actuated joints {m.joint_names} differ from JOINT_NAMES")
    return m.limits.copy()


JOINT_LIMITS: np.ndarray = _limits()
"""(20, 2) [rad] lower and upper limits, read from the URDF."""
JOINT_LIMITS.setflags(write=False)


def fk(joints: np.ndarray) -> dict[str, np.ndarray]:
    """Link poses ``T_wrist_link`` (..., 4, 4) for joints (..., 20) [rad]."""
    return model().fk(joints)


def fingertip_positions(joints: np.ndarray) -> np.ndarray:
    """Fingertip positions in the wrist frame, (..., 20) -> (..., 5, 3) [m], :data:`FINGERS` order."""
    poses = fk(joints)
    return np.stack([poses[t][..., :3, 3] for t in TIP_LINKS], axis=-2)
