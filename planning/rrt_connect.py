"""RRT-CONNECT with a learned sampling distribution and a grasp-quality goal test (paper section VII).

The planner knows nothing of pybullet or GTSAM: it takes injected callables (as caelan/motion-planners
does), so a learned sampler is just another ``sample_fn``:

* ``sample_fn(rng) -> (y (d,), is_goal_sample: bool)``: a draw of P(Y); ``is_goal_sample`` is true when
  the draw came from the last time step of a strategy (k = T_s), or from the goal distribution of a
  baseline;
* ``is_edge_free(q_a, q_b) -> bool``: the straight edge (in the space's interpolation) is free; the
  planner's steps are at most one unit of the configuration space long;
* ``quality_fn(q) -> (quality, payload)``: phi_o, the grasp quality after closing the hand at ``q``.

The tree is a forest rooted at the start configurations. Each iteration draws ``y``, finds the nearest
node and extends towards ``y`` with the CONNECT heuristic (repeated unit steps until ``y`` is reached or
an edge is blocked). When an extension towards a goal sample ended within ``goal_radius`` of it (at the
sample itself, or where an obstacle, usually the object, stopped it), phi_o is evaluated at the node where
it ended; a quality ``>= quality_threshold`` ends the search with the path from its root. An extension
whose first step is blocked ends at its nearest node, which is then scored if it never was
(``score_stalled``): a tree that stops on the rim of a hole, above a grasp it cannot reach, closes the
hand where it stands, which is how the paper's jam jar in a hole gets its grasp "a few cm above the
demonstrated grasping position".

With ``goal_trees`` (not in the paper; Kuffner and LaValle's two-tree RRT-Connect, as OMPL's RRTConnect
grows it) a goal sample that the extension did not reach is itself checked: if it is collision-free and
its phi_o reaches the threshold, it becomes the root of a *goal tree*. While goal trees exist the
iterations alternate: one forest (start or goal) extends towards ``y``, the other CONNECTs towards the
node it added; a connection ends the search with the path from a start root through the meeting node to
the valid grasp at a goal root. A single tree has to reach a grasp in a narrow slot from above, where
every extension of its nearest node may be blocked; a goal tree grows out of the slot from the grasp.

With ``goal_region_tries`` > 0 the goal trees also get roots from dedicated draws of the goal
distribution (``goal_sample_fn``), by OMPL's RRTConnect rule: before an iteration, while there is no goal
tree or fewer goal roots than half the goal trees' nodes, up to ``goal_region_tries`` draws are checked
(collision-free, phi_o >= the threshold) and the first valid one becomes a root. That is what OMPL's
RRTConnect does with a sampleable goal region, so the two differ only in the samples their trees grow
towards (P(Y) here, uniform there).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["PlannerConfig", "PlanResult", "rrt_connect"]


@dataclass(frozen=True)
class PlannerConfig:
    """Settings of :func:`rrt_connect`.

    Attributes:
        time_limit_s: wall-clock budget of one planning query.
        max_nodes: the search stops when the tree holds this many nodes.
        quality_threshold: epsilon; a grasp with phi_o >= it is valid (the paper's 0.05).
        step: the longest edge added in one extension step, in configuration-space units.
        connect: extend with CONNECT (repeated steps); ``False`` gives single-step EXTEND.
        goal_radius: phi_o is evaluated at the node where an extension towards a goal sample ended when
            that node is within this distance of the sample (configuration-space units; 0: only when the
            sample itself was reached). The paper evaluates phi_o whenever "the RRT was extended by a
            sample with k = T_s": a last-step sample often has a finger inside the object, the extension
            towards it stops at the surface, and closing the hand there is the grasp. The default, 3 units
            (3 cm, 15 deg of wrist or 30 deg of a joint with the hand space's defaults), skips extensions
            blocked far from their sample, where closing the hand cannot touch what the sample touched.
        score_stalled: an extension towards a goal sample whose first step is blocked ends at its nearest
            node; score that node (once per node) if it is within ``goal_radius`` of the sample.
            ``False`` scores only nodes an extension added (docs/method.md: the goal test).
        goal_trees: root goal trees at valid grasps that the start forest did not reach and grow both
            (see the module docstring); ``False`` is the paper's single tree.
        goal_region_tries: with ``goal_trees``, draws of ``goal_sample_fn`` per attempt to root a goal tree
            by OMPL's rule (module docstring); 0: goal trees are rooted only at goal samples of P(Y).
        record_tree: return the tree in ``PlanResult.extra`` (``tree_q`` (N, d) nodes, ``tree_parent``
            (N,) parent index, -1 for the roots), e.g. for plotting; off by default (copies the arrays).
    """

    time_limit_s: float = 10.0
    max_nodes: int = 50_000
    quality_threshold: float = 0.05
    step: float = 1.0
    connect: bool = True
    goal_radius: float = 3.0
    score_stalled: bool = True
    goal_trees: bool = False
    goal_region_tries: int = 0
    record_tree: bool = False

    def __post_init__(self):
        if not (
            self.time_limit_s > 0
            and self.max_nodes > 0
            and self.step > 0
            and self.goal_radius >= 0
            and self.goal_region_tries >= 0
        ):
            raise ValueError(
                "PlannerConfig: time_limit_s, max_nodes and step must be > 0, goal_radius and "
                f"goal_region_tries >= 0, found {self}"
            )


@dataclass(frozen=True)
class PlanResult:
    """The outcome of one planning query.

    Attributes:
        success: a grasp with quality >= the threshold was found.
        message: why the search ended.
        eta_s: time to the first valid grasp (or the time spent, on failure) [s].
        nodes: nodes in the tree (roots included).
        quality: phi_o of the grasp found (the best one evaluated, on failure).
        path: (K, d) configurations from a root to the grasp; empty on failure.
        grasp: the quality function's payload of the grasp found (e.g. the closed hand), or ``None``.
        quality_evaluations, collision_checks, iterations: counters.
        time_quality_s, time_collision_s: time spent inside ``quality_fn`` and ``is_edge_free``.
    """

    success: bool
    message: str
    eta_s: float
    nodes: int
    quality: float
    path: np.ndarray
    grasp: Any = None
    quality_evaluations: int = 0
    collision_checks: int = 0
    iterations: int = 0
    time_quality_s: float = 0.0
    time_collision_s: float = 0.0
    extra: dict = field(default_factory=dict)


class _Forest:
    """Nodes, their parents and their distance features in growing arrays."""

    def __init__(self, space, roots: np.ndarray, capacity: int):
        n, d = roots.shape
        cap = max(capacity, n)
        f0 = space.features(roots)
        self.space = space
        self.q = np.empty((cap, d))
        self.f = np.empty((cap, f0.shape[1]))
        self.parent = np.full(cap, -1, dtype=np.int64)
        self.q[:n], self.f[:n] = roots, f0
        self.count = n

    def add(self, q: np.ndarray, parent: int) -> int:
        if self.count >= len(self.q):
            self._grow()
        i = self.count
        self.q[i] = q
        self.f[i] = self.space.features(q)[0]
        self.parent[i] = parent
        self.count += 1
        return i

    def nearest(self, q: np.ndarray) -> int:
        return self.space.nearest(self.f[: self.count], q)

    def _grow(self) -> None:
        """Doubles the arrays' capacity."""
        cap, n = 2 * len(self.q), self.count
        for name in ("q", "f"):
            arr = getattr(self, name)
            new = np.empty((cap, arr.shape[1]))
            new[:n] = arr[:n]
            setattr(self, name, new)
        parent = np.full(cap, -1, dtype=np.int64)
        parent[:n] = self.parent[:n]
        self.parent = parent

    def root_of(self, i: int) -> int:
        while self.parent[i] >= 0:
            i = int(self.parent[i])
        return i

    def path_to(self, i: int) -> np.ndarray:
        idx = []
        while i >= 0:
            idx.append(i)
            i = int(self.parent[i])
        return self.q[idx[::-1]].copy()


def rrt_connect(
    roots: np.ndarray,
    sample_fn: Callable[[np.random.Generator], tuple[np.ndarray, bool]],
    is_edge_free: Callable[[np.ndarray, np.ndarray], bool],
    quality_fn: Callable[[np.ndarray], tuple[float, Any]],
    space,
    rng: np.random.Generator,
    config: PlannerConfig = PlannerConfig(),
    goal_sample_fn: Callable[[np.random.Generator], np.ndarray] | None = None,
) -> PlanResult:
    """Grow a forest from ``roots`` until a goal sample with quality >= the threshold is reached.

    Args:
        roots: (R, d) collision-free start configurations (the paper draws 100 from N(b_1, B_1)).
        sample_fn: the sampling distribution P(Y), see the module docstring.
        is_edge_free: edge validity (counted as one collision check per call).
        quality_fn: phi_o.
        space: a configuration space of :mod:`planning.config_space`.
        rng: the only source of randomness.
        config: limits and thresholds.
        goal_sample_fn: one draw (d,) of the goal distribution, for ``config.goal_region_tries``.

    Returns:
        A :class:`PlanResult`; failure is a result with ``success=False`` and the reason.
    """
    roots = np.atleast_2d(np.asarray(roots, dtype=float))
    region = config.goal_trees and config.goal_region_tries > 0  # OMPL's goal-region sampling
    if region and goal_sample_fn is None:
        raise ValueError("rrt_connect: goal_region_tries > 0 needs a goal_sample_fn")
    t0 = time.perf_counter()
    if len(roots) == 0:
        return PlanResult(False, "no collision-free start configuration", 0.0, 0, 0.0, np.empty((0, 0)))
    forest = _Forest(space, roots, min(config.max_nodes, 4096))
    stats = {"checks": 0, "evals": 0, "t_col": 0.0, "t_q": 0.0, "best": 0.0, "best_payload": None}

    def edge_free(a, b):
        t = time.perf_counter()
        ok = is_edge_free(a, b)
        stats["t_col"] += time.perf_counter() - t
        stats["checks"] += 1
        return ok

    def nodes() -> int:
        """Nodes of the start forest and of the goal trees."""
        return forest.count + (goal.count if goal is not None else 0)

    def result(success, message, path=None, quality=None, payload=None, it=0):
        return PlanResult(
            success=success,
            message=message,
            eta_s=time.perf_counter() - t0,
            nodes=nodes(),
            quality=float(stats["best"] if quality is None else quality),
            path=np.empty((0, roots.shape[1])) if path is None else path,
            grasp=stats["best_payload"] if payload is None else payload,
            quality_evaluations=stats["evals"],
            collision_checks=stats["checks"],
            iterations=it,
            time_quality_s=stats["t_q"],
            time_collision_s=stats["t_col"],
            extra=_tree(forest) if config.record_tree else {},
        )

    def extend(f: _Forest, y: np.ndarray) -> tuple[int, bool, bool]:
        """Steps from the node of ``f`` nearest to ``y`` towards it: (last node, added any, reached y)."""
        i = f.nearest(y)
        reached = added = False
        while nodes() < config.max_nodes:
            q_near = f.q[i]
            q_new, reached = space.steer(q_near, y, config.step)
            if not edge_free(q_near, q_new):
                reached = False
                break
            i = f.add(q_new, i)
            added = True
            if reached or not config.connect:
                break
        return i, added, reached

    def score(q):
        t = time.perf_counter()
        quality, payload = quality_fn(q)
        stats["t_q"] += time.perf_counter() - t
        stats["evals"] += 1
        if quality > stats["best"] or stats["best_payload"] is None:
            stats["best"], stats["best_payload"] = float(quality), payload
        return quality, payload

    def joined(i: int, j: int, it: int) -> PlanResult:
        """Start node ``i`` and goal node ``j`` are the same configuration: the path through them."""
        path = np.concatenate([forest.path_to(i), goal.path_to(j)[::-1][1:]])
        quality, payload = goal_grasps[goal.root_of(j)]
        return result(True, "valid grasp found (goal tree joined)", path, quality, payload, it)

    goal: _Forest | None = None  # goal trees, rooted at valid grasps (config.goal_trees)
    goal_grasps: dict[int, tuple[float, Any]] = {}  # goal root index -> (quality, payload)
    stalled_scored: set[int] = set()  # start-forest nodes scored where a stalled extension ended

    def root_goal_tree(y: np.ndarray) -> bool:
        """Roots a goal tree at ``y`` if it is collision-free and a valid grasp."""
        nonlocal goal
        if not edge_free(y, y):
            return False
        quality, payload = score(y)
        if quality < config.quality_threshold:
            return False
        if goal is None:
            goal = _Forest(space, y[None, :], min(config.max_nodes, 4096))
            goal_grasps[0] = (quality, payload)
        else:
            goal_grasps[goal.add(y, -1)] = (quality, payload)
        return True

    it = 0
    while True:
        if time.perf_counter() - t0 > config.time_limit_s:
            return result(False, f"time limit of {config.time_limit_s:g} s reached", it=it)
        if nodes() >= config.max_nodes:
            return result(False, f"node limit of {config.max_nodes} reached", it=it)
        it += 1
        if region and (goal is None or len(goal_grasps) < goal.count / 2):
            for _ in range(config.goal_region_tries):  # OMPL's RRTConnect: sample the goal region
                if root_goal_tree(np.asarray(goal_sample_fn(rng), dtype=float)):
                    break
        y, is_goal = sample_fn(rng)
        if goal is not None and it % 2 == 0:
            # the goal trees extend towards y, the start forest CONNECTs towards what they added
            j, added, _ = extend(goal, y)
            if added:
                i, _, met = extend(forest, goal.q[j])
                if met:
                    return joined(i, j, it)
            continue
        i, added, reached = extend(forest, y)
        fresh = added or (config.score_stalled and i not in stalled_scored)
        if is_goal and fresh and (reached or space.distance(forest.q[i], y) <= config.goal_radius):
            if not added:
                stalled_scored.add(i)
            quality, payload = score(forest.q[i])
            if quality >= config.quality_threshold:
                return result(True, "valid grasp found", forest.path_to(i), quality, payload, it)
        # a valid grasp the start forest did not reach roots a goal tree
        new_root = config.goal_trees and is_goal and not reached and root_goal_tree(y)
        if goal is not None and (added or new_root):
            j, _, met = extend(goal, forest.q[i])
            if met:
                return joined(i, j, it)


def _tree(forest: _Forest) -> dict:
    """The tree's nodes and parents (copies) for ``PlanResult.extra``."""
    n = forest.count
    return {"tree_q": forest.q[:n].copy(), "tree_parent": forest.parent[:n].copy()}
