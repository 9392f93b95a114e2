"""A small URDF kinematic-tree parser and vectorized numpy forward kinematics, shared by both hands.

Supports what the hand models use: ``revolute`` (and ``continuous``) joints about an arbitrary axis,
``fixed`` joints, and ``<mimic>`` (``q_j = multiplier * q_m + offset``). The base link is the URDF
root (the wrist for both hands); every link pose is ``T_base_link`` (..., 4, 4) in the base frame. A
URDF child link's frame is its joint's frame, so the joint axis of link ``c`` in the base frame is
``T_base_c[:3, :3] @ axis`` through the origin ``T_base_c[:3, 3]``.

Example:
    >>> model = HandModel.from_urdf(assets.hand_urdf("sah"))
    >>> poses = model.fk(np.zeros((10, model.n)))  # dict: link -> (10, 4, 4)
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from assets.errors import InputError

from .se3 import make_pose, skew

__all__ = ["Joint", "HandModel", "load_hand_model"]

_SUPPORTED = ("revolute", "continuous", "fixed")


@dataclass(frozen=True)
class Joint:
    """One URDF joint.

    Attributes:
        name: joint name.
        type: ``revolute``, ``continuous`` or ``fixed``.
        parent, child: link names.
        T_parent_joint: (4, 4) the joint frame (= child link frame at zero angle) in the parent frame.
        axis: (3,) unit rotation axis in the joint frame.
        limits: (lower, upper) [rad]; (-inf, inf) for continuous and fixed joints.
        mimic: name of the joint this one copies, or None.
        multiplier, offset: mimic coupling ``q = multiplier * q_mimic + offset``.
    """

    name: str
    type: str
    parent: str
    child: str
    T_parent_joint: np.ndarray
    axis: np.ndarray
    limits: tuple[float, float]
    mimic: str | None = None
    multiplier: float = 1.0
    offset: float = 0.0


def _floats(text: str | None, n: int, default: float, where: str) -> np.ndarray:
    if text is None:
        return np.full(n, default)
    try:
        vals = np.array([float(v) for v in text.split()])
    except ValueError:
        raise InputError(f"{where}: expected {n} numbers, found {text!r}") from None
    if vals.shape != (n,):
        raise InputError(f"{where}: expected {n} numbers, found {text!r}")
    return vals


def _rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF fixed-axis roll-pitch-yaw: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


@dataclass(frozen=True)
class HandModel:
    """A kinematic tree parsed from a URDF, with vectorized forward kinematics.

    Attributes:
        name: the robot name.
        base_link: the root link (the wrist frame).
        joints: all joints in topological order (parents before children).
        joint_names: the actuated (non-fixed, non-mimic) joints, in URDF order; ``n`` of them.
        limits: (n, 2) [rad] lower and upper limits of the actuated joints.
        link_names: all links, base first, in topological order.
    """

    name: str
    base_link: str
    joints: tuple[Joint, ...]
    joint_names: tuple[str, ...]
    limits: np.ndarray
    link_names: tuple[str, ...]
    _plan: tuple = field(repr=False, compare=False, default=())

    @property
    def n(self) -> int:
        """Number of actuated joints."""
        return len(self.joint_names)

    @classmethod
    def from_urdf(cls, path: str | Path) -> HandModel:
        """Parse a URDF file.

        Raises:
            InputError: unreadable XML, an unsupported joint type, a missing link, a cycle or
                several roots, or a mimic of an unknown or non-actuated joint.
        """
        path = Path(path)
        try:
            root = ET.parse(path).getroot()
        except (OSError, ET.ParseError) as exc:
            raise InputError(f"cannot read URDF ({exc})", path) from None
        links = [el.get("name") for el in root.findall("link")]
        raw = []
        for el in root.findall("joint"):
            name, jtype = el.get("name"), el.get("type")
            if jtype not in _SUPPORTED:
                raise InputError(f"joint {name!r}: unsupported type {jtype!r}; supported: {_SUPPORTED}", path)
            parent, child = el.find("parent").get("link"), el.find("child").get("link")
            for ln in (parent, child):
                if ln not in links:
                    raise InputError(f"joint {name!r}: unknown link {ln!r}", path)
            org = el.find("origin")
            xyz = _floats(None if org is None else org.get("xyz"), 3, 0.0, f"{path}: joint {name} xyz")
            rpy = _floats(None if org is None else org.get("rpy"), 3, 0.0, f"{path}: joint {name} rpy")
            ax_el = el.find("axis")
            axis = _floats(None if ax_el is None else ax_el.get("xyz"), 3, 0.0, f"{path}: joint {name} axis")
            if jtype == "fixed":
                axis = np.zeros(3)
            else:
                if ax_el is None:
                    axis = np.array([1.0, 0.0, 0.0])  # URDF default
                norm = np.linalg.norm(axis)
                if norm < 1e-12:
                    raise InputError(f"joint {name!r}: zero axis", path)
                axis = axis / norm
            limits = (-np.inf, np.inf)
            lim = el.find("limit")
            if jtype == "revolute":
                if lim is None:
                    raise InputError(f"revolute joint {name!r} has no <limit>", path)
                limits = (float(lim.get("lower", 0.0)), float(lim.get("upper", 0.0)))
            mim = el.find("mimic")
            mimic, mult, off = None, 1.0, 0.0
            if mim is not None and jtype != "fixed":
                mimic = mim.get("joint")
                mult, off = float(mim.get("multiplier", 1.0)), float(mim.get("offset", 0.0))
            T_parent_joint = make_pose(_rpy_matrix(rpy), xyz)
            raw.append(Joint(name, jtype, parent, child, T_parent_joint, axis, limits, mimic, mult, off))
        children = {j.child for j in raw}
        roots = [ln for ln in links if ln not in children]
        if len(roots) != 1:
            raise InputError(f"expected one root link, found {roots}", path)
        # topological order: breadth-first from the root, keeping URDF order among siblings
        order, known, pending = [], {roots[0]}, list(raw)
        while pending:
            ready = [j for j in pending if j.parent in known]
            if not ready:
                raise InputError(f"links not connected to the root: {[j.child for j in pending]}", path)
            for j in ready:
                order.append(j)
                known.add(j.child)
            pending = [j for j in pending if j.parent not in known or j.child not in known]
        actuated = [j.name for j in raw if j.type != "fixed" and j.mimic is None]
        for j in raw:
            if j.mimic is not None and j.mimic not in actuated:
                raise InputError(f"joint {j.name!r} mimics {j.mimic!r}, which is not an actuated joint", path)
        limits = np.array([next(j.limits for j in raw if j.name == n) for n in actuated], dtype=float)
        link_names = (roots[0],) + tuple(j.child for j in order)
        plan = _build_plan(order, actuated)
        name = root.get("name", path.stem)
        return cls(name, roots[0], tuple(order), tuple(actuated), limits, link_names, plan)

    def expand(self, joints: np.ndarray) -> np.ndarray:
        """Values of every joint in :attr:`joints` order (fixed = 0, mimic applied): (..., n) -> (..., J)."""
        joints = np.asarray(joints, dtype=float)
        if joints.shape[-1] != self.n:
            raise InputError(f"{self.name}: expected {self.n} joint values, found shape {joints.shape}")
        src, mult, off = self._plan[1]
        return joints[..., src] * mult + off

    def fk(self, joints: np.ndarray) -> dict[str, np.ndarray]:
        """Forward kinematics.

        Args:
            joints: (..., n) actuated joint values [rad] in :attr:`joint_names` order.

        Returns:
            dict link name -> ``T_base_link`` (..., 4, 4), including the base link (identity).
        """
        q = self.expand(joints)
        batch = q.shape[:-1]
        out = {self.base_link: np.broadcast_to(np.eye(4), batch + (4, 4))}
        K, K2 = self._plan[2]
        for i, j in enumerate(self.joints):
            T = out[j.parent] @ j.T_parent_joint
            if j.type != "fixed":
                th = q[..., i, None, None]
                R = np.eye(3) + np.sin(th) * K[i] + (1.0 - np.cos(th)) * K2[i]
                T = T.copy()
                T[..., :3, :3] = T[..., :3, :3] @ R
            out[j.child] = T
        return out

    def chain(self, link: str) -> list[int]:
        """Indices into :attr:`joints` of the moving joints from the base to ``link``."""
        if link not in self.link_names:
            raise InputError(f"{self.name}: unknown link {link!r}; valid names: {', '.join(self.link_names)}")
        by_child = {j.child: i for i, j in enumerate(self.joints)}
        idx, cur = [], link
        while cur in by_child:
            i = by_child[cur]
            if self.joints[i].type != "fixed":
                idx.append(i)
            cur = self.joints[i].parent
        return idx[::-1]

    def point_jacobian(
        self,
        joints: np.ndarray,
        link: str,
        poses: dict[str, np.ndarray] | None = None,
        point: np.ndarray | None = None,
    ) -> np.ndarray:
        """Analytic Jacobian of a point fixed to ``link`` (base frame) w.r.t. the actuated joints.

        A mimic joint adds ``multiplier`` times its column to the joint it copies.

        Args:
            joints: (..., n) [rad].
            link: the link the point moves with.
            poses: the result of :meth:`fk` at ``joints``, to avoid recomputing it.
            point: (..., 3) the point's current position in the base frame [m]; default the link's origin.

        Returns:
            (..., 3, n) [m/rad].
        """
        joints = np.asarray(joints, dtype=float)
        poses = self.fk(joints) if poses is None else poses
        p = poses[link][..., :3, 3] if point is None else np.asarray(point, dtype=float)
        J = np.zeros(joints.shape[:-1] + (3, self.n))
        src = self._plan[1][0]
        mult = self._plan[1][1]
        for i in self.chain(link):
            jt = self.joints[i]
            T = poses[jt.child]
            axis = T[..., :3, :3] @ jt.axis
            col = np.cross(axis, p - T[..., :3, 3])
            J[..., :, src[i]] += mult[i] * col
        return J


def _build_plan(order: list[Joint], actuated: list[str]) -> tuple:
    """Precompute the index map from actuated to all joints and the axis cross matrices."""
    pos = {n: k for k, n in enumerate(actuated)}
    src = np.zeros(len(order), dtype=int)
    mult = np.zeros(len(order))
    off = np.zeros(len(order))
    for i, j in enumerate(order):
        if j.type == "fixed":
            continue
        if j.mimic is None:
            src[i], mult[i] = pos[j.name], 1.0
        else:
            src[i], mult[i], off[i] = pos[j.mimic], j.multiplier, j.offset
    K = np.array([skew(j.axis) for j in order]) if order else np.zeros((0, 3, 3))
    return (None, (src, mult, off), (K, K @ K))


@lru_cache(maxsize=8)
def collision_radius(path: str | Path, link: str) -> float:
    """The radius [m] of a link's round collision shape (capsule, sphere or cylinder) in a URDF.

    Raises:
        InputError: the link is missing or has no round collision shape.
    """
    root = ET.parse(path).getroot()
    for el in root.findall("link"):
        if el.get("name") == link:
            radii = [
                float(g.get("radius"))
                for g in el.iterfind("collision/geometry/*")
                if g.tag in ("capsule", "sphere", "cylinder")
            ]
            if radii:
                return max(radii)
            raise InputError(f"link {link!r} has no capsule, sphere or cylinder collision shape", path)
    raise InputError(f"no link {link!r}", path)


@lru_cache(maxsize=8)
def load_hand_model(path: str) -> HandModel:
    """:meth:`HandModel.from_urdf`, cached by path (the models are immutable)."""
    return HandModel.from_urdf(path)
