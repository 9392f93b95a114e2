"""Hand configuration files (``Q.json``), as ``pbdgrasp render --q`` reads them.

Two forms are accepted:

* the plain vector ``{"q": [19 numbers]}``: wrist position (m), wrist rotation vector (rad), then the
  13 SAH joints (rad) in ``assets.sah.JOINT_NAMES`` order;
* the named form ``{"wrist_position_m": [x, y, z], "wrist_rotvec_rad": [rx, ry, rz],
  "joints_deg": {"index_prox": 30, ...}}``: joints in degrees by name, missing joints at the rest pose
  (:func:`planning.hand_urdf.hand_rest_joints`).

:func:`save_q` writes either form atomically.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.io import atomic_write
from assets.q_layout import JOINTS, POS, ROT

from .hand_urdf import hand_joint_names, hand_rest_joints

__all__ = ["load_q", "save_q", "q_from_dict", "q_to_dict"]


def _vector(value, field: str, n: int, path) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        raise InputError(f"{field}: expected a list of {n} numbers, found {value!r}", path)
    for i, x in enumerate(value):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
            raise InputError(f"{field}[{i}]: expected a finite number, found {x!r}", path)
    return np.array(value, dtype=float)


def q_from_dict(d, hand: str = "sah", path=None) -> np.ndarray:
    """A configuration (6 + joints,) from a parsed Q.json of either form (see the module docstring).

    Raises:
        InputError: wrong shape or type, a non-finite value, an unknown joint name (the valid ones are
            listed) or a mix of both forms.
    """
    names = hand_joint_names(hand)
    if not isinstance(d, dict):
        raise InputError(f"expected a JSON object, found {type(d).__name__}", path)
    if "q" in d:
        if len(d) != 1:
            raise InputError(f"'q' given together with {sorted(set(d) - {'q'})}; use one form", path)
        return _vector(d["q"], "q", 6 + len(names), path)
    allowed = {"wrist_position_m", "wrist_rotvec_rad", "joints_deg"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise InputError(f"{unknown[0]}: unknown field; valid: q or {', '.join(sorted(allowed))}", path)
    for key in ("wrist_position_m", "wrist_rotvec_rad"):
        if key not in d:
            raise InputError(f"{key}: missing field", path)
    joints = hand_rest_joints(hand)
    named = d.get("joints_deg", {}) or {}
    if not isinstance(named, dict):
        raise InputError(
            f"joints_deg: expected an object of name: degrees, found {type(named).__name__}", path
        )
    for name, value in named.items():
        if name not in names:
            raise InputError(f"joints_deg.{name}: unknown joint; valid: {', '.join(names)}", path)
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise InputError(f"joints_deg.{name}: expected a finite number, found {value!r}", path)
        joints[names.index(name)] = math.radians(value)
    return np.concatenate(
        [
            _vector(d["wrist_position_m"], "wrist_position_m", 3, path),
            _vector(d["wrist_rotvec_rad"], "wrist_rotvec_rad", 3, path),
            joints,
        ]
    )


def q_to_dict(q: np.ndarray, hand: str = "sah", named: bool = False) -> dict:
    """The JSON-ready dict of a configuration, plain (``{"q": [...]}``) or named."""
    q = np.asarray(q, dtype=float)
    names = hand_joint_names(hand)
    if q.shape != (6 + len(names),) or not np.all(np.isfinite(q)):
        raise InputError(f"q: expected {6 + len(names)} finite numbers, found shape {q.shape}")
    if not named:
        return {"q": [float(x) for x in q]}
    return {
        "wrist_position_m": [float(x) for x in q[POS]],
        "wrist_rotvec_rad": [float(x) for x in q[ROT]],
        "joints_deg": {n: float(np.degrees(x)) for n, x in zip(names, q[JOINTS], strict=True)},
    }


def load_q(path: str | Path, hand: str = "sah") -> np.ndarray:
    """Read a Q.json file (either form) into q (6 + joints,).

    Raises:
        InputError: missing or unreadable file, or the errors of :func:`q_from_dict`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such configuration file", path)
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path) from None
    return q_from_dict(d, hand, path)


def save_q(path: str | Path, q: np.ndarray, hand: str = "sah", named: bool = False) -> Path:
    """Write q to a Q.json file atomically; returns the path."""
    text = json.dumps(q_to_dict(q, hand, named), indent=2) + "\n"
    return atomic_write(path, lambda f: f.write(text.encode()))
