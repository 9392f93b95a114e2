"""The human hand as sphere samples, and an object's signed distance: the geometry of the synthetic
demonstrations (:mod:`assets.demonstrations.generate`).

The samples are found from the human hand's kinematics (``assets.human_hand``), with no link names: per
finger, :data:`_SAMPLES_PER_SEGMENT` spheres along each of its three segments, and 16 palm spheres on the
lines from the wrist to the four finger bases. All positions in metres, in the wrist frame unless a name
says otherwise.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

import assets
from assets import human_hand
from retarget.demonstration import FINGERS

__all__ = [
    "FINGER_RADIUS_M",
    "PALM_RADIUS_M",
    "GenerationError",
    "ObjectDistance",
    "HandSamples",
    "hand_samples",
    "sample_points",
    "to_object",
    "penetration",
]

#: Radius of each finger's sample spheres (and its fingertip sphere) [m].
FINGER_RADIUS_M = {"thumb": 0.009, "index": 0.008, "middle": 0.0085, "ring": 0.008, "little": 0.0075}
#: Half the palm thickness: radius of the palm sample spheres [m].
PALM_RADIUS_M = 0.014
_SAMPLES_PER_SEGMENT = 5


class GenerationError(RuntimeError):
    """The generated grasp violates the contact or penetration check (a bug in a strategy)."""


class ObjectDistance:
    """Signed distance to an object's watertight mesh (negative inside), in the object frame.

    Args:
        name: object name (``assets.objects()``).
    """

    def __init__(self, name: str):
        mesh = o3d.io.read_triangle_mesh(str(assets.object_mesh(name)))
        self.name = name
        self._scene = o3d.t.geometry.RaycastingScene()
        self._scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))

    def signed(self, p_object: np.ndarray) -> np.ndarray:
        """Signed distances (...,) [m] of points ``p_object`` (..., 3)."""
        p = np.asarray(p_object, dtype=np.float32)
        d = self._scene.compute_signed_distance(o3d.core.Tensor(p.reshape(-1, 3))).numpy()
        return d.astype(float).reshape(p.shape[:-1])

    def closest(self, p_object: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Closest surface points (N, 3) and outward unit normals (N, 3) for points (N, 3)."""
        p = np.asarray(p_object, dtype=np.float32).reshape(-1, 3)
        ans = self._scene.compute_closest_points(o3d.core.Tensor(p))
        c = ans["points"].numpy().astype(float)
        n = ans["primitive_normals"].numpy().astype(float)
        return c, n / np.linalg.norm(n, axis=-1, keepdims=True)


@dataclass(frozen=True)
class HandSamples:
    """Sphere samples covering the human hand, found from the kinematics (no link names needed).

    Attributes:
        owner: (N,) finger index 0..4 (``FINGERS``) or 5 for the palm.
        segment: (N,) 0..2 for the finger segment after each flexion joint, -1 for the palm.
        radius: (N,) sphere radii [m].
    """

    owner: np.ndarray
    segment: np.ndarray
    radius: np.ndarray
    flex_joints: dict = field(default_factory=dict)

    def points(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Sample centres (..., N, 3) and fingertip sphere centres (..., 5, 3) in the wrist frame."""
        return sample_points(joints)


_LAYOUT: dict = {}


def _layout():
    """Finger chains from the FK: each link's finger and level (how many flexion joints move it)."""
    if _LAYOUT:
        return _LAYOUT
    hand = human_hand
    names = list(hand.JOINT_NAMES)
    limits = np.asarray(hand.JOINT_LIMITS, dtype=float)
    j0 = np.clip(np.zeros(len(names)), limits[:, 0], limits[:, 1]) + 0.1
    j0 = np.minimum(j0, limits[:, 1])
    base = hand.fk(j0)
    flex = {}
    for f in FINGERS:
        idx = [i for i, n in enumerate(names) if n.startswith(f + "_")]
        flex[f] = [i for i in idx if not names[i].endswith("_abd")]
        if len(flex[f]) != 3:
            raise GenerationError(f"expected 3 flexion joints for {f}, found {[names[i] for i in flex[f]]}")
    chains = {f: {} for f in FINGERS}
    for link, T in base.items():
        moved = []
        for i in range(len(names)):
            j = j0.copy()
            j[i] += 0.05
            if np.abs(hand.fk(j)[link] - T).max() > 1e-9:
                moved.append(i)
        for f in FINGERS:
            if moved and all(i in flex[f] or names[i].startswith(f + "_") for i in moved):
                level = sum(i in flex[f] for i in moved)
                if level >= 1:
                    chains[f].setdefault(level, []).append(link)
    for f in FINGERS:
        if sorted(chains[f]) != [1, 2, 3]:
            raise GenerationError(f"could not find the 3 segments of {f} in the hand's FK: {chains[f]}")
        # the segment starts at the joint: the link of that level nearest to the wrist
        chains[f] = [min(chains[f][lv], key=lambda n: np.linalg.norm(base[n][:3, 3])) for lv in (1, 2, 3)]
    _LAYOUT.update(chains=chains, flex=flex)
    return _LAYOUT


def sample_points(joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hand sample centres (..., N, 3) and fingertip sphere centres (..., 5, 3) in the wrist frame.

    The layout (owner finger, segment, radius of each sample) is :func:`hand_samples`; a fingertip sphere
    centre sits one finger radius behind ``human_hand.fingertip_positions`` along the distal segment.
    """
    hand = human_hand
    lay = _layout()
    frames = hand.fk(joints)
    tips = hand.fingertip_positions(joints)
    s = np.linspace(0.0, 1.0, _SAMPLES_PER_SEGMENT)
    pts, centres, bases = [], [], []
    for k, f in enumerate(FINGERS):
        o = [frames[n][..., :3, 3] for n in lay["chains"][f]]
        d = tips[..., k, :] - o[2]
        centre = tips[..., k, :] - FINGER_RADIUS_M[f] * d / np.linalg.norm(d, axis=-1, keepdims=True)
        ends = [o[0], o[1], o[2], centre]
        for a, b in zip(ends[:-1], ends[1:], strict=True):
            pts.append(a[..., None, :] + s[:, None] * (b - a)[..., None, :])
        centres.append(centre)
        bases.append(o[0])
    wrist = np.zeros_like(bases[0])
    for b in bases[1:]:  # palm: lines from the wrist to the four finger bases
        pts.append(wrist[..., None, :] + np.linspace(0.25, 0.9, 4)[:, None] * (b - wrist)[..., None, :])
    return np.concatenate(pts, axis=-2), np.stack(centres, axis=-2)


def hand_samples() -> HandSamples:
    """The layout of the samples returned by ``HandSamples.points``."""
    owner, segment, radius = [], [], []
    for k, f in enumerate(FINGERS):
        for seg in range(3):
            owner += [k] * _SAMPLES_PER_SEGMENT
            segment += [seg] * _SAMPLES_PER_SEGMENT
            radius += [FINGER_RADIUS_M[f]] * _SAMPLES_PER_SEGMENT
    owner += [5] * 16
    segment += [-1] * 16
    radius += [PALM_RADIUS_M] * 16
    return HandSamples(np.array(owner), np.array(segment), np.array(radius), dict(_layout()["flex"]))


def to_object(T_object_wrist: np.ndarray, p_wrist: np.ndarray) -> np.ndarray:
    """Points (..., N, 3) of the wrist frame into the object frame, for one pose (4, 4)."""
    return p_wrist @ T_object_wrist[:3, :3].T + T_object_wrist[:3, 3]


def penetration(
    dist: ObjectDistance, T: np.ndarray, J: np.ndarray, radius: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Signed clearances [m] of every hand sample sphere (N,) and of the five fingertip spheres (5,) to the
    object, for the wrist pose ``T`` (4, 4, object frame) and joints ``J`` (20,); negative: penetrating."""
    pts, centres = sample_points(J)
    sd = dist.signed(to_object(T, pts)) - radius
    rt = np.array([FINGER_RADIUS_M[f] for f in FINGERS])
    gaps = dist.signed(to_object(T, centres)) - rt
    return sd, gaps
