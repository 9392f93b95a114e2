"""The report's figures: success over time per planner and row, and renders of each row's best grasp.

``table1_success.png``: fraction of the trials solved by time t, one curve per planner, one panel per row
(as OMPL's Planner Arena draws its progress plots); ``best_grasps.png``: pybullet renders of the best
learned grasp of each row, closed hand (the paper's Fig. 7 and 9). Each planner's colour, label and line
style: :data:`PLANNER_STYLE`.
"""

from __future__ import annotations

import io
import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from assets.io import atomic_write

from .paper import PAPER_TABLE1
from .results_db import TrialRecord

__all__ = [
    "PLANNER_STYLE",
    "best_trials",
    "format_quality",
    "planner_style",
    "plot_success",
    "render_best_grasps",
]


def format_quality(x: float | None) -> str:
    """A quality to 3 decimals, rounded down (a value under epsilon never prints as epsilon); "—" if
    missing. The report's tables and figures print qualities with it alike."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "—"
    return f"{math.floor(x * 1000 + 1e-9) / 1000:.3f}"


log = logging.getLogger(__name__)

PLANNER_STYLE = {
    "learned": ("tab:blue", "learned P(Y)", "-"),
    "baseline": ("tab:red", "baseline RRT", "--"),
    "ompl": ("tab:green", "OMPL RRTConnect", ":"),
    "bidirectional": ("tab:purple", "learned P(Y), goal trees", "-."),
    "goal_region": ("tab:orange", "learned P(Y), goal region", (0, (3, 1, 1, 1, 1, 1))),
}
"""planner -> (matplotlib colour, label, line style)."""


def planner_style(planner: str) -> tuple[str, str, str]:
    """The colour, label and line style of ``planner`` (black, its name, solid for an unknown one)."""
    return PLANNER_STYLE.get(planner, ("k", planner, "-"))


def _save_figure(fig, path: Path) -> Path:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return atomic_write(path, lambda f: f.write(buf.getvalue()))


def _grid(n: int) -> tuple[int, int]:
    cols = min(4, n)
    return math.ceil(n / cols), cols


def plot_success(
    records: Sequence[TrialRecord], rows: Sequence[str], planners: Sequence[str], time_limit_s: float, path
) -> Path:
    """Fraction of trials solved by time t (0..time limit) per row and planner, one panel per row."""
    from matplotlib.figure import Figure

    nr, nc = _grid(len(rows) + 1)
    fig = Figure(figsize=(3.0 * nc, 2.4 * nr), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False).ravel()
    t = np.linspace(0.0, time_limit_s, 401)
    for ax, row in zip(axes, rows, strict=False):
        for planner in planners:
            rec = [r for r in records if r.row == row and r.planner == planner]
            if not rec:
                continue
            eta = np.sort([r.eta_s for r in rec if r.success])
            solved = np.searchsorted(eta, t, side="right") / len(rec)
            color, label, ls = planner_style(planner)
            ax.step(t, solved, where="post", color=color, ls=ls, lw=1.5, label=f"{label} (n={len(rec)})")
        ax.set_title(PAPER_TABLE1[row].label if row in PAPER_TABLE1 else row, fontsize=9)
        ax.set_xlim(0, time_limit_s)
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=7)
        ax.set_xlabel("time [s]", fontsize=7)
        ax.set_ylabel("solved fraction", fontsize=7)
    legend_ax = axes[len(rows)]
    handles = [
        legend_ax.plot([], [], color=c, ls=ls, label=label)[0]
        for c, label, ls in (planner_style(p) for p in planners)
    ]
    legend_ax.legend(handles=handles, loc="center", fontsize=9, frameon=False)
    legend_ax.axis("off")
    for ax in axes[len(rows) + 1 :]:
        ax.axis("off")
    fig.suptitle("Success over time (fraction of trials with a valid grasp by time t)", fontsize=10)
    return _save_figure(fig, Path(path))


def best_trials(records: Sequence[TrialRecord], rows: Sequence[str]) -> dict[str, TrialRecord | None]:
    """Per row the learned trial with the highest quality that has a grasp (any planner if none)."""
    out = {}
    for row in rows:
        cand = [r for r in records if r.row == row and "closed_q" in json.loads(r.grasp_json)]
        learned = [r for r in cand if r.planner == "learned"]
        pool = learned or cand
        out[row] = max(pool, key=lambda r: (r.success, r.quality), default=None)
    return out


def _close_camera(scene, zoom: float) -> dict:
    from planning.camera import default_camera

    cam = default_camera(scene, "side")
    target = np.asarray(cam["target"], dtype=float)
    return dict(cam, eye=target + zoom * (np.asarray(cam["eye"], dtype=float) - target))


def render_best_grasps(
    records: Sequence[TrialRecord],
    rows: Sequence[str],
    path,
    fallback_q: dict[str, np.ndarray] | None = None,
    size_px: tuple[int, int] = (400, 300),
    zoom: float = 0.6,
) -> Path:
    """A grid of pybullet renders of each row's best grasp (closed hand); see :func:`best_trials`.

    Args:
        records: the stored trials.
        rows: one panel each.
        path: the PNG to write.
        fallback_q: per row a configuration (19,) in the world to show when no grasp was evaluated (e.g.
            the strategy's mean final step), labelled as such.
        size_px: (width, height) of each render.
        zoom: the camera's distance as a fraction of :func:`planning.camera.default_camera`'s side view.
    """
    from matplotlib.figure import Figure

    from planning.world import World

    best = best_trials(records, rows)
    nr, nc = _grid(len(rows))
    fig = Figure(figsize=(3.2 * nc, 2.7 * nr), layout="constrained")
    axes = fig.subplots(nr, nc, squeeze=False).ravel()
    for ax, row in zip(axes, rows, strict=False):
        rec = best[row]
        with World(row) as world:
            cam = _close_camera(world.scene, zoom)
            q, title = None, "no grasp evaluated"
            if rec is not None:
                q = np.asarray(json.loads(rec.grasp_json)["closed_q"], dtype=float)
                status = "valid" if rec.success else "best attempt, NOT valid"
                title = f"{rec.planner} #{rec.trial}: eps {format_quality(rec.quality)} ({status})"
            elif fallback_q and row in fallback_q:
                q = np.asarray(fallback_q[row], dtype=float)
                title = "no grasp evaluated; strategy's mean final step"
            img = world.render(q, width=size_px[0], height=size_px[1], camera=cam)
        ax.imshow(img)
        label = PAPER_TABLE1[row].label if row in PAPER_TABLE1 else row
        ax.set_title(f"{label}\n{title}", fontsize=8)
        ax.axis("off")
    for ax in axes[len(rows) :]:
        ax.axis("off")
    return _save_figure(fig, Path(path))
