"""The per-step cost of retargeting (paper section IV, problem (2)): the distances d1..d7 of an SAH
configuration and the objective that Rosenbrock's method minimises.

The distances (the paper's weights ``(3, 1, 1, 1, 0.1, 10000, 10)``, :data:`~retarget.config.PAPER_WEIGHTS`):

* d1..d4: fingertip distance thumb, index, middle, ring to their tau_v target [mm]; the targets match the
  fingertip pads, not the tip points (:func:`virtual_finger_targets`).
* d5: wrist distance to the human wrist carried over by ``rT_h``: position error [mm] plus rotation
  angle [deg] between ``T_object_rwrist`` and ``T_object_hwrist @ T_hwrist_rwrist``.
* d6: 0 if the hand is collision-free (object and table), else 1; from an injected ``is_free`` callable,
  or from a ``penetration`` callable (the hand's penetration depth [m], 0 when free), with which a
  colliding configuration also costs ``penetration_weight_per_mm`` per mm of depth. When the IK's
  fingers are what collides, they stop at contact instead (:attr:`RetargetConfig.contact_stop`). Each
  step's search stays within a trust region about the previous optimum.
* d7: ``max_i |J_i(k) - J_i(tau_r(t - 1))|`` over the 13 joints, in radians by default
  (:attr:`RetargetConfig.smoothness_unit`); 0 at the first step.

``rT_h`` (:func:`palm_alignment`): both hand models share the wrist axes (+z along the middle finger, +y
towards the thumb, +x out of the palm); the SAH is placed with the same orientation and its palm centre on
the human palm centre. The palm centre of a hand is the midpoint between its wrist origin and the centroid
of the index, middle and ring knuckles (MCP joints) at zero joints.

d6 is evaluated lazily: Rosenbrock accepts a trial only if its value is not above the best value seen so
far, and d6 >= 0, so a trial whose other terms already exceed that value is rejected without a collision
query (the objective returns that lower bound instead of the exact value; accepted values are exact).
Why each of our additions is there, and what it changed when measured: docs/method.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from assets import sah
from assets.q_layout import POSE_DIM, TAN_POSE, TAN_ROT
from assets.se3 import make_pose, q_from_pose, se3_exp

from . import ik
from .config import IsFree, Penetration, RetargetConfig
from .virtual_fingers import VirtualFingers

__all__ = [
    "StepCosts",
    "StepObjective",
    "palm_alignment",
    "palm_centre",
    "hand_scale",
    "scaled_targets",
    "step_costs",
    "virtual_finger_targets",
]

THUMB_BASE = ik.THUMB_BASE
"""Index of the thumb's opposition joint, the seventh search variable, in the 13 joints."""


@dataclass(frozen=True)
class StepCosts:
    """The distances of one configuration at one step (see :mod:`retarget.objective` for units)."""

    d: np.ndarray  # (7,) d1..d7
    total: float  # sum w_i d_i
    fingertip_error_m: np.ndarray  # (4, 3) robot minus target, object frame
    penetration_mm: float = 0.0  # depth of the collision, if measured (a ``penetration`` callable)


def palm_centre(hand) -> np.ndarray:
    """Palm centre (3,) [m] in the wrist frame of a hand module (``sah`` or ``human_hand``).

    The midpoint between the wrist origin and the centroid of the index, middle and ring knuckles at zero
    joints; the knuckle of a finger is the origin of the first link of its chain below the wrist.
    """
    poses = hand.fk(np.zeros(len(hand.JOINT_NAMES)))
    knuckles = []
    for finger in ("index", "middle", "ring"):
        names = [n for n in poses if n.startswith(finger + "_")]
        if not names:
            raise RuntimeError(f"{hand.__name__}: no link of the {finger} finger in fk()")
        # The knuckle is the finger link nearest the wrist origin along the finger.
        p = np.stack([poses[n][:3, 3] for n in names])
        knuckles.append(p[np.argmin(p[:, 2])])
    return 0.5 * np.mean(knuckles, axis=0)


def palm_alignment() -> np.ndarray:
    """rT_h as ``T_hwrist_rwrist`` (4, 4): same axes, SAH palm centre on the human palm centre."""
    from assets import human_hand

    return make_pose(np.eye(3), palm_centre(human_hand) - palm_centre(sah))


def step_costs(
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    p_object_targets: np.ndarray,
    T_object_wrist_desired: np.ndarray,
    joints_prev: np.ndarray | None,
    collision_free: bool,
    config: RetargetConfig,
) -> StepCosts:
    """d1..d7 and their weighted sum for one SAH configuration (pure; see :mod:`retarget.objective`).

    Args:
        T_object_wrist: (4, 4) SAH wrist pose.
        joints: (13,) [rad].
        p_object_targets: (4, 3) tau_v(t) fingertips [m], SAH finger order.
        T_object_wrist_desired: (4, 4) the human wrist carried over, ``T_object_hwrist @ T_hwrist_rwrist``.
        joints_prev: (13,) tau_r(t - 1) joints, or None at the first step.
        collision_free: the value of the collision check.
        config: the weights and the unit of d7.
    """
    err = ik.fingertips(joints) @ T_object_wrist[:3, :3].T + T_object_wrist[:3, 3] - p_object_targets
    d = np.zeros(7)
    d[:4] = 1e3 * np.linalg.norm(err, axis=-1)
    d[4] = _wrist_distance(T_object_wrist, T_object_wrist_desired)
    d[5] = 0.0 if collision_free else 1.0
    d[6] = _smoothness(joints, joints_prev, config.smoothness_unit)
    return StepCosts(d=d, total=float(np.dot(config.weights, d)), fingertip_error_m=err)


def _wrist_distance(T: np.ndarray, T_des: np.ndarray) -> float:
    """Position error [mm] plus rotation angle [deg]."""
    dp = 1e3 * np.linalg.norm(T[:3, 3] - T_des[:3, 3])
    R = T_des[:3, :3].T @ T[:3, :3]
    sin_norm = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    angle = np.arctan2(sin_norm, 0.5 * (np.trace(R) - 1.0))
    return float(dp + np.rad2deg(angle))


def _smoothness(joints: np.ndarray, joints_prev: np.ndarray | None, unit: str) -> float:
    if joints_prev is None:
        return 0.0
    delta = float(np.max(np.abs(joints - joints_prev)))
    return float(np.rad2deg(delta)) if unit == "deg" else delta


def hand_scale(virtual_fingers: VirtualFingers) -> np.ndarray:
    """(4,) per SAH finger: its palm-centre-to-fingertip distance over its human finger's, both hands
    straight (zero joints); about 2.1 for the thumb and 1.3-1.5 for the fingers."""
    from assets import human_hand

    tips_r = sah.fingertip_positions(np.zeros(len(sah.JOINT_NAMES)))
    links = human_hand.fk(np.zeros(len(human_hand.JOINT_NAMES)))
    tips_h = np.stack([links[human_hand.TIP_LINKS[i]][:3, 3] for i in virtual_fingers.human_indices])
    r = np.linalg.norm(tips_r - palm_centre(sah), axis=-1)
    return r / np.linalg.norm(tips_h - palm_centre(human_hand), axis=-1)


def scaled_targets(targets: np.ndarray, T_object_hwrist: np.ndarray, scale: np.ndarray) -> np.ndarray:
    """tau_v moved away from the human palm centre: ``P_h + scale_i (tau_v_i - P_h)``, (T, 4, 3) [m].

    Args:
        targets: (T, 4, 3) tau_v, object frame. T_object_hwrist: (T, 4, 4). scale: (4,), :func:`hand_scale`.
    """
    from assets import human_hand

    T = np.asarray(T_object_hwrist, dtype=float)
    palm = T[:, :3, :3] @ palm_centre(human_hand) + T[:, :3, 3]
    return palm[:, None] + np.asarray(scale)[None, :, None] * (targets - palm[:, None])


def virtual_finger_targets(
    T_object_hwrist: np.ndarray,
    human_joints: np.ndarray,
    virtual_fingers: VirtualFingers,
    pad_clearance_m: float = 0.005,
) -> np.ndarray:
    """tau_v: the SAH fingertip targets in the object frame, (T, 4, 4), (T, 20) -> (T, 4, 3) [m].

    The correspondence is made at the fingertip pads, not at the fingertip centres: a human fingertip
    touches the object with its pad, ``r_h`` (6.5-8.5 mm) in front of its tip point along the distal
    phalanx's flexion axis (its local +x), while the SAH's pad is ``r_r`` = 13 mm in front of its tip point.
    Each target is the human tip point moved back by ``r_r - r_h + pad_clearance_m`` along that axis, so
    that the SAH pad ends ``pad_clearance_m`` before the place where the human pad touched, instead of
    4.5-6.5 mm inside the object: tau_r ends at a near-contact pre-grasp which the planner's autograsp
    closes. (The paper leaves the finger width to Sigma_m's 8 mm; without this the retargeted grasps
    penetrate the object and almost no draw of the last marginals is collision-free.)
    """
    from assets import human_hand

    idx = list(virtual_fingers.human_indices)
    links = human_hand.fk(human_joints)
    tips = np.stack([links[human_hand.TIP_LINKS[i]][..., :3, 3] for i in idx], axis=-2)
    pad_axis = np.stack([links[f"{human_hand.FINGERS[i]}_distal"][..., :3, 0] for i in idx], axis=-2)
    r_human = np.array([human_hand.FINGERTIP_RADII_M[i] for i in idx])
    shift = r_human - np.array(sah.FINGERTIP_RADII_M) - pad_clearance_m
    p_wrist = tips + shift[:, None] * pad_axis
    T = np.asarray(T_object_hwrist, dtype=float)
    return np.einsum("tij,tkj->tki", T[:, :3, :3], p_wrist) + T[:, None, :3, 3]


class StepObjective:
    """The per-step cost of ``x = [omega, v, thumb opposition step]`` (7,): the wrist perturbed about
    ``T_start`` in its body frame, ``T_start @ Exp([omega, v])``, and the thumb's opposition moved by the
    last entry [rad]; the other joints come from the per-finger IK.

    Args:
        T_start: (4, 4) the previous step's optimum (object frame).
        targets: (4, 3) tau_v(t) fingertips [m], SAH finger order.
        T_des: (4, 4) the human wrist carried over by rT_h.
        joints_seed: (13,) the IK seed [rad]. joints_prev: (13,) tau_r(t - 1), None at the first step.
        is_free, penetration: d6's collision check (see :mod:`retarget.config`), None to drop d6.
        config: the weights and the search settings.
    """

    def __init__(
        self,
        T_start: np.ndarray,
        targets: np.ndarray,
        T_des: np.ndarray,
        joints_seed: np.ndarray,
        joints_prev: np.ndarray | None,
        is_free: IsFree | None,
        config: RetargetConfig,
        penetration: Penetration | None = None,
    ):
        self.T_start = T_start
        self.targets = targets
        self.T_des = T_des
        self.joints_seed = joints_seed
        self.joints_prev = joints_prev
        # The fingers stop at contact moving from tau_r(t - 1), or at the first step from the seed.
        self.joints_from = joints_seed if joints_prev is None else joints_prev
        self.is_free = is_free
        self.penetration = penetration
        self.config = config
        self.best = np.inf
        self.n_checks = 0
        self.checked = is_free is not None or penetration is not None
        self.max_step = (1e-3 * config.max_wrist_step_mm, np.deg2rad(config.max_wrist_step_deg))

    # x = [wrist body-frame step (6), thumb opposition step (1)]
    def wrist(self, x: np.ndarray) -> np.ndarray:
        """T_object_wrist of ``x``."""
        return self.T_start @ se3_exp(x[TAN_POSE])

    def ik_joints(self, T: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The per-finger IK's joints at wrist ``T``, with the thumb's opposition of ``x``."""
        p_wrist = (self.targets - T[:3, 3]) @ T[:3, :3]
        seed = self.joints_seed.copy()
        seed[THUMB_BASE] = np.clip(seed[THUMB_BASE] + x[POSE_DIM], *sah.JOINT_LIMITS[THUMB_BASE])
        return ik.hand_ik(p_wrist, seed)

    def in_trust_region(self, T: np.ndarray, x: np.ndarray) -> bool:
        """The wrist ``T`` of ``x`` is within ``max_wrist_step_mm`` and ``_deg`` of ``T_start``."""
        return bool(
            np.linalg.norm(T[:3, 3] - self.T_start[:3, 3]) <= self.max_step[0]
            and np.linalg.norm(x[TAN_ROT]) <= self.max_step[1]
        )

    def _depth_mm(self, T: np.ndarray, joints: np.ndarray) -> float:
        """d6's collision depth [mm] (0 when free; 1 for a collision of the 0/1 ``is_free`` check)."""
        self.n_checks += 1
        q = np.concatenate([q_from_pose(T), joints])
        if self.penetration is not None:
            return 1e3 * max(0.0, float(self.penetration(q)))
        return 0.0 if self.is_free(q) else 1.0

    def _stop_at_contact(self, T: np.ndarray, joints: np.ndarray) -> np.ndarray | None:
        """Each finger's joints moved from ``joints_from`` (tau_r(t - 1), the seed at the first step)
        towards ``joints`` as far as the hand stays free (finger by finger, thumb first), or None when
        ``joints_from`` itself collides at this wrist (see :attr:`RetargetConfig.contact_stop`)."""
        out = np.array(self.joints_from, dtype=float)
        if self._depth_mm(T, out) > 0.0:
            return None
        for finger in sah.FINGERS:
            idx = list(sah.FINGER_JOINTS[finger])
            start, goal = out[idx].copy(), joints[idx]
            out[idx] = goal
            if self._depth_mm(T, out) <= 0.0:
                continue
            lo, hi = 0.0, 1.0
            for _ in range(self.config.contact_stop_iterations):
                mid = 0.5 * (lo + hi)
                out[idx] = start + mid * (goal - start)
                if self._depth_mm(T, out) > 0.0:
                    hi = mid
                else:
                    lo = mid
            out[idx] = start + lo * (goal - start)
        return out

    def evaluate(self, T: np.ndarray, joints: np.ndarray, lazy: bool) -> tuple[np.ndarray, StepCosts]:
        """(joints, costs) at wrist ``T`` with the IK's ``joints``: the joints stopped at contact if they
        were. With ``lazy``, a trial whose lower bound is above the best value so far is rejected without a
        collision query (its collision-free costs come back)."""
        cfg = self.config
        base = step_costs(T, joints, self.targets, self.T_des, self.joints_prev, True, cfg)
        stop = self.checked and cfg.contact_stop
        # Stopping the fingers at contact can lower d7 (towards tau_r(t - 1)), never below 0.
        bound = base.total - (cfg.weights[6] * base.d[6] if stop else 0.0)
        if not self.checked or (lazy and bound > self.best):
            return joints, base
        depth_mm = self._depth_mm(T, joints)
        if depth_mm <= 0.0:
            return joints, base
        stopped = self._stop_at_contact(T, joints) if stop else None
        if stopped is not None:
            return stopped, step_costs(T, stopped, self.targets, self.T_des, self.joints_prev, True, cfg)
        d = base.d.copy()
        d[5] = 1.0
        pen = depth_mm if self.penetration is not None else 0.0  # the 0/1 check has no depth
        total = base.total + cfg.weights[5] + cfg.penetration_weight_per_mm * pen
        costs = StepCosts(d=d, total=total, fingertip_error_m=base.fingertip_error_m, penetration_mm=pen)
        return joints, costs

    def solution(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray, StepCosts]:
        """(T_object_wrist, joints, exact costs) of the optimum ``x``."""
        T = self.wrist(x)
        joints, costs = self.evaluate(T, self.ik_joints(T, x), lazy=False)
        return T, joints, costs

    def __call__(self, x: np.ndarray) -> float:
        T = self.wrist(x)
        if not self.in_trust_region(T, x):
            return np.inf
        _, c = self.evaluate(T, self.ik_joints(T, x), lazy=True)
        self.best = min(self.best, c.total)
        return c.total
