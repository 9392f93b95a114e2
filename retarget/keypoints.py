"""Hand keypoints: the 21-point layout of hand trackers on the human hand model, and the keypoint file.

Hand trackers (MediaPipe Hands, MANO's joint regressor, the DexYCB and HO-3D annotations) give per frame
21 points, :data:`KEYPOINT_NAMES`: 0 wrist; 1-4 thumb CMC, MCP, IP, tip; 5-8 index MCP, PIP, DIP, tip;
then middle, ring and little alike. Each is a joint centre (or the fingertip frame) of
``assets.human_hand``, :data:`KEYPOINT_LINKS`, so the model's wrist pose and 20 joints explain them.

The file (:func:`load_keypoints`, ``numpy.savez``, no pickles): ``keypoints`` (T, 21, 3) [m] in the object
frame, ``rate_hz`` () [Hz], optionally ``t_s`` (T,) [s] increasing time stamps and ``T_frame_object``
(T, 4, 4), the object in the frame of the points (a camera's), when they are not in the object frame.
The fit that turns a file into a demonstration is :mod:`retarget.keypoint_fit`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from assets import human_hand
from assets.errors import InputError
from assets.io import load_npz, require_finite, require_rotation, require_shape
from assets.kinematics import HandModel
from assets.se3 import se3_inverse

from .demonstration import MAX_WRIST_DISTANCE_M

__all__ = [
    "KEYPOINT_NAMES",
    "KEYPOINT_LINKS",
    "PALM_POINTS",
    "SEGMENTS",
    "MODEL_SEGMENT_LENGTHS_M",
    "KeypointRecording",
    "load_keypoints",
    "hand_keypoints",
    "keypoints_in_object",
    "scaled_model",
    "segment_vectors",
    "transform_points",
]

_DIGITS = {
    "thumb": ("cmc", "mcp", "ip", "tip"),
    **{f: ("mcp", "pip", "dip", "tip") for f in human_hand.FINGERS[1:]},
}
KEYPOINT_NAMES: tuple[str, ...] = ("wrist",) + tuple(
    f"{f}_{j}" for f in human_hand.FINGERS for j in _DIGITS[f]
)
"""The 21 points in file order."""
KEYPOINT_LINKS: tuple[str, ...] = (
    "wrist",
    "thumb_knuckle",
    "thumb_proximal",
    "thumb_distal",
    "thumb_tip",
) + tuple(f"{f}_{s}" for f in human_hand.FINGERS[1:] for s in ("proximal", "middle", "distal", "tip"))
"""The ``human_hand`` link whose origin each point is (a joint centre, or the fingertip frame)."""
PALM_POINTS: tuple[int, ...] = (0, 1, 5, 9, 13, 17)
"""Wrist, thumb CMC and the four MCPs: fixed in the wrist frame, they give the wrist pose and the scale."""
SEGMENTS: tuple[tuple[int, int], ...] = tuple((b + i, b + i + 1) for b in (1, 5, 9, 13, 17) for i in range(3))
"""The 15 finger segments as (proximal point, distal point); the joint ending one carries its length."""


@dataclass(frozen=True)
class KeypointRecording:
    """A validated keypoint file, in the object frame.

    Attributes:
        p_object: (T, 21, 3) [m] the points in the object frame, :data:`KEYPOINT_NAMES` order.
        t_s: (T,) [s] increasing times, from 0.
        rate_hz: the recording's rate [Hz].
        path: the file, if any.
    """

    p_object: np.ndarray
    t_s: np.ndarray
    rate_hz: float
    path: str | None = None

    def resampled(self, rate_hz: float) -> np.ndarray:
        """The points (T', 21, 3) at ``arange(T') / rate_hz`` over the recording, linearly interpolated."""
        n = int(np.floor(self.t_s[-1] * rate_hz + 1e-9)) + 1
        t = np.arange(n) / rate_hz
        flat = self.p_object.reshape(len(self.t_s), -1)
        return np.stack([np.interp(t, self.t_s, c) for c in flat.T], axis=-1).reshape(n, 21, 3)


def load_keypoints(path: str | Path) -> KeypointRecording:
    """Read and validate a keypoint file (see ``assets/demonstrations/README.md``).

    Raises:
        InputError: unreadable, a pickle, unknown or missing keys, wrong shapes, NaN, fewer than 2
            frames, frames out of order (``t_s``), a bad ``T_frame_object``, a wrist over 1 m from the
            object. The message names the file and the field.
    """
    d = load_npz(path, required=("keypoints", "rate_hz"))
    unknown = sorted(set(d) - {"keypoints", "rate_hz", "t_s", "T_frame_object"})
    if unknown:
        raise InputError(
            f"unknown keys {unknown}; expected keypoints, rate_hz and optionally t_s, T_frame_object", path
        )
    p = require_finite("keypoints", require_shape("keypoints", d["keypoints"], (None, 21, 3), path), path)
    n = p.shape[0]
    if n < 2:
        raise InputError(f"keypoints: a demonstration needs at least 2 frames, found {n}", path)
    rate = float(require_finite("rate_hz", require_shape("rate_hz", d["rate_hz"], (), path), path))
    if rate <= 0:
        raise InputError(f"rate_hz: must be a positive number of Hz, found {rate}", path)
    t = np.arange(n) / rate
    if "t_s" in d:
        t = require_finite("t_s", require_shape("t_s", d["t_s"], (n,), path), path)
        back = np.flatnonzero(np.diff(t) <= 0)
        if back.size:
            i = int(back[0]) + 1
            raise InputError(
                f"t_s: frames out of order: frame {i} at {t[i]:.4g} s is not after frame {i - 1} at "
                f"{t[i - 1]:.4g} s; expected increasing times",
                path,
            )
        t = t - t[0]
    if "T_frame_object" in d:
        T = require_finite(
            "T_frame_object", require_shape("T_frame_object", d["T_frame_object"], (n, 4, 4), path), path
        )
        require_rotation("T_frame_object", T[:, :3, :3], path)
        if not np.allclose(T[:, 3], [0.0, 0.0, 0.0, 1.0]):
            raise InputError("T_frame_object: last row of a homogeneous transform must be [0, 0, 0, 1]", path)
        p = transform_points(se3_inverse(T), p)
    dist = np.linalg.norm(p[:, 0], axis=-1)
    if dist.max() > MAX_WRIST_DISTANCE_M:
        i = int(dist.argmax())
        raise InputError(
            f"keypoints: wrist {dist[i]:.4g} from the object at frame {i}, more than {MAX_WRIST_DISTANCE_M} "
            "m: points must be in metres, in the object frame (millimetres? a camera frame without "
            "T_frame_object?)",
            path,
        )
    return KeypointRecording(p, t, rate, None if path is None else str(path))


def scaled_model(scale: float = 1.0, segment_lengths_m: np.ndarray | None = None) -> HandModel:
    """``human_hand.model()`` with every offset times ``scale``, then the 15 :data:`SEGMENTS` set to
    ``segment_lengths_m`` (15,) [m] if given. Joint axes, limits and names are the model's."""
    base = human_hand.model()
    ends = {KEYPOINT_LINKS[b]: i for i, (_, b) in enumerate(SEGMENTS)}
    joints = []
    for j in base.joints:
        T = j.T_parent_joint.copy()
        if segment_lengths_m is not None and j.child in ends:
            T[:3, 3] *= segment_lengths_m[ends[j.child]] / np.linalg.norm(T[:3, 3])
        else:
            T[:3, 3] *= scale
        joints.append(replace(j, T_parent_joint=T))
    return replace(base, joints=tuple(joints))


def hand_keypoints(
    joints: np.ndarray, model: HandModel | None = None, poses: dict | None = None
) -> np.ndarray:
    """The 21 points (..., 21, 3) [m] in the wrist frame for joints (..., 20) [rad] (default: the model)."""
    poses = (model or human_hand.model()).fk(joints) if poses is None else poses
    return np.stack([poses[link][..., :3, 3] for link in KEYPOINT_LINKS], axis=-2)


def keypoints_in_object(
    T_object_wrist: np.ndarray, joints: np.ndarray, model: HandModel | None = None
) -> np.ndarray:
    """The 21 points (T, 21, 3) [m] in the object frame for wrist poses (T, 4, 4) and joints (T, 20)."""
    return transform_points(T_object_wrist, hand_keypoints(joints, model))


def transform_points(T_a_b: np.ndarray, p_b: np.ndarray) -> np.ndarray:
    """Points (T, K, 3) of frame b into frame a, one pose (T, 4, 4) a frame."""
    return np.einsum("tij,tkj->tki", T_a_b[:, :3, :3], p_b) + T_a_b[:, None, :3, 3]


def segment_vectors(k: np.ndarray) -> np.ndarray:
    """The 15 :data:`SEGMENTS` as vectors (..., 15, 3) from points (..., 21, 3)."""
    a, b = np.array(SEGMENTS).T
    return k[..., b, :] - k[..., a, :]


MODEL_SEGMENT_LENGTHS_M: np.ndarray = np.linalg.norm(segment_vectors(hand_keypoints(np.zeros(20))), axis=-1)
"""(15,) [m] the model's :data:`SEGMENTS` lengths."""
MODEL_SEGMENT_LENGTHS_M.setflags(write=False)
