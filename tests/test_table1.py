"""Table I runner and report: the quick mode end to end on Dask, resume, settings guard, seeds, summaries.

The end-to-end test runs the real pipeline (retargeting, inference, planning) on two rows with two trials
per planner and a short time limit; it asserts the database rows, that a re-run repeats nothing, and that
the report files hold the rows. The summaries are checked against hand-computed values on synthetic trials.
"""

import csv
import json
import math
import sqlite3

import numpy as np
import pytest

from pbdgrasp.cli import main
from pbdgrasp.figures import best_trials, format_quality
from pbdgrasp.paper import PAPER_TABLE1, ROWS
from pbdgrasp.report import success_interval, summarize, write_report
from pbdgrasp.results_db import TrialRecord, load_trials
from pbdgrasp.table1 import Table1Config, parse_names, trial_rng

QUICK_ROWS = ("ham", "jam_hole")
PLANNERS = ("learned", "baseline")
TRIALS = 2
TIME_LIMIT_S = 3.0
FLOAT_TOL = 1e-12
RETARGET_MAX_NFEV = 40  # a coarse strategy keeps the end-to-end test short; the runner is under test


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    d = tmp_path_factory.mktemp("table1")
    argv = [
        "table1",
        "--trials", str(TRIALS),
        "--rows", ",".join(QUICK_ROWS),
        "--time-limit-s", str(TIME_LIMIT_S),
        "--workers", "2",
        "--db", str(d / "t.sqlite"),
        "--cache-dir", str(d / "cache"),
        "--report-dir", str(d / "report"),
        "--no-progress",
        "--retarget-max-nfev", str(RETARGET_MAX_NFEV),
    ]  # fmt: skip
    status = main(argv)
    return d, argv, status


def _records(path):
    conn = sqlite3.connect(path)
    try:
        return load_trials(conn)
    finally:
        conn.close()


def test_quick_mode_stores_every_trial(quick_run):
    d, _, status = quick_run
    assert status == 0
    recs = _records(d / "t.sqlite")
    keys = sorted(r.key() for r in recs)
    assert keys == sorted((r, p, t) for r in QUICK_ROWS for p in PLANNERS for t in range(TRIALS))
    for r in recs:
        params = json.loads(r.params_json)
        assert params["row"] == r.row and params["planner"] == r.planner and params["seed"] == 0
        assert params["settings"]["time_limit_s"] == TIME_LIMIT_S and params["settings"]["beta"] == 0.05
        assert r.nodes >= 1 and r.collision_checks >= 1 and r.git_commit
        assert 0.0 <= r.quality and (r.success == (r.quality >= 0.05))
        # a query stopped by the time limit took at least that long (root sampling included)
        assert "time limit" not in r.message or r.eta_s >= TIME_LIMIT_S
        grasp = json.loads(r.grasp_json)
        if r.success:
            assert len(grasp["closed_q"]) == 19 and len(grasp["q"]) == 19


def test_rerun_repeats_nothing(quick_run, capsys):
    d, argv, _ = quick_run
    before = _records(d / "t.sqlite")
    cache_files = sorted(p.name for p in (d / "cache").iterdir())
    capsys.readouterr()
    assert main(argv + ["--no-renders"]) == 0
    out = capsys.readouterr().out
    assert f"0 new trials, {len(before)} resumed" in out
    assert _records(d / "t.sqlite") == before  # identical rows, eta_s included
    assert sorted(p.name for p in (d / "cache").iterdir()) == cache_files  # strategies came from the cache


def test_a_killed_run_resumes_with_only_the_missing_trials(quick_run, capsys):
    d, argv, _ = quick_run
    db = d / "t.sqlite"
    before = {r.key(): r for r in _records(db)}
    lost = [("ham", "baseline", 1), ("jam_hole", "learned", 0)]  # as if the run had died before them
    conn = sqlite3.connect(db)
    with conn:
        conn.executemany("DELETE FROM trials WHERE row=? AND planner=? AND trial=?", lost)
    conn.close()
    i = argv.index("--workers")
    in_process = argv[: i + 1] + ["0"] + argv[i + 2 :] + ["--no-renders"]
    capsys.readouterr()
    assert main(in_process) == 0
    assert f"{len(lost)} new trials, {len(before) - len(lost)} resumed" in capsys.readouterr().out
    after = {r.key(): r for r in _records(db)}
    assert sorted(after) == sorted(before)
    assert all(after[k] == before[k] for k in before if k not in lost)  # finished trials untouched
    for k in lost:  # the same trial stream again: same seed and settings
        assert after[k].seed == before[k].seed and after[k].params_json == before[k].params_json
        if not any("time limit" in r.message for r in (before[k], after[k])):
            # not cut by the clock: the same trial in this process as on a Dask worker
            assert after[k].deterministic_fields() == before[k].deterministic_fields()


def test_other_settings_on_the_same_db_are_refused(quick_run, capsys):
    d, argv, _ = quick_run
    i = argv.index("--time-limit-s")
    changed = argv[: i + 1] + ["4.0"] + argv[i + 2 :]
    capsys.readouterr()
    assert main(changed) == 2
    assert "other parameters (settings)" in capsys.readouterr().err


def test_report_files_hold_the_rows(quick_run):
    d, _, _ = quick_run
    rep = d / "report"
    md = (rep / "table1.md").read_text()
    for row in QUICK_ROWS:
        assert f"| {PAPER_TABLE1[row].label} | {PAPER_TABLE1[row].quality:.2f} \\|" in md
    assert "Reduced run" in md and f"{TRIALS} / {TRIALS}" in md
    with open(rep / "table1.csv") as f:
        rows = list(csv.DictReader(f))
    assert [r["row"] for r in rows] == list(QUICK_ROWS)
    assert all(int(r["trials"]) == TRIALS and int(r["trials0"]) == TRIALS for r in rows)
    # the paper's MSE (6.5^2 mm^2) and ours for the demonstrated ham; none for the obstacle row
    assert float(rows[0]["paper_mse_mm2"]) == pytest.approx(6.5**2) and float(rows[0]["mse_mm2"]) > 0
    assert rows[1]["mse_mm2"] == "" and rows[1]["paper_mse_mm2"] == ""
    for png in ("table1_success.png", "best_grasps.png"):
        assert (rep / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


# -- pieces, no planning -----------------------------------------------------------------------------
def test_trial_streams_depend_only_on_the_key():
    a = trial_rng(0, "jam", "baseline", 7).random(4)
    for _ in range(2):  # other streams drawn in between change nothing
        trial_rng(0, "ham", "learned", 0).random(100)
        np.testing.assert_array_equal(trial_rng(0, "jam", "baseline", 7).random(4), a)
    others = [
        trial_rng(0, "jam", "learned", 7),
        trial_rng(0, "jam", "baseline", 8),
        trial_rng(1, "jam", "baseline", 7),
    ]
    for g in others:
        assert not np.array_equal(g.random(4), a)


def test_strategy_cache_keys_follow_the_hand_model(tmp_path, monkeypatch, caplog):
    """Editing the SAH's URDF must miss the strategy cache (it once did not: a corrected hand reused old
    strategies). The retargeting is replaced by a stub that stops at the cache miss."""
    import assets
    import pbdgrasp.strategy
    from pbdgrasp.table1 import prepare_strategy

    class CacheMiss(Exception):
        pass

    def stop(*args, **kwargs):
        raise CacheMiss

    monkeypatch.setattr(pbdgrasp.strategy, "retarget_in_scene", stop)
    original = assets.hand_urdf

    def missed_path() -> str:
        caplog.clear()
        with caplog.at_level("INFO", logger="pbdgrasp.cache"), pytest.raises(CacheMiss):
            prepare_strategy("ham", tmp_path / "cache")
        (line,) = [r.getMessage() for r in caplog.records if "cache miss" in r.getMessage()]
        return line.split("-> ")[1]

    first = missed_path()
    edited = tmp_path / "sah.urdf"
    edited.write_text(original("sah").read_text() + "<!-- edited -->\n")
    monkeypatch.setattr(assets, "hand_urdf", lambda name: edited if name == "sah" else original(name))
    second = missed_path()
    assert first != second and first.endswith(".traj.npz") and second.endswith(".traj.npz")


def test_names_and_config_are_validated():
    assert parse_names(None, ROWS, "--rows") == ROWS
    assert parse_names("jam_hole, ham,ham", ROWS, "--rows") == ("jam_hole", "ham")
    with pytest.raises(ValueError, match="unknown nope; valid: ham"):
        parse_names("ham,nope", ROWS, "--rows")
    assert Table1Config(rows=("jam_hole", "ham"), workers=1).rows == ("ham", "jam_hole")  # ROWS order
    with pytest.raises(ValueError, match="trials: expected a positive number"):
        Table1Config(trials=0, workers=1)
    with pytest.raises(ValueError, match="must be positive"):
        Table1Config(time_limit_s=0.0, workers=1)
    with pytest.raises(ValueError, match="planners: unknown"):
        Table1Config(planners=("rrt*",), workers=1)


def test_cli_rejects_unknown_rows(tmp_path, capsys):
    assert main(["table1", "--rows", "ham,spam", "--db", str(tmp_path / "x.sqlite")]) == 2
    assert "error: --rows: unknown spam" in capsys.readouterr().err
    assert not (tmp_path / "x.sqlite").exists()


def _rec(row, planner, trial, success, eta_s, nodes, quality, q=None):
    grasp = {} if q is None else {"closed_q": list(q)}
    return TrialRecord(
        row, planner, trial, 0, success, eta_s, nodes, quality, 10, 1, "", "c", "{}", json.dumps(grasp)
    )


def test_summary_matches_hand_computed_values(tmp_path):
    recs = [
        _rec("ham", "learned", 0, True, 1.0, 100, 0.20, np.zeros(19)),
        _rec("ham", "learned", 1, True, 3.0, 300, 0.30, np.ones(19)),
        _rec("ham", "learned", 2, False, 10.0, 999, 0.01),
        _rec("ham", "learned", 3, True, 2.0, 200, 0.10, np.zeros(19)),
        _rec("ham", "baseline", 0, False, 10.0, 50, 0.0),
        _rec("ham", "baseline", 1, True, 4.0, 40, 0.06),
        _rec("ham_arc", "learned", 0, False, 10.0, 5, 0.0),
        _rec("ham_arc", "bidirectional", 0, True, 1.5, 900, 0.12),
        _rec("ham_arc", "bidirectional", 1, False, 10.0, 9000, 0.02),
        _rec("ham_arc", "bidirectional", 2, True, 2.5, 700, 0.07),
    ]
    s_ham, s_arc = summarize(recs, ["ham", "ham_arc"], {"ham": 49.0, "ham_arc": 12.0})
    assert s_ham.trials == 4 and s_ham.trials0 == 2
    assert abs(s_ham.success - 0.75) < FLOAT_TOL and abs(s_ham.success0 - 0.5) < FLOAT_TOL
    assert abs(s_ham.eta_s - 2.0) < FLOAT_TOL  # mean of 1, 3, 2 s: failures excluded
    assert abs(s_ham.nodes - 200.0) < FLOAT_TOL and abs(s_ham.quality - 0.30) < FLOAT_TOL
    assert abs(s_ham.eta0_s - 4.0) < FLOAT_TOL and s_ham.mse_mm2 == 49.0
    # the obstacle row: no success, no baseline trials, and no MSE column (as in the paper)
    assert s_arc.success == 0.0 and math.isnan(s_arc.eta_s) and math.isnan(s_arc.nodes)
    assert math.isnan(s_arc.success0) and math.isnan(s_arc.mse_mm2)
    assert best_trials(recs, ["ham", "ham_arc"]) == {"ham": recs[1], "ham_arc": None}
    files = write_report(
        recs,
        ["ham", "ham_arc"],
        list(PLANNERS),
        tmp_path,
        time_limit_s=10.0,
        renders=False,
        mse_mm2={"ham": 49.0},
    )
    assert [f.name for f in files] == ["table1.md", "table1.csv", "table1_success.png"]
    md = (tmp_path / "table1.md").read_text()
    ham = "| Ham | 0.25 \\| 0.300 | 1.3 \\| 2.00 (75%) | 774 \\| 200 | 42.2 \\| 49.0 "
    ham += "| 0% \\| 4.00 (50%) | 4 / 2 |"
    assert ham in md
    assert "| 6.1 \\| — (0%) | 502 \\| — | — \\| — | 0% \\| — | 1 / 0 |" in md
    # planners beyond the paper's two get their own table: 2 of 3, mean ETA of the successes 2.0 s
    assert "| Row | learned P(Y), goal trees |" in md
    assert "| Ham (arc, obstacles) | 67% (3), 2.00, 0.120 |" in md and "| Ham | — |" in md
    # every planner's successes with the Wilson interval (3 of 4: 30-95 %, 1 of 2: 9-91 %, 2 of 3: 21-94 %)
    assert "| Row | learned P(Y) | baseline RRT | learned P(Y), goal trees |" in md
    assert "| Ham | 3 / 4 (30%-95%) | 1 / 2 (9%-91%) | — |" in md
    assert "| Ham (arc, obstacles) | 0 / 1 (0%-79%) | — | 2 / 3 (21%-94%) |" in md
    with open(tmp_path / "table1.csv") as f:
        ham_csv = next(csv.DictReader(f))
    assert float(ham_csv["success_ci_low"]) == pytest.approx(_wilson(3, 4)[0], abs=1e-5)
    assert float(ham_csv["success0_ci_high"]) == pytest.approx(_wilson(1, 2)[1], abs=1e-5)


def _wilson(k, n, z=1.959963984540054):
    """The Wilson score interval written out (E. B. Wilson, JASA 1927), the reference of the report's."""
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return centre - half, centre + half


@pytest.mark.parametrize("k, n", [(0, 100), (1, 100), (50, 100), (68, 100), (100, 100), (3, 7)])
def test_success_interval_is_wilsons(k, n):
    lo, hi = success_interval(k, n)
    ref = _wilson(k, n)
    assert lo == pytest.approx(max(ref[0], 0.0), abs=1e-12) and hi == pytest.approx(
        min(ref[1], 1.0), abs=1e-12
    )
    assert lo <= k / n <= hi


def test_success_interval_of_68_in_100_and_of_no_trials():
    lo, hi = success_interval(68, 100)
    assert (round(lo, 4), round(hi, 4)) == (0.5834, 0.7633)  # by hand: centre 0.6733, half-width 0.0900
    assert all(math.isnan(x) for x in success_interval(0, 0))


def test_sigkill_mid_run_resumes_without_losing_or_repeating_trials(quick_run):
    """A real ``pbdgrasp table1`` process killed with SIGKILL after its first stored trial, then resumed."""
    import os
    import signal
    import subprocess
    import sys
    import time

    d, argv, _ = quick_run
    db = d / "killed.sqlite"
    args = list(argv)
    args[args.index("--db") + 1] = str(db)
    args[args.index("--workers") + 1] = "0"  # in-process: SIGKILL hits the process that writes
    args += ["--no-renders", "--report-dir", str(d / "killed_report")]
    proc = subprocess.Popen(
        [sys.executable, "-m", "pbdgrasp.cli", *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
    )  # fmt: skip
    deadline = time.monotonic() + 300
    stored = 0
    while time.monotonic() < deadline and proc.poll() is None and stored < 1:
        time.sleep(0.2)
        if db.exists():
            try:
                stored = len(_records(db))
            except sqlite3.OperationalError:  # the schema is being created
                stored = 0
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    before = {r.key(): r for r in _records(db)}  # the database is readable after the kill
    total = len(QUICK_ROWS) * len(PLANNERS) * TRIALS
    assert 1 <= len(before) < total, "the kill should land mid-run"
    assert main(args) == 0
    after = {r.key(): r for r in _records(db)}
    uninterrupted = {r.key(): r for r in _records(d / "t.sqlite")}
    assert sorted(after) == sorted(uninterrupted)  # nothing lost, nothing repeated (one row per key)
    assert all(after[k] == before[k] for k in before)  # finished trials kept as they were
    for k, rec in after.items():
        ref = uninterrupted[k]
        assert rec.seed == ref.seed and rec.params_json == ref.params_json
        if not any("time limit" in r.message for r in (rec, ref)):
            assert rec.deterministic_fields() == ref.deterministic_fields()


def test_the_cache_key_skips_the_demonstration_generator(tmp_path, monkeypatch):
    from pbdgrasp import cache as table1

    (tmp_path / "assets" / "demonstrations").mkdir(parents=True)
    (tmp_path / "assets" / "sah.py").write_text("x = 1\n")
    (tmp_path / "assets" / "demonstrations" / "generate.py").write_text("y = 1\n")
    monkeypatch.setattr(table1, "_PACKAGE_ROOT", tmp_path)
    before = table1._source_digest(("assets",))
    (tmp_path / "assets" / "demonstrations" / "generate.py").write_text("y = 2\n")  # writes hashed files
    assert table1._source_digest(("assets",)) == before
    (tmp_path / "assets" / "sah.py").write_text("x = 2\n")
    assert table1._source_digest(("assets",)) != before


@pytest.mark.parametrize("edited", ["planning/world.py", "planning/autograsp.py", "inference/solve.py"])
def test_the_trajectory_key_covers_the_world_the_closing_and_the_model_that_retargeting_runs(
    tmp_path, monkeypatch, edited
):
    """Retargeting's d6 runs the pybullet world, and the refined final grasp closes the hand and solves a
    variation model: an edit of any of them must change the trajectory's source digest (the world's did not
    before 2026-12-01, so stale trajectories were reused)."""
    from pbdgrasp import cache as table1

    rels = ("retarget/retargeting.py", "pbdgrasp/strategy.py", "planning/world.py", "planning/autograsp.py")
    for rel in (*rels, "inference/solve.py"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("x = 1\n")
    monkeypatch.setattr(table1, "_PACKAGE_ROOT", tmp_path)
    before = table1._source_digest(table1.RETARGET_SOURCES)
    (tmp_path / edited).write_text("x = 2\n")
    assert table1._source_digest(table1.RETARGET_SOURCES) != before


def test_the_source_digest_follows_the_code_not_its_docstrings_or_comments(tmp_path, monkeypatch):
    """A docstring, a comment or a re-wrapped line recomputes nothing (a docstring edit of
    pbdgrasp/strategy.py once re-ran every retargeting); any change of the code does, a string constant
    that is not a docstring included."""
    from pbdgrasp import cache as table1

    src = tmp_path / "retarget" / "step.py"
    src.parent.mkdir()
    monkeypatch.setattr(table1, "_PACKAGE_ROOT", tmp_path)

    def digest(text):
        src.write_text(text)
        return table1._source_digest(("retarget",))

    base = digest('"""Module."""\n\n\ndef f(x):\n    """Doc."""\n    return x + 1  # one\n\n\nNAME = "a"\n')
    same = [
        '"""Another."""\n\n\ndef f(x):\n    """Other doc."""\n    return x + 1\n\n\nNAME = "a"\n',
        'def f(x):\n    return (x\n            + 1)  # a comment\nNAME = "a"\n',
    ]
    changed = [
        '"""Module."""\n\n\ndef f(x):\n    """Doc."""\n    return x + 2\n\n\nNAME = "a"\n',
        '"""Module."""\n\n\ndef f(x):\n    """Doc."""\n    return x + 1\n\n\nNAME = "b"\n',
        '"""Module."""\n\n\ndef f(y):\n    """Doc."""\n    return y + 1\n\n\nNAME = "a"\n',
    ]
    assert all(digest(t) == base for t in same)
    assert len({digest(t) for t in changed} | {base}) == len(changed) + 1
    assert digest("def f(:\n") != base  # a file that does not parse is hashed by its bytes


def test_the_report_keeps_dirty_in_a_shortened_commit():
    from pbdgrasp.cli.table1 import _short

    assert _short("c764d460cb8c1234abcd-dirty") == "c764d460cb8c-dirty"
    assert _short("c764d460cb8c1234abcd") == "c764d460cb8c" and _short("unknown") == "unknown"


@pytest.mark.parametrize(
    "quality, text",
    [(0.116935, "0.116"), (0.0499999, "0.049"), (0.05, "0.050"), (0.2674, "0.267"), (None, "—")],
)
def test_qualities_print_rounded_down_in_tables_and_figures(quality, text):
    """A grasp just under epsilon must not read as valid: 0.0499999 prints 0.049 (rounding would say 0.050);
    the figures' titles use the same text as the tables."""
    assert format_quality(quality) == text
    assert format_quality(float("nan")) == "—"
