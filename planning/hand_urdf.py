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
    "FLOATING_JOINTS",
    "default_excluded_pairs",
    "floating_urdf",
    "hand_joint_limits",
    "hand_joint_names",
    "hand_rest_joints",
    "urdf_joints",
]


#: the joints that carry a hand's root link in the pybullet world: prismatic along the world's x, y and z
#: from a fixed anchor, then spherical (the root link's orientation, a quaternion)
FLOATING_JOINTS = ("floating_x", "floating_y", "floating_z", "floating_rotation")

_INERTIAL = (
    '<inertial><mass value="0.001"/>'
    '<inertia ixx="1e-9" iyy="1e-9" izz="1e-9" ixy="0" ixz="0" iyz="0"/></inertial>'
)


def floating_urdf(urdf: Path) -> str:
    """The text of a hand's URDF with its root link carried by :data:`FLOATING_JOINTS` from a fixed anchor
    (links ``floating_anchor``, ``floating_x``, ``floating_y``, ``floating_z``: no geometry).

    pybullet sets the base pose of a floating body and its joints in two calls, each of which runs the
    forward kinematics and moves every link's collision shape; with the wrist pose as joints, one
    ``resetJointStatesMultiDof`` sets the whole hand (:meth:`planning.world.World.set_q`).

    Raises:
        InputError: the URDF has no single root link or already uses a floating joint name.
    """
    root = ET.parse(urdf).getroot()
    children = {j.find("child").get("link") for j in root.iter("joint")}
    roots = [link.get("name") for link in root.iter("link") if link.get("name") not in children]
    names = {j.get("name") for j in root.iter("joint")} | {link.get("name") for link in root.iter("link")}
    if len(roots) != 1 or names & {*FLOATING_JOINTS, "floating_anchor"}:
        raise InputError(f"{urdf}: expected one root link and no floating_* names, found roots {roots}")
    parent, chain = "floating_anchor", [f'<link name="floating_anchor">{_INERTIAL}</link>']
    for name, axis in zip(FLOATING_JOINTS[:3], ("1 0 0", "0 1 0", "0 0 1"), strict=True):
        chain.append(
            f'<link name="{name}">{_INERTIAL}</link><joint name="{name}" type="prismatic">'
            f'<parent link="{parent}"/><child link="{name}"/><axis xyz="{axis}"/>'
            '<limit lower="-1000" upper="1000" effort="0" velocity="0"/></joint>'
        )
        parent = name
    chain.append(
        f'<joint name="{FLOATING_JOINTS[3]}" type="spherical"><parent link="{parent}"/>'
        f'<child link="{roots[0]}"/><axis xyz="0 0 1"/></joint>'
    )
    for i, element in enumerate(ET.fromstring(f"<chain>{''.join(chain)}</chain>")):
        root.insert(i, element)
    return ET.tostring(root, encoding="unicode")


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
