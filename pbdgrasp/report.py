"""The Table I report: the paper's values and ours side by side, success over time, and the best grasps.

Our columns, from the stored trials (:mod:`pbdgrasp.results_db`) of one run's rows, planners and trial
numbers:

* Quality: the best phi_o over all learned trials (the paper: "the best quality of all trials"), three
  decimals rounded down, so that a row whose best attempt stayed under epsilon does not print as it;
* ETA [s]: mean time to the first valid grasp over the *successful* learned trials (root sampling
  included), with the learned success rate;
* Nodes: mean tree size at success over the successful learned trials;
* MSE [mm^2]: the retargeting's fingertip mean square error, mean over the steps of tau_r (only the five
  demonstrated rows, as in the paper);
* ETA_0 [s]: mean time over the successful baseline trials, with the baseline success rate.

A second table gives every planner's valid grasps out of its trials with the 95 % Wilson score interval of
the success rate (scipy's ``binomtest``), so that a difference between planners or runs can be read
against the sampling error of 100 trials (68 of 100 is 58-76 %).

Figures: ``table1_success.png`` and ``best_grasps.png`` (:mod:`pbdgrasp.figures`).
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.stats import binomtest

from assets.io import atomic_write
from planning.planners import REGISTRY

from .figures import format_quality, planner_style, plot_success, render_best_grasps
from .paper import PAPER_TABLE1
from .results_db import TrialRecord

__all__ = [
    "RowSummary",
    "summarize",
    "success_interval",
    "write_report",
]

log = logging.getLogger(__name__)

_PAPER_PLANNERS = tuple(name for name, spec in REGISTRY.items() if spec.in_paper)


@dataclass(frozen=True)
class RowSummary:
    """Our Table I row (NaN where there is nothing to average).

    Attributes:
        row: the scene. trials, trials0: learned and baseline trials stored.
        quality: best phi_o of the learned trials. success: learned success rate in [0, 1].
        eta_s: mean time of the successful learned trials [s]. nodes: their mean tree size.
        mse_mm2: retargeting fingertip MSE [mm^2] (NaN for the rows the paper leaves blank).
        eta0_s: mean time of the successful baseline trials [s]. success0: baseline success rate.
        success_ci, success0_ci: the 95 % Wilson intervals of the two success rates (NaNs without trials).
    """

    row: str
    trials: int
    quality: float
    success: float
    eta_s: float
    nodes: float
    mse_mm2: float
    trials0: int
    eta0_s: float
    success0: float
    success_ci: tuple[float, float] = (math.nan, math.nan)
    success0_ci: tuple[float, float] = (math.nan, math.nan)


def _mean(xs) -> float:
    return float(np.mean(xs)) if len(xs) else math.nan


def success_interval(successes: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """The Wilson score interval of a success rate from ``successes`` of ``trials`` (NaNs for no trials)."""
    if trials == 0:
        return math.nan, math.nan
    ci = binomtest(successes, trials).proportion_ci(confidence_level=confidence, method="wilson")
    return float(ci.low), float(ci.high)


def summarize(
    records: Sequence[TrialRecord], rows: Sequence[str], mse_mm2: dict[str, float] | None = None
) -> list[RowSummary]:
    """One :class:`RowSummary` per row from the stored trials.

    Args:
        records: the trials (of any rows; only ``rows`` are summarized).
        rows: the rows, in order.
        mse_mm2: retargeting MSE per row; shown only for rows whose demonstration is their own object.
    """
    out = []
    for row in rows:
        lr = [r for r in records if r.row == row and r.planner == "learned"]
        br = [r for r in records if r.row == row and r.planner == "baseline"]
        ok = [r for r in lr if r.success]
        ok0 = [r for r in br if r.success]
        paper = PAPER_TABLE1.get(row)
        show_mse = paper is not None and paper.mse_mm2 is not None
        out.append(
            RowSummary(
                row=row,
                trials=len(lr),
                quality=max((r.quality for r in lr), default=math.nan),
                success=len(ok) / len(lr) if lr else math.nan,
                eta_s=_mean([r.eta_s for r in ok]),
                nodes=_mean([r.nodes for r in ok]),
                mse_mm2=float((mse_mm2 or {}).get(row, math.nan)) if show_mse else math.nan,
                trials0=len(br),
                eta0_s=_mean([r.eta_s for r in ok0]),
                success0=len(ok0) / len(br) if br else math.nan,
                success_ci=success_interval(len(ok), len(lr)),
                success0_ci=success_interval(len(ok0), len(br)),
            )
        )
    return out


def _missing(x: float | None) -> bool:
    return x is None or (isinstance(x, float) and math.isnan(x))


def _f(x: float | None, fmt: str) -> str:
    return "—" if _missing(x) else format(x, fmt)


def _eta0(eta: float | None, rate: float) -> str:
    if _missing(rate):
        return "—"
    if rate == 0:
        return "0%"
    return f"{_f(eta, '.2f')} ({rate:.0%})"


def _planner_table(
    title: str,
    intro: str,
    records: Sequence[TrialRecord],
    rows: Sequence[str],
    planners: Sequence[str],
    cell: Callable[[list[TrialRecord]], str],
) -> list[str]:
    """Markdown lines of a table with one column per planner: ``cell`` of a row's trials of a planner."""
    if not planners:
        return []
    lines = [
        f"## {title}",
        "",
        intro,
        "",
        "| Row | " + " | ".join(planner_style(p)[1] for p in planners) + " |",
        "|---|" + "---|" * len(planners),
    ]
    for row in rows:
        label = PAPER_TABLE1[row].label if row in PAPER_TABLE1 else row
        cells = []
        for p in planners:
            rec = [r for r in records if r.row == row and r.planner == p]
            cells.append(cell(rec) if rec else "—")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def _other_planners(records: Sequence[TrialRecord], rows: Sequence[str]) -> list[str]:
    """Markdown lines for the planners of the database beyond the paper's two (OMPL, goal trees)."""

    def cell(rec: list[TrialRecord]) -> str:
        ok = [r for r in rec if r.success]
        return (
            f"{len(ok) / len(rec):.0%} ({len(rec)}), {_f(_mean([r.eta_s for r in ok]), '.2f')}, "
            f"{format_quality(max(r.quality for r in rec))}"
        )

    others = sorted({r.planner for r in records} - set(_PAPER_PLANNERS))
    intro = (
        "Not in the paper's table; the same rows, strategies, roots and time limit. Goal trees: the learned "
        "planner whose valid last-step samples that the tree did not reach root a second tree; goal region: "
        "goal trees also rooted at draws of N(b_T, B_T) by OMPL's RRTConnect rule; OMPL: its RRTConnect, "
        "uniform samples and a goal region of collision-free valid N(b_T, B_T) draws (OMPL's own sampler "
        "uses its process-global RNG, so its trials do not repeat one by one). Per cell: success rate "
        "(trials), mean ETA over the successful trials (s), best phi_o."
    )
    return _planner_table("Other planners", intro, records, rows, others, cell)


def _success_rates(records: Sequence[TrialRecord], rows: Sequence[str]) -> list[str]:
    """Markdown lines: every planner's valid grasps per row with the 95 % Wilson interval."""

    def cell(rec: list[TrialRecord]) -> str:
        k = sum(r.success for r in rec)
        lo, hi = success_interval(k, len(rec))
        return f"{k} / {len(rec)} ({lo:.0%}-{hi:.0%})"

    present = {r.planner for r in records}
    planners = [p for p in _PAPER_PLANNERS if p in present] + sorted(present - set(_PAPER_PLANNERS))
    intro = "Valid grasps out of the trials, and the 95 % Wilson score interval of the success rate."
    return _planner_table("Success rates", intro, records, rows, planners, cell)


def _markdown(summaries: list[RowSummary], info: dict, extra: Sequence[str] = ()) -> str:
    lines = [f"# Table I: {info.get('title', 'reproduction')}", ""]
    if info.get("status"):
        lines += [f"**{info['status']}**", ""]
    lines += [
        "Each cell: the paper's value \\| ours. Quality: best phi_o of the learned trials (below epsilon "
        "where none was valid); "
        "ETA: mean time to a valid grasp over the successful learned trials (learned success rate in "
        "brackets); Nodes: mean tree size at success; MSE: retargeting fingertip mean square error over "
        "the steps of tau_r; ETA_0: the baseline RRT's mean time over its successful trials (success rate "
        "in brackets, 0% = no success).",
        "",
        "| Row | Quality | ETA (s) | Nodes | MSE (mm²) | ETA_0 (s) | trials |",
        "|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        p = PAPER_TABLE1[s.row]
        p_mse = _f(p.mse_mm2, ".1f")
        lines.append(
            f"| {p.label} | {p.quality:.2f} \\| {format_quality(s.quality)} "
            f"| {p.eta_s:g} \\| {_f(s.eta_s, '.2f')} ({_f(s.success, '.0%')}) "
            f"| {p.nodes} \\| {_f(s.nodes, '.0f')} "
            f"| {p_mse} \\| {_f(s.mse_mm2, '.1f')} "
            f"| {_eta0(p.eta0_s, p.eta0_success)} \\| {_eta0(s.eta0_s, s.success0)} "
            f"| {s.trials} / {s.trials0} |"
        )
    lines += [""] + list(extra)
    lines += ["## Settings", ""]
    for k, v in info.get("settings", {}).items():
        lines.append(f"- {k}: {v}")
    lines += ["", "## Run", ""]
    for k, v in info.get("run", {}).items():
        lines.append(f"- {k}: {v}")
    lines += [
        "",
        "## Figures",
        "",
        "- `table1_success.png`: fraction of the trials solved by time t (each planner, one panel per row).",
        "- `best_grasps.png`: the best learned grasp of each row (closed hand, pybullet render).",
        "",
    ]
    return "\n".join(lines)


def _csv(summaries: list[RowSummary]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(
        ["row", "label", "paper_quality", "quality", "paper_eta_s", "eta_s", "success", "paper_nodes",
         "nodes", "paper_mse_mm2", "mse_mm2", "paper_eta0_s", "paper_success0", "eta0_s", "success0",
         "trials", "trials0", "success_ci_low", "success_ci_high", "success0_ci_low", "success0_ci_high"]
    )  # fmt: skip

    def num(x):
        return "" if _missing(x) else f"{x:.6g}"

    for s in summaries:
        p = PAPER_TABLE1[s.row]
        w.writerow(
            [s.row, p.label, num(p.quality), num(s.quality), num(p.eta_s), num(s.eta_s), num(s.success),
             p.nodes, num(s.nodes), num(p.mse_mm2), num(s.mse_mm2), num(p.eta0_s), num(p.eta0_success),
             num(s.eta0_s), num(s.success0), s.trials, s.trials0, *map(num, s.success_ci),
             *map(num, s.success0_ci)]
        )  # fmt: skip
    return buf.getvalue()


def write_report(
    records: Sequence[TrialRecord],
    rows: Sequence[str],
    planners: Sequence[str],
    out_dir,
    *,
    time_limit_s: float,
    mse_mm2: dict[str, float] | None = None,
    info: dict | None = None,
    renders: bool = True,
    fallback_q: dict[str, np.ndarray] | None = None,
) -> list[Path]:
    """Write ``table1.md``, ``table1.csv``, ``table1_success.png`` and ``best_grasps.png`` to ``out_dir``.

    Args:
        records: the stored trials to report.
        rows, planners: what to report, in order.
        out_dir: the report folder (created if missing).
        time_limit_s: the x range of the success plot [s].
        mse_mm2: retargeting MSE per row.
        info: ``title``, ``status`` (a bold line), ``settings`` and ``run`` (dicts listed in the md).
        renders: also render the best grasps (needs pybullet).
        fallback_q: see :func:`render_best_grasps`.

    Returns:
        The files written.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summaries = summarize(records, rows, mse_mm2)
    info = dict(info or {})
    info.setdefault("settings", {})
    md = _markdown(summaries, info, _success_rates(records, rows) + _other_planners(records, rows))
    files = [
        atomic_write(out / "table1.md", lambda f: f.write(md.encode())),
        atomic_write(out / "table1.csv", lambda f: f.write(_csv(summaries).encode())),
        plot_success(records, rows, planners, time_limit_s, out / "table1_success.png"),
    ]
    if renders:
        files.append(render_best_grasps(records, rows, out / "best_grasps.png", fallback_q=fallback_q))
    log.info("report: %s", ", ".join(str(f) for f in files))
    return files


def summaries_as_dicts(summaries: list[RowSummary]) -> list[dict]:
    """Plain dicts of :func:`summarize`'s rows (for JSON)."""
    return [asdict(s) for s in summaries]
