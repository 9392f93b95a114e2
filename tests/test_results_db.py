"""The trial store: rows written one by one, resumable, never duplicated."""

from pbdgrasp.results_db import TrialRecord, finished_keys, insert_trial, load_trials, open_db, source_commit


def rec(trial, success=True, planner="learned"):
    return TrialRecord(
        "ham", planner, trial, 100 + trial, success, 0.5, 300, 0.12, 1000, 3, "ok", "abc", "{}"
    )


def test_insert_resume_and_no_duplicates(tmp_path):
    db = tmp_path / "r.sqlite"
    conn = open_db(db)
    for t in range(3):
        insert_trial(conn, rec(t))
    conn.close()
    conn = open_db(db)  # a new process resuming
    assert finished_keys(conn) == {("ham", "learned", t) for t in range(3)}
    insert_trial(conn, rec(1, success=False))  # a repeat is ignored, the first result kept
    insert_trial(conn, rec(0, planner="baseline"))
    rows = load_trials(conn)
    assert len(rows) == 4
    assert [r.success for r in rows if r.planner == "learned"] == [True, True, True]
    assert rows[1] == rec(0)
    assert conn.execute("PRAGMA journal_mode").fetchone()[0] == "wal"


def test_source_commit_names_head_and_marks_uncommitted_sources_dirty(tmp_path):
    import subprocess

    def git(*args):
        return subprocess.run(["git", "-C", str(tmp_path), *args], capture_output=True, text=True, check=True)

    assert source_commit(tmp_path) == "unknown"  # not a checkout
    git("init", "-q")
    (tmp_path / "results").mkdir()
    (tmp_path / "code.py").write_text("a = 1\n")
    (tmp_path / "results" / "table1.md").write_text("old\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@example.org", "commit", "-qm", "init")
    head = git("rev-parse", "HEAD").stdout.strip()
    assert len(head) == 40 and source_commit(tmp_path) == head
    (tmp_path / "results" / "table1.md").write_text("a new report\n")  # the run's own output
    assert source_commit(tmp_path) == head
    (tmp_path / "code.py").write_text("a = 2\n")
    assert source_commit(tmp_path) == head + "-dirty"


# -- checked at opening, settings remembered, nothing lost ------------------------------------------
def test_a_database_of_schema_version_1_is_read_and_upgraded(tmp_path):
    import sqlite3

    from pbdgrasp.results_db import _SCHEMA, SCHEMA_VERSION

    db = tmp_path / "v1.sqlite"
    conn = sqlite3.connect(db)
    conn.execute(_SCHEMA)  # the trials table alone, as version 1 wrote it
    conn.commit()
    conn.close()
    conn = open_db(db)
    insert_trial(conn, rec(0))
    version = conn.execute("SELECT value FROM meta WHERE key='schema_version'").fetchone()[0]
    assert int(version) == SCHEMA_VERSION and len(load_trials(conn)) == 1
    conn.close()


def test_a_locked_database_is_refused_at_opening_not_after_the_work(tmp_path):
    import sqlite3

    import pytest

    from assets.errors import InputError

    db = tmp_path / "r.sqlite"
    open_db(db).close()
    other = sqlite3.connect(db)
    other.execute("BEGIN IMMEDIATE")  # another run holds the write lock
    try:
        with pytest.raises(InputError, match="locked by another process"):
            open_db(db, lock_timeout_s=0.05)
    finally:
        other.rollback()
        other.close()


def test_a_trial_that_cannot_be_stored_is_kept_beside_the_database(tmp_path):
    import dataclasses
    import json
    import sqlite3

    import pytest

    from assets.errors import InputError

    db = tmp_path / "r.sqlite"
    conn = open_db(db, busy_timeout_s=0.05)
    other = sqlite3.connect(db)
    other.execute("BEGIN IMMEDIATE")
    try:
        with pytest.raises(InputError, match="r.sqlite.unsaved.jsonl"):
            insert_trial(conn, rec(7))
    finally:
        other.rollback()
        other.close()
    kept = [json.loads(line) for line in (tmp_path / "r.sqlite.unsaved.jsonl").read_text().splitlines()]
    assert kept == [dataclasses.asdict(rec(7))]
    conn.close()


def test_set_aside_keeps_every_stored_trial(tmp_path):
    from pbdgrasp.results_db import set_aside

    db = tmp_path / "r.sqlite"
    conn = open_db(db)
    for t in range(5):
        insert_trial(conn, rec(t))  # in the write-ahead log until a checkpoint
    conn.close()
    backup = set_aside(db)
    assert not any(tmp_path.glob("r.sqlite-*"))  # the log folded in, nothing left behind
    assert not db.exists() and backup.name.startswith("r.sqlite.") and backup.suffix == ".bak"
    conn = open_db(backup, create=False)
    assert finished_keys(conn) == {("ham", "learned", t) for t in range(5)}
    conn.close()
    assert set_aside(db) is None


def test_other_parameters_are_refused_naming_what_differs(tmp_path):
    import pytest

    from assets.errors import InputError
    from pbdgrasp.results_db import check_params, params_json

    conn = open_db(tmp_path / "r.sqlite")
    stored = {"scene": "ham", "seed": 0, "settings": {"time_limit_s": 10.0}}
    insert_trial(conn, _with_params(rec(0), stored))
    check_params(conn, {("ham", "learned"): params_json(stored)}, "hint")  # the same: accepted
    check_params(conn, {("ham", "baseline"): params_json({**stored, "seed": 1})}, "hint")  # other planner
    with pytest.raises(
        InputError, match=r"ham/learned trials run with other parameters \(seed, settings\); h"
    ):
        check_params(
            conn,
            {("ham", "learned"): params_json({**stored, "seed": 1, "settings": {"time_limit_s": 1}})},
            "h",
        )
    check_params(conn, {("ham", "learned"): params_json({**stored, "seed": 1})}, "h", ignore=("seed",))
    conn.close()


def _with_params(r: TrialRecord, params: dict) -> TrialRecord:
    import dataclasses

    from pbdgrasp.results_db import params_json

    return dataclasses.replace(r, params_json=params_json(params))


def test_a_solved_trial_stores_its_path_and_find_trial_returns_it(tmp_path):
    import json

    import numpy as np
    import pytest

    from assets.errors import InputError
    from pbdgrasp.results_db import find_trial, record_from_plan
    from planning.rrt_connect import PlanResult

    path = np.arange(3 * 19, dtype=float).reshape(3, 19) / 7.0
    result = PlanResult(True, "solved", 1.0, 12, 0.2, path)
    conn = open_db(tmp_path / "r.sqlite")
    for planner in ("learned", "baseline"):
        rec = record_from_plan(
            result, row="ham", planner=planner, trial=4, seed=1, git_commit="x", params_json="{}"
        )
        insert_trial(conn, rec)
    conn.close()
    stored = find_trial(tmp_path / "r.sqlite", 4, planner="baseline")
    grasp = json.loads(stored.grasp_json)
    assert (
        stored.planner == "baseline"
        and np.array_equal(grasp["path"], path)
        and grasp["q"] == path[-1].tolist()
    )
    with pytest.raises(InputError, match="several planners"):
        find_trial(tmp_path / "r.sqlite", 4)
    with pytest.raises(InputError, match="no trial 5"):
        find_trial(tmp_path / "r.sqlite", 5, planner="learned")
