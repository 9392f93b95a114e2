"""How well can the SAH hold an object at all? A grasp-quality ceiling, independent of any strategy.

:func:`grasp_ceiling` places the hand at random about the object of a scene, closes it there the way the
planner's goal test does (:class:`planning.autograsp.HandCloser`: GraspIt!'s autograsp, then the L1
epsilon quality) and reports how often a collision-free pose closes to a valid grasp and how good the
grasps are. The best ones are then refined by hill climbing on epsilon, and each refined pose is shaken
by a small wrist perturbation to tell a robust grasp from a knife edge. It answers, before any learning,
whether a figure asked of a strategy (a quality, a fraction of valid draws) is within the hand's reach.

Sampling: poses about the object's surface, or draws of a strategy's last marginal
(:mod:`pbdgrasp.ceiling_poses` says how); collisions count against every body of the scene (table,
obstacles, the object, the hand itself).

Refinement: from each of the ``refine_best`` best valid samples, ``refine_iterations`` proposals of a
Gaussian wrist step (``refine_step_m``, ``refine_step_deg``) and thumb-opposition step; a proposal is kept
when it is collision-free and closes better. Robustness: ``perturb_draws`` draws of a wrist perturbation
(``perturb_m`` per axis, ``perturb_deg`` about a random axis) about each refined pose; a colliding draw
scores 0.

Near a strategy (``near``, a :class:`~inference.model.VariationModel`): ``samples`` draws of its last
marginal instead, and the refinement keeps to a :class:`~pbdgrasp.ceiling_poses.Region` about its last
mean (``near_position_m`` per axis of the mean's wrist frame, ``near_rotation_deg`` of turn; by default
the trust region of the refined final grasp, :class:`retarget.final_grasp.FinalGraspConfig`): how strong
the grasps are that the demonstrated grasp leads to, as against what the hand can hold at all.

Workers: the sampled poses are drawn first, then closed in chunks of ``chunk`` poses; each refinement
and its shaking runs with its own generator, spawned from ``rng`` (``Generator.spawn``). With ``workers``
> 1 and more than one chunk or refinement, both run on ``workers`` single-threaded Dask worker processes
(:func:`pbdgrasp.workers.task_client`), each task in a pybullet world of its own; otherwise in this
process. Closing is deterministic, so the result is the same for any number of workers.
"""

from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass

import numpy as np
from scipy.spatial.transform import Rotation
from tqdm import tqdm

from assets import sah
from assets.errors import InputError
from assets.se3 import pose_from_q, q_from_pose
from inference.model import VariationModel
from planning.autograsp import AutoGraspConfig, HandCloser
from planning.scene import Scene
from planning.world import World
from retarget.final_grasp import FinalGraspConfig
from retarget.objective import THUMB_BASE

from .ceiling_poses import Region, strategy_draws, surface_poses
from .workers import map_tasks, task_client

__all__ = ["CeilingConfig", "Ceiling", "grasp_ceiling"]


@dataclass(frozen=True)
class CeilingConfig:
    """Settings of :func:`grasp_ceiling` (module docstring); lengths [m], angles [deg].

    Raises:
        InputError: a count below its minimum, or a range or angle out of bounds.
    """

    samples: int = 100_000
    standoff_m: tuple[float, float] = (0.01, 0.06)
    reach_beyond_knuckles_m: float = 0.03
    cone_deg: float = 30.0
    epsilon: float = 0.05
    refine_best: int = 20
    refine_iterations: int = 1_000
    refine_step_m: float = 0.002
    refine_step_deg: float = 2.0
    perturb_m: float = 0.001
    perturb_deg: float = 1.0
    perturb_draws: int = 50
    near_position_m: float = 1e-3 * FinalGraspConfig.max_position_mm
    near_rotation_deg: float = FinalGraspConfig.max_rotation_deg
    workers: int = 1
    chunk: int = 5_000

    def __post_init__(self):
        lo, hi = self.standoff_m
        if self.samples < 1 or self.refine_best < 0 or self.refine_iterations < 0 or self.perturb_draws < 1:
            raise InputError(
                "ceiling: need samples >= 1, refine_best >= 0, refine_iterations >= 0, perturb_draws >= 1"
            )
        if not (0.0 <= lo <= hi <= 0.2):
            raise InputError(
                f"ceiling: standoff_m must satisfy 0 <= lo <= hi <= 0.2 m, found {self.standoff_m}"
            )
        if self.workers < 1 or self.chunk < 1:
            raise InputError(f"ceiling: need workers >= 1 and chunk >= 1, found {self.workers}, {self.chunk}")
        if not (0.0 <= self.cone_deg <= 90.0 and 0.0 < self.epsilon < 1.0):
            raise InputError("ceiling: need cone_deg in [0, 90] and epsilon in (0, 1)")
        steps = (self.refine_step_m, self.refine_step_deg, self.perturb_m, self.perturb_deg)
        steps += (self.reach_beyond_knuckles_m, self.near_position_m, self.near_rotation_deg)
        if not all(np.isfinite(v) and v >= 0.0 for v in steps):
            raise InputError(f"ceiling: steps and perturbations must be finite and >= 0, found {steps}")


@dataclass(frozen=True)
class Ceiling:
    """What :func:`grasp_ceiling` measured.

    Attributes:
        scene, object: the scene's name and its object.
        tried, free, valid: sampled poses, collision-free ones, ones that closed to epsilon >= ``epsilon``.
        valid_quantiles: epsilon of the valid samples at the median, the 95th percentile and the maximum
            (empty where none was valid).
        refined: the refined poses' epsilon, best first.
        refined_q: (k, 19) the refined poses, world frame [m, rad], in the order of ``refined``.
        robust_mean, robust_valid: per refined pose, the mean epsilon and the valid fraction of its
            perturbed draws.
        epsilon: the validity threshold.
        seconds: wall time.
        near: ``""`` for poses about the object's surface; else the strategy whose last marginal was drawn
            (its object and file).
        region: with ``near``, the trust region of the refinement ``(mm per axis, deg)``; else empty.
    """

    scene: str
    object: str
    tried: int
    free: int
    valid: int
    valid_quantiles: tuple[float, ...]
    refined: tuple[float, ...]
    refined_q: tuple[tuple[float, ...], ...]
    robust_mean: tuple[float, ...]
    robust_valid: tuple[float, ...]
    epsilon: float
    seconds: float
    near: str = ""
    region: tuple[float, ...] = ()

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2)

    @property
    def most_robust(self) -> int | None:
        """Index into ``refined`` of the pose with the best mean epsilon under the perturbation (the first
        on ties), or None where nothing was refined."""
        return int(np.argmax(self.robust_mean)) if self.robust_mean else None

    def summary(self) -> str:
        """A few lines for the terminal."""
        share = self.valid / self.free if self.free else 0.0
        what = f"draws of {self.near}'s last marginal" if self.near else "poses"
        lines = [
            f"{self.object} in {self.scene}: {self.tried} {what}, {self.free} collision-free, {self.valid} "
            f"valid (epsilon >= {self.epsilon:g}; {share:.3%} of the free), {self.seconds:.0f} s",
        ]
        if self.near:
            lines.append(
                f"refined within {self.region[0]:g} mm per axis and {self.region[1]:g} deg of its last mean"
            )
        if self.valid_quantiles:
            med, p95, top = self.valid_quantiles
            lines.append(f"valid samples: median {med:.3f}, p95 {p95:.3f}, max {top:.3f}")
        if self.refined:
            best = self.most_robust
            lines.append(
                "refined: "
                + ", ".join(f"{e:.3f}" for e in self.refined[:5])
                + (" ..." if len(self.refined) > 5 else "")
            )
            lines.append(
                f"robust best: mean epsilon {self.robust_mean[best]:.3f} under the perturbation "
                f"({self.robust_valid[best]:.0%} valid), refined {self.refined[best]:.3f}"
            )
        return "\n".join(lines)


def _perturbed(q: np.ndarray, step_m: float, step_deg: float, thumb_rad: float, rng, n: int) -> np.ndarray:
    """``n`` copies (n, 19) of the world-frame ``q`` with a Gaussian wrist step (``step_m`` per axis, a
    rotation of ``step_deg`` about a random axis applied in the wrist frame) and thumb-opposition step."""
    T = pose_from_q(q)
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    turn = Rotation.from_rotvec(axis * np.deg2rad(step_deg) * np.abs(rng.normal(size=(n, 1)))).as_matrix()
    out = np.tile(q, (n, 1))
    for i in range(n):
        Ti = T.copy()
        Ti[:3, :3] = T[:3, :3] @ turn[i]
        Ti[:3, 3] += rng.normal(0.0, step_m, 3)
        out[i, :6] = q_from_pose(Ti)
    lo, hi = sah.JOINT_LIMITS[THUMB_BASE]
    out[:, 6 + THUMB_BASE] = np.clip(out[:, 6 + THUMB_BASE] + rng.normal(0.0, thumb_rad, n), lo, hi)
    return out


class _Scorer:
    """phi_o of world-frame configurations in one scene: ``(collision-free, epsilon)``, epsilon 0 for a
    configuration in collision (:meth:`HandCloser.close` checks that first)."""

    def __init__(self, scene: Scene):
        self.world = World(scene)
        self.closer = HandCloser(self.world, AutoGraspConfig())

    def __call__(self, q: np.ndarray) -> tuple[bool, float]:
        grasp = self.closer.close(q)
        return not grasp.in_collision, float(grasp.quality)


def grasp_ceiling(
    scene: Scene,
    config: CeilingConfig = CeilingConfig(),
    rng: np.random.Generator | None = None,
    progress: bool = False,
    near: VariationModel | None = None,
) -> Ceiling:
    """Sample, close, refine and shake grasps of ``scene``'s object (module docstring).

    Args:
        scene: the scene; its object at its nominal pose.
        config: :class:`CeilingConfig`.
        rng: the only source of randomness (default: seed 0).
        progress: a tqdm bar over the poses on a terminal (stderr).
        near: a strategy: draw its last marginal and refine within :class:`Region` about its last mean,
            instead of poses about the whole object.
    """
    rng = rng or np.random.default_rng(0)
    t0 = time.perf_counter()
    region = None
    if near is None:
        q_sampled = surface_poses(scene, config, rng)
    else:
        q_sampled, region = strategy_draws(scene, near, config, rng)
    starts = range(0, config.samples, config.chunk)
    bars = dict(disable=None if progress else True, leave=False)  # None: the bars only on a terminal
    parallel = len(starts) > 1 or config.refine_best > 1  # the closings or the refinements
    with task_client(config.workers if parallel else 1) as client:
        with tqdm(desc="closing the hand", total=config.samples, unit="pose", **bars) as bar:
            chunks = map_tasks(
                client,
                _score_chunk,
                [(scene, q_sampled[start : start + config.chunk], config.epsilon) for start in starts],
                lambda task, result: bar.update(len(task[1])),
            )
        free = sum(c[0] for c in chunks)
        valid = [(e, q_sampled[start + i]) for start, c in zip(starts, chunks, strict=True) for e, i in c[1]]
        valid.sort(key=lambda v: -v[0])
        best = [v for v in valid if region is None or region.contains(v[1])][: config.refine_best]
        chain_rngs = rng.spawn(len(best))
        with tqdm(desc="refining", total=len(best), unit="grasp", **bars) as bar:
            chains = map_tasks(
                client,
                _refine_and_shake,
                [(scene, e, q, config, r, region) for (e, q), r in zip(best, chain_rngs, strict=True)],
                lambda task, result: bar.update(),
            )
    chains.sort(key=lambda c: -c[0])
    refined = [(e, q) for e, q, _, _ in chains]
    shaken = [(m, v) for _, _, m, v in chains]
    eps = np.array([e for e, _ in valid])
    return Ceiling(
        scene=scene.name,
        object=scene.object.name,
        tried=int(config.samples),
        free=int(free),
        valid=len(valid),
        valid_quantiles=tuple(float(x) for x in np.quantile(eps, [0.5, 0.95, 1.0])) if len(eps) else (),
        refined=tuple(float(e) for e, _ in refined),
        refined_q=tuple(tuple(float(x) for x in q) for _, q in refined),
        robust_mean=tuple(float(m) for m, _ in shaken),
        robust_valid=tuple(float(v) for _, v in shaken),
        epsilon=float(config.epsilon),
        seconds=time.perf_counter() - t0,
        near="" if near is None else f"the {near.object} strategy ({near.path or 'in memory'})",
        region=() if near is None else (1e3 * config.near_position_m, config.near_rotation_deg),
    )


def _score_chunk(scene: Scene, q: np.ndarray, epsilon: float) -> tuple[int, list[tuple[float, int]]]:
    """Close the hand at each of the configurations ``q`` (n, 19) in a world of its own: the number of
    collision-free ones and ``(epsilon, index)`` of the valid ones, in the order of ``q``."""
    score = _Scorer(scene)
    try:
        free, valid = 0, []
        for i, x in enumerate(q):
            ok, e = score(x)
            free += ok
            if e >= epsilon:
                valid.append((e, i))
        return free, valid
    finally:
        score.world.close()


def _refine_and_shake(scene: Scene, e: float, q: np.ndarray, config: CeilingConfig, rng, region=None):
    """One valid sample refined (:func:`_refine`, within ``region``) and its result shaken (:func:`_shake`)
    in a world of its own, with its own generator: ``(epsilon, q, mean epsilon shaken, valid fraction
    shaken)``."""
    score = _Scorer(scene)
    try:
        e, q = _refine(score, e, q, config, rng, region)
        return (e, q, *_shake(score, q, config, rng))
    finally:
        score.world.close()


def _refine(
    score, e: float, q: np.ndarray, config: CeilingConfig, rng, region: Region | None = None
) -> tuple[float, np.ndarray]:
    """Hill climbing on epsilon from ``q`` (quality ``e``): keep a proposal that is free and closes better
    (and lies in ``region``; a proposal outside it is not closed and counts as an iteration)."""
    thumb = np.deg2rad(config.refine_step_deg)
    for _ in range(config.refine_iterations):
        x = _perturbed(q, config.refine_step_m, config.refine_step_deg, thumb, rng, 1)[0]
        if region is not None and not region.contains(x):
            continue
        ok, ex = score(x)
        if ok and ex > e:
            e, q = ex, x
    return e, q


def _shake(score, q: np.ndarray, config: CeilingConfig, rng) -> tuple[float, float]:
    """Mean epsilon and valid fraction of ``perturb_draws`` wrist perturbations of ``q`` (thumb held)."""
    draws = _perturbed(q, config.perturb_m, config.perturb_deg, 0.0, rng, config.perturb_draws)
    e = np.array([score(x)[1] for x in draws])
    return float(e.mean()), float(np.mean(e >= config.epsilon))
