"""The results database of long runs: one SQLite row per finished trial (standard library sqlite3).

A trial row is written as soon as the trial ends, in WAL mode with one short transaction per row, so a
run killed at any moment loses nothing that finished and repeats nothing on resume: the runner asks
:func:`finished_keys` first and skips those trials. Only the coordinating process writes.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
from dataclasses import asdict, dataclass, fields
from pathlib import Path

__all__ = ["TrialRecord", "open_db", "finished_keys", "insert_trial", "load_trials", "source_commit"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS trials (
    row TEXT NOT NULL,
    planner TEXT NOT NULL,
    trial INTEGER NOT NULL,
    seed INTEGER NOT NULL,
    success INTEGER NOT NULL,
    eta_s REAL NOT NULL,
    nodes INTEGER NOT NULL,
    quality REAL NOT NULL,
    collision_checks INTEGER NOT NULL,
    quality_evaluations INTEGER NOT NULL,
    message TEXT NOT NULL,
    git_commit TEXT NOT NULL,
    params_json TEXT NOT NULL,
    grasp_json TEXT NOT NULL,
    PRIMARY KEY (row, planner, trial)
)
"""


def source_commit(root: str | os.PathLike | None = None) -> str:
    """The commit of a source tree (default: this package's), for a trial's provenance: ``git rev-parse
    HEAD``, with ``-dirty`` appended when tracked files outside ``results/`` differ from it (a run of
    uncommitted code), or ``"unknown"`` outside a git checkout."""
    root = Path(__file__).resolve().parent.parent if root is None else Path(root)

    def git(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, timeout=10)

    try:
        head = git("rev-parse", "HEAD")
        if head.returncode != 0 or not head.stdout.strip():
            return "unknown"
        # exit status 1: tracked sources differ from HEAD (the reports under results/ do not count)
        dirty = git("diff", "--quiet", "HEAD", "--", ".", ":(exclude)results").returncode == 1
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head.stdout.strip() + ("-dirty" if dirty else "")


@dataclass(frozen=True)
class TrialRecord:
    """One finished planning trial (a row of the ``trials`` table)."""

    row: str
    planner: str
    trial: int
    seed: int
    success: bool
    eta_s: float
    nodes: int
    quality: float
    collision_checks: int
    quality_evaluations: int
    message: str
    git_commit: str
    params_json: str
    grasp_json: str = "{}"

    def key(self) -> tuple[str, str, int]:
        return (self.row, self.planner, self.trial)

    def deterministic_fields(self) -> dict:
        """The fields that must not depend on timing or on the number of workers."""
        d = asdict(self)
        for k in ("eta_s", "git_commit"):
            d.pop(k)
        return d


def open_db(path: str | os.PathLike) -> sqlite3.Connection:
    """Open (creating if needed) a results database in WAL mode."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(path, timeout=30.0)
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute("PRAGMA synchronous=NORMAL")
    conn.execute(_SCHEMA)
    conn.commit()
    return conn


def finished_keys(conn: sqlite3.Connection) -> set[tuple[str, str, int]]:
    """The (row, planner, trial) keys already stored."""
    return {(r, p, int(t)) for r, p, t in conn.execute("SELECT row, planner, trial FROM trials")}


def insert_trial(conn: sqlite3.Connection, rec: TrialRecord) -> None:
    """Store one trial in its own transaction; a trial already stored is left as it is."""
    names = [f.name for f in fields(TrialRecord)]
    values = [getattr(rec, n) for n in names]
    values[names.index("success")] = int(rec.success)
    with conn:
        conn.execute(
            f"INSERT OR IGNORE INTO trials ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})",
            values,
        )


def load_trials(conn: sqlite3.Connection, rows: list[str] | None = None) -> list[TrialRecord]:
    """All stored trials (optionally of some rows), ordered by row, planner and trial."""
    names = [f.name for f in fields(TrialRecord)]
    out = []
    for values in conn.execute(f"SELECT {', '.join(names)} FROM trials ORDER BY row, planner, trial"):
        d = dict(zip(names, values, strict=True))
        d["success"] = bool(d["success"])
        if rows is None or d["row"] in rows:
            out.append(TrialRecord(**d))
    return out


def params_json(params: dict) -> str:
    """Canonical JSON of a run's parameters (sorted keys)."""
    return json.dumps(params, sort_keys=True)


def record_from_plan(
    result,
    *,
    row: str,
    planner: str,
    trial: int,
    seed: int,
    git_commit: str,
    params_json: str,
    eta_s: float | None = None,
) -> TrialRecord:
    """The :class:`TrialRecord` of one planning query's :class:`~planning.rrt_connect.PlanResult`.

    Args:
        result: the query's result.
        row, planner, trial, seed, git_commit, params_json: the trial's key and provenance.
        eta_s: the query's wall time [s] as measured by the caller; default the planner's own
            ``result.eta_s``.

    The grasp column holds the closed grasp (``closed_q``, ``quality``, ``contact_links``) of the best
    phi_o evaluation and, for a solved trial, the path's last configuration ``q`` (19,) [m, rad].
    """
    grasp: dict = {}
    if result.grasp is not None:
        grasp = {
            "closed_q": [float(x) for x in result.grasp.closed_q],
            "quality": float(result.grasp.quality),
            "contact_links": list(result.grasp.contact_links),
        }
    if result.success and len(result.path):
        grasp["q"] = [float(x) for x in result.path[-1]]
    return TrialRecord(
        row=row,
        planner=planner,
        trial=int(trial),
        seed=int(seed),
        success=bool(result.success),
        eta_s=float(result.eta_s if eta_s is None else eta_s),
        nodes=int(result.nodes),
        quality=float(result.quality),
        collision_checks=int(result.extra.get("collision_checks_total", result.collision_checks)),
        quality_evaluations=int(result.quality_evaluations),
        message=result.message,
        git_commit=git_commit,
        params_json=params_json,
        grasp_json=json.dumps(grasp),
    )
