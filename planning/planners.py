"""The planner registry: each planner :class:`~planning.grasp_planner.GraspPlanner` runs is one entry.

An entry says what the planner is (``description``), how it grows its trees (``engine``, ``samples``,
``connect``) and how it handles goals (``goal_trees``, ``goal_region_tries``). All planners root their
trees at collision-free draws of N(b_1, B_1) and share the goal test (phi_o >= epsilon). Adding a
planner is adding an entry to :data:`REGISTRY`, at its end: a trial's random stream is spawned from the
planner's index in :data:`PLANNERS`, so the order of the existing entries is fixed.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

from assets.errors import InputError

__all__ = ["GOAL_REGION_TRIES", "PLANNERS", "REGISTRY", "PlannerSpec", "planner_spec"]

GOAL_REGION_TRIES = 20
"""Draws of N(b_T, B_T) per goal-root attempt (``goal_region``; the ``ompl`` peer's goal_tries)."""


@dataclass(frozen=True)
class PlannerSpec:
    """One planner.

    Attributes:
        name: the name used by ``--planner``, the results database and the report.
        description: one line for ``--help`` and the docs.
        engine: ``"rrt"``, our :func:`~planning.rrt_connect.rrt_connect`, or ``"ompl"``, OMPL's
            RRTConnect (:func:`~planning.ompl_peer.plan_ompl`) with a goal region of N(b_T, B_T) draws.
        samples: the samples our trees grow towards: ``"mixture"``, P(Y) (probability ``beta`` uniform,
            else a random step's marginal of a random strategy; last-step draws are goal samples), or
            ``"uniform"``, uniform samples with a target from N(b_T, B_T) with probability
            ``goal_probability`` (the paper's baseline). Unused by ``ompl``.
        connect: CONNECT (repeated extension) towards a sample, or a single-step EXTEND.
        goal_trees: a collision-free valid goal sample that the start forest did not reach roots a goal
            tree, and the forests grow towards each other as OMPL's RRTConnect does.
        goal_region_tries: goal trees are also rooted at dedicated draws of N(b_T, B_T) by OMPL's
            RRTConnect rule, up to this many draws per attempt (0: none).
        in_paper: the planner is one of the paper's two.
    """

    name: str
    description: str
    engine: str = "rrt"
    samples: str = "mixture"
    connect: bool = True
    goal_trees: bool = False
    goal_region_tries: int = 0
    in_paper: bool = False

    def __post_init__(self):
        if self.engine not in ("rrt", "ompl") or self.samples not in ("mixture", "uniform"):
            raise InputError(
                f"planner {self.name}: unknown engine {self.engine!r} or samples {self.samples!r}"
            )


REGISTRY = MappingProxyType(
    {
        s.name: s
        for s in (
            PlannerSpec(
                "learned",
                "the paper's planner: RRT-CONNECT towards samples of the mixture P(Y)",
                in_paper=True,
            ),
            PlannerSpec(
                "baseline",
                "the paper's simple RRT: EXTEND towards uniform samples, 10 % targets from N(b_T, B_T)",
                samples="uniform",
                connect=False,
                in_paper=True,
            ),
            PlannerSpec(
                "ompl",
                "OMPL's RRTConnect, uniform samples, a goal region of valid N(b_T, B_T) draws",
                engine="ompl",
            ),
            PlannerSpec(
                "bidirectional",
                "learned with goal trees rooted at valid last-step samples the tree did not reach",
                goal_trees=True,
            ),
            PlannerSpec(
                "goal_region",
                "bidirectional whose goal trees are also rooted at draws of N(b_T, B_T) (OMPL's rule)",
                goal_trees=True,
                goal_region_tries=GOAL_REGION_TRIES,
            ),
        )
    }
)
"""name -> :class:`PlannerSpec`, in the order of :data:`PLANNERS` (append only)."""

PLANNERS: tuple[str, ...] = tuple(REGISTRY)
"""The planners' names; a trial's seed uses the index, so new planners are appended."""


def planner_spec(name: str) -> PlannerSpec:
    """The registry entry of ``name``.

    Raises:
        InputError: an unknown name (the message lists the valid ones).
    """
    if name not in REGISTRY:
        raise InputError(f"planner: expected one of {', '.join(PLANNERS)}, found {name!r}")
    return REGISTRY[name]
