"""Settings of the retargeting (paper section IV): the weights of d1..d7 and the search, with their
validation. The defaults are the paper's where it gives them; our additions are named, and why each is
there, and what it changed when measured, is in docs/method.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from assets.errors import InputError
from assets.io import is_finite_number
from assets.sah import FINGERTIP_COV_MAPS

from .final_grasp import FinalGraspConfig

__all__ = [
    "PAPER_WEIGHTS",
    "SCALED_WRIST_WEIGHTS",
    "TARGETS",
    "FINAL_GRASPS",
    "IsFree",
    "Penetration",
    "RetargetConfig",
]

PAPER_WEIGHTS: tuple[float, ...] = (3.0, 1.0, 1.0, 1.0, 0.1, 10000.0, 10.0)
"""(w1..w7) of the paper for the SAH: thumb, index, middle, ring, wrist, collision, smoothness."""

TARGETS = ("by_grasp_type", "fingertips", "scaled")
"""The retargeting's fingertip targets (:attr:`RetargetConfig.targets`)."""

FINAL_GRASPS = ("by_grasp_type", "paper", "refined")
"""What the last step is (:attr:`RetargetConfig.final_grasp`)."""

SCALED_WRIST_WEIGHTS: dict[str, float] = {"salt": 3.0}
"""w5 of the strategies (by the demonstration's object) whose scaled targets, with the paper's w5, pull
the palm off the human palm's place; measured in docs/method.md (retargeting's addition 9): salt's best
grasps 0.125-0.149 over three seeds against 0.101-0.123, while the chips strategy, which the bottle
borrows, loses the bottle with any heavier w5. The others keep the paper's 0.1."""


IsFree = Callable[[np.ndarray], bool]
"""``is_free(q)``: q (19,) = [p (m), rotation vector (rad), 13 joints (rad)], SAH in the OBJECT frame."""

Penetration = Callable[[np.ndarray], float]
"""``penetration(q)``: the SAH's penetration depth [m] at q (object frame, as :data:`IsFree`); 0 when free."""


@dataclass(frozen=True)
class RetargetConfig:
    """Settings of the per-step optimisation; defaults are the paper's where it gives them.

    Attributes:
        weights: (w1..w7), see :data:`PAPER_WEIGHTS`.
        smoothness_unit: ``"rad"`` or ``"deg"``, the unit of d7 (the paper gives none; in degrees w7 = 10
            weighs one degree of joint change as 10 mm of fingertip error, and the optimum freezes the
            fingers).
        step_rot_deg: Rosenbrock's initial step of the wrist rotation [deg].
        step_pos_mm: Rosenbrock's initial step of the wrist position [mm].
        step_thumb_deg: Rosenbrock's initial step of the thumb's opposition joint [deg]. The per-finger IK
            solves the thumb's other three joints and keeps its opposition (``thumb_base``) from the seed,
            so Rosenbrock searches it together with the wrist pose: 7 variables a step.
        xtol: stop when all steps are below this fraction of the initial ones (0.02: 0.1 mm, 0.06 deg).
        max_nfev: objective evaluations per step (a trade-off of accuracy and time).
        escape_factors: when a step's optimum collides, Rosenbrock restarts from it with the initial steps
            multiplied by each factor in turn (until one ends collision-free), keeping the best result.
            Off by default.
        pad_clearance_mm: the SAH fingertip pads aim this far in front of the human pads' contact
            points (see :func:`~retarget.objective.virtual_finger_targets`).
        n_virtual: opposing virtual fingers, l - 1 = 3 for the SAH.
        adjacent_only: virtual fingers group neighbouring fingers only.
        penetration_weight_per_mm: with a ``penetration`` callable, a colliding configuration costs
            ``w6 + penetration_weight_per_mm * depth_mm``; 1 mm of depth outweighs 1 m of fingertip error,
            so the search leaves the collision first.
        contact_stop: when the per-finger IK's fingers make a trial configuration collide (d6 checked),
            the fingers stop at contact instead: finger by finger, the joints move from tau_r(t - 1)'s
            (at the first step from the seed's) towards the IK solution only as far as the hand stays free
            (bisection, ``contact_stop_iterations`` halvings).
        contact_stop_iterations: bisection steps of ``contact_stop`` (4: 1/16 of a finger's motion in the
            step; up to ``1 + 4 * (1 + iterations)`` collision queries for a trial).
        max_wrist_step_mm, max_wrist_step_deg: the trust region of a step's search: trials whose wrist
            is farther than this from the previous step's optimum are rejected.
        thumb_base_seed_deg: the thumb's opposition at the first step's seed (without ``joints0``); not
            the rest pose's 90 deg, its upper limit, from which the search rarely leaves.
        targets: what d1..d4 measure against. ``"fingertips"`` (the paper's): the human fingertip pads,
            tau_v. ``"scaled"``: each tau_v target moved away from the human palm centre by the SAH's
            size ratio for that finger (:func:`~retarget.objective.hand_scale`), the palm-to-fingertip
            vectors of dex-retargeting's vector optimizer and DexPilot; with ``rT_h``'s palm on the human
            palm, the larger SAH then keeps the human palm's place on the object and its fingers, aimed
            beyond the human's, stop at contact around it instead of the wrist standing back.
            ``"by_grasp_type"`` (the default): ``"scaled"`` for a power grasp, ``"fingertips"`` for a
            precision grasp (measured: docs/results.md, "Strategies that hold").
        scaled_wrist_weight: w5 where the targets are ``"scaled"``: a number, None (``weights[4]``, the
            paper's 0.1) or ``"by_strategy"`` (the default): :data:`SCALED_WRIST_WEIGHTS` for the
            demonstration's object, else the paper's. Scaled targets lie beyond the object by design, so
            with the paper's w5 the thumb's (w1 = 3) can pull the palm off the human palm's place (salt:
            the thumb over the box's top); a heavier wrist keeps the palm where the human's was.
        covariance_map: how Sigma_r(t)'s fingertip covariance is realised in the configuration
            (:func:`assets.sah.config_cov_from_fingertip_cov`): ``"configuration"`` (the default), the
            pseudo-inverse of the whole fingertip Jacobian, wrist and joints sharing it (mostly the wrist:
            metres are cheap against radians in its norm), or ``"finger_joints"``, the fingers' joints
            alone with the wrist held (measured in docs/method.md: tighter models whose draws close
            better in open scenes, but whose wrists cannot move far enough in two obstacle rows).
        final_grasp: ``"paper"``: the last step is the fingertip search's; ``"refined"``: searched again
            near it for the configuration whose draws close to the best grasps (:mod:`retarget.final_grasp`;
            needs the collision check's scene, and is skipped without it); ``"by_grasp_type"`` (the
            default): ``"refined"`` for a precision grasp, ``"paper"`` for a power grasp (measured: the
            chips strategy refined opens its hand, and its row between two cans fell from 95 to 78 %).
        final_grasp_settings: :class:`~retarget.final_grasp.FinalGraspConfig` of ``"refined"``.

    Raises:
        InputError: a value out of its range.
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
    targets: str = "by_grasp_type"
    scaled_wrist_weight: float | str | None = "by_strategy"
    covariance_map: str = "configuration"
    final_grasp: str = "by_grasp_type"
    final_grasp_settings: FinalGraspConfig = field(default_factory=FinalGraspConfig)

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
        w5 = self.scaled_wrist_weight
        if not (w5 is None or w5 == "by_strategy" or (is_finite_number(w5) and w5 >= 0)):
            raise InputError(
                f"scaled_wrist_weight: expected a number >= 0, None or 'by_strategy', found {w5!r}"
            )
        if self.targets not in TARGETS:
            raise InputError(f"targets: expected one of {', '.join(TARGETS)}, found {self.targets!r}")
        if self.covariance_map not in FINGERTIP_COV_MAPS:
            valid = ", ".join(FINGERTIP_COV_MAPS)
            raise InputError(f"covariance_map: expected one of {valid}, found {self.covariance_map!r}")
        if self.final_grasp not in FINAL_GRASPS:
            raise InputError(
                f"final_grasp: expected one of {', '.join(FINAL_GRASPS)}, found {self.final_grasp!r}"
            )
        if not isinstance(self.final_grasp_settings, FinalGraspConfig):
            raise InputError("final_grasp_settings: expected a FinalGraspConfig")
        if not all(f > 0 for f in self.escape_factors):
            raise InputError(f"escape_factors: expected positive factors, found {self.escape_factors!r}")

    def targets_for(self, grasp_type: str) -> str:
        """``"fingertips"`` or ``"scaled"``: :attr:`targets` for a demonstration's grasp type."""
        if self.targets == "by_grasp_type":
            return "scaled" if grasp_type == "power" else "fingertips"
        return self.targets

    def weights_for(self, targets: str, strategy: str | None = None) -> tuple[float, ...]:
        """(w1..w7) for ``"fingertips"`` or ``"scaled"`` targets of the demonstration of object
        ``strategy``: :attr:`weights`, with w5 from :attr:`scaled_wrist_weight` for scaled ones."""
        w5 = self.scaled_wrist_weight
        if w5 == "by_strategy":
            w5 = SCALED_WRIST_WEIGHTS.get(strategy)
        if targets != "scaled" or w5 is None:
            return self.weights
        return (*self.weights[:4], float(w5), *self.weights[5:])

    def final_grasp_for(self, grasp_type: str) -> str:
        """``"paper"`` or ``"refined"``: :attr:`final_grasp` for a demonstration's grasp type."""
        if self.final_grasp == "by_grasp_type":
            return "refined" if grasp_type == "precision" else "paper"
        return self.final_grasp
