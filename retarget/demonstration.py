"""A recorded human demonstration tau_h (paper section III): the ``assets/demonstrations/<object>.npz`` file.

The recording is what a 6-D wrist tracker and a dataglove would have produced at 20 Hz, stored relative
to the grasped object. See ``assets/demonstrations/README.md`` for the full description.

File format (``numpy.savez_compressed``, no pickles), T steps:

=========================  ============  ============================================================
key                        shape         meaning
=========================  ============  ============================================================
``T_object_wrist``         (T, 4, 4)     recorded (noisy) human wrist pose in the object frame [m]
``joints``                 (T, 20)       recorded (noisy) glove joints [rad], ``human_hand.JOINT_NAMES``
``t_s``                    (T,)          time stamps [s], 1 / rate_hz apart, starting at 0
``T_object_wrist_true``    (T, 4, 4)     optional: the noise-free wrist poses the noise was added to
``joints_true``            (T, 20)       optional: the noise-free joints (the contact check holds here)
``header_yaml``            () str        YAML header, see :data:`FORMAT` and :meth:`Demonstration.header`
=========================  ============  ============================================================

The header holds: ``format``, ``version``, ``object``, ``grasp_type`` (precision | power), ``rate_hz``,
``joint_names``, ``frames``, ``units``, ``object_prior`` (``T_world_object_mean`` 4x4 and ``cov_object``
6x6 in GTSAM Pose3 tangent ``[omega (rad), v (m)]`` body coordinates), ``contact_fingers``, ``strategy``,
``noise``, ``seed`` and, optionally, ``hand`` (the demonstrator's hand as fitted by
:mod:`retarget.keypoints`: scale and segment lengths).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import numpy as np
import yaml

import assets
from assets.errors import InputError
from assets.io import atomic_savez, load_npz, require_finite, require_rotation, require_shape, require_spd

__all__ = [
    "Demonstration",
    "FORMAT",
    "VERSION",
    "GRASP_TYPES",
    "FINGERS",
    "RATE_HZ",
    "JOINT_MARGIN_RAD",
    "MAX_WRIST_DISTANCE_M",
    "default_object_prior",
]

FORMAT = "pbdgrasp.demonstration"
VERSION = 1
GRASP_TYPES = ("precision", "power")
FINGERS = ("thumb", "index", "middle", "ring", "little")
RATE_HZ = 20.0
N_HAND_JOINTS = 20
#: Recorded joints may leave the model's limits by this much (5 sigma of the 3 deg glove noise).
JOINT_MARGIN_RAD = float(np.deg2rad(15.0))
#: A wrist further than this from the object origin is implausible: the file is probably in mm.
MAX_WRIST_DISTANCE_M = 1.0
_KEYS = ("T_object_wrist", "joints", "t_s", "header_yaml")


def default_object_prior() -> tuple[np.ndarray, np.ndarray]:
    """The object localization prior N(mu_o, Sigma_o) of the demonstration scene.

    The object stands at the world origin (table top z = 0, the object frame's origin at its bottom
    centre). Sigma_o is the paper's 3^2 I mm^2 on the position and (2 deg)^2 I on the rotation, in GTSAM
    Pose3 tangent ``[omega, v]`` body coordinates.

    Returns:
        ``T_world_object_mean`` (4, 4) and ``cov_object`` (6, 6) [rad^2, m^2].
    """
    cov = np.diag([np.deg2rad(2.0) ** 2] * 3 + [0.003**2] * 3)
    return np.eye(4), cov


def _hand():
    from assets import human_hand

    return human_hand


def _check_poses(name: str, T, n: int | None, path) -> np.ndarray:
    T = require_shape(name, T, (n, 4, 4), path)
    require_finite(name, T, path)
    require_rotation(name, T[:, :3, :3], path, atol=1e-6)
    if not np.allclose(T[:, 3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError(f"{name}: last row of a homogeneous transform must be [0, 0, 0, 1]", path)
    dist = np.linalg.norm(T[:, :3, 3], axis=-1)
    if dist.size and dist.max() > MAX_WRIST_DISTANCE_M:
        i = int(dist.argmax())
        raise InputError(
            f"{name}: wrist {dist[i]:.4g} from the object at step {i}, more than {MAX_WRIST_DISTANCE_M} m: "
            "positions must be in metres (millimetres?)",
            path,
        )
    return T


def _check_joints(name: str, J, n: int, path) -> np.ndarray:
    J = require_finite(name, require_shape(name, J, (n, N_HAND_JOINTS), path), path)
    limits = np.asarray(_hand().JOINT_LIMITS, dtype=float)
    lo, hi = limits[:, 0] - JOINT_MARGIN_RAD, limits[:, 1] + JOINT_MARGIN_RAD
    bad = (J < lo) | (J > hi)
    if bad.any():
        t, j = (int(i) for i in np.argwhere(bad)[0])
        raise InputError(
            f"{name}: {_hand().JOINT_NAMES[j]} = {J[t, j]:.4g} rad at step {t} is outside its limits "
            f"[{limits[j, 0]:.3g}, {limits[j, 1]:.3g}] rad +- {JOINT_MARGIN_RAD:.3g} (radians, not degrees?)",
            path,
        )
    return J


@dataclass(frozen=True, eq=False)
class Demonstration:
    """One human demonstration tau_h relative to its object; validated on construction.

    Attributes:
        T_object_wrist: (T, 4, 4) recorded wrist poses in the object frame [m].
        joints: (T, 20) recorded joint values [rad] in ``human_hand.JOINT_NAMES`` order.
        t_s: (T,) time stamps [s].
        object: object name, one of ``assets.objects()``.
        grasp_type: ``"precision"`` or ``"power"``.
        T_world_object_mean: (4, 4) mean object pose mu_o in the demonstration scene.
        cov_object: (6, 6) Sigma_o, GTSAM Pose3 tangent ``[omega, v]`` body coordinates [rad^2, m^2].
        rate_hz: sampling rate [Hz].
        T_object_wrist_true: optional (T, 4, 4) noise-free wrist poses.
        joints_true: optional (T, 20) noise-free joints.
        contact_fingers: fingers touching the object at the last step.
        strategy: one line describing the grasping strategy.
        noise: the noise model (free-form mapping, documented in the README).
        seed: the generator's seed, if any.
        hand: the demonstrator's hand, when it is not the model's (free-form mapping; an imported
            demonstration's scale and segment lengths, see :mod:`retarget.keypoints`); empty for the
            synthetic demonstrations, whose hand is the model.
        path: the file it was loaded from, if any.
    """

    T_object_wrist: np.ndarray
    joints: np.ndarray
    t_s: np.ndarray
    object: str
    grasp_type: str
    T_world_object_mean: np.ndarray
    cov_object: np.ndarray
    rate_hz: float = RATE_HZ
    T_object_wrist_true: np.ndarray | None = None
    joints_true: np.ndarray | None = None
    contact_fingers: tuple[str, ...] = ()
    strategy: str = ""
    noise: dict = field(default_factory=dict)
    seed: int | None = None
    hand: dict = field(default_factory=dict)
    path: str | None = None

    def __post_init__(self):
        p = self.path
        T = _check_poses("T_object_wrist", self.T_object_wrist, None, p)
        n = T.shape[0]
        if n < 2:
            raise InputError(f"T_object_wrist: a demonstration needs at least 2 steps, found {n}", p)
        J = _check_joints("joints", self.joints, n, p)
        try:
            rate = float(self.rate_hz)
        except (TypeError, ValueError):
            raise InputError(f"rate_hz: expected a number, found {self.rate_hz!r}", p) from None
        if not (np.isfinite(rate) and rate > 0):
            raise InputError(f"rate_hz: must be a positive number of Hz, found {rate}", p)
        t = require_finite("t_s", require_shape("t_s", self.t_s, (n,), p), p)
        dt = np.diff(t)
        if t[0] < 0 or np.abs(dt - 1.0 / rate).max() > 1e-6:
            raise InputError(
                f"t_s: expected times from 0 at 1/rate_hz = {1.0 / rate:.4g} s apart, "
                f"found start {t[0]:.4g} s and steps {dt.min():.4g}..{dt.max():.4g} s",
                p,
            )
        if self.object not in assets.objects():
            raise InputError(
                f"object: unknown object {self.object!r}; valid names: {', '.join(assets.objects())}", p
            )
        if self.grasp_type not in GRASP_TYPES:
            raise InputError(f"grasp_type: expected one of {GRASP_TYPES}, found {self.grasp_type!r}", p)
        To = require_shape("T_world_object_mean", self.T_world_object_mean, (4, 4), p)
        require_rotation("T_world_object_mean", require_finite("T_world_object_mean", To, p)[:3, :3], p)
        Co = require_spd("cov_object", require_shape("cov_object", self.cov_object, (6, 6), p), p)
        unknown = [f for f in self.contact_fingers if f not in FINGERS]
        if unknown:
            raise InputError(
                f"contact_fingers: unknown fingers {unknown}; valid names: {', '.join(FINGERS)}", p
            )
        values = {"T_object_wrist": T, "joints": J, "t_s": t, "T_world_object_mean": To, "cov_object": Co}
        if self.T_object_wrist_true is not None:
            values["T_object_wrist_true"] = _check_poses(
                "T_object_wrist_true", self.T_object_wrist_true, n, p
            )
        if self.joints_true is not None:
            values["joints_true"] = _check_joints("joints_true", self.joints_true, n, p)
        for name, value in values.items():
            value = np.array(value, dtype=float)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "rate_hz", rate)
        object.__setattr__(self, "contact_fingers", tuple(self.contact_fingers))
        if not isinstance(self.hand, dict):
            raise InputError(f"hand: expected a mapping, found {self.hand!r}", p)

    @property
    def num_steps(self) -> int:
        return self.T_object_wrist.shape[0]

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0])

    def first_steps(self, n: int) -> Demonstration:
        """The demonstration's first ``n`` steps (all of them when ``n`` is not smaller), every per-step
        array cut alike.

        Raises:
            InputError: fewer than 2 steps.
        """
        return self if n >= self.num_steps else self._steps(slice(None, n))

    def last_steps(self, n: int) -> Demonstration:
        """The demonstration's last ``n`` steps (all of them when ``n`` is not smaller), every per-step
        array cut alike; the time stamps keep their values.

        Raises:
            InputError: fewer than 2 steps.
        """
        return self if n >= self.num_steps else self._steps(slice(self.num_steps - n, None))

    def _steps(self, steps: slice) -> Demonstration:
        whole = self.num_steps
        cut = {
            f.name: getattr(self, f.name)[steps]
            for f in fields(self)
            if isinstance(getattr(self, f.name), np.ndarray) and getattr(self, f.name).shape[:1] == (whole,)
        }
        return replace(self, **cut)

    def q26(self, step: int, true: bool = False) -> np.ndarray:
        """The human hand configuration ``[p (3, m), rotvec (3, rad), 20 joints (rad)]`` at ``step``.

        Args:
            step: index into the T steps (negative counts from the end).
            true: use the noise-free arrays (requires them in the file).
        """
        T = self.T_object_wrist_true if true else self.T_object_wrist
        J = self.joints_true if true else self.joints
        if T is None or J is None:
            raise InputError("this demonstration holds no noise-free recording", self.path)
        if not -self.num_steps <= step < self.num_steps:
            raise InputError(f"step {step} out of range for {self.num_steps} steps", self.path)
        from assets.se3 import q_from_pose

        return np.concatenate([q_from_pose(T[step]), J[step]])

    def header(self) -> dict:
        """The YAML header as a mapping (everything but the arrays)."""
        hand = _hand()
        return {
            "format": FORMAT,
            "version": VERSION,
            "object": self.object,
            "grasp_type": self.grasp_type,
            "rate_hz": self.rate_hz,
            "num_steps": self.num_steps,
            "joint_names": list(hand.JOINT_NAMES),
            "frames": {
                "T_object_wrist": "human wrist in the object frame (origin at the bottom centre, +z up); "
                "wrist: +z along the middle finger, +y to the thumb, +x out of the palm",
                "T_world_object_mean": "object in the demonstration scene (table top z = 0)",
            },
            "units": {"positions": "m", "angles": "rad", "t_s": "s", "cov_object": "rad^2 (omega), m^2 (v)"},
            "object_prior": {
                "T_world_object_mean": self.T_world_object_mean.tolist(),
                "cov_object": self.cov_object.tolist(),
                "coordinates": "GTSAM Pose3 tangent [omega (3), v (3)], body frame, T = T_mean @ Exp(xi)",
            },
            "contact_fingers": list(self.contact_fingers),
            "strategy": self.strategy,
            "noise": self.noise,
            "seed": self.seed,
            **({"hand": self.hand} if self.hand else {}),
        }

    def save(self, path: str | os.PathLike) -> Path:
        """Write the ``.npz`` file atomically (the name is kept exactly)."""
        arrays = {
            "T_object_wrist": self.T_object_wrist,
            "joints": self.joints,
            "t_s": self.t_s,
            "header_yaml": np.str_(yaml.safe_dump(self.header(), sort_keys=False)),
        }
        if self.T_object_wrist_true is not None:
            arrays["T_object_wrist_true"] = self.T_object_wrist_true
        if self.joints_true is not None:
            arrays["joints_true"] = self.joints_true
        return atomic_savez(path, **arrays)

    @classmethod
    def load(cls, name_or_path: str | os.PathLike) -> Demonstration:
        """Read and validate a demonstration: a shipped one by name (``"ham"``) or a file path.

        Raises:
            InputError: the file is unreadable, lacks a key, or holds invalid values; the message names
                the file and the field.
        """
        path = assets.demonstration_path(name_or_path)
        d = load_npz(path, required=_KEYS)
        if d["header_yaml"].ndim != 0 or d["header_yaml"].dtype.kind != "U":
            raise InputError("header_yaml: expected one string", path)
        try:
            h = yaml.safe_load(str(d["header_yaml"]))
        except yaml.YAMLError as exc:
            raise InputError(f"header_yaml: not valid YAML ({' '.join(str(exc).split())})", path) from None
        if not isinstance(h, dict):
            raise InputError("header_yaml: expected a mapping", path)
        if h.get("format") != FORMAT:
            raise InputError(f"header_yaml: format: expected {FORMAT!r}, found {h.get('format')!r}", path)
        if h.get("version") != VERSION:
            raise InputError(f"header_yaml: version: expected {VERSION}, found {h.get('version')!r}", path)
        missing = [
            k for k in ("object", "grasp_type", "rate_hz", "joint_names", "object_prior") if k not in h
        ]
        if missing:
            raise InputError(f"header_yaml: missing keys {missing}", path)
        names = h["joint_names"]
        expected = list(_hand().JOINT_NAMES)
        if not isinstance(names, list) or names != expected:
            unknown = [n for n in names if n not in expected] if isinstance(names, list) else names
            raise InputError(
                f"header_yaml: joint_names: expected the 20 names of human_hand.JOINT_NAMES in order, "
                f"found {len(names) if isinstance(names, list) else names!r} names (unknown: {unknown})",
                path,
            )
        prior = h["object_prior"]
        if not isinstance(prior, dict) or not {"T_world_object_mean", "cov_object"} <= set(prior):
            raise InputError("header_yaml: object_prior: expected T_world_object_mean and cov_object", path)
        contacts = h.get("contact_fingers") or []
        if not isinstance(contacts, list):
            raise InputError(f"header_yaml: contact_fingers: expected a list, found {contacts!r}", path)
        noise = h.get("noise") or {}
        if not isinstance(noise, dict):
            raise InputError(f"header_yaml: noise: expected a mapping, found {noise!r}", path)
        hand = h.get("hand") or {}
        if not isinstance(hand, dict):
            raise InputError(f"header_yaml: hand: expected a mapping, found {hand!r}", path)
        return cls(
            T_object_wrist=d["T_object_wrist"],
            joints=d["joints"],
            t_s=d["t_s"],
            object=str(h["object"]),
            grasp_type=str(h["grasp_type"]),
            T_world_object_mean=prior["T_world_object_mean"],
            cov_object=prior["cov_object"],
            rate_hz=h["rate_hz"],
            T_object_wrist_true=d.get("T_object_wrist_true"),
            joints_true=d.get("joints_true"),
            contact_fingers=tuple(contacts),
            strategy=str(h.get("strategy", "")),
            noise=noise,
            seed=h.get("seed"),
            hand=hand,
            path=str(path),
        )
