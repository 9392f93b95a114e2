"""The peer planner: OMPL's RRTConnect on the same problems as our planner.

OMPL plans in the compound space R^3 x SO(3) x R^13 with uniform sampling inside the same bounds, the
same validity checker (``is_free``) and a goal region whose samples are drawn from N(b_T, B_T) and kept
only when their grasp quality phi_o reaches the threshold. OMPL 2.0's Python bindings accept a
``GoalSampleableRegion`` subclass for RRTConnect (a Python state sampler is ignored, so the peer cannot be
given our learned sampler: it is the standard library planner, not a second implementation of ours).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from assets.q_layout import JOINTS, N_JOINTS, POS, Q_DIM, ROT

from .rrt_connect import PlanResult

__all__ = ["plan_ompl"]


_SEEDED = []  # OMPL's RNG is process-global and accepts a seed only before its first draw


def _import_ompl(seed: int):
    from ompl import base as ob
    from ompl import geometric as og
    from ompl import util as ou

    ou.setLogLevel(ou.LogLevel.LOG_ERROR)
    if not _SEEDED:
        ou.RNG.setSeed(seed)
        _SEEDED.append(seed)
    return ob, og


def plan_ompl(
    roots: np.ndarray,
    goal_sample_fn: Callable[[np.random.Generator], np.ndarray],
    is_free: Callable[[np.ndarray], bool],
    quality_fn: Callable[[np.ndarray], tuple[float, Any]],
    wrist_bounds_m: tuple[np.ndarray, np.ndarray],
    joint_limits: np.ndarray,
    rng: np.random.Generator,
    time_limit_s: float = 10.0,
    quality_threshold: float = 0.05,
    range_units: float = 0.05,
    resolution: float = 0.005,
    goal_tries: int = 20,
) -> PlanResult:
    """Plan with OMPL's RRTConnect from ``roots`` to a grasp of quality >= ``quality_threshold``.

    Args:
        roots: (R, 19) collision-free start configurations ``[p, rotvec, joints]`` (the same as ours).
        goal_sample_fn: draws one configuration (19,) from N(b_T, B_T).
        is_free: configuration validity (collision-free).
        quality_fn: phi_o, ``q -> (quality, payload)``.
        wrist_bounds_m: ``(low (3,), high (3,))`` of the wrist position.
        joint_limits: (13, 2) [rad].
        rng: randomness of the goal sampler. OMPL's own uniform sampler uses OMPL's process-global RNG,
            seeded from ``rng`` once per process: OMPL runs are reproducible only as a first run in a
            fresh process.
        time_limit_s: OMPL's solve time.
        quality_threshold: epsilon.
        range_units: RRTConnect's range as a fraction of the space's maximum extent.
        resolution: state validity checking resolution, as a fraction of the maximum extent.
        goal_tries: draws of N(b_T, B_T) per goal sample before giving up on that call.

    Returns:
        A :class:`PlanResult`; ``nodes`` is the number of vertices of OMPL's planner data.
    """
    ob, og = _import_ompl(int(rng.integers(1, 2**31 - 1)))
    lo, hi = (np.asarray(b, dtype=float) for b in wrist_bounds_m)
    joint_limits = np.asarray(joint_limits, dtype=float)

    space = ob.CompoundStateSpace()
    r3 = ob.RealVectorStateSpace(3)
    b3 = ob.RealVectorBounds(3)
    for i in range(3):
        b3.setLow(i, float(lo[i]))
        b3.setHigh(i, float(hi[i]))
    r3.setBounds(b3)
    rj = ob.RealVectorStateSpace(N_JOINTS)
    bj = ob.RealVectorBounds(N_JOINTS)
    for i in range(N_JOINTS):
        bj.setLow(i, float(joint_limits[i, 0]))
        bj.setHigh(i, float(joint_limits[i, 1]))
    rj.setBounds(bj)
    # weights: 1 m of wrist travel ~ 1 rad of wrist rotation / 10 ~ 1 rad of the joints / 10
    space.addSubspace(r3, 1.0)
    space.addSubspace(ob.SO3StateSpace(), 0.1)
    space.addSubspace(rj, 0.1)

    def to_q(state) -> np.ndarray:
        rot = state[1]
        q = np.empty(Q_DIM)
        q[POS] = [state[0][i] for i in range(3)]
        q[ROT] = Rotation.from_quat([rot.x, rot.y, rot.z, rot.w]).as_rotvec()
        q[JOINTS] = [state[2][i] for i in range(N_JOINTS)]
        return q

    def from_q(q: np.ndarray, state) -> None:
        for i in range(3):
            state[0][i] = float(q[i])
        x, y, z, w = Rotation.from_rotvec(q[ROT]).as_quat()
        rot = state[1]
        rot.x, rot.y, rot.z, rot.w = float(x), float(y), float(z), float(w)
        for i in range(N_JOINTS):
            state[2][i] = float(q[6 + i])

    stats = {"checks": 0, "evals": 0, "t_col": 0.0, "t_q": 0.0, "best": 0.0, "payload": None, "goal": None}

    def valid(state) -> bool:
        t = time.perf_counter()
        ok = space.satisfiesBounds(state) and bool(is_free(to_q(state)))
        stats["t_col"] += time.perf_counter() - t
        stats["checks"] += 1
        return ok

    si = ob.SpaceInformation(space)
    si.setStateValidityChecker(valid)
    si.setStateValidityCheckingResolution(resolution)
    si.setup()

    class _GraspGoal(ob.GoalSampleableRegion):
        """Goal states are draws of N(b_T, B_T) whose grasp quality reaches the threshold."""

        def __init__(self, si_):
            super().__init__(si_)
            self.setThreshold(1e-9)
            self.goals: list[np.ndarray] = []

        def distanceGoal(self, state) -> float:
            if not self.goals:
                return np.inf
            q = to_q(state)
            return float(min(np.linalg.norm(q - g) for g in self.goals))

        def sampleGoal(self, state) -> None:
            for _ in range(goal_tries):
                q = goal_sample_fn(rng)
                if not is_free(q):
                    continue
                t = time.perf_counter()
                quality, payload = quality_fn(q)
                stats["t_q"] += time.perf_counter() - t
                stats["evals"] += 1
                if quality > stats["best"]:
                    stats["best"], stats["payload"] = float(quality), payload
                if quality >= quality_threshold:
                    self.goals.append(q)
                    from_q(q, state)
                    return
            # nothing valid found: hand back a state outside the bounds, which the checker rejects
            bad = np.zeros(Q_DIM)
            bad[POS] = hi + 1.0
            from_q(bad, state)

        def maxSampleCount(self) -> int:
            return 1 << 30

    pdef = ob.ProblemDefinition(si)
    state = space.allocState()
    for r in np.atleast_2d(roots):
        from_q(r, state)
        pdef.addStartState(state)
    goal = _GraspGoal(si)
    pdef.setGoal(goal)
    planner = og.RRTConnect(si)
    planner.setRange(range_units * space.getMaximumExtent())
    planner.setProblemDefinition(pdef)
    planner.setup()

    t0 = time.perf_counter()
    solved = planner.solve(float(time_limit_s))
    eta = time.perf_counter() - t0
    data = ob.PlannerData(si)
    planner.getPlannerData(data)
    nodes = int(data.numVertices())
    exact = bool(solved) and pdef.hasExactSolution()
    path = np.empty((0, Q_DIM))
    quality = stats["best"]
    payload = stats["payload"]
    if exact:
        sol = pdef.getSolutionPath()
        path = np.array([to_q(sol.getState(i)) for i in range(sol.getStateCount())])
        # the path ends at one of the goal samples; report that grasp's quality
        last = path[-1]
        j = int(np.argmin([np.linalg.norm(last - g) for g in goal.goals]))
        quality, payload = quality_fn(goal.goals[j])
    return PlanResult(
        success=exact,
        message="valid grasp found" if exact else f"no solution within {time_limit_s:g} s",
        eta_s=eta,
        nodes=nodes,
        quality=float(quality),
        path=path,
        grasp=payload,
        quality_evaluations=stats["evals"],
        collision_checks=stats["checks"],
        iterations=0,
        time_quality_s=stats["t_q"],
        time_collision_s=stats["t_col"],
    )
