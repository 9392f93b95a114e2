"""A grasp-planning problem in one scene, and the planners that solve it (paper section VII).

:class:`GraspPlanner` owns one pybullet :class:`~planning.world.World` (its own client), the collision
checker, the hand closer (phi_o) and the learned strategies, and runs one planning query per call,
with each planner an entry of the registry :data:`planning.planners.REGISTRY` (learned, baseline, ompl,
bidirectional, goal_region; what each is and how it grows its trees and handles goals is written there).

All of them root their trees at ``num_roots`` (100) collision-free draws of N(b_1, B_1), the first marginal,
and use the same goal test: phi_o >= ``quality_threshold`` (0.05). Ours (learned and baseline) runs it
where an extension towards a goal sample ended (the node it added last, or its nearest node when its
first step was blocked), if within ``goal_radius`` of the sample; OMPL's goal region holds
collision-free N(b_T, B_T) draws only.

The strategies' marginals P(X_t | O) live in the object frame; their object prior P(O) is replaced by
the scene's localization N(mu_o, Sigma_o), so a strategy learned on one object plans on another.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from assets.errors import InputError
from assets.q_layout import Q_DIM
from assets.sah import JOINT_LIMITS
from inference.model import VariationModel
from inference.sampler import MixtureSampler, sample

from .autograsp import AutoGraspConfig, HandCloser
from .collision import CollisionChecker
from .config_space import HandConfigSpace
from .ompl_peer import plan_ompl
from .planners import PlannerSpec, planner_spec
from .rrt_connect import PlannerConfig, PlanResult, rrt_connect
from .scene import Scene, load_scene
from .world import World

__all__ = ["PlanningSettings", "GraspPlanner"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PlanningSettings:
    """Settings of one planning query (the paper's values by default).

    Attributes:
        planner: ``learned``, ``baseline`` or ``ompl``.
        beta: probability of the uniform strategy in P(Y) (learned planner).
        goal_probability: probability of a N(b_T, B_T) target (baseline).
        num_roots: start configurations drawn from N(b_1, B_1) (collision-free ones kept).
        time_limit_s: budget of one query [s].
        max_nodes: node limit of our tree.
        quality_threshold: epsilon; phi_o >= it is a valid grasp.
        sample_batch: draws of P(Y) per vectorized call.
        goal_radius: phi_o runs where an extension towards a goal sample ended within this distance of
            it (see :class:`~planning.rrt_connect.PlannerConfig`); the same for learned and baseline.
        score_stalled: phi_o also runs at the nearest node of an extension towards a goal sample that was
            blocked at its first step (once per node; see :class:`~planning.rrt_connect.PlannerConfig`).
        record_tree: return the tree in ``PlanResult.extra`` (``tree_q``, ``tree_parent``; learned and
            baseline planners only), for plots.
    """

    planner: str = "learned"
    beta: float = 0.05
    goal_probability: float = 0.1
    num_roots: int = 100
    time_limit_s: float = 10.0
    max_nodes: int = 50_000
    quality_threshold: float = 0.05
    sample_batch: int = 256
    goal_radius: float = 3.0
    score_stalled: bool = True
    record_tree: bool = False

    def __post_init__(self):
        planner_spec(self.planner)
        if not 0.0 <= self.beta <= 1.0 or not 0.0 <= self.goal_probability <= 1.0:
            raise InputError("beta and goal_probability must be probabilities in [0, 1]")
        if self.num_roots < 1 or self.time_limit_s <= 0 or self.max_nodes < 1 or self.sample_batch < 1:
            raise InputError(f"num_roots, time_limit_s, max_nodes and sample_batch must be positive: {self}")


class _Buffered:
    """Turns a vectorized ``draw(n, rng) -> (q (n, 19), is_goal (n,))`` into ``sample_fn(rng)``."""

    def __init__(self, draw, batch: int):
        self.draw, self.batch = draw, batch
        self.q = np.empty((0, Q_DIM))
        self.goal = np.empty(0, dtype=bool)
        self.i = 0

    def __call__(self, rng: np.random.Generator) -> tuple[np.ndarray, bool]:
        if self.i >= len(self.q):
            self.q, self.goal = self.draw(self.batch, rng)
            self.i = 0
        self.i += 1
        return self.q[self.i - 1], bool(self.goal[self.i - 1])


class GraspPlanner:
    """One scene, its learned strategies and a pybullet world; :meth:`plan` runs one query.

    Args:
        scene: a :class:`~planning.scene.Scene` or a scene name/path.
        models: the learned strategies (at least one).
        grasp_config: the hand-closing settings of phi_o.

    Raises:
        InputError: no models.
    """

    def __init__(self, scene: Scene | str, models: Sequence[VariationModel], grasp_config=None):
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        if not models:
            raise InputError("planning needs at least one learned strategy (a .model.npz)")
        self.models = [
            dataclasses.replace(
                m, T_world_object_mean=self.scene.T_world_object, cov_object=self.scene.cov_object
            )
            for m in models
        ]
        self.world = World(self.scene)
        self.checker = CollisionChecker(self.world)
        self.closer = HandCloser(self.world, grasp_config or AutoGraspConfig())
        self.space = HandConfigSpace()
        self.bounds = self._wrist_bounds(margin_m=0.05)

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> GraspPlanner:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- pieces --------------------------------------------------------------------------------------
    def _wrist_bounds(self, margin_m: float) -> np.ndarray:
        """(2, 3) box of the uniform samples: the scene's wrist bounds grown to hold every strategy's mean
        wrist path (in this scene's object pose) with a margin, so roots and goals are inside it."""
        lo, hi = np.array(self.scene.wrist_bounds_m, dtype=float)
        for m in self.models:
            p = (self.scene.T_world_object @ m.T_object_wrist_mean)[:, :3, 3]
            lo = np.minimum(lo, p.min(axis=0) - margin_m)
            hi = np.maximum(hi, p.max(axis=0) + margin_m)
        return np.stack([lo, hi])

    def draw_marginal(
        self, k_from_end: int | None, n: int, rng: np.random.Generator, k: int = 0
    ) -> np.ndarray:
        """``n`` world-frame draws (n, 19) of step ``k`` (or of ``T_s - k_from_end``) of random strategies."""
        which = rng.integers(len(self.models), size=n)
        out = np.empty((n, Q_DIM))
        for s, model in enumerate(self.models):
            idx = np.flatnonzero(which == s)
            if idx.size:
                step = k if k_from_end is None else model.num_steps - k_from_end
                out[idx] = sample(model, step, idx.size, rng, joint_limits=JOINT_LIMITS)
        return out

    def roots(self, rng: np.random.Generator, n: int, max_draws: int | None = None) -> np.ndarray:
        """Up to ``n`` collision-free draws (R, 19) of N(b_1, B_1), the first marginal."""
        max_draws = max_draws or 20 * n
        kept: list[np.ndarray] = []
        drawn = 0
        while len(kept) < n and drawn < max_draws:
            batch = self.draw_marginal(None, min(n, max_draws - drawn), rng, k=0)
            drawn += len(batch)
            kept.extend(q for q in batch if self.checker.is_free(q))
        return np.array(kept[:n]).reshape(-1, Q_DIM)

    def quality(self, q: np.ndarray):
        """phi_o at ``q``: ``(quality, GraspResult)``."""
        res = self.closer.close(q)
        return res.quality, res

    # -- planning ------------------------------------------------------------------------------------
    def plan(self, rng: np.random.Generator, settings: PlanningSettings = PlanningSettings()) -> PlanResult:
        """One planning query with a fresh tree; see the module docstring for the planners."""
        checks_before = self.checker.checks
        roots = self.roots(rng, settings.num_roots)
        if len(roots) == 0:
            return PlanResult(
                False,
                "no collision-free start configuration in N(b_1, B_1)",
                0.0,
                0,
                0.0,
                np.empty((0, Q_DIM)),
            )
        lo, hi = self.bounds

        def draw_goal(r: np.random.Generator) -> np.ndarray:
            """One draw of N(b_T, B_T): the goal region of ``ompl`` and ``goal_region``."""
            return self.draw_marginal(1, 1, r)[0]

        spec = planner_spec(settings.planner)
        if spec.engine == "ompl":
            result = plan_ompl(
                roots,
                draw_goal,
                self.checker.is_free,
                self.quality,
                (lo, hi),
                JOINT_LIMITS,
                rng,
                time_limit_s=settings.time_limit_s,
                quality_threshold=settings.quality_threshold,
            )
        else:
            config = PlannerConfig(
                time_limit_s=settings.time_limit_s,
                max_nodes=settings.max_nodes,
                quality_threshold=settings.quality_threshold,
                connect=spec.connect,
                goal_trees=spec.goal_trees,
                goal_region_tries=spec.goal_region_tries,
                goal_radius=settings.goal_radius,
                score_stalled=settings.score_stalled,
                record_tree=settings.record_tree,
            )
            result = rrt_connect(
                roots,
                _Buffered(self._sample_draw(spec, settings), settings.sample_batch),
                self.checker.is_edge_free,
                self.quality,
                self.space,
                rng,
                config,
                goal_sample_fn=draw_goal,
            )
        # count configurations checked (roots and every edge's points), not edge queries
        return dataclasses.replace(
            result,
            collision_checks=self.checker.checks - checks_before,
            extra=dict(result.extra, roots=len(roots)),
        )

    def _sample_draw(self, spec: PlannerSpec, settings: PlanningSettings):
        """The vectorized ``draw(n, rng) -> (q (n, 19), is_goal (n,))`` of a planner's ``samples``."""
        lo, hi = self.bounds
        if spec.samples == "mixture":
            mixture = MixtureSampler(self.models, lo, hi, settings.beta, JOINT_LIMITS)

            def draw(n, r):
                s = mixture.sample(n, r)
                return s.q, s.is_last & (s.strategy >= 0)

            return draw
        uniform = MixtureSampler(self.models, lo, hi, 1.0, JOINT_LIMITS)

        def draw(n, r):
            goal = r.random(n) < settings.goal_probability
            q = uniform.sample(n, r).q
            if goal.any():
                q[goal] = self.draw_marginal(1, int(goal.sum()), r)
            return q, goal

        return draw
