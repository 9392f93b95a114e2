"""Where a strategy fails in a scene, before planning: how many draws of each marginal are collision-free,
and how many of the last step's close to a valid grasp.

:func:`inspect_model` draws ``n`` configurations per step from P(X_t | O) with O ~ P(O) (the planner's
draws, :meth:`planning.grasp_planner.GraspPlanner.draw_marginal`, joints clipped to the SAH's limits),
checks each for collisions as the planner does (pybullet: every link against the table, the object, the
obstacles and the hand itself; for the colliding ones, which of them it penetrates and with which links),
and closes the hand at each of the last step's draws (GraspIt!'s autograsp and the L1 epsilon quality,
:mod:`planning.autograsp`): the valid fraction of all of them and of the free ones tells a weak grasp from
draws that collide. It also follows the means from step to step as the planner's edges go (linear in
position and joints, a slerp of the wrist, at the collision checker's resolution) and names the steps where
that path passes through the table, an obstacle or the hand itself: each step's draws can be free while the
way from one step's to the next is blocked, and then the planner cannot follow the strategy (the grasped
object is not counted: a grasp's last means touch it). The model is placed in the scene's object pose, as
the planner places it. The checks and closings run on every core
(:class:`planning.closing_pool.ClosingPool`), with the same result.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from assets import sah
from assets.errors import InputError
from assets.q_layout import JOINTS
from inference.model import VariationModel
from planning.autograsp import HandCloser
from planning.closing_pool import ClosingPool
from planning.collision import CollisionChecker
from planning.grasp_planner import GraspPlanner
from planning.scene import Scene

from .report import success_interval

__all__ = ["HIT_KINDS", "Inspection", "blocked_mean_steps", "inspect_model", "plot_free_fraction"]

HIT_KINDS = ("object", "environment", "self")


@dataclass(frozen=True)
class Inspection:
    """What :func:`inspect_model` measured.

    Attributes:
        scene, object: the scene's name and the model's object.
        draws: draws per step.
        free_fraction: (T,) the fraction of collision-free draws per step.
        hits: what the colliding draws penetrate, per step the fraction of draws (T,) each: ``object``
            (the grasped object), ``environment`` (table and obstacles) and ``self`` (the hand itself); a
            draw can count in more than one.
        links: per step, the fraction of draws in which each hand link penetrates something (only the
            links that do in some draw), the most frequent first.
        valid_fraction: the fraction of the last step's draws whose closed grasp has epsilon >= ``epsilon``.
        valid_of_free: the same among the last step's collision-free draws (NaN if none is free): low
            where the grasp itself is weak, high where the draws fail by collision.
        best_epsilon: the best epsilon of those grasps.
        epsilon: the validity threshold.
        iterations, converged, solve_time_s: the model's solve (:class:`~inference.model.VariationModel`).
        constrained_steps: how many steps had a clearance factor or a joint-limit site.
        blocked_mean_steps: the steps t whose edge from the mean of step t to that of step t + 1 passes
            through the table, an obstacle or the hand itself (:func:`blocked_mean_steps`).
    """

    scene: str
    object: str
    draws: int
    free_fraction: tuple[float, ...]
    hits: dict[str, tuple[float, ...]]
    links: tuple[dict[str, float], ...]
    valid_fraction: float
    valid_of_free: float
    best_epsilon: float
    epsilon: float
    iterations: int
    converged: bool
    solve_time_s: float
    constrained_steps: int
    blocked_mean_steps: tuple[int, ...] = ()

    def to_json(self) -> str:
        """The measurements as JSON; ``valid_of_free`` is null where no last-step draw was free."""
        d = asdict(self)
        if math.isnan(d["valid_of_free"]):
            d["valid_of_free"] = None
        return json.dumps(d, indent=2)

    def _interval(self, fraction: float) -> str:
        """The 95 % Wilson interval of a fraction of this inspection's draws, as text."""
        low, high = success_interval(round(fraction * self.draws), self.draws)
        return f"95 % interval {low:.0%}-{high:.0%}"

    def summary(self) -> str:
        """A few lines for the terminal: the model, the worst step and the last step."""
        free = np.asarray(self.free_fraction)
        worst = int(np.argmin(free))
        of_free = (
            "no draw free" if math.isnan(self.valid_of_free) else f"{self.valid_of_free:.0%} of the free ones"
        )
        lines = [
            f"model: {self.iterations} iterations, {'converged' if self.converged else 'NOT converged'}, "
            f"solve {self.solve_time_s:.1f} s, {self.constrained_steps} constrained steps",
            f"collision-free draws ({self.draws} per step): min {free.min():.0%} at step {worst} "
            f"({self._interval(free.min())}; the least of {len(free)} estimates, biased low), "
            f"mean {free.mean():.0%}, last step {free[-1]:.0%}",
            f"at step {worst} the draws penetrate: "
            + ", ".join(f"{name} {self.hits[name][worst]:.0%}" for name in HIT_KINDS)
            + (f"; {_top_links(self.links[worst])}" if self.links[worst] else ""),
            f"last step: {self.valid_fraction:.0%} close to a valid grasp "
            f"({self._interval(self.valid_fraction)}; epsilon >= {self.epsilon:g}; {of_free}), "
            f"best epsilon {self.best_epsilon:.3f}",
        ]
        last = len(free) - 1
        if worst != last and self.links[last]:
            lines.append(f"at the last step {_top_links(self.links[last])}")
        below = np.flatnonzero(free < 0.5)
        if below.size:
            lines.append(f"steps below 50 % free: {_ranges(below)}")
        if self.blocked_mean_steps:
            lines.append(
                "the means' path passes through the table, an obstacle or the hand from steps "
                f"{_ranges(np.asarray(self.blocked_mean_steps))} to the next"
            )
        return "\n".join(lines)


def inspect_model(
    model: VariationModel,
    scene: Scene,
    draws: int,
    rng: np.random.Generator,
    epsilon: float = 0.05,
    processes: int | None = None,
) -> Inspection:
    """Measure ``model``'s marginals in ``scene`` (module docstring); the draws are checked and the last
    step's closed on ``processes`` processes (default: the machine's cores, at most 8;
    :class:`~planning.closing_pool.ClosingPool`, the same result on any number).

    Raises:
        InputError: ``draws`` below 1 or ``epsilon`` not in (0, 1).
    """
    if draws < 1:
        raise InputError(f"draws: expected at least 1, found {draws}")
    if not 0.0 < epsilon < 1.0:
        raise InputError(f"epsilon: expected a quality in (0, 1), found {epsilon}")
    with (
        GraspPlanner(scene, [model]) as planner,
        ClosingPool(scene, planner.closer.config, processes, world=planner.world) as pool,
    ):
        q = np.concatenate([planner.draw_marginal(None, draws, rng, k=t) for t in range(model.num_steps)])
        checked = pool.map_rows(_penetrations, q)
        last = planner.draw_marginal(1, draws, rng)
        grasps = pool.close_many(last)
        blocked = blocked_mean_steps(model, planner.world)
    free, hits, links = [], {name: [] for name in HIT_KINDS}, []
    for t in range(model.num_steps):
        step = checked[t * draws : (t + 1) * draws]
        counts = dict.fromkeys(HIT_KINDS, 0)
        link_counts: dict[str, int] = {}
        for _, kinds, inside in step:
            for kind in kinds:
                counts[kind] += 1
            for link in inside:
                link_counts[link] = link_counts.get(link, 0) + 1
        free.append(float(np.mean([is_free for is_free, _, _ in step])))
        for name in HIT_KINDS:
            hits[name].append(counts[name] / draws)
        ranked = sorted(link_counts.items(), key=lambda kv: (-kv[1], kv[0]))
        links.append({link: n / draws for link, n in ranked})
    qualities = np.array([g.quality for g in grasps])
    last_free = ~np.array([g.in_collision for g in grasps])
    return Inspection(
        scene=scene.name,
        object=model.object,
        draws=int(draws),
        free_fraction=tuple(free),
        hits={name: tuple(v) for name, v in hits.items()},
        links=tuple(links),
        valid_fraction=float(np.mean(qualities >= epsilon)),
        valid_of_free=float(np.mean(qualities[last_free] >= epsilon)) if last_free.any() else float("nan"),
        best_epsilon=float(qualities.max()),
        epsilon=float(epsilon),
        iterations=int(model.iterations),
        converged=bool(model.converged),
        solve_time_s=float(model.solve_time_s),
        constrained_steps=int(np.sum(model.constrained)),
        blocked_mean_steps=blocked,
    )


def blocked_mean_steps(model: VariationModel, world) -> tuple[int, ...]:
    """The steps t (0..T-2) whose edge from the mean of step t to the mean of step t + 1 passes through the
    table, an obstacle or the hand itself in ``world`` (a :class:`planning.world.World` of the scene).

    The means are placed at the scene's object pose with the joints clipped to the SAH's limits, and each
    edge is checked at :class:`planning.collision.CollisionChecker`'s resolution, the planner's, from its
    start (step 0's mean included in the first edge) to its end. Penetrations of the grasped object do not
    count.
    """
    q = model.world_means(world.scene.T_world_object)
    q[:, JOINTS] = sah.clip_joints(q[:, JOINTS])
    checker = CollisionChecker(world)

    def blocked(x: np.ndarray) -> bool:
        return bool(_hits(world, x)[1] - {"object"})

    out = []
    for t in range(model.num_steps - 1):
        world.forget_contacts()  # an edge through the table must not leave its points to the next one
        points = checker.edge_points(q[t], q[t + 1])
        if (t == 0 and blocked(q[0])) or any(blocked(x) for x in points):
            out.append(t)
    return tuple(out)


def _top_links(links: dict[str, float], n: int = 3) -> str:
    """``'links inside: a 24%, b 20%, c 18%'`` for the ``n`` most frequent of ``links`` (not empty)."""
    return "links inside: " + ", ".join(f"{link} {f:.0%}" for link, f in list(links.items())[:n])


def _penetrations(closer: HandCloser, rows: np.ndarray) -> list[tuple[bool, set[str], set[str]]]:
    """Per configuration: collision-free, and else which :data:`HIT_KINDS` and which links penetrate (a
    :data:`planning.closing_pool.RowsFn`)."""
    return [_hits(closer.world, x) for x in rows]


def _hits(world, x: np.ndarray) -> tuple[bool, set[str], set[str]]:
    """The hand at ``x`` in ``world``: collision-free, and else which :data:`HIT_KINDS` and which links
    penetrate."""
    if world.is_free(x):
        return True, set(), set()
    inside = [c for c in world.hand_contacts(x) if c.distance_m < 0]
    return False, {_kind(c.other, world.scene) for c in inside}, {c.link for c in inside}


def _kind(other: str, scene: Scene) -> str:
    """A contact's other body (:attr:`planning.world.Contact.other`) as one of :data:`HIT_KINDS`."""
    if other.startswith("self:"):
        return "self"
    return "object" if other == scene.object.name else "environment"


def plot_free_fraction(inspections: dict[str, Inspection], path: str | Path) -> Path:
    """The collision-free fraction per time step, one curve per labelled inspection, as a PNG."""
    from matplotlib.figure import Figure

    from .figures import _save_figure

    fig = Figure(figsize=(6.0, 3.2))
    ax = fig.add_subplot()
    for label, ins in inspections.items():
        ax.plot(np.arange(len(ins.free_fraction)), ins.free_fraction, label=label)
    ax.axhline(0.5, color="0.6", linestyle=":", linewidth=1)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("time step t")
    ax.set_ylabel("collision-free draws")
    ax.legend(fontsize=8, loc="lower left")
    fig.tight_layout()
    return _save_figure(fig, Path(path))


def _ranges(steps: np.ndarray) -> str:
    """``[3, 4, 5, 9]`` -> ``'3-5, 9'``."""
    out, start = [], int(steps[0])
    for a, b in zip(steps, [*steps[1:], None], strict=True):
        if b is None or b != a + 1:
            out.append(f"{start}" if start == a else f"{start}-{a}")
            start = None if b is None else int(b)
    return ", ".join(out)
