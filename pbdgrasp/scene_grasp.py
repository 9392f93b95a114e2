"""The final grasp chosen again in the scene the model is solved in (our addition to sections V-VII).

A strategy's final grasp is refined in the scene it was demonstrated in, on tau_r and its covariance
(:mod:`retarget.final_grasp`). The variation model then moves the grasp by its constraint factors, which
keep the hand out of the scene but do not ask whether the hand, closed there, holds the object: in the jam
jar in a hole the model lifts the hand above the block, and the thumb then closes past the jar in half of
the draws. :func:`adapt_final_grasp` chooses the grasp again in the scene, from the solved model's own
draws, and solves the model again about it:

1. **Probe**: ``probe_draws`` draws of the model's last marginal in the scene (the object's pose drawn from
   P(O), the configuration about the last mean; joints clipped to the limits), each closed and scored.
2. **Candidates**: the last mean and the ``candidates`` best-closing probe draws (object frame). Each is
   scored by the expected quality ``E[phi_o]`` of ``draws`` draws of the last covariance about it
   (:class:`pbdgrasp.strategy.ExpectedQuality`, common random numbers). The ``resolves`` best that score
   above the mean go on.
3. **Re-solve**: for each, tau_r's last ``blend_steps`` steps are blended onto it
   (:func:`retarget.final_grasp.blend_final_change`), tau_r's last step keeping its offset from the
   model's last mean, so that the re-solved mean lands near the candidate; the model is solved again in
   the scene. Sigma_r and the fingertip errors stay tau_r's: the change is deliberate, not a mapping
   error (as for the refined final grasp).
4. **Keep** the model, of the original and the ``resolves`` best candidates re-solved, whose draws the
   planner can use most: the largest product of the last step's valid fraction (draws that close to
   epsilon >= 0.05) and the least collision-free fraction of any step, both measured by
   :func:`pbdgrasp.inspect.inspect_model` with the same generator for every model. A candidate whose
   last step closes better but whose approach collides (the blend sweeps the fingers through the scene)
   is not kept for its grasp alone. A re-solved model is kept only where its product beats the
   original's by ``margin_se`` standard errors of the difference (:func:`product_se`, the two fractions
   as binomial proportions of ``accept_draws`` draws): a tie within the draws' noise keeps the model GTSAM
   solved from tau_r. Nor is one kept whose means' path, followed as the planner's edges go, passes
   through the table, an obstacle or the hand at more steps than the original's
   (:func:`pbdgrasp.inspect.blocked_mean_steps`): each step's draws can be free while the way between two
   steps is not (a re-solve in ham on an arc passed the wall the other way, 33 mm and 19 deg between two
   steps, and the planner found no grasp in 19 of 19 trials).

It runs in any scene, the demonstration's own included: there tau_r's final grasp was refined on tau_r's
covariance before the model was solved, and the solved marginal (its clearances, its smoothing) can sit
elsewhere.

The result records what happened in its trajectory's ``meta["scene_grasp"]``. Probe, candidates and
acceptance are deterministic for a given ``seed``, and the same on any number of closing processes.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import time
from typing import NamedTuple

import numpy as np

from assets import sah
from assets.errors import InputError
from inference.model import VariationModel
from inference.params import VariationParams
from planning.closing_pool import ClosingPool
from planning.scene import Scene
from retarget.final_grasp import blend_final_change

from .inspect import inspect_model
from .scene_model import learn_in_scene
from .strategy import ExpectedQuality

__all__ = ["SceneGraspConfig", "adapt_final_grasp", "product_se"]

log = logging.getLogger(__name__)


@dataclasses.dataclass(frozen=True)
class SceneGraspConfig:
    """Settings of :func:`adapt_final_grasp` (module docstring).

    Attributes:
        probe_draws: draws of the last marginal closed to find candidates.
        candidates: the best-closing probe draws scored as candidates (besides the last mean).
        draws: draws about a candidate for its expected quality.
        accept_draws: draws per step of each model (:func:`pbdgrasp.inspect.inspect_model`) compared to
            keep a re-solved one.
        resolves: the best candidates (by expected quality, above the mean's) solved again.
        blend_steps: the last steps of tau_r blended onto the new final grasp (the refined final grasp's 20).
        margin_se: how many standard errors of the difference a re-solved model's product must beat the
            original's by to be kept.
        seed: the seed of the probe's and the scores' standard normals.
    """

    probe_draws: int = 300
    candidates: int = 10
    draws: int = 64
    accept_draws: int = 200
    resolves: int = 3
    blend_steps: int = 20
    margin_se: float = 1.0
    seed: int = 0

    def __post_init__(self):
        counts = (self.probe_draws, self.candidates, self.draws, self.accept_draws, self.resolves)
        counts += (self.blend_steps,)
        if min(counts) < 1 or self.seed < 0 or not self.margin_se >= 0:
            raise InputError(f"SceneGraspConfig: counts must be >= 1, seed and margin_se >= 0, found {self}")


def product_se(valid: float, free: float, n: int) -> float:
    """The standard error of ``valid * free``, two fractions of ``n`` draws each taken as independent
    binomial proportions (the delta method): sqrt((free^2 v(1-v) + v^2 f(1-f)) / n)."""
    return float(np.sqrt((free**2 * valid * (1 - valid) + valid**2 * free * (1 - free)) / n))


class _Measured(NamedTuple):
    """What the keep rule compares of a model: its last step's valid fraction, the least free fraction of
    any step, and how many steps' means' edges to the next are blocked (by anything but the grasped
    object)."""

    valid_fraction: float
    least_free_fraction: float
    blocked_mean_steps: int

    @property
    def product(self) -> float:
        return self.valid_fraction * self.least_free_fraction

    def se(self, n: int) -> float:
        """:func:`product_se` of the two fractions, each of ``n`` draws."""
        return product_se(self.valid_fraction, self.least_free_fraction, n)


def _expected(closer, scene: Scene, cov: np.ndarray, n: int, seed: int) -> ExpectedQuality:
    rng = np.random.default_rng(seed)
    return ExpectedQuality(closer, scene.T_world_object, scene.cov_object, cov, n, rng)


def adapt_final_grasp(
    model: VariationModel,
    scene: Scene,
    params: VariationParams | None = None,
    cache_dir: str | os.PathLike | None = None,
    config: SceneGraspConfig = SceneGraspConfig(),
    processes: int | None = None,
) -> VariationModel:
    """The model of ``model.source`` in ``scene`` with its final grasp chosen again there (module docstring).

    Args:
        model: the strategy's model solved in ``scene`` (:func:`pbdgrasp.scene_model.learn_in_scene`), with
            its trajectory as ``source``.
        params: the model's parameters (default: ``model.params``); cache_dir: the distance fields' cache.
        processes: processes that close the draws (:class:`planning.closing_pool.ClosingPool`).

    Returns:
        The re-solved model that was kept, or ``model`` itself; either way its source trajectory's
        ``meta["scene_grasp"]`` records the candidates' scores and the models measured.

    Raises:
        InputError: ``model`` has no source trajectory.
    """
    traj = model.source
    if traj is None:
        raise InputError("adapt_final_grasp: the model has no source trajectory to re-solve")
    params = params or model.params
    start = time.perf_counter()
    T_mean, J_mean = model.T_object_wrist_mean[-1], model.joints_mean[-1]
    T_object_world = np.linalg.inv(scene.T_world_object)
    with ClosingPool(scene, processes=processes) as closer:
        probe = _expected(closer, scene, model.cov[-1], config.probe_draws, config.seed)
        q_probe = probe.qualities(T_mean, J_mean)
        T_world_wrist, J_probe = probe.draws(T_mean, J_mean)
        best = [i for i in np.argsort(-q_probe, kind="stable")[: config.candidates] if q_probe[i] > 0]
        candidates = [(T_mean, J_mean)] + [(T_object_world @ T_world_wrist[i], J_probe[i]) for i in best]
        score = _expected(closer, scene, model.cov[-1], config.draws, config.seed + 1)
        scores = np.array([score(T, J) for T, J in candidates])
    order = [int(i) for i in np.argsort(-scores, kind="stable") if i > 0 and scores[i] > scores[0]]

    def measure(m: VariationModel) -> _Measured:
        rng = np.random.default_rng(config.seed + 2)  # the same draws' generator for every model
        found = inspect_model(m, scene, config.accept_draws, rng, processes=processes)
        return _Measured(found.valid_fraction, min(found.free_fraction), len(found.blocked_mean_steps))

    before = measure(model)
    info = {
        "kept": False,
        "probe_valid_fraction": float(np.mean(q_probe >= 0.05)),
        "candidate_scores": [float(x) for x in scores],
        "before": before._asdict(),
        "tried": [],
        "config": dataclasses.asdict(config),
    }
    adapted, best_score = model, before.product
    T_mean_from_tau = np.linalg.inv(traj.T_object_wrist[-1]) @ T_mean
    for pick in order[: config.resolves]:
        T_cand, J_cand = candidates[pick]
        T_end = T_cand @ np.linalg.inv(T_mean_from_tau)  # tau_r keeps its offset from the mean
        J_end = sah.clip_joints(traj.joints[-1] + (J_cand - J_mean))
        steps = config.blend_steps
        T_blend, J_blend = blend_final_change(traj.T_object_wrist, traj.joints, T_end, J_end, steps)
        moved = dataclasses.replace(traj, T_object_wrist=T_blend, joints=J_blend, path=None)
        resolved = learn_in_scene(moved, scene, params, cache_dir)
        after = measure(resolved)
        info["tried"].append({"candidate": pick, **after._asdict()})
        margin = config.margin_se * np.hypot(before.se(config.accept_draws), after.se(config.accept_draws))
        clear = after.blocked_mean_steps <= before.blocked_mean_steps
        if clear and after.product > max(best_score, before.product + margin):
            best_score, adapted = after.product, resolved
            info.update(kept=True, candidate=pick)
    info["time_s"] = time.perf_counter() - start
    log.info("scene grasp in %s: %s", scene.name, info)
    source = dataclasses.replace(adapted.source, meta={**adapted.source.meta, "scene_grasp": info})
    return dataclasses.replace(adapted, source=source)
