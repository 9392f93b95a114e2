"""The results database of long runs: one SQLite row per finished trial (standard library sqlite3).

A trial row is written as soon as the trial ends, in WAL mode with one short transaction per row, so a
run killed at any moment loses nothing that finished and repeats nothing on resume: the runner asks
:func:`finished_keys` first and skips those trials. Only the coordinating process writes.

A database is checked when it is opened, before any work: an existing file must be an SQLite database
with this project's ``trials`` table and a schema version this code reads (table ``meta``), and must not
be locked by another writer. Every trial stores the parameters of its run (``params_json``: scene or row,
the models by content hash, the planner's settings, the seed); :func:`check_params` refuses to add trials
of the same row and planner made with other parameters, and :func:`set_aside` moves a database out of the
way (keeping it) for a fresh start.
"""

from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import time
from dataclasses import asdict, dataclass, fields
from pathlib import Path

from assets.errors import InputError

__all__ = [
    "SCHEMA_VERSION",
    "TrialRecord",
    "open_db",
    "set_aside",
    "check_params",
    "finished_keys",
    "insert_trial",
    "load_trials",
    "find_trial",
    "source_commit",
]

SCHEMA_VERSION = 2
"""Version 1: the ``trials`` table alone; 2: with the ``meta`` table (read and upgraded in place)."""

_META = "CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL)"
_SQLITE_HEADER = b"SQLite format 3\x00"

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


def _columns() -> list[str]:
    return [f.name for f in fields(TrialRecord)]


def open_db(
    path: str | os.PathLike,
    *,
    create: bool = True,
    lock_timeout_s: float = 5.0,
    busy_timeout_s: float = 600.0,
) -> sqlite3.Connection:
    """Open a results database in WAL mode, checked (module docstring), creating it if missing.

    Args:
        path: the database file.
        create: make a new database if ``path`` does not exist (``False``: refuse).
        lock_timeout_s: how long to wait at opening for another writer to finish.
        busy_timeout_s: how long a later write waits for another writer (long, so that a finished trial
            is not lost to a reader's brief lock).

    Raises:
        InputError: missing (with ``create=False``), not a regular file, not an SQLite database, damaged,
            of another schema or a newer version, or locked by another process.
    """
    path = Path(path)
    existed = path.exists()
    if existed:
        if not path.is_file():
            raise InputError("is not a regular file; expected a results database", path)
        with path.open("rb") as f:
            header = f.read(len(_SQLITE_HEADER))
        if header != _SQLITE_HEADER:
            raise InputError("is not an SQLite database (an empty, truncated or foreign file)", path)
    elif not create:
        raise InputError("no such results database", path)
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
    conn = sqlite3.connect(path, timeout=lock_timeout_s)
    try:
        _check_and_upgrade(conn, path, existed)
    except sqlite3.OperationalError as exc:
        conn.close()
        if "locked" in str(exc) or "busy" in str(exc):
            raise InputError(
                "is locked by another process (a run still writing to it?); wait for it to finish or use "
                "another database",
                path,
            ) from None
        raise InputError(f"is not a readable results database ({exc})", path) from None
    except sqlite3.DatabaseError as exc:
        conn.close()
        raise InputError(f"is not a readable SQLite database ({exc})", path) from None
    except InputError:
        conn.close()
        raise
    conn.execute(f"PRAGMA busy_timeout={int(busy_timeout_s * 1000)}")
    return conn


def _check_and_upgrade(conn: sqlite3.Connection, path: Path, existed: bool) -> None:
    if existed:
        (ok,) = conn.execute("PRAGMA quick_check").fetchone()
        if ok != "ok":
            raise InputError(f"is a damaged SQLite database ({ok})", path)
        tables = {n for (n,) in conn.execute("SELECT name FROM sqlite_master WHERE type='table'")}
        if "trials" not in tables:
            raise InputError(
                f"is an SQLite database of another schema (tables: {', '.join(sorted(tables)) or 'none'}; "
                "expected pbdgrasp's 'trials')",
                path,
            )
        columns = [r[1] for r in conn.execute("PRAGMA table_info(trials)")]
        if columns != _columns():
            raise InputError(f"has a 'trials' table of another schema (columns {', '.join(columns)})", path)
        version = 1
        if "meta" in tables:
            row = conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()
            version = int(row[0]) if row and str(row[0]).isdigit() else 0
        if not 1 <= version <= SCHEMA_VERSION:
            raise InputError(
                f"has schema version {version}; this pbdgrasp reads versions 1 to {SCHEMA_VERSION}", path
            )
    conn.execute(
        "BEGIN IMMEDIATE"
    )  # the lock probe: fails now, not after the work, if another writer holds it
    conn.execute(_SCHEMA)
    conn.execute(_META)
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
    conn.commit()
    if conn.execute("PRAGMA journal_mode=WAL").fetchone()[0] != "wal":
        raise InputError("cannot be switched to WAL mode (a read-only or network file system?)", path)
    conn.execute("PRAGMA synchronous=NORMAL")


def set_aside(path: str | os.PathLike) -> Path | None:
    """Move a results database out of the way for a fresh one, keeping it: its write-ahead log is folded in
    first, then it is renamed to ``<name>.<YYYYmmdd-HHMMSS>.bak`` beside it. No connection to it may be
    open (this process's or another's).

    Returns:
        The backup's path, or ``None`` if there was no database.

    Raises:
        InputError: the file is not a results database (nothing is moved), or it is locked.
    """
    path = Path(path)
    if not path.exists():
        return None
    conn = open_db(path, create=False)
    try:
        conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
        conn.execute("PRAGMA journal_mode=DELETE")
    finally:
        conn.close()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    backup = path.with_name(f"{path.name}.{stamp}.bak")
    n = 1
    while backup.exists():
        backup = path.with_name(f"{path.name}.{stamp}-{n}.bak")
        n += 1
    os.replace(path, backup)
    return backup


def check_params(
    conn: sqlite3.Connection, expected: dict[tuple[str, str], str], hint: str, ignore: tuple[str, ...] = ()
) -> None:
    """Refuse a run whose parameters differ from those of the trials stored for the same row and planner.

    Args:
        expected: per (row, planner), the run's canonical :func:`params_json`.
        hint: what the user can do instead (named options), appended to the message.
        ignore: parameter names left out of the comparison (not known yet).

    Raises:
        InputError: naming the row, the planner and the parameters that differ.
    """
    for (row, planner), pj in expected.items():
        stored = {
            p for (p,) in conn.execute("SELECT DISTINCT params_json FROM trials WHERE row=? AND planner=?",
                                       (row, planner))
        }  # fmt: skip
        b = json.loads(pj)
        for text in stored:
            a = json.loads(text)
            diff = sorted(k for k in set(a) | set(b) if k not in ignore and a.get(k) != b.get(k))
            if not diff:
                continue
            raise InputError(
                f"the database holds {row}/{planner} trials run with other parameters ({', '.join(diff)}); "
                f"{hint}"
            )


def finished_keys(conn: sqlite3.Connection) -> set[tuple[str, str, int]]:
    """The (row, planner, trial) keys already stored."""
    return {(r, p, int(t)) for r, p, t in conn.execute("SELECT row, planner, trial FROM trials")}


def insert_trial(conn: sqlite3.Connection, rec: TrialRecord) -> None:
    """Store one trial in its own transaction; a trial already stored is left as it is.

    Raises:
        InputError: the database stayed locked for the whole busy timeout of :func:`open_db`; the trial
            is then appended as a JSON line to ``<database>.unsaved.jsonl`` beside it, and the message
            names that file.
    """
    names = _columns()
    values = [getattr(rec, n) for n in names]
    values[names.index("success")] = int(rec.success)
    try:
        with conn:
            conn.execute(
                f"INSERT OR IGNORE INTO trials ({', '.join(names)}) VALUES ({', '.join('?' * len(names))})",
                values,
            )
    except sqlite3.OperationalError as exc:
        db = Path(conn.execute("PRAGMA database_list").fetchone()[2])
        side = db.with_name(db.name + ".unsaved.jsonl")
        with side.open("a") as f:
            f.write(json.dumps(asdict(rec), sort_keys=True) + "\n")
        raise InputError(f"cannot store a finished trial ({exc}); it was kept in {side}", db) from None


def load_trials(
    conn: sqlite3.Connection, rows: list[str] | None = None, *, trial: int | None = None
) -> list[TrialRecord]:
    """The stored trials (of some rows, of one trial number, if given), ordered by row, planner and trial.

    The selection is made by SQLite, so a stored path (kilobytes a trial) is read only for the trials kept.
    """
    names = _columns()
    where, params = [], []
    if rows is not None:
        where.append(f"row IN ({', '.join('?' * len(rows))})")
        params += list(rows)
    if trial is not None:
        where.append("trial = ?")
        params.append(int(trial))
    sql = f"SELECT {', '.join(names)} FROM trials"
    if where:
        sql += " WHERE " + " AND ".join(where)
    out = []
    for values in conn.execute(sql + " ORDER BY row, planner, trial", params):
        d = dict(zip(names, values, strict=True))
        d["success"] = bool(d["success"])
        out.append(TrialRecord(**d))
    return out


def find_trial(
    path: str | os.PathLike, trial: int, row: str | None = None, planner: str | None = None
) -> TrialRecord:
    """The stored trial ``trial`` of an existing database, narrowed by ``row`` and ``planner``.

    Raises:
        InputError: the database cannot be opened (:func:`open_db`), no such trial is stored, or the
            trial is stored for several rows or planners and ``row`` / ``planner`` does not choose one.
    """
    conn = open_db(path, create=False)
    try:
        records = load_trials(conn, trial=trial)
    finally:
        conn.close()
    for attr, wanted in (("row", row), ("planner", planner)):
        if wanted is not None:
            records = [r for r in records if getattr(r, attr) == wanted]
        choices = sorted({getattr(r, attr) for r in records})
        if len(choices) > 1:
            raise InputError(
                f"trial {trial} is stored for several {attr}s ({', '.join(choices)}); "
                f"choose one with --{attr}",
                path,
            )
    if not records:
        raise InputError(f"no trial {trial} of these settings is stored", path)
    return records[0]


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
    phi_o evaluation and, for a solved trial, the path's last configuration ``q`` (19,) and the whole
    ``path`` (K, 19) [m, rad] from the start to it (for ``pbdgrasp view``).
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
        grasp["path"] = [[float(x) for x in q] for q in result.path]
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
