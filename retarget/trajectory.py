"""The retargeted robot trajectory tau_r with its error covariances Sigma_r(t): the ``.traj.npz`` file.

This is the contract between retargeting (section IV) and the variation model (section V).

File format (``numpy.savez_compressed``, no pickles), T steps at a fixed rate:

==========================  ============  =========================================================
key                         shape         meaning
==========================  ============  =========================================================
``T_object_wrist``          (T, 4, 4)     SAH wrist pose in the object frame [m]
``joints``                  (T, 13)       SAH joints [rad], order ``assets.sah.JOINT_NAMES``
``cov_retarget``            (T, 19, 19)   Sigma_r(t), tangent ``[omega, v, 13 joints]`` (GTSAM Pose3
                                          body convention for the wrist); symmetric PSD, may be
                                          rank-deficient (the paper's degenerate covariances)
``fingertip_rmse_mm``       (T,)          RMS fingertip distance robot vs. virtual fingers [mm]
``T_world_object_mean``     (4, 4)        object localization prior mean mu_o
``cov_object``              (6, 6)        Sigma_o in ``[omega, v]`` body coordinates [rad^2, m^2]
``dt_s``                    ()            time step [s] (0.05 at 20 Hz)
``object``                  () str        object name (``assets.objects()``)
``grasp_type``              () str        ``"precision"`` or ``"power"``
``meta_json``               () str        free-form provenance (demonstration, virtual fingers, ...)
==========================  ============  =========================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.io import (
    atomic_savez,
    load_npz,
    require_finite,
    require_psd,
    require_rotation,
    require_shape,
    require_spd,
)
from assets.q_layout import N_JOINTS, Q_DIM

__all__ = ["Trajectory", "GRASP_TYPES"]

GRASP_TYPES = ("precision", "power")
_KEYS = (
    "T_object_wrist",
    "joints",
    "cov_retarget",
    "fingertip_rmse_mm",
    "T_world_object_mean",
    "cov_object",
    "dt_s",
    "object",
    "grasp_type",
)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """tau_r and Sigma_r(t); see the module docstring for shapes, frames and units.

    Validated on construction: shapes, finiteness, rotations, (semi-)definiteness, names.
    """

    T_object_wrist: np.ndarray
    joints: np.ndarray
    cov_retarget: np.ndarray
    fingertip_rmse_mm: np.ndarray
    T_world_object_mean: np.ndarray
    cov_object: np.ndarray
    dt_s: float
    object: str
    grasp_type: str
    meta: dict = field(default_factory=dict)
    path: str | None = None

    def __post_init__(self):
        p = self.path
        T = require_shape("T_object_wrist", self.T_object_wrist, (None, 4, 4), p)
        n = T.shape[0]
        if n < 2:
            raise InputError(f"T_object_wrist: a trajectory needs at least 2 steps, found {n}", p)
        require_rotation("T_object_wrist", T[:, :3, :3], p)
        require_finite("T_object_wrist", T, p)
        if not np.allclose(T[:, 3], [0, 0, 0, 1]):
            raise InputError("T_object_wrist: last row of a homogeneous transform must be [0, 0, 0, 1]", p)
        J = require_finite("joints", require_shape("joints", self.joints, (n, N_JOINTS), p), p)
        C = require_psd(
            "cov_retarget", require_shape("cov_retarget", self.cov_retarget, (n, Q_DIM, Q_DIM), p), p
        )
        R = require_finite(
            "fingertip_rmse_mm", require_shape("fingertip_rmse_mm", self.fingertip_rmse_mm, (n,), p), p
        )
        if np.any(R < 0):
            raise InputError("fingertip_rmse_mm: must be >= 0", p)
        To = require_shape("T_world_object_mean", self.T_world_object_mean, (4, 4), p)
        require_rotation("T_world_object_mean", To[:3, :3], p)
        Co = require_spd("cov_object", require_shape("cov_object", self.cov_object, (6, 6), p), p)
        try:
            dt = float(self.dt_s)
        except (TypeError, ValueError):
            raise InputError(f"dt_s: expected a number of seconds, found {self.dt_s!r}", p) from None
        if not (np.isfinite(dt) and dt > 0):
            raise InputError(f"dt_s: must be a positive number of seconds, found {dt}", p)
        if self.grasp_type not in GRASP_TYPES:
            raise InputError(f"grasp_type: expected one of {GRASP_TYPES}, found {self.grasp_type!r}", p)
        if not isinstance(self.object, str) or not self.object:
            raise InputError(f"object: expected an object name, found {self.object!r}", p)
        for name, value in (
            ("T_object_wrist", T),
            ("joints", J),
            ("cov_retarget", C),
            ("fingertip_rmse_mm", R),
            ("T_world_object_mean", To),
            ("cov_object", Co),
        ):
            value = np.array(value, dtype=float)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "dt_s", dt)

    @property
    def num_steps(self) -> int:
        return self.T_object_wrist.shape[0]

    def arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        """The ``.traj.npz`` keys and arrays (see the module docstring), each key prefixed by ``prefix``
        (a ``.model.npz`` embeds its source trajectory under ``traj_``)."""
        arrays = dict(
            T_object_wrist=self.T_object_wrist,
            joints=self.joints,
            cov_retarget=self.cov_retarget,
            fingertip_rmse_mm=self.fingertip_rmse_mm,
            T_world_object_mean=self.T_world_object_mean,
            cov_object=self.cov_object,
            dt_s=np.float64(self.dt_s),
            object=np.str_(self.object),
            grasp_type=np.str_(self.grasp_type),
            meta_json=np.str_(json.dumps(self.meta, sort_keys=True)),
        )
        return {prefix + k: v for k, v in arrays.items()}

    def save(self, path: str | os.PathLike) -> Path:
        """Write the ``.traj.npz`` file atomically."""
        return atomic_savez(path, **self.arrays())

    @classmethod
    def from_arrays(cls, d, path: str | os.PathLike | None = None, prefix: str = "") -> Trajectory:
        """The trajectory held by the arrays ``d`` (a mapping of ``prefix + key`` to arrays, as
        :meth:`arrays` makes them).

        Raises:
            InputError: a key is missing, or a value is invalid.
        """
        missing = [prefix + k for k in _KEYS if prefix + k not in d]
        if missing:
            raise InputError(f"missing keys {missing}", path)
        g = {k: d[prefix + k] for k in (*_KEYS, "meta_json") if prefix + k in d}
        try:
            meta = json.loads(str(g["meta_json"])) if "meta_json" in g else {}
            if not isinstance(meta, dict):
                raise ValueError("not an object")
        except ValueError as exc:
            raise InputError(f"{prefix}meta_json: not a JSON object ({exc})", path) from None
        for key in ("object", "grasp_type", "dt_s"):
            if g[key].ndim != 0:
                raise InputError(f"{prefix}{key}: expected a scalar, found shape {g[key].shape}", path)
        return cls(
            T_object_wrist=g["T_object_wrist"],
            joints=g["joints"],
            cov_retarget=g["cov_retarget"],
            fingertip_rmse_mm=g["fingertip_rmse_mm"],
            T_world_object_mean=g["T_world_object_mean"],
            cov_object=g["cov_object"],
            dt_s=g["dt_s"].item() if g["dt_s"].dtype.kind in "fiu" else str(g["dt_s"]),
            object=str(g["object"]),
            grasp_type=str(g["grasp_type"]),
            meta=meta,
            path=None if path is None else str(path),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> Trajectory:
        """Read and validate a ``.traj.npz`` file.

        Raises:
            InputError: the file is unreadable, lacks a key, or holds invalid values.
        """
        return cls.from_arrays(load_npz(path, required=_KEYS), path)
