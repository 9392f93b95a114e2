"""The trial store: rows written one by one, resumable, never duplicated."""

from planning.results_db import TrialRecord, finished_keys, insert_trial, load_trials, open_db


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
