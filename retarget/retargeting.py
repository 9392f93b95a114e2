"""Retargeting a human demonstration to the SAH: tau_h -> tau_v -> tau_r and Sigma_r(t) (paper, section IV).

Steps, per demonstration:

1. **Virtual fingers** (:mod:`retarget.virtual_fingers`) at the last step of tau_h pick the human finger
   each SAH finger follows; their fingertips in the object frame form tau_v.
2. **Per step t**, the SAH wrist pose (6 DOF) and the thumb's opposition joint minimise
   ``sum_i w_i d_i(k, t)`` with Rosenbrock's method (:mod:`retarget.rosenbrock`), warm-started at the
   previous step's optimum. The other finger joints are no variables: for each trial the robust
   per-finger IK (:func:`retarget.ik.hand_ik`, seeded with the previous step's joints) places the
   fingertips at tau_v(t) as well as it can; it solves three thumb joints and takes the opposition from
   the search. The targets match the fingertip pads, not the tip points (:func:`virtual_finger_targets`).
3. **Sigma_r(t)**: the step's fingertip mean squared error ``mse = mean_j |F_j(k) - F_j(tau_v)|^2`` taken
   as an isotropic fingertip covariance ``mse / 3 * I_12`` (so that each fingertip's expected squared
   distance is the MSE) and mapped into the 19-D tangent ``[omega, v, 13 joints]`` by the fingertip
   Jacobian's pseudo-inverse (:func:`assets.sah.config_cov_from_fingertip_cov`): rank <= 12, the
   paper's degenerate covariances. The wrist part is GTSAM's Pose3 body tangent (right perturbation).

The distances (paper's d1..d7, weights ``(3, 1, 1, 1, 0.1, 10000, 10)``):

* d1..d4: fingertip distance thumb, index, middle, ring to their tau_v target [mm].
* d5: wrist distance to the human wrist carried over by ``rT_h``: position error [mm] plus rotation
  angle [deg] between ``T_object_rwrist`` and ``T_object_hwrist @ T_hwrist_rwrist``.
* d6: 0 if the hand is collision-free (object and table), else 1; from an injected ``is_free`` callable,
  or from a ``penetration`` callable (the hand's penetration depth [m], 0 when free). With the latter the
  cost of a colliding configuration also grows with its depth (``penetration_weight_per_mm``, our
  addition): the 0/1 term alone is a plateau on which Rosenbrock, started inside it, only contracts; the
  per-finger IK pulls the fingers to targets that a thicker SAH finger cannot reach without penetrating,
  so without a slope the last steps of every demonstration stayed in collision (the SAH's thumb 7-21 mm
  deep in the object or in its own palm, the small cup's fingers 12 mm in the cup). When the IK's fingers
  are what collides, they stop at contact instead (:attr:`RetargetConfig.contact_stop`, our addition):
  the trial is then free with the stopped fingers' fingertip error. Each step's search stays within a
  trust region about the previous optimum (``max_wrist_step_mm``, ``max_wrist_step_deg``).
* d7: ``max_i |J_i(k) - J_i(tau_r(t - 1))|`` over the 13 joints, in **radians** by default
  (:attr:`RetargetConfig.smoothness_unit`); 0 at the first step. The paper gives no unit. In degrees,
  w7 = 10 makes one degree of joint change weigh as much as 10 mm of fingertip error (3.3 mm of the
  thumb's): on a synthetic demonstration that the SAH reproduces exactly (60 steps, tests) the optimum then
  drifts the wrist to freeze the fingers and the fingertip error grows to 35 mm, against 0 mm in radians.

``rT_h`` (:func:`palm_alignment`): both hand models share the wrist axes (+z along the middle finger, +y
towards the thumb, +x out of the palm); the SAH is about 1.5 times larger, so its wrist is placed with the
same orientation and its palm centre on the human palm centre. The palm centre of a hand is the midpoint
between its wrist origin and the centroid of the index, middle and ring knuckles (MCP joints) at zero joints.

d6 is evaluated lazily: Rosenbrock accepts a trial only if its value is not above the best value seen so
far, and d6 >= 0, so a trial whose other terms already exceed that value is rejected without a collision
query (the objective returns that lower bound instead of the exact value; accepted values are exact).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from assets import sah
from assets.errors import InputError
from assets.se3 import make_pose, q_from_pose, se3_exp

from . import ik
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

PAPER_WEIGHTS: tuple[float, ...] = (3.0, 1.0, 1.0, 1.0, 0.1, 10000.0, 10.0)
"""(w1..w7) of the paper for the SAH: thumb, index, middle, ring, wrist, collision, smoothness."""

IsFree = Callable[[np.ndarray], bool]
"""``is_free(q)``: q (19,) = [p (m), rotation vector (rad), 13 joints (rad)], SAH in the OBJECT frame."""

Penetration = Callable[[np.ndarray], float]
"""``penetration(q)``: the SAH's penetration depth [m] at q (object frame, as :data:`IsFree`); 0 when free."""


@dataclass(frozen=True)
class RetargetConfig:
    """Settings of the per-step optimisation; defaults are the paper's where it gives them.

    Attributes:
        weights: (w1..w7), see :data:`PAPER_WEIGHTS`.
        smoothness_unit: ``"rad"`` or ``"deg"``, the unit of d7 (the paper does not say; see the module
            docstring for why radians).
        step_rot_deg: Rosenbrock's initial step of the wrist rotation [deg].
        step_pos_mm: Rosenbrock's initial step of the wrist position [mm].
        step_thumb_deg: Rosenbrock's initial step of the thumb's opposition joint [deg]. The per-finger IK
            solves the thumb's other three joints and keeps its opposition (``thumb_base``) from the seed,
            so Rosenbrock searches it together with the wrist pose: 7 variables a step.
        xtol: stop when all steps are below this fraction of the initial ones (0.02: 0.1 mm, 0.06 deg).
        max_nfev: objective evaluations per step (a trade-off of accuracy and time).
        escape_factors: when a step's optimum collides, Rosenbrock restarts from it with the initial steps
            multiplied by each factor in turn (until one ends collision-free), keeping the best result:
            a local search started inside the +w6 plateau with the other terms at their minimum only
            contracts and never sees the free region (our addition; the paper only says w6 is finite
            "to allow for the traversal of forbidden areas"). Off by default: on the ham demonstration
            (4, 16) leaves 4 of 61 steps colliding but pulls the hand off the grasp (RMSE 27.3 mm),
            none leaves 12 colliding (fingers on the object at the end) with an RMSE of 7.0 mm.
        pad_clearance_mm: the SAH fingertip pads aim this far in front of the human pads' contact
            points (see :func:`virtual_finger_targets`; our addition for the SAH's thicker fingers).
            10 mm: with the depth-graded d6, 5 mm still left the small cup's and the jam's last steps
            1-2 mm deep in the object; 10 mm ends them free, a pre-grasp that autograsp closes.
        n_virtual: opposing virtual fingers, l - 1 = 3 for the SAH.
        adjacent_only: virtual fingers group neighbouring fingers only.
        penetration_weight_per_mm: with a ``penetration`` callable, a colliding configuration costs
            ``w6 + penetration_weight_per_mm * depth_mm`` (see the module docstring); 1 mm of depth
            outweighs 1 m of fingertip error, so the search leaves the collision first.
        contact_stop: when the per-finger IK's fingers make a trial configuration collide (d6 checked),
            the fingers stop at contact instead: finger by finger, the joints move from tau_r(t - 1)'s
            (at the first step from the seed's) towards the IK solution only as far as the hand stays free
            (bisection, ``contact_stop_iterations`` halvings; our addition).
            Without it the IK pulls a finger into the object whenever the human's finger passes closer
            than the thicker SAH finger can, and the only free trials move the wrist until the targets are
            out of reach: the jam's last 7 steps ended with a fingertip RMSE of 88-117 mm, the thumb
            module 18 mm in the jar on the human-aligned wrist. A human finger stops on the surface too.
            Without the first step's stop the chips demonstration began with the SAH thumb in its own
            palm (the human thumb curled towards the palm): tau_r's first two steps self-colliding, no
            collision-free root for the planner, and a fingertip MSE of 3525 mm^2 (856 with it).
        contact_stop_iterations: bisection steps of ``contact_stop`` (4: 1/16 of a finger's motion in the
            step; up to ``1 + 4 * (1 + iterations)`` collision queries for a trial).
        max_wrist_step_mm, max_wrist_step_deg: the trust region of a step's search: trials whose wrist
            is farther than this from the previous step's optimum are rejected (our addition). Without
            it a step whose neighbourhood is all in collision can leave for any free place: the salt's
            step 53 jumped 1.45 m, where the fingertip terms cost less than w6.
        thumb_base_seed_deg: the thumb's opposition at the first step's seed (without ``joints0``). Not
            the rest pose's 90 deg, its upper limit: started on the bound, the search rarely leaves it.
            Measured with the corrected thumb (see ``assets/hands/sah/README.md``): seeded at 60 deg, 73 % of
            the ham strategy's collision-free last-marginal draws close to epsilon >= 0.05 (22 of 80
            draws free) and the jam's fingertip RMSE is 5.9 mm; seeded at 85 deg, 50 % and 27.6 mm.
    """

    weights: tuple[float, ...] = PAPER_WEIGHTS
    smoothness_unit: str = "rad"
    step_rot_deg: float = 2.0
    step_pos_mm: float = 5.0
    step_thumb_deg: float = 5.0
    xtol: float = 0.02
    max_nfev: int = 300
    escape_factors: tuple[float, ...] = ()
    pad_clearance_mm: float = 10.0
    n_virtual: int = 3
    adjacent_only: bool = True
    penetration_weight_per_mm: float = 1000.0
    thumb_base_seed_deg: float = 60.0
    contact_stop: bool = True
    contact_stop_iterations: int = 4
    max_wrist_step_mm: float = 50.0
    max_wrist_step_deg: float = 20.0

    def __post_init__(self):
        w = tuple(float(x) for x in self.weights)
        if len(w) != 7 or not all(np.isfinite(x) and x >= 0 for x in w):
            raise InputError(f"weights: expected 7 non-negative numbers (w1..w7), found {self.weights!r}")
        object.__setattr__(self, "weights", w)
        if self.smoothness_unit not in ("deg", "rad"):
            raise InputError(f"smoothness_unit: expected 'deg' or 'rad', found {self.smoothness_unit!r}")
        steps = (self.step_rot_deg, self.step_pos_mm, self.step_thumb_deg, self.xtol)
        if not (all(v > 0 for v in steps) and self.max_nfev >= 1):
            raise InputError("step_rot_deg, step_pos_mm, step_thumb_deg, xtol must be > 0 and max_nfev >= 1")
        if not (np.isfinite(self.penetration_weight_per_mm) and self.penetration_weight_per_mm >= 0):
            raise InputError(
                f"penetration_weight_per_mm: expected >= 0, found {self.penetration_weight_per_mm}"
            )
        if not np.isfinite(self.thumb_base_seed_deg):
            raise InputError(f"thumb_base_seed_deg: expected a number, found {self.thumb_base_seed_deg}")
        trust = (self.max_wrist_step_mm, self.max_wrist_step_deg)
        if not (self.contact_stop_iterations >= 1 and all(np.isfinite(v) and v > 0 for v in trust)):
            raise InputError("contact_stop_iterations must be >= 1, max_wrist_step_mm and _deg > 0")
        if not all(f > 0 for f in self.escape_factors):
            raise InputError(f"escape_factors: expected positive factors, found {self.escape_factors!r}")


@dataclass(frozen=True)
class StepCosts:
    """The distances of one configuration at one step (see the module docstring for units)."""

    d: np.ndarray  # (7,) d1..d7
    total: float  # sum w_i d_i
    fingertip_error_m: np.ndarray  # (4, 3) robot minus target, object frame
    penetration_mm: float = 0.0  # depth of the collision, if measured (a ``penetration`` callable)


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
        n_collision_checks: (T,) collision queries per step (the lazy d6 of the module docstring saves
            some; a contact stop adds up to ``1 + 4 * (1 + contact_stop_iterations)``).
        converged: (T,) Rosenbrock's success flag per step.
        virtual_fingers: the chosen virtual fingers, if computed from a demonstration.
        T_hwrist_rwrist: (4, 4) rT_h used.
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
    virtual_fingers: VirtualFingers | None = None
    meta: dict = field(default_factory=dict)

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


_THUMB_BASE = sah.JOINT_NAMES.index("thumb_base")


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


def fingertip_cov_to_config(T_object_wrist: np.ndarray, joints: np.ndarray, mse_m2: np.ndarray) -> np.ndarray:
    """Sigma_r from per-step fingertip MSE: (T, 4, 4), (T, 13), (T,) [m^2] -> (T, 19, 19) PSD.

    The fingertip covariance is ``mse / 3 * I_12`` (isotropic; trace per fingertip = mse).
    """
    J = sah.fingertip_jacobian(T_object_wrist, joints)
    cov12 = (np.asarray(mse_m2, dtype=float) / 3.0)[:, None, None] * np.eye(12)
    return sah.config_cov_from_fingertip_cov(J, cov12)


def step_costs(
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    p_object_targets: np.ndarray,
    T_object_wrist_desired: np.ndarray,
    joints_prev: np.ndarray | None,
    collision_free: bool,
    config: RetargetConfig,
) -> StepCosts:
    """d1..d7 and their weighted sum for one SAH configuration (pure; see the module docstring).

    Args:
        T_object_wrist: (4, 4) SAH wrist pose.
        joints: (13,) [rad].
        p_object_targets: (4, 3) tau_v(t) fingertips [m], SAH finger order.
        T_object_wrist_desired: (4, 4) the human wrist carried over, ``T_object_hwrist @ T_hwrist_rwrist``.
        joints_prev: (13,) tau_r(t - 1) joints, or None at the first step.
        collision_free: the value of the collision check.
        config: the weights and the unit of d7.
    """
    err = sah.fingertip_positions_in(T_object_wrist, joints) - p_object_targets
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


class _Objective:
    """The per-step cost of a wrist perturbation ``x = [omega, v]`` about ``T_start`` (body frame)."""

    def __init__(self, T_start, targets, T_des, joints_seed, joints_prev, is_free, config, penetration=None):
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
        return self.T_start @ se3_exp(x[:6])

    def ik_joints(self, T: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The per-finger IK's joints at wrist ``T``, with the thumb's opposition of ``x``."""
        p_wrist = (self.targets - T[:3, 3]) @ T[:3, :3]
        seed = self.joints_seed.copy()
        seed[_THUMB_BASE] = np.clip(seed[_THUMB_BASE] + x[6], *sah.JOINT_LIMITS[_THUMB_BASE])
        return ik.hand_ik(p_wrist, seed)

    def in_trust_region(self, T: np.ndarray, x: np.ndarray) -> bool:
        """The wrist ``T`` of ``x`` is within ``max_wrist_step_mm`` and ``_deg`` of ``T_start``."""
        return bool(
            np.linalg.norm(T[:3, 3] - self.T_start[:3, 3]) <= self.max_step[0]
            and np.linalg.norm(x[:3]) <= self.max_step[1]
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
            adds the depth term of the module docstring.
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
        joints_seed[_THUMB_BASE] = np.deg2rad(config.thumb_base_seed_deg)
        joints_seed = sah.clip_joints(joints_seed)
    else:
        joints_seed = sah.clip_joints(joints0)
    step0 = np.r_[
        np.full(3, np.deg2rad(config.step_rot_deg)),
        np.full(3, 1e-3 * config.step_pos_mm),
        np.deg2rad(config.step_thumb_deg),
    ]

    out_T = np.zeros((n, 4, 4))
    out_joints = np.zeros((n, 13))
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
        obj = _Objective(T_start, P[t], T_des[t], joints_seed, joints_prev, is_free, config, penetration)
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
    cov = fingertip_cov_to_config(out_T, out_joints, mse_m2)
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
        meta={
            "weights": list(config.weights),
            "smoothness_unit": config.smoothness_unit,
            "max_nfev": config.max_nfev,
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
    result = retarget_fingertips(
        targets, demo.T_object_wrist, T_hwrist_rwrist=T_hwrist_rwrist, is_free=is_free, config=config,
        progress=progress, penetration=penetration,
    )  # fmt: skip
    meta = dict(result.meta)
    meta.update({"demonstration": demo.path, "object": demo.object, "grasp_type": demo.grasp_type})
    return RetargetResult(**{**result.__dict__, "virtual_fingers": vf, "meta": meta})
