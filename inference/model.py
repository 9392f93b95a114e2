"""Build and solve the variation model's factor graph, its marginals P(X_t | O), and the ``.model.npz`` file.

The graph (paper section V, see :mod:`inference.factors`) is P(O) P(X_1..X_T | O) with O ~ N(mu_o, Sigma_o)
(``PriorFactorPose3``), the demonstration factors f_1t, the smoothness factors f_2t and, given a
``constraint_fn``, linearized constraint factors f_3t/f_4t. It is solved by Gauss-Newton from
``O = mu_o, W_t = mu_o tau_r(t), J_t = joints_r(t)``.

Constraints (sections V-B and VI): ``phi = constraint_fn(T_world_wrist (4,4), joints (13,))``, a scalar or a
vector (e.g. the signed distance of each hand link to the table and obstacles), is evaluated at
``mu_o tau_r(t)``; its components below ``activation_distance`` are active. A step with active components gets
a vector variable ``C_t``, a factor ``C_t = phi0 + G dx`` (the active rows of phi linearized at the current
estimate, by central differences or by a given ``constraint_gradient_fn``; variance 1e-10) and a prior
``N(r_t, R_t)`` with ``r_t = phi(mu_o tau_r(t))`` clipped to ``[clearance, activation_distance]`` and
``R_t = constraint_std^2 I``; the clearance may differ per component (``constraint_clearance_mm``: the planner
holds the hand's links 10 mm from the table and obstacles, 3 mm from the grasped object).
Linearize, solve (with a trust region: priors ``N(x0, trust_stds)`` tying each constrained step to its
linearization point ``x0``, so that one solve stays where the linearization holds), move the linearization
point half way (``relinearization_damping``) to the new means and repeat until they move less than
``mean_tolerance`` (max-norm over all steps of the tangent change [rad, m]);
components that come below the activation distance on the way join the active set (it only grows, and a
grown set is solved once more before convergence is declared); ``iterations`` counts the solves. The final
solve drops the trust region (at a fixed point its priors have zero error), so that the marginals are those
of the paper's graph. One constraint per link matters: the minimum over all links switches between links
from one linearization to the next (the fingers in one wall, the thumb in the other), and its single
gradient never pushes both out.

Joint limits (``joint_limits``, our addition): the Gaussian graph knows no joint limits, and the constraint
factors of a scene move whatever is cheapest in its metric. They bent the SAH's fingers backwards to clear a
wall, the means up to 27 deg beyond the limits; the sampler clips each draw to the limits, so every draw of
such a joint landed on the limit, the finger flexed back into the wall (ham_arc). A limit is an inequality,
which no Gaussian factor states: a prior on the distance to the limit (tried first) also pinned every joint
near a limit to the prior's std, 0.5 deg instead of 3-8, and the narrower marginals planned worse
(chips_flat: the baseline found 2 grasps in 6 trials instead of 6). So the limits enter by expectation
propagation, the moment matching of loopy belief propagation (Toussaint's AICO handles such constraints the
same way): each joint whose marginal puts more than ``joint_limit_min_probability`` beyond a limit gets a
Gaussian *site* such that the marginal has the mean and variance of the cavity (the marginal without the
site) truncated to the limits; the sites are updated, damped, once per relinearization and then to their
fixed point on the final graph. With one site on a Gaussian prior this is exact (tests: the truncated
normal's moments); on the chain it agrees with rejection sampling of the truncated posterior.

Conditioning on O (the marginals P(X_t | O = mu_o)): Gaussian conditioning deletes O's rows and columns from
the information matrix, which is the Schur complement ``Sigma_x|o = Sigma_xx - Sigma_xo Sigma_oo^-1 Sigma_ox``
of the joint covariance of ``(O, X)``. We compute it by building the graph with O held fixed at mu_o
(``build_graph(..., fixed_object=True)``: f_1t becomes unary in ``(W_t, J_t)`` and P(O) drops out) and taking
``gtsam.Marginals`` of ``(W_t, J_t)`` there: the same numbers (tests compare both against the Schur complement
of the full graph's joint marginals) at ~70 us per step instead of ~4 ms for a ``jointMarginalCovariance``
that includes O, which sits in every clique's separator. The means are the MAP of that conditioned graph (with
the constraints, relinearized as above). The wrist mean is returned in the object frame,
``T_object_wrist_mean = mu_o^-1 W_t``; the body-frame covariance is unchanged by that left multiplication.
The full graph ``build_graph(..., fixed_object=False)`` is P(O) P(X | O) itself, for joint marginals.

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
``params_json``            () str       :class:`VariationParams` as JSON
``iterations``             ()           relinearization solves (1 without constraints)
``converged``              ()           the relinearization met its tolerance
``constrained``            (T,)         steps that carried constraint factors
``grasp_type``, ``object`` () str       from the trajectory
``traj_*``                              the source trajectory's keys (``retarget.trajectory``), if any
=========================  ===========  ===========================================================
"""

from __future__ import annotations

import json
import logging
import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import gtsam
import numpy as np
from scipy.special import log_ndtr, ndtr

from assets.errors import InputError
from assets.io import atomic_savez, load_npz, require_finite, require_rotation, require_shape, require_spd
from assets.se3 import local, retract, se3_inverse
from retarget.trajectory import GRASP_TYPES, Trajectory

from .factors import (
    N_JOINTS,
    ConstraintFn,
    ConstraintGradientFn,
    FingertipMap,
    constraint_factors,
    constraint_gradient,
    demonstration_factors,
    modeling_covariance,
    smoothness_factors,
)
from .params import VariationParams

__all__ = [
    "VariationModel",
    "build_graph",
    "solve",
    "factor_covariances",
    "key_o",
    "key_w",
    "key_j",
    "key_c",
    "initial_values",
    "truncated_normal_moments",
]

log = logging.getLogger(__name__)
_SOURCE_KEYS = (
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


def key_o() -> int:
    """GTSAM key of the object pose O."""
    return gtsam.symbol("o", 0)


def key_w(t: int) -> int:
    """GTSAM key of the wrist pose W_t (world frame)."""
    return gtsam.symbol("w", t)


def key_j(t: int) -> int:
    """GTSAM key of the joints J_t."""
    return gtsam.symbol("j", t)


def key_c(t: int) -> int:
    """GTSAM key of the constraint value C_t."""
    return gtsam.symbol("c", t)


@dataclass(frozen=True, eq=False)
class VariationModel:
    """The marginals P(X_t | O) of a solved variation model; see the module docstring for the file format.

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
        J = require_finite("joints_mean", require_shape("joints_mean", self.joints_mean, (n, 13), p), p)
        C = require_spd("cov", require_shape("cov", self.cov, (n, 19, 19), p), p)
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
            s = self.source
            arrays.update(
                traj_T_object_wrist=s.T_object_wrist,
                traj_joints=s.joints,
                traj_cov_retarget=s.cov_retarget,
                traj_fingertip_rmse_mm=s.fingertip_rmse_mm,
                traj_T_world_object_mean=s.T_world_object_mean,
                traj_cov_object=s.cov_object,
                traj_dt_s=np.float64(s.dt_s),
                traj_object=np.str_(s.object),
                traj_grasp_type=np.str_(s.grasp_type),
                traj_meta_json=np.str_(json.dumps(s.meta, sort_keys=True)),
            )
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
        params = VariationParams.from_dict(params_dict, path)
        source = None
        traj_keys = [f"traj_{k}" for k in _SOURCE_KEYS]
        if any(k in d for k in traj_keys):
            missing = [k for k in traj_keys if k not in d]
            if missing:
                raise InputError(f"source trajectory: missing keys {missing}", path)
            for key in ("traj_dt_s", "traj_object", "traj_grasp_type"):
                if d[key].ndim != 0:
                    raise InputError(f"{key}: expected a scalar, found shape {d[key].shape}", path)
            if d["traj_dt_s"].dtype.kind not in "iuf":
                raise InputError(f"traj_dt_s: expected a number of seconds, found {d['traj_dt_s']!r}", path)
            try:
                meta = json.loads(str(d.get("traj_meta_json", "{}")))
            except ValueError as exc:
                raise InputError(f"traj_meta_json: not JSON ({exc})", path) from None
            source = Trajectory(
                T_object_wrist=d["traj_T_object_wrist"],
                joints=d["traj_joints"],
                cov_retarget=d["traj_cov_retarget"],
                fingertip_rmse_mm=d["traj_fingertip_rmse_mm"],
                T_world_object_mean=d["traj_T_world_object_mean"],
                cov_object=d["traj_cov_object"],
                dt_s=float(d["traj_dt_s"]),
                object=str(d["traj_object"]),
                grasp_type=str(d["traj_grasp_type"]),
                meta=meta if isinstance(meta, dict) else {},
                path=str(path),
            )
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


def factor_covariances(
    traj: Trajectory, params: VariationParams, fingertip_map: FingertipMap | None = None
) -> np.ndarray:
    """Sigma_r(t) + Sigma_m(t) (T, 19, 19), checked positive definite.

    Raises:
        InputError: the sum is not positive definite at some step (raise ``joint_floor_std_deg``).
    """
    cov = np.asarray(traj.cov_retarget) + modeling_covariance(
        traj.T_object_wrist, traj.joints, traj.grasp_type, params, fingertip_map
    )
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    eig_min = np.linalg.eigvalsh(cov).min(axis=-1)
    if not np.all(eig_min > 0):
        t = int(np.argmin(eig_min))
        raise InputError(
            f"Sigma_r + Sigma_m at step {t} is not positive definite (smallest eigenvalue "
            f"{eig_min[t]:.3g}); raise joint_floor_std_deg or give sigma_m_std_config"
        )
    return cov


def build_graph(
    traj: Trajectory,
    params: VariationParams,
    cov_f1: np.ndarray,
    T_world_object: np.ndarray,
    cov_object: np.ndarray | None,
    linearizations: dict | None = None,
    fixed_object: bool = False,
) -> gtsam.NonlinearFactorGraph:
    """The factor graph P(O) P(X_1..X_T | O) (and the constraint factors of ``linearizations``).

    Args:
        traj: tau_r and Sigma_r.
        params: parameters (smoothness, constraint noise).
        cov_f1: (T, 19, 19) Sigma_r + Sigma_m (:func:`factor_covariances`).
        T_world_object: (4, 4) mu_o. cov_object: (6, 6) Sigma_o ``[omega, v]``.
        linearizations: ``{t: (T_world_wrist0, joints0, phi0 (m,), grad (m, 19), r_t (m,))}`` for constrained
            steps (scalars and (19,) for one constraint).
        fixed_object: hold O fixed at ``T_world_object`` (the graph of P(X | O = mu_o); no O variable, no
            prior, ``cov_object`` unused).
    """
    graph = gtsam.NonlinearFactorGraph()
    T_world_object = np.asarray(T_world_object, dtype=float)
    if not fixed_object:
        graph.add(
            gtsam.PriorFactorPose3(
                key_o(),
                gtsam.Pose3(T_world_object),
                gtsam.noiseModel.Gaussian.Covariance(np.asarray(cov_object, dtype=float)),
            )
        )
    stds = params.smoothness_stds()
    n = traj.num_steps
    for t in range(n):
        for f in demonstration_factors(
            key_o(),
            key_w(t),
            key_j(t),
            traj.T_object_wrist[t],
            traj.joints[t],
            cov_f1[t],
            T_world_object if fixed_object else None,
        ):
            graph.add(f)
        if t + 1 < n:
            for f in smoothness_factors(key_w(t), key_w(t + 1), key_j(t), key_j(t + 1), stds):
                graph.add(f)
    for t, (T0, j0, phi0, grad, r_t) in (linearizations or {}).items():
        for f in constraint_factors(
            key_c(t),
            key_w(t),
            key_j(t),
            T0,
            j0,
            phi0,
            grad,
            r_t,
            params.constraint_std_mm * 1e-3,
            params.constraint_delta_variance,
        ):
            graph.add(f)
    return graph


def initial_values(traj: Trajectory, T_world_object: np.ndarray, fixed_object: bool = False) -> gtsam.Values:
    """The starting point ``O = mu_o, W_t = mu_o tau_r(t), J_t = joints_r(t)`` (no O if ``fixed_object``)."""
    values = gtsam.Values()
    if not fixed_object:
        values.insert(key_o(), gtsam.Pose3(T_world_object))
    T_world_wrist = T_world_object @ traj.T_object_wrist
    for t in range(traj.num_steps):
        values.insert(key_w(t), gtsam.Pose3(T_world_wrist[t]))
        values.insert(key_j(t), np.array(traj.joints[t]))
    return values


def _means(values: gtsam.Values, n: int) -> tuple[np.ndarray, np.ndarray]:
    W = np.stack([values.atPose3(key_w(t)).matrix() for t in range(n)])
    J = np.stack([values.atVector(key_j(t)) for t in range(n)])
    return W, J


def solve(
    traj: Trajectory,
    params: VariationParams | None = None,
    *,
    T_world_object: np.ndarray | None = None,
    cov_object: np.ndarray | None = None,
    constraint_fn: ConstraintFn | None = None,
    fingertip_map: FingertipMap | None = None,
    constraint_clearance_mm: float | Sequence[float] | None = None,
    constraint_gradient_fn: ConstraintGradientFn | None = None,
    joint_limits: np.ndarray | None = None,
) -> VariationModel:
    """Build the graph, solve it, and return the marginals P(X_t | O) as a :class:`VariationModel`.

    Args:
        traj: the retargeted trajectory tau_r with Sigma_r(t).
        params: defaults if None.
        T_world_object, cov_object: the object prior (4, 4), (6, 6) ``[omega, v]``; the trajectory's if None.
        constraint_fn: ``phi(T_world_wrist (4,4), joints (13,)) -> float or (m,)`` (e.g. signed distances
            [m]); None for no constraint factors.
        fingertip_map: the Sigma_m mapping of :func:`inference.factors.modeling_covariance`.
        constraint_clearance_mm: the clearance of each component of phi [mm] (a number for all, or one per
            component); default ``params.clearance_mm`` for all.
        constraint_gradient_fn: ``(T_world_wrist, joints) -> (phi (m,), grad (m, 19))``, the same phi with
            its gradient (e.g. from the contact normals); default central differences of ``constraint_fn``
            (``params.gradient_step``), 2 x 19 more evaluations of phi per constrained step.
        joint_limits: (13, 2) lower and upper joint limits [rad] (the SAH's: ``assets.sah.JOINT_LIMITS``),
            held by expectation propagation (see the module docstring); None: none, and the means may leave
            the limits.

    Raises:
        InputError: invalid object prior or a covariance that is not positive definite.
    """
    start = time.perf_counter()
    params = params or VariationParams()
    mu_o = traj.T_world_object_mean if T_world_object is None else T_world_object
    mu_o = require_finite("T_world_object", require_shape("T_world_object", mu_o, (4, 4)))
    require_rotation("T_world_object", mu_o[:3, :3])
    cov_o = traj.cov_object if cov_object is None else cov_object
    cov_o = require_spd("cov_object", require_shape("cov_object", cov_o, (6, 6)))
    n = traj.num_steps
    cov_f1 = factor_covariances(traj, params, fingertip_map)

    # constrained components per step: phi_i below the activation distance at tau_r or, as the means move,
    # at any linearization point (the active set only grows); targets r_i = phi_i(tau_r) clipped to
    # [clearance, activation]: keep the demonstrated distance, but at least the clearance
    act_m = params.activation_distance_mm * 1e-3
    clear_mm = params.clearance_mm if constraint_clearance_mm is None else constraint_clearance_mm
    clear_m = 1e-3 * np.asarray(clear_mm, dtype=float)
    if clear_m.ndim > 1 or not np.all(np.isfinite(clear_m)) or np.any(clear_m < 0):
        raise InputError(f"constraint_clearance_mm: expected finite numbers >= 0, found {clear_mm!r}")
    active: dict[int, np.ndarray] = {}
    phi_tau: list[np.ndarray] = []
    if constraint_fn is not None:
        T_world_wrist_tau = mu_o @ traj.T_object_wrist
        phi_tau = [
            _constraint_values(constraint_fn, T_world_wrist_tau[t], traj.joints[t], t) for t in range(n)
        ]
        if clear_m.ndim == 1 and clear_m.shape != phi_tau[0].shape:
            raise InputError(
                f"constraint_clearance_mm: {clear_m.size} clearances for {phi_tau[0].size} "
                "constraint components"
            )
        _grow_active(active, phi_tau, act_m)
    sites = _JointLimitSites(joint_limits, n, params)

    def graph_at(lin: dict) -> gtsam.NonlinearFactorGraph:
        """P(X | O = mu_o) with the constraint factors linearized as in ``lin`` and the joint-limit sites."""
        return sites.add_to(build_graph(traj, params, cov_f1, mu_o, None, lin, fixed_object=True))

    values = initial_values(traj, mu_o, fixed_object=True)
    W_prev, J_prev = _means(values, n)
    gn = gtsam.GaussNewtonParams()
    gn.setMaxIterations(params.gauss_newton_max_iterations)
    gn.setRelativeErrorTol(params.gauss_newton_relative_tolerance)
    gn.setAbsoluteErrorTol(0.0)
    iterations, converged = 0, not active
    grew = False
    lin: dict = {}
    for iterations in range(1, (params.max_iterations if active else 1) + 1):
        lin = {}
        for t, mask in active.items():
            if constraint_gradient_fn is None:
                phi0, grad = constraint_gradient(constraint_fn, W_prev[t], J_prev[t], params.gradient_step)
            else:
                phi0, grad = _constraint_gradient_values(constraint_gradient_fn, W_prev[t], J_prev[t], t)
            phi0, grad = np.atleast_1d(phi0)[mask], np.atleast_2d(grad)[mask]
            clear_t = np.broadcast_to(clear_m, mask.shape)[mask]
            r_t = np.clip(phi_tau[t][mask], clear_t, np.maximum(act_m, clear_t))
            lin[t] = (W_prev[t], J_prev[t], phi0, grad, r_t)
            if values.exists(key_c(t)):
                values.erase(key_c(t))  # its dimension grows with the active set
            values.insert(key_c(t), phi0)
        graph = graph_at(lin)
        if active:
            graph = _with_trust_region(graph, lin, params.trust_stds())
        values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
        W_new, J_new = _means(values, n)
        if sites and active:  # one EP step per relinearization keeps the linearization points in the limits
            sites.update(graph, values)
        if active:
            dW = local(W_prev, W_new)
            moves = np.abs(np.concatenate([dW, J_new - J_prev], axis=1))  # (T, 19) [omega, v, joints]
            move = float(moves.max())
            if log.isEnabledFor(logging.DEBUG):
                t_max, i_max = np.unravel_index(int(np.argmax(moves)), moves.shape)
                log.debug("relinearization %d: means moved %.3g (step %d, tangent coordinate %d), %d "
                          "constraints", iterations, move, t_max, i_max,
                          sum(int(m.sum()) for m in active.values()))  # fmt: skip
            # damped update of the linearization point (damped loopy belief propagation): the closest-point
            # distances change their witness points, and undamped relinearization oscillates between them
            a = params.relinearization_damping
            W_prev, J_prev = retract(W_prev, a * dW), J_prev + a * (J_new - J_prev)
            if move < params.mean_tolerance and not grew:
                converged = True
                break
            phi_now = [_constraint_values(constraint_fn, W_prev[t], J_prev[t], t) for t in range(n)]
            grew = _grow_active(active, phi_now, act_m)
    if active:  # the final solve without the trust region, at the last linearization point
        graph = graph_at(lin)
        values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
    if not converged:
        log.warning("constraint relinearization did not converge in %d iterations", iterations)
    if sites:  # expectation propagation of the joint limits on the final graph, to its fixed point
        for _ in range(params.joint_limit_max_iterations):
            change = sites.update(graph, values)
            graph = graph_at(lin)
            values = gtsam.GaussNewtonOptimizer(graph, values, gn).optimize()
            if change < params.joint_limit_tolerance:
                break
        else:
            converged = False
            log.warning(
                "joint-limit propagation did not converge in %d iterations", params.joint_limit_max_iterations
            )

    T_object_wrist, joints, cov = _conditional_marginals(graph, values, mu_o, n)
    return VariationModel(
        T_object_wrist_mean=T_object_wrist,
        joints_mean=joints,
        cov=cov,
        T_world_object_mean=mu_o,
        cov_object=cov_o,
        params=params,
        iterations=iterations,
        grasp_type=traj.grasp_type,
        object=traj.object,
        converged=converged,
        constrained=np.isin(np.arange(n), list(active)) | sites.steps(),
        source=traj,
        solve_time_s=time.perf_counter() - start,
    )


def _with_trust_region(
    graph: gtsam.NonlinearFactorGraph, linearizations: dict, stds: np.ndarray
) -> gtsam.NonlinearFactorGraph:
    """A copy of ``graph`` with priors tying each constrained step to its linearization point."""
    out = gtsam.NonlinearFactorGraph(graph)
    wrist = gtsam.noiseModel.Diagonal.Sigmas(stds[:6])
    joints = gtsam.noiseModel.Diagonal.Sigmas(stds[6:])
    for t, (W0, J0, *_rest) in linearizations.items():
        out.add(gtsam.PriorFactorPose3(key_w(t), gtsam.Pose3(np.asarray(W0, dtype=float)), wrist))
        out.add(gtsam.PriorFactorVector(key_j(t), np.asarray(J0, dtype=float), joints))
    return out


def truncated_normal_moments(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of the standard normal truncated to ``[a, b]`` (arrays, ``a < b``, +-inf allowed).

    Computed in log space and, for an interval in the upper tail, by symmetry from the lower one: against
    scipy's ``truncnorm.stats`` (some 100x slower on arrays) the means agree to 1e-13 and the variances to
    1e-10 relative for bounds within 30 sigma of the mean and at least 1 sigma apart (1e-8 for narrower
    intervals deep in a tail).
    """
    a, b = np.broadcast_arrays(np.asarray(a, dtype=float), np.asarray(b, dtype=float))
    flip = a > -b  # the interval lies more above 0 than below: use its mirror image, then negate the mean
    lo, hi = np.where(flip, -b, a), np.where(flip, -a, b)
    log_z = log_ndtr(hi) + np.log1p(-np.exp(log_ndtr(lo) - log_ndtr(hi)))
    log_phi = lambda x: -0.5 * x * x - 0.5 * math.log(2 * math.pi)  # noqa: E731
    with np.errstate(invalid="ignore", over="ignore"):
        r_lo = np.where(np.isfinite(lo), np.exp(log_phi(lo) - log_z), 0.0)
        r_hi = np.where(np.isfinite(hi), np.exp(log_phi(hi) - log_z), 0.0)
        x_lo = np.where(np.isfinite(lo), lo * r_lo, 0.0)
        x_hi = np.where(np.isfinite(hi), hi * r_hi, 0.0)
    mean = r_lo - r_hi
    var = np.maximum(1.0 + x_lo - x_hi - mean * mean, 0.0)
    return np.where(flip, -mean, mean), var


class _JointLimitSites:
    """The joint limits ``lo <= J_t <= hi`` by expectation propagation (see the module docstring).

    Each joint of each step whose marginal puts more than ``params.joint_limit_min_probability`` beyond a
    limit gets a *site*, a Gaussian factor ``N(J_t,i; m, 1/tau)`` standing in for the limits' indicator:
    with the site's cavity ``N(m_c, v_c)`` (the marginal with the site divided out), the site is chosen so
    that cavity x site has the mean and variance of the cavity truncated to ``[lo, hi]``. A truncation
    never widens a Gaussian, so ``tau >= 0``. Updates are damped in the natural parameters.
    Falsy without limits.
    """

    _FREE_STD = 1e6  # [rad] the prior std of a joint without a site: precision 1e-12, no information

    def __init__(self, joint_limits: np.ndarray | None, n: int, params: VariationParams):
        self.n = n
        self.enabled = joint_limits is not None
        if self.enabled:
            lim = require_shape("joint_limits", joint_limits, (N_JOINTS, 2))
            lim = require_finite("joint_limits", lim)
            if np.any(lim[:, 0] >= lim[:, 1]):
                raise InputError(f"joint_limits: each lower limit must be below its upper: {lim.tolist()}")
            self.lo, self.hi = lim[:, 0].copy(), lim[:, 1].copy()
        self.tau = np.zeros((n, N_JOINTS))  # site precisions [1/rad^2]
        self.tau_m = np.zeros((n, N_JOINTS))  # site precision x mean
        self._last: np.ndarray | None = None  # (2, T, 13) the marginal means and stds of the last update
        self.min_probability = params.joint_limit_min_probability
        self.damping = params.joint_limit_damping

    def __bool__(self) -> bool:
        return self.enabled

    def steps(self) -> np.ndarray:
        """(T,) bool: the steps with a site."""
        return np.any(self.tau > 0, axis=1)

    def add_to(self, graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
        """``graph`` plus a prior on ``J_t`` at each step with a site (joints without one: no information)."""
        for t in np.flatnonzero(self.steps()):
            on = self.tau[t] > 0
            mean = np.where(on, self.tau_m[t] / np.where(on, self.tau[t], 1.0), 0.0)
            std = np.where(on, 1.0 / np.sqrt(np.where(on, self.tau[t], 1.0)), self._FREE_STD)
            graph.add(gtsam.PriorFactorVector(key_j(int(t)), mean, gtsam.noiseModel.Diagonal.Sigmas(std)))
        return graph

    def update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> float:
        """One damped EP update of every site from the marginals of ``graph`` at ``values``; returns how far
        those marginals moved since the last update: the largest change of a joint's mean or std [rad]
        (infinite at the first update, 0 when no joint needs a site)."""
        marginals = gtsam.Marginals(graph, values)
        m = np.stack([values.atVector(key_j(t)) for t in range(self.n)])
        v = np.stack([np.diag(marginals.marginalCovariance(key_j(t))) for t in range(self.n)])
        tau_c = 1.0 / v - self.tau
        with np.errstate(divide="ignore", invalid="ignore"):
            m_c = (m / v - self.tau_m) / tau_c
        ok = tau_c > 0
        s_c = np.sqrt(np.where(ok, 1.0 / np.where(ok, tau_c, 1.0), 1.0))
        m_c = np.where(ok, m_c, m)
        alpha, beta = (self.lo - m_c) / s_c, (self.hi - m_c) / s_c
        outside = ndtr(alpha) + ndtr(-beta)
        todo = ok & ((outside > self.min_probability) | (self.tau > 0))
        if not todo.any():
            return 0.0
        now = np.stack([m, np.sqrt(v)])
        change = np.inf if self._last is None else float(np.abs(now - self._last).max())
        self._last = now
        mean_z, var_z = truncated_normal_moments(alpha[todo], beta[todo])
        mean_t, var_t = m_c[todo] + s_c[todo] * mean_z, s_c[todo] ** 2 * var_z
        tau_new = np.maximum(1.0 / var_t - tau_c[todo], 0.0)
        tau_m_new = mean_t / var_t - tau_c[todo] * m_c[todo]
        d = self.damping
        self.tau[todo] = (1 - d) * self.tau[todo] + d * tau_new
        self.tau_m[todo] = (1 - d) * self.tau_m[todo] + d * tau_m_new
        return change


def _constraint_values(constraint_fn: ConstraintFn, T_world_wrist: np.ndarray, joints: np.ndarray, t: int):
    phi = np.atleast_1d(np.asarray(constraint_fn(T_world_wrist, np.array(joints)), dtype=float))
    if phi.ndim != 1 or not np.all(np.isfinite(phi)):
        raise InputError(f"constraint function returned {phi.tolist()} at step {t}: expected finite values")
    return phi


def _constraint_gradient_values(
    gradient_fn: ConstraintGradientFn, T_world_wrist: np.ndarray, joints: np.ndarray, t: int
) -> tuple[np.ndarray, np.ndarray]:
    phi, grad = gradient_fn(T_world_wrist, np.array(joints))
    phi, grad = np.atleast_1d(np.asarray(phi, dtype=float)), np.atleast_2d(np.asarray(grad, dtype=float))
    if phi.ndim != 1 or grad.shape != (phi.size, 19):
        raise InputError(
            f"constraint gradient function at step {t}: expected phi (m,) and grad (m, 19), found shapes "
            f"{phi.shape} and {grad.shape}"
        )
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(grad))):
        raise InputError(f"constraint gradient function returned a non-finite value at step {t}")
    return phi, grad


def _grow_active(active: dict[int, np.ndarray], phi: list[np.ndarray], activation: float) -> bool:
    """Add the components with ``phi < activation`` (a distance [m]) to ``active`` (step -> bool mask); True
    if any was new."""
    grew = False
    for t, values in enumerate(phi):
        below = values < activation
        old = active.get(t, np.zeros(len(values), dtype=bool))
        if np.any(below & ~old):
            active[t] = old | below
            grew = True
    return grew


def _conditional_marginals(
    graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, mu_o: np.ndarray, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P(X_t | O = mu_o) from the solved graph with O fixed: means in the object frame and (T, 19, 19)."""
    marginals = gtsam.Marginals(graph, values)
    cov = np.stack([marginals.jointMarginalCovariance([key_w(t), key_j(t)]).fullMatrix() for t in range(n)])
    cov = 0.5 * (cov + np.swapaxes(cov, -1, -2))
    W, J = _means(values, n)
    return se3_inverse(mu_o) @ W, J, cov
