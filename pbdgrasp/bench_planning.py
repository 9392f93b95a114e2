"""The planning part of ``pbdgrasp bench`` (:mod:`pbdgrasp.bench`): every planner of
:data:`planning.planners.PLANNERS` on :data:`PLANNING_SCENES`, a few trials each, with the Table I strategies
(or the in-code quick model, or a model given with ``--model``)."""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

import numpy as np

from .bench_fixtures import quick_model, strategy_model

if TYPE_CHECKING:
    from .bench import BenchConfig

__all__ = ["PLANNING_SCENES", "bench_planning"]

log = logging.getLogger(__name__)

PLANNING_SCENES = ("ham", "chips_between_cans", "jam_hole")


def _planner_row(results) -> dict:
    ok = [r for r in results if r.success]
    total = sum(r.eta_s for r in results)
    t_col = sum(r.time_collision_s for r in results)
    t_q = sum(r.time_quality_s for r in results)
    return {
        "trials": len(results),
        "success_rate": len(ok) / len(results),
        "median_eta_s": float(np.median([r.eta_s for r in ok])) if ok else None,
        "median_nodes": float(np.median([r.nodes for r in results])),
        "median_collision_checks": float(np.median([r.collision_checks for r in results])),
        "quality_evaluations": int(sum(r.quality_evaluations for r in results)),
        "share_collision": t_col / total if total > 0 else None,
        "share_quality": t_q / total if total > 0 else None,
        "share_overhead": (total - t_col - t_q) / total if total > 0 else None,
        "messages": sorted({r.message for r in results if not r.success}),
    }


def bench_planning(config: BenchConfig, rng: np.random.Generator) -> dict:
    """Success, ETA, nodes, checks and time shares of each planner of ``PLANNERS`` on ``PLANNING_SCENES``.

    Trial ``i`` of every planner uses the same spawned seed, so the planners start from the same roots.
    """
    from planning.grasp_planner import GraspPlanner, PlanningSettings
    from planning.planners import PLANNERS

    scenes = ("ham",) if config.quick else PLANNING_SCENES
    out = {}
    for scene_name, seq in zip(scenes, rng.bit_generator.seed_seq.spawn(len(scenes)), strict=True):
        given = dict(config.models)
        if scene_name in given:
            from inference.model import VariationModel

            model, info = VariationModel.load(given[scene_name]), {"model": given[scene_name], "given": True}
        elif config.quick:
            model, info = quick_model(), {"model": "built in code (quick)"}
        else:
            model, info = strategy_model(scene_name, config.cache_dir, config.retarget_max_nfev)
        seeds = seq.spawn(config.trials)
        rows = {}
        with GraspPlanner(scene_name, [model]) as planner:
            for name in PLANNERS:
                settings = PlanningSettings(planner=name, time_limit_s=config.time_limit_s)
                results = [planner.plan(np.random.default_rng(s), settings) for s in seeds]
                rows[name] = _planner_row(results)
                log.info("bench %s %s: %s", scene_name, name, rows[name])
        ratios = {}
        for other in ("ompl", "baseline"):
            a, b = rows["learned"]["median_eta_s"], rows[other]["median_eta_s"]
            ratios[f"learned_over_{other}"] = a / b if a is not None and b else None
        out[scene_name] = {"strategy": info, "planners": rows, "ratios": ratios}
    return out
