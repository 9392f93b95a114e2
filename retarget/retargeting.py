"""Retargeting a human demonstration to the SAH: tau_h -> tau_v -> tau_r and Sigma_r(t) (paper, section IV).

Steps, per demonstration:

1. **Virtual fingers** (:mod:`retarget.virtual_fingers`) at the last step of tau_h pick the human finger
   each SAH finger follows; their fingertips in the object frame form tau_v.
   With ``RetargetConfig.targets = "scaled"`` (the default for power grasps) each target is moved away
   from the human palm centre by the SAH's size ratio for its finger
   (:func:`~retarget.objective.hand_scale`).
2. **Per step t**, the SAH wrist pose (6 DOF) and the thumb's opposition joint minimise
   ``sum_i w_i d_i(k, t)`` (:mod:`retarget.objective`) with Rosenbrock's method
   (:mod:`retarget.rosenbrock`), warm-started at the previous step's optimum. The other finger joints
   are no variables: for each trial the robust per-finger IK (:func:`retarget.ik.hand_ik`, seeded with
   the previous step's joints) places the fingertips at tau_v(t) as well as it can.
3. **Sigma_r(t)**: the step's fingertip mean squared error ``mse = mean_j |F_j(k) - F_j(tau_v)|^2`` taken
   as an isotropic fingertip covariance ``mse / 3 * I_12`` (so that each fingertip's expected squared
   distance is the MSE) and mapped into the 19-D tangent ``[omega, v, 13 joints]`` by the fingertip
   Jacobian's pseudo-inverse (:func:`assets.sah.config_cov_from_fingertip_cov`, through
   :attr:`RetargetConfig.covariance_map`): rank <= 12, the paper's degenerate covariances. The wrist part is
   GTSAM's Pose3 body tangent (right perturbation).
4. **The final grasp** (ours, :mod:`retarget.final_grasp`): the last step searched again for how the hand
   closed at its draws holds the object, the change blended into the approach
   (:meth:`RetargetResult.with_final_grasp`). It needs the pybullet world and a variation model, so
   :func:`pbdgrasp.strategy.retarget_in_scene` runs it after :func:`retarget_demonstration`.

Settings: :class:`~retarget.config.RetargetConfig`.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from assets import sah
from assets.errors import InputError
from assets.q_layout import N_JOINTS
from assets.se3 import q_from_pose

from .config import PAPER_WEIGHTS, IsFree, Penetration, RetargetConfig
from .final_grasp import FinalGraspResult
from .objective import (
    THUMB_BASE,
    StepCosts,
    StepObjective,
    hand_scale,
    palm_alignment,
    palm_centre,
    scaled_targets,
    step_costs,
    virtual_finger_targets,
)
from .rosenbrock import minimize_rosenbrock
from .trajectory import Trajectory
from .virtual_fingers import VirtualFingers, virtual_fingers_of

__all__ = [
    "PAPER_WEIGHTS",
    "RetargetConfig",
    "StepCosts",
    "RetargetResult",
    "palm_alignment",
    "palm_centre",
    "step_costs",
    "virtual_finger_targets",
    "retarget_fingertips",
    "retarget_demonstration",
    "fingertip_cov_to_config",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True, eq=False)
class RetargetResult:
    """tau_r with Sigma_r(t) and diagnostics; T steps.

    Attributes:
        T_object_wrist: (T, 4, 4) SAH wrist poses in the object frame [m].
        joints: (T, 13) SAH joints [rad], ``sah.JOINT_NAMES`` order.
        cov_retarget: (T, 19, 19) Sigma_r(t) in ``[omega, v, 13 joints]`` [rad^2, m^2].
        fingertip_error_mm: (T, 4) distance of each SAH fingertip to its tau_v target [mm].
        fingertip_rmse_mm: (T,) root mean square over the four fingertips [mm].
        distances: (T, 7) d1..d7 at the optimum.
        cost: (T,) the optimum's weighted sum.
        nfev: (T,) objective evaluations per step.
        n_collision_checks: (T,) collision queries per step (the lazy d6 of :mod:`retarget.objective`
            saves some; a contact stop adds up to ``1 + 4 * (1 + contact_stop_iterations)``).
        converged: (T,) Rosenbrock's success flag per step.
        virtual_fingers: the chosen virtual fingers, if computed from a demonstration.
        T_hwrist_rwrist: (4, 4) rT_h used.
        p_object_targets: (T, 4, 3) tau_v, the fingertip targets [m] (object frame).

    After :meth:`with_final_grasp`, ``fingertip_error_mm`` and ``fingertip_rmse_mm`` are those of the
    trajectory as written, while ``distances``, ``cost`` and ``cov_retarget`` stay the fingertip search's.
    """

    T_object_wrist: np.ndarray
    joints: np.ndarray
    cov_retarget: np.ndarray
    fingertip_error_mm: np.ndarray
    fingertip_rmse_mm: np.ndarray
    distances: np.ndarray
    cost: np.ndarray
    nfev: np.ndarray
    n_collision_checks: np.ndarray
    converged: np.ndarray
    T_hwrist_rwrist: np.ndarray
    p_object_targets: np.ndarray | None = None
    virtual_fingers: VirtualFingers | None = None
    meta: dict = field(default_factory=dict)

    def with_final_grasp(self, refined: FinalGraspResult) -> RetargetResult:
        """This result with the trajectory of a :func:`~retarget.final_grasp.refine_final_grasp`: its wrist
        poses and joints, the fingertip errors against tau_v recomputed, the refinement in ``meta``."""
        T, joints = refined.T_object_wrist, refined.joints
        err = sah.fingertip_positions_in(T, joints) - self.p_object_targets
        err_mm = 1e3 * np.linalg.norm(err, axis=-1)
        meta = {**self.meta, "final_grasp": refined.to_meta()}
        return dataclasses.replace(
            self,
            T_object_wrist=T,
            joints=joints,
            fingertip_error_mm=err_mm,
            fingertip_rmse_mm=np.sqrt(np.mean(err_mm**2, axis=-1)),
            meta=meta,
        )

    @property
    def rmse_mm(self) -> float:
        """Fingertip RMSE over all steps and fingers [mm]."""
        return float(np.sqrt(np.mean(self.fingertip_error_mm**2)))

    @property
    def q(self) -> np.ndarray:
        """(T, 19) configurations ``[p, rotation vector, joints]`` in the object frame."""
        return np.concatenate([q_from_pose(self.T_object_wrist), self.joints], axis=-1)

    def to_trajectory(
        self,
        T_world_object_mean: np.ndarray,
        cov_object: np.ndarray,
        dt_s: float,
        object_name: str,
        grasp_type: str,
        meta: dict | None = None,
    ) -> Trajectory:
        """The validated :class:`retarget.trajectory.Trajectory` (the ``.traj.npz`` contents)."""
        info = dict(self.meta)
        info.update(meta or {})
        if self.virtual_fingers is not None:
            info["virtual_fingers"] = {
                "groups": [list(g) for g in self.virtual_fingers.groups],
                "human_for_robot": list(self.virtual_fingers.human_for_robot),
                "cohesive_index": self.virtual_fingers.cohesive_index,
            }
        info["rmse_mm"] = self.rmse_mm
        info["T_hwrist_rwrist"] = self.T_hwrist_rwrist.tolist()
        return Trajectory(
            T_object_wrist=self.T_object_wrist,
            joints=self.joints,
            cov_retarget=self.cov_retarget,
            fingertip_rmse_mm=self.fingertip_rmse_mm,
            T_world_object_mean=T_world_object_mean,
            cov_object=cov_object,
            dt_s=dt_s,
            object=object_name,
            grasp_type=grasp_type,
            meta=info,
        )


def fingertip_cov_to_config(
    T_object_wrist: np.ndarray, joints: np.ndarray, mse_m2: np.ndarray, through: str = "configuration"
) -> np.ndarray:
    """Sigma_r from per-step fingertip MSE: (T, 4, 4), (T, 13), (T,) [m^2] -> (T, 19, 19) PSD.

    The fingertip covariance is ``mse / 3 * I_12`` (isotropic; trace per fingertip = mse), realised
    ``through`` the whole configuration or the finger joints alone
    (:func:`assets.sah.config_cov_from_fingertip_cov`).
    """
    J = sah.fingertip_jacobian(T_object_wrist, joints)
    cov12 = (np.asarray(mse_m2, dtype=float) / 3.0)[:, None, None] * np.eye(12)
    return sah.config_cov_from_fingertip_cov(J, cov12, through=through)


def retarget_fingertips(
    p_object_targets: np.ndarray,
    T_object_hwrist: np.ndarray,
    T_hwrist_rwrist: np.ndarray | None = None,
    is_free: IsFree | None = None,
    config: RetargetConfig | None = None,
    joints0: np.ndarray | None = None,
    progress: bool = False,
    penetration: Penetration | None = None,
) -> RetargetResult:
    """Solve the paper's problem (2) step by step for given virtual-finger targets.

    Args:
        p_object_targets: (T, 4, 3) tau_v fingertips in the object frame [m], SAH finger order.
        T_object_hwrist: (T, 4, 4) human wrist poses in the object frame.
        T_hwrist_rwrist: (4, 4) rT_h; default :func:`palm_alignment`.
        is_free: the collision check of d6 (q in the object frame), or None to drop d6.
        penetration: the depth of d6's collision [m] (q in the object frame); replaces ``is_free`` and
            adds the depth term of :mod:`retarget.objective`.
        config: :class:`RetargetConfig`; default the paper's weights.
        joints0: (13,) IK seed of the first step (default ``sah.rest_joints()`` with the thumb's
            opposition at ``config.thumb_base_seed_deg``).
        progress: show a tqdm progress bar over the steps.

    Returns:
        The :class:`RetargetResult`.

    Raises:
        InputError: shapes or values are invalid.
    """
    config = config or RetargetConfig()
    P = np.asarray(p_object_targets, dtype=float)
    H = np.asarray(T_object_hwrist, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (4, 3) or H.shape != (P.shape[0], 4, 4) or P.shape[0] < 1:
        raise InputError(
            f"expected targets (T, 4, 3) and human wrist poses (T, 4, 4), found {P.shape} and {H.shape}"
        )
    if not (np.all(np.isfinite(P)) and np.all(np.isfinite(H))):
        raise InputError("targets and wrist poses must be finite")
    rTh = palm_alignment() if T_hwrist_rwrist is None else np.asarray(T_hwrist_rwrist, dtype=float)
    if rTh.shape != (4, 4):
        raise InputError(f"T_hwrist_rwrist: expected (4, 4), found {rTh.shape}")
    n = P.shape[0]
    T_des = H @ rTh
    if joints0 is None:
        joints_seed = sah.rest_joints()
        joints_seed[THUMB_BASE] = np.deg2rad(config.thumb_base_seed_deg)
        joints_seed = sah.clip_joints(joints_seed)
    else:
        joints_seed = sah.clip_joints(joints0)
    step0 = np.r_[
        np.full(3, np.deg2rad(config.step_rot_deg)),
        np.full(3, 1e-3 * config.step_pos_mm),
        np.deg2rad(config.step_thumb_deg),
    ]

    out_T = np.zeros((n, 4, 4))
    out_joints = np.zeros((n, N_JOINTS))
    out_err = np.zeros((n, 4, 3))
    out_d = np.zeros((n, 7))
    out_cost = np.zeros(n)
    out_nfev = np.zeros(n, dtype=int)
    out_checks = np.zeros(n, dtype=int)
    out_ok = np.zeros(n, dtype=bool)
    out_pen = np.zeros(n)
    T_start = T_des[0]
    joints_prev = None
    checked = is_free is not None or penetration is not None
    for t in tqdm(range(n), desc="retarget", unit="step", disable=not progress, leave=False):
        obj = StepObjective(T_start, P[t], T_des[t], joints_seed, joints_prev, is_free, config, penetration)
        res = minimize_rosenbrock(obj, np.zeros(7), step0=step0, xtol=config.xtol, max_nfev=config.max_nfev)
        T_opt, joints_opt, costs = obj.solution(res.x)
        nfev = res.nfev
        for factor in config.escape_factors if checked else ():
            if costs.d[5] == 0.0:
                break
            again = minimize_rosenbrock(
                obj, res.x, step0=factor * step0, xtol=config.xtol / factor, max_nfev=config.max_nfev
            )
            nfev += again.nfev
            if again.fun <= res.fun:
                res = again
                T_opt, joints_opt, costs = obj.solution(res.x)
        out_T[t], out_joints[t], out_err[t] = T_opt, joints_opt, costs.fingertip_error_m
        out_d[t], out_cost[t] = costs.d, costs.total
        out_nfev[t], out_checks[t], out_ok[t] = nfev, obj.n_checks, res.success
        out_pen[t] = costs.penetration_mm
        T_start, joints_seed, joints_prev = T_opt, joints_opt, joints_opt
    mse_m2 = np.mean(np.sum(out_err**2, axis=-1), axis=-1)
    cov = fingertip_cov_to_config(out_T, out_joints, mse_m2, config.covariance_map)
    err_mm = 1e3 * np.linalg.norm(out_err, axis=-1)
    result = RetargetResult(
        T_object_wrist=out_T,
        joints=out_joints,
        cov_retarget=cov,
        fingertip_error_mm=err_mm,
        fingertip_rmse_mm=1e3 * np.sqrt(mse_m2),
        distances=out_d,
        cost=out_cost,
        nfev=out_nfev,
        n_collision_checks=out_checks,
        converged=out_ok,
        T_hwrist_rwrist=rTh,
        p_object_targets=P,
        meta={
            "weights": list(config.weights),
            "smoothness_unit": config.smoothness_unit,
            "max_nfev": config.max_nfev,
            "covariance_map": config.covariance_map,
            "steps_in_collision": int(np.sum(out_d[:, 5] > 0)) if checked else None,
            "max_penetration_mm": float(np.max(out_pen)) if penetration is not None else None,
        },
    )
    log.info(
        "retargeted %d steps: fingertip RMSE %.2f mm, %d evaluations, %d collision checks",
        n,
        result.rmse_mm,
        int(out_nfev.sum()),
        int(out_checks.sum()),
    )
    return result


def retarget_demonstration(
    demo,
    is_free: IsFree | None = None,
    config: RetargetConfig | None = None,
    T_hwrist_rwrist: np.ndarray | None = None,
    progress: bool = False,
    penetration: Penetration | None = None,
) -> RetargetResult:
    """Retarget a :class:`retarget.demonstration.Demonstration` to the SAH (virtual fingers, then per step).

    Args:
        demo: the demonstration (its recorded, noisy ``T_object_wrist`` and ``joints`` are used).
        is_free: d6's collision check of the SAH against the object and the table, q (19,) in the object
            frame; None drops d6 (logged as a warning).
        config: :class:`RetargetConfig`.
        T_hwrist_rwrist: rT_h; default :func:`palm_alignment`.
        progress: tqdm progress bar over the steps.
        penetration: d6 with the depth of the collision, see :func:`retarget_fingertips`.
    """
    config = config or RetargetConfig()
    if is_free is None and penetration is None:
        log.warning("retargeting %s without a collision check: d6 = 0", demo.object)
    vf = virtual_fingers_of(demo.joints[-1], n_virtual=config.n_virtual, adjacent_only=config.adjacent_only)
    log.info("%s: %s", demo.object, vf.describe())
    targets = virtual_finger_targets(demo.T_object_wrist, demo.joints, vf, 1e-3 * config.pad_clearance_mm)
    mode = config.targets_for(demo.grasp_type)
    scale = np.ones(4)
    if mode == "scaled":
        scale = hand_scale(vf)
        targets = scaled_targets(targets, demo.T_object_wrist, scale)
    step_config = dataclasses.replace(config, weights=config.weights_for(mode, demo.object))
    result = retarget_fingertips(
        targets, demo.T_object_wrist, T_hwrist_rwrist=T_hwrist_rwrist, is_free=is_free, config=step_config,
        progress=progress, penetration=penetration,
    )  # fmt: skip
    meta = dict(result.meta)
    meta.update({"demonstration": demo.path, "object": demo.object, "grasp_type": demo.grasp_type})
    meta.update({"targets": mode, "hand_scale": scale.tolist()})
    return RetargetResult(**{**result.__dict__, "virtual_fingers": vf, "meta": meta})
