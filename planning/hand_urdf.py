"""A hand's joints as the pybullet world sees them: their order in ``q``, the rest pose, and the link pairs
that touch by construction. The SAH's come from :mod:`assets.sah` and :mod:`assets.q_layout`, other hands'
(the human hand, for pictures) from their URDF.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

import assets
from assets import human_hand, sah
from assets.errors import InputError
from assets.q_layout import JOINT_NAMES

__all__ = [
    "default_excluded_pairs",
    "hand_joint_limits",
    "hand_joint_names",
    "hand_rest_joints",
    "urdf_joints",
]


def urdf_joints(urdf: Path) -> tuple[list[str], dict[str, tuple[str, float, float]]]:
    """Actuated joint names (URDF order) and mimic joints ``{name: (master, multiplier, offset)}``."""
    actuated, mimic, _ = _urdf_joint_table(urdf)
    return actuated, mimic


def _urdf_joint_table(urdf: Path):
    root = ET.parse(urdf).getroot()
    actuated, mimic, limits = [], {}, {}
    for j in root.iter("joint"):
        if j.get("type") in ("fixed", "floating", "planar"):
            continue
        m = j.find("mimic")
        if m is not None:
            mimic[j.get("name")] = (m.get("joint"), float(m.get("multiplier", 1)), float(m.get("offset", 0)))
            continue
        actuated.append(j.get("name"))
        lim = j.find("limit")
        if lim is not None and j.get("type") != "continuous":
            limits[j.get("name")] = (float(lim.get("lower", 0)), float(lim.get("upper", 0)))
    return actuated, mimic, limits


def hand_rest_joints(hand: str) -> np.ndarray:
    """The rest (open) pose of a hand's joints in :func:`hand_joint_names` order [rad].

    SAH: ``assets.sah.rest_joints()`` (thumb opposed, fingers slightly flexed, free of self-collision);
    other hands: 0 clipped into the URDF limits.
    """
    if hand == "sah":
        return np.asarray(sah.rest_joints(), dtype=float)
    _, _, limits = _urdf_joint_table(assets.hand_urdf(hand))
    out = []
    for name in hand_joint_names(hand):
        lo, hi = limits.get(name, (0.0, 0.0))
        out.append(float(np.clip(0.0, lo, hi)) if hi > lo else 0.0)
    return np.array(out)


def hand_joint_limits(hand: str) -> np.ndarray:
    """(n, 2) lower and upper limits [rad] of a hand's joints in :func:`hand_joint_names` order, from its
    URDF (a joint without limits: infinite)."""
    _, _, limits = _urdf_joint_table(assets.hand_urdf(hand))
    return np.array([limits.get(n, (-np.inf, np.inf)) for n in hand_joint_names(hand)], dtype=float)


def hand_joint_names(hand: str) -> list[str]:
    """The joint order of ``q[JOINTS]`` for a hand: :data:`assets.q_layout.JOINT_NAMES` for the SAH, else
    the URDF's."""
    actuated, _ = urdf_joints(assets.hand_urdf(hand))
    if hand == "sah":
        if sorted(JOINT_NAMES) != sorted(actuated):
            raise InputError(
                f"assets.q_layout.JOINT_NAMES {list(JOINT_NAMES)} disagree with the URDF's {actuated}"
            )
        return list(JOINT_NAMES)
    return actuated


def default_excluded_pairs(hand: str) -> tuple[tuple[str, str], ...]:
    """Link pairs of a hand that touch by construction (``SELF_COLLISION_EXCLUDED_PAIRS`` of its module)."""
    if hand == "sah":
        return tuple(sah.SELF_COLLISION_EXCLUDED_PAIRS)
    if hand == "human":
        return tuple(human_hand.SELF_COLLISION_EXCLUDED_PAIRS)
    return ()
