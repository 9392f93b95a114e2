"""The variation model's result, the marginals P(X_t | O), and its ``.model.npz`` file.

:func:`inference.solve.solve` makes a :class:`VariationModel`; :meth:`VariationModel.save` and
:meth:`VariationModel.load` write and read it. The marginals are conditioned on the object at its prior
mean, O = mu_o; the wrist means are in the object frame, ``T_object_wrist_mean = mu_o^-1 W_t``.

``.model.npz`` (``numpy.savez_compressed``, no pickles; written atomically):

=========================  ===========  ===========================================================
key                        shape        meaning
=========================  ===========  ===========================================================
``T_object_wrist_mean``    (T, 4, 4)    mean wrist pose of P(X_t | O) in the object frame [m]
``joints_mean``            (T, 13)      mean joints [rad]
``cov``                    (T, 19, 19)  covariance ``[omega, v, joints]`` (Pose3 body tangent of the
                                        wrist, right perturbation ``T Exp(xi)``) [rad^2, m^2]
``T_world_object_mean``    (4, 4)       object prior mean mu_o
``cov_object``             (6, 6)       Sigma_o, ``[omega, v]`` body
``params_json``            () str       :class:`~inference.params.VariationParams` as JSON
``iterations``             ()           relinearization solves (1 without constraints)
``converged``              ()           the relinearization met its tolerance
``constrained``            (T,)         steps that carried constraint factors
``solve_time_s``           ()           wall time of the solve [s]
``grasp_type``, ``object`` () str       from the trajectory
``traj_*``                              the source trajectory's keys (:mod:`retarget.trajectory`), if any
=========================  ===========  ===========================================================
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.io import atomic_savez, load_npz, require_finite, require_rotation, require_shape, require_spd
from assets.q_layout import N_JOINTS, Q_DIM
from assets.se3 import q_from_pose
from retarget.trajectory import GRASP_TYPES, Trajectory

from .params import VariationParams

__all__ = ["VariationModel"]

_SOURCE_PREFIX = "traj_"


@dataclass(frozen=True, eq=False)
class VariationModel:
    """The marginals P(X_t | O) of a solved variation model; see :mod:`inference.model` for the file format.

    Attributes:
        T_object_wrist_mean: (T, 4, 4) wrist means in the object frame.
        joints_mean: (T, 13) [rad].
        cov: (T, 19, 19) ``[omega, v, joints]``, SPD.
        T_world_object_mean: (4, 4) mu_o. cov_object: (6, 6) Sigma_o, ``[omega, v]``.
        params: the parameters used. iterations: relinearization solves. converged: met the tolerance.
        grasp_type, object: from the trajectory. source: the trajectory, if known.
        constrained: (T,) bool, steps with constraint factors. solve_time_s: wall time of :func:`solve`.
    """

    T_object_wrist_mean: np.ndarray
    joints_mean: np.ndarray
    cov: np.ndarray
    T_world_object_mean: np.ndarray
    cov_object: np.ndarray
    params: VariationParams
    iterations: int
    grasp_type: str
    object: str
    converged: bool = True
    constrained: np.ndarray | None = None
    source: Trajectory | None = None
    solve_time_s: float = float("nan")
    path: str | None = None

    def __post_init__(self):
        p = self.path
        T = require_shape("T_object_wrist_mean", self.T_object_wrist_mean, (None, 4, 4), p)
        n = T.shape[0]
        if n < 2:
            raise InputError(f"T_object_wrist_mean: a model needs at least 2 steps, found {n}", p)
        require_finite("T_object_wrist_mean", T, p)
        require_rotation("T_object_wrist_mean", T[:, :3, :3], p)
        J = require_finite("joints_mean", require_shape("joints_mean", self.joints_mean, (n, N_JOINTS), p), p)
        C = require_spd("cov", require_shape("cov", self.cov, (n, Q_DIM, Q_DIM), p), p)
        To = require_finite(
            "T_world_object_mean",
            require_shape("T_world_object_mean", self.T_world_object_mean, (4, 4), p),
            p,
        )
        require_rotation("T_world_object_mean", To[:3, :3], p)
        Co = require_spd("cov_object", require_shape("cov_object", self.cov_object, (6, 6), p), p)
        if self.grasp_type not in GRASP_TYPES:
            raise InputError(f"grasp_type: expected one of {GRASP_TYPES}, found {self.grasp_type!r}", p)
        if not isinstance(self.params, VariationParams):
            raise InputError(f"params: expected VariationParams, found {type(self.params).__name__}", p)
        if int(self.iterations) < 1:
            raise InputError(f"iterations: expected >= 1, found {self.iterations}", p)
        mask = np.zeros(n, bool) if self.constrained is None else np.asarray(self.constrained, dtype=bool)
        require_shape("constrained", mask, (n,), p, dtype=bool)
        for name, value in (
            ("T_object_wrist_mean", T),
            ("joints_mean", J),
            ("cov", C),
            ("T_world_object_mean", To),
            ("cov_object", Co),
            ("constrained", mask),
        ):
            value = np.array(value)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "iterations", int(self.iterations))
        object.__setattr__(self, "converged", bool(self.converged))

    @property
    def num_steps(self) -> int:
        return self.T_object_wrist_mean.shape[0]

    def world_means(self, T_world_object: np.ndarray) -> np.ndarray:
        """The means as configurations (T, 19) ``[p (m), rotation vector (rad), joints (rad)]`` with the
        object at ``T_world_object`` (4, 4), as the planner places a model in a scene."""
        T_world_wrist = np.asarray(T_world_object, dtype=float) @ self.T_object_wrist_mean
        return np.concatenate([q_from_pose(T_world_wrist), self.joints_mean], axis=-1)

    def save(self, path: str | os.PathLike) -> Path:
        """Write the ``.model.npz`` file atomically (temporary file, then rename)."""
        arrays = dict(
            T_object_wrist_mean=self.T_object_wrist_mean,
            joints_mean=self.joints_mean,
            cov=self.cov,
            T_world_object_mean=self.T_world_object_mean,
            cov_object=self.cov_object,
            params_json=np.str_(json.dumps(self.params.to_dict(), sort_keys=True)),
            iterations=np.int64(self.iterations),
            converged=np.bool_(self.converged),
            constrained=self.constrained,
            grasp_type=np.str_(self.grasp_type),
            object=np.str_(self.object),
            solve_time_s=np.float64(self.solve_time_s),
        )
        if self.source is not None:
            arrays.update(self.source.arrays(_SOURCE_PREFIX))
        return atomic_savez(path, **arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> VariationModel:
        """Read and validate a ``.model.npz`` file.

        Raises:
            InputError: unreadable file, missing key, or invalid values (shapes, NaN, non-SPD, T < 2).
        """
        required = (
            "T_object_wrist_mean",
            "joints_mean",
            "cov",
            "T_world_object_mean",
            "cov_object",
            "params_json",
            "iterations",
            "grasp_type",
            "object",
        )
        d = load_npz(path, required=required)
        try:
            params_dict = json.loads(str(d["params_json"]))
        except ValueError as exc:
            raise InputError(f"params_json: not JSON ({exc})", path) from None
        if isinstance(params_dict, dict):  # models written before the option were mapped so
            params_dict.setdefault("fingertip_cov_map", "configuration")
        try:
            params = VariationParams.from_dict(params_dict, path)
        except InputError as exc:
            if exc.reason.startswith("unknown parameters"):  # a model of another pbdgrasp version
                raise InputError(f"{exc.reason}; learn the model again (pbdgrasp infer)", path) from None
            raise
        source = None
        if any(k.startswith(_SOURCE_PREFIX) for k in d):
            source = Trajectory.from_arrays(d, path, prefix=_SOURCE_PREFIX)
        for key in ("iterations", "grasp_type", "object"):
            if d[key].ndim != 0:
                raise InputError(f"{key}: expected a scalar, found shape {d[key].shape}", path)
        for key in ("iterations", "solve_time_s", "converged"):
            if key in d and (d[key].ndim != 0 or d[key].dtype.kind not in "biuf"):
                raise InputError(
                    f"{key}: expected a number, found {d[key].dtype} of shape {d[key].shape}", path
                )
        return cls(
            T_object_wrist_mean=d["T_object_wrist_mean"],
            joints_mean=d["joints_mean"],
            cov=d["cov"],
            T_world_object_mean=d["T_world_object_mean"],
            cov_object=d["cov_object"],
            params=params,
            iterations=int(d["iterations"]),
            grasp_type=str(d["grasp_type"]),
            object=str(d["object"]),
            converged=bool(d["converged"]) if "converged" in d else True,
            constrained=d.get("constrained"),
            source=source,
            solve_time_s=float(d["solve_time_s"]) if "solve_time_s" in d else float("nan"),
            path=str(path),
        )
