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
