"""Hand configuration files (``Q.json``), as ``pbdgrasp render --q`` reads them.

Two forms are accepted:

* the plain vector ``{"q": [19 numbers]}``: wrist position (m), wrist rotation vector (rad), then the
  13 SAH joints (rad) in ``assets.sah.JOINT_NAMES`` order;
* the named form ``{"wrist_position_m": [x, y, z], "wrist_rotvec_rad": [rx, ry, rz],
  "joints_deg": {"index_prox": 30, ...}}``: joints in degrees by name, missing joints at the rest pose
  (:func:`planning.hand_urdf.hand_rest_joints`).

Ranges: the wrist within :data:`MAX_WRIST_DISTANCE_M` of the world origin (every scene's table and
object are near it), a rotation vector of norm at most 2 pi, every joint within its URDF limits (to
:data:`LIMIT_TOLERANCE_RAD`).

:func:`save_q` writes either form atomically.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.io import atomic_write, is_finite_number
from assets.q_layout import JOINTS, POS, ROT

from .hand_urdf import hand_joint_names, hand_rest_joints

__all__ = ["load_q", "save_q", "q_from_dict", "q_to_dict", "MAX_WRIST_DISTANCE_M", "LIMIT_TOLERANCE_RAD"]

MAX_WRIST_DISTANCE_M = 2.0
LIMIT_TOLERANCE_RAD = 1e-6
MAX_FILE_BYTES = 1 << 20


def _vector(value, field: str, n: int, path) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        raise InputError(f"{field}: expected a list of {n} numbers, found {value!r}", path)
    for i, x in enumerate(value):
        if not is_finite_number(x):
            raise InputError(f"{field}[{i}]: expected a finite number, found {x!r}", path)
    return np.array(value, dtype=float)


def q_from_dict(d, hand: str = "sah", path=None) -> np.ndarray:
    """A configuration (6 + joints,) from a parsed Q.json of either form (see the module docstring).

    Raises:
        InputError: wrong shape or type, a non-finite value, an unknown joint name (the valid ones are
            listed), a mix of both forms, or a value out of range (module docstring).
    """
    q = _parse(d, hand, path)
    _check_ranges(q, hand, path)
    return q


def _check_ranges(q: np.ndarray, hand: str, path) -> None:
    from .hand_urdf import hand_joint_limits

    distance = math.hypot(*q[POS])  # no overflow for huge entries
    if distance > MAX_WRIST_DISTANCE_M:
        raise InputError(
            f"wrist position: {distance:.3g} m from the world origin; expected at most "
            f"{MAX_WRIST_DISTANCE_M:g} m (positions are in metres)",
            path,
        )
    angle = math.hypot(*q[ROT])
    if angle > 2 * math.pi + 1e-9:
        raise InputError(f"wrist rotation vector: norm {angle:.3g} rad; expected at most 2 pi rad", path)
    limits = hand_joint_limits(hand)
    joints = q[JOINTS]
    bad = np.flatnonzero(
        (joints < limits[:, 0] - LIMIT_TOLERANCE_RAD) | (joints > limits[:, 1] + LIMIT_TOLERANCE_RAD)
    )
    if bad.size:
        i = int(bad[0])
        name = hand_joint_names(hand)[i]
        raise InputError(
            f"joint {name}: {math.degrees(joints[i]):.4g} deg outside its limits "
            f"[{math.degrees(limits[i, 0]):.4g}, {math.degrees(limits[i, 1]):.4g}] deg",
            path,
        )


def _parse(d, hand: str, path) -> np.ndarray:
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
        if not is_finite_number(value):
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
    if path.stat().st_size > MAX_FILE_BYTES:
        raise InputError(
            f"{path.stat().st_size} bytes; a configuration file is at most {MAX_FILE_BYTES}", path
        )
    try:
        d = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid JSON ({exc})", path) from None
    except RecursionError:
        raise InputError("not a configuration: JSON nested too deeply", path) from None
    return q_from_dict(d, hand, path)


def save_q(path: str | Path, q: np.ndarray, hand: str = "sah", named: bool = False) -> Path:
    """Write q to a Q.json file atomically; returns the path."""
    text = json.dumps(q_to_dict(q, hand, named), indent=2) + "\n"
    return atomic_write(path, lambda f: f.write(text.encode()))
