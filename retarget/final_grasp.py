"""The final grasp chosen by how the SAH holds the object when closed (our addition to section IV).

The paper's per-step search ends where the SAH's fingertips best match the human's; nothing in it asks
whether the SAH, closed from there, holds the object, nor whether the strategy's variations do. The
variation model then spreads its last marginal about that configuration, and the planner closes the hand
at its draws (GraspIt!'s autograsp and the epsilon quality). This module searches the last step's
configuration near the paper's solution for the one whose *draws* close best:

* **Variables** ``x`` (8,): the wrist's body-frame twist about tau_r(T) ``[omega (3) rad, v (3) m]``
  (``T_object_wrist @ Exp(x[:6])``), a change of the thumb's opposition [rad] and an aperture [rad]
  added to every flexion joint (proximal and middle; negative opens the hand), the joints clipped to the
  SAH's limits. A box trust region about the paper's solution (:class:`FinalGraspConfig`) keeps the
  demonstrated grasp: the search may open the hand, shift it by a few centimetres and turn it by a few
  degrees, not choose another grasp. A candidate whose blended approach (below) collides anywhere (the
  retargeting's d6 check) is rejected, so tau_r stays collision-free.
* **Objective**: the expected quality ``E[phi_o]`` of configurations drawn about the candidate, an
  injected callable (:data:`ExpectedQuality`; :class:`pbdgrasp.strategy.ExpectedQuality` builds it from
  the pybullet world, the hand closer and the strategy's last marginal, with common random numbers so
  that it is a deterministic function of the candidate). A draw in collision scores 0, so the search trades a
  stronger grasp against draws that penetrate the object.
* **Search**: Rosenbrock's method (:mod:`retarget.rosenbrock`, as the per-step search) from ``x = 0``;
  the result is kept only if its expected quality is higher than the paper's solution's.
* **Blend**: the change is carried into the last ``blend_steps`` steps with a minimum-jerk weight
  (0 before them, 1 at the last step): the wrist position shifted in the object frame, its orientation
  turned about the wrist (object frame), the joints moved, so the approach leads smoothly into the new
  final grasp.

Errors and their covariance: :func:`retarget.retargeting.retarget_demonstration` recomputes the fingertip
errors of the blended steps against tau_v (the reported MSE is that of the trajectory as written) and
keeps Sigma_r of the fingertip search (the refinement's deliberate change is not a mapping error).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from assets import sah
from assets.errors import InputError
from assets.se3 import se3_exp, so3_exp, so3_log

from .rosenbrock import minimize_rosenbrock

__all__ = [
    "ExpectedQuality",
    "FinalGraspConfig",
    "FinalGraspResult",
    "FLEXION_JOINTS",
    "blend_final_change",
    "final_configuration",
    "refine_final_grasp",
]

log = logging.getLogger(__name__)

ExpectedQuality = Callable[[np.ndarray, np.ndarray], float]
"""``expected_quality(T_object_wrist (4, 4), joints (13,)) -> float``: the mean epsilon of the hand closed
at draws about that configuration (0 for a draw in collision), object frame."""

FLEXION_JOINTS = np.array([name.endswith(("_prox", "_mid")) for name in sah.JOINT_NAMES])
"""(13,) bool: the proximal and middle flexion joints, which the aperture moves together."""


@dataclass(frozen=True)
class FinalGraspConfig:
    """Settings of :func:`refine_final_grasp`.

    Attributes:
        max_position_mm, max_rotation_deg: the trust region of the wrist about the paper's final step, per
            component of the body-frame twist [mm, deg].
        max_thumb_deg: the largest change of the thumb's opposition [deg].
        max_aperture_deg: the largest aperture, opening or closing every flexion joint together [deg].
        step_position_mm, step_rotation_deg, step_thumb_deg, step_aperture_deg: Rosenbrock's initial steps.
        xtol: stop when all steps are below this fraction of the initial ones.
        max_nfev: objective evaluations (each closes the hand ``draws`` times).
        draws: configurations drawn about a candidate to estimate its expected quality (common random
            numbers: the same standard normal draws for every candidate).
        blend_steps: the last steps of the trajectory that the change is blended into (20: 1 s at 20 Hz;
            measured in docs/method.md against 10 and 30).
        seed: the seed of the common random numbers (the draws' standard normals).
    """

    max_position_mm: float = 25.0
    max_rotation_deg: float = 12.0
    max_thumb_deg: float = 15.0
    max_aperture_deg: float = 17.0
    step_position_mm: float = 5.0
    step_rotation_deg: float = 3.0
    step_thumb_deg: float = 5.0
    step_aperture_deg: float = 6.0
    xtol: float = 0.05
    max_nfev: int = 100
    draws: int = 32
    blend_steps: int = 20
    seed: int = 0

    def __post_init__(self):
        values = (
            self.max_position_mm,
            self.max_rotation_deg,
            self.max_thumb_deg,
            self.max_aperture_deg,
            self.step_position_mm,
            self.step_rotation_deg,
            self.step_thumb_deg,
            self.step_aperture_deg,
            self.xtol,
        )
        if not all(np.isfinite(v) and v > 0 for v in values):
            raise InputError(f"FinalGraspConfig: trust region, steps and xtol must be > 0, found {self}")
        if self.max_nfev < 1 or self.draws < 1 or self.blend_steps < 1 or self.seed < 0:
            raise InputError(
                f"FinalGraspConfig: max_nfev, draws and blend_steps must be >= 1 (seed >= 0), found {self}"
            )

    def bounds(self) -> np.ndarray:
        """(8,) the trust region of ``x`` in its units [rad, m, rad, rad]."""
        return np.r_[
            np.full(3, np.deg2rad(self.max_rotation_deg)),
            np.full(3, 1e-3 * self.max_position_mm),
            np.deg2rad(self.max_thumb_deg),
            np.deg2rad(self.max_aperture_deg),
        ]

    def steps(self) -> np.ndarray:
        """(8,) Rosenbrock's initial steps of ``x`` [rad, m, rad, rad]."""
        return np.r_[
            np.full(3, np.deg2rad(self.step_rotation_deg)),
            np.full(3, 1e-3 * self.step_position_mm),
            np.deg2rad(self.step_thumb_deg),
            np.deg2rad(self.step_aperture_deg),
        ]


@dataclass(frozen=True, eq=False)
class FinalGraspResult:
    """The outcome of :func:`refine_final_grasp`.

    Attributes:
        T_object_wrist: (T, 4, 4) the trajectory with the change blended in (the input when not kept).
        joints: (T, 13) [rad], likewise.
        x: (8,) the kept change (zeros when not kept), see the module docstring.
        quality_before, quality_after: the expected quality of the paper's and of the kept final step.
        kept: the change improved the expected quality and was blended in.
        nfev: objective evaluations.
        message: the search's stopping reason.
    """

    T_object_wrist: np.ndarray
    joints: np.ndarray
    x: np.ndarray
    quality_before: float
    quality_after: float
    kept: bool
    nfev: int
    message: str

    def to_meta(self) -> dict:
        """The provenance recorded in a trajectory's meta (JSON-able)."""
        return {
            "kept": self.kept,
            "expected_quality_before": self.quality_before,
            "expected_quality_after": self.quality_after,
            "rotation_deg": np.rad2deg(self.x[:3]).round(3).tolist(),
            "position_mm": (1e3 * self.x[3:6]).round(3).tolist(),
            "thumb_deg": round(float(np.rad2deg(self.x[6])), 3),
            "aperture_deg": round(float(np.rad2deg(self.x[7])), 3),
            "nfev": self.nfev,
            "message": self.message,
        }


def final_configuration(T_object_wrist: np.ndarray, joints: np.ndarray, x: np.ndarray):
    """The final step ``(T (4, 4), joints (13,))`` changed by ``x`` (8,) (module docstring)."""
    T = np.asarray(T_object_wrist, dtype=float) @ se3_exp(np.asarray(x[:6], dtype=float))
    out = np.array(joints, dtype=float)
    out[0] += x[6]  # the thumb's opposition, thumb_base
    out[FLEXION_JOINTS] += x[7]
    return T, sah.clip_joints(out)


def blend_final_change(
    T_object_wrist: np.ndarray, joints: np.ndarray, T_end: np.ndarray, joints_end: np.ndarray, steps: int
) -> tuple[np.ndarray, np.ndarray]:
    """Carry a new last step into the last ``steps`` steps with a minimum-jerk weight.

    Step ``T - steps + i`` (i = 1..steps) moves by ``w(i / steps)`` of the change, ``w(s) = 10 s^3 - 15 s^4
    + 6 s^5``: its wrist position by ``w dp`` (object frame), its orientation by ``Exp(w dtheta)`` on the
    left (a turn about the wrist, in the object frame), its joints by ``w dq`` (clipped to the limits).

    Args:
        T_object_wrist: (T, 4, 4); joints: (T, 13) [rad]. T_end: (4, 4), joints_end: (13,) the new last step.
        steps: how many steps the change is spread over (clipped to T).

    Returns:
        (T, 4, 4) and (T, 13): new arrays; the last step equals ``T_end``, ``joints_end``.
    """
    T = np.array(T_object_wrist, dtype=float)
    J = np.array(joints, dtype=float)
    n = T.shape[0]
    dp = T_end[:3, 3] - T[-1, :3, 3]
    dtheta = so3_log(T_end[:3, :3] @ T[-1, :3, :3].T)
    dq = np.asarray(joints_end, dtype=float) - J[-1]
    steps = min(int(steps), n)
    for k in range(n - steps, n):
        s = (k - (n - steps) + 1) / steps
        w = s**3 * (10.0 - 15.0 * s + 6.0 * s**2)
        T[k, :3, 3] += w * dp
        T[k, :3, :3] = so3_exp(w * dtheta) @ T[k, :3, :3]
        J[k] = sah.clip_joints(J[k] + w * dq)
    T[-1] = T_end
    J[-1] = joints_end
    return T, J


def refine_final_grasp(
    T_object_wrist: np.ndarray,
    joints: np.ndarray,
    expected_quality: ExpectedQuality,
    config: FinalGraspConfig | None = None,
    is_free: Callable[[np.ndarray, np.ndarray], bool] | None = None,
) -> FinalGraspResult:
    """Search the last step for the configuration whose draws close best, and blend it in.

    Args:
        T_object_wrist: (T, 4, 4) tau_r's wrist poses (object frame).
        joints: (T, 13) tau_r's joints [rad].
        expected_quality: the objective, :data:`ExpectedQuality`.
        config: :class:`FinalGraspConfig`.
        is_free: ``is_free(T_object_wrist (4, 4), joints (13,))``, the collision check that a candidate's
            blended steps must pass (None: none).

    Returns:
        The :class:`FinalGraspResult`.

    Raises:
        InputError: shapes that do not match.
    """
    config = config or FinalGraspConfig()
    T = np.asarray(T_object_wrist, dtype=float)
    J = np.asarray(joints, dtype=float)
    if T.ndim != 3 or T.shape[1:] != (4, 4) or J.shape != (T.shape[0], len(sah.JOINT_NAMES)):
        raise InputError(f"expected (T, 4, 4) wrist poses and (T, 13) joints, found {T.shape} and {J.shape}")
    bound = config.bounds()
    steps = min(config.blend_steps, T.shape[0])

    def cost(x: np.ndarray) -> float:
        if np.any(np.abs(x) > bound):
            return np.inf
        candidate = final_configuration(T[-1], J[-1], x)
        if is_free is not None and x.any():
            window = blend_final_change(T[-steps:], J[-steps:], *candidate, steps)
            if not all(is_free(T_k, J_k) for T_k, J_k in zip(*window, strict=True)):
                return np.inf
        return -float(expected_quality(*candidate))

    before = -cost(np.zeros(8))
    res = minimize_rosenbrock(
        cost, np.zeros(8), step0=config.steps(), xtol=config.xtol, max_nfev=config.max_nfev
    )
    after = -float(res.fun)
    kept = after > before
    x = np.array(res.x, dtype=float) if kept else np.zeros(8)
    if kept:
        T_end, J_end = final_configuration(T[-1], J[-1], x)
        T_out, J_out = blend_final_change(T, J, T_end, J_end, config.blend_steps)
    else:
        T_out, J_out = T.copy(), J.copy()
    log.info(
        "final grasp: expected quality %.4f -> %.4f (%s), %d evaluations",
        before,
        after,
        "kept" if kept else "not kept",
        res.nfev,
    )
    return FinalGraspResult(
        T_object_wrist=T_out,
        joints=J_out,
        x=x,
        quality_before=before,
        quality_after=after if kept else before,
        kept=kept,
        nfev=int(res.nfev) + 1,
        message=res.message,
    )
