"""The CLI's error contract: one line ``error: ...`` and exit status 2."""

import subprocess
import sys


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "pbdgrasp.cli", *args], capture_output=True, text=True)


def test_unknown_subcommand_is_one_error_line_and_status_2():
    res = run_cli("no-such-command")
    assert res.returncode == 2
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ")


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """``pbdgrasp assets | head -0``: the pipe's reader is closed before anything is written; the command
    stops with status 141 (128 + SIGPIPE) and writes no traceback."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "pbdgrasp.cli", "assets"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    proc.stdout.close()
    err = proc.stderr.read().decode()
    assert proc.wait() == 141, err
    assert "Traceback" not in err and "BrokenPipeError" not in err


# -- plan -> Q.json -> quality, and a database that remembers its settings --------------------------
import json  # noqa: E402

import pytest  # noqa: E402

from pbdgrasp.cli import main  # noqa: E402


@pytest.fixture(scope="module")
def ham_model_file(tmp_path_factory, ham_top_down_model):
    path = tmp_path_factory.mktemp("model") / "ham.model.npz"
    ham_top_down_model(12).save(path)
    return path


def _plan(model, db, *extra):
    return main(["plan", "--scene", "ham", "--model", str(model), "--trials", "1", "--time-limit-s", "3",
                 "-o", str(db), "--no-progress", *extra])  # fmt: skip


def test_plan_writes_the_best_q_and_quality_reads_the_stored_grasp(ham_model_file, tmp_path, capsys):
    db = tmp_path / "r.sqlite"
    assert _plan(ham_model_file, db) == 0
    out = capsys.readouterr().out
    assert "1/1 solved" in out and "r.Q.json" in out
    q = json.loads((tmp_path / "r.Q.json").read_text())["q"]
    assert len(q) == 19
    assert main(["quality", "--from-db", str(db), "--trial", "0", "--json"]) == 0
    from_db = json.loads(capsys.readouterr().out)
    assert main(["quality", "--scene", "ham", "--q", str(tmp_path / "r.Q.json"), "--json"]) == 0
    from_file = json.loads(capsys.readouterr().out)
    assert from_db["epsilon"] == from_file["epsilon"] >= 0.05  # the same grasp, closed twice
    assert main(["quality", "--from-db", str(db), "--trial", "5"]) == 2
    assert "no trial 5" in capsys.readouterr().err


def test_a_database_refuses_other_settings_until_new(ham_model_file, tmp_path, capsys):
    db = tmp_path / "r.sqlite"
    assert _plan(ham_model_file, db) == 0
    capsys.readouterr()
    assert _plan(ham_model_file, db, "--seed", "1") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other parameters (seed)" in err[0] and "--new" in err[0]
    assert _plan(ham_model_file, db) == 0  # the same settings: resumed, nothing run
    assert "already stored" in capsys.readouterr().out
    assert _plan(ham_model_file, db, "--seed", "1", "--new") == 0
    assert "kept as" in capsys.readouterr().err
    assert len(list(tmp_path.glob("r.sqlite.*.bak"))) == 1


def test_a_model_of_another_object_gets_a_warning(ham_model_file, tmp_path, capsys):
    status = main(["plan", "--scene", "jam", "--model", str(ham_model_file), "--trials", "1",
                   "--time-limit-s", "0.5", "--no-progress"])  # fmt: skip
    assert status == 0
    err = capsys.readouterr().err
    assert "warning: " in err and "learned on 'ham'" in err and "'jam'" in err


def test_table1_report_only_refuses_a_missing_database_and_builds_nothing(tmp_path, capsys):
    assert main(["table1", "--report-only", "--db", str(tmp_path / "typo.sqlite"),
                 "--run-dir", str(tmp_path / "run")]) == 2  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no such results database" in err[0]
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "argv, what",
    [
        (["plan", "--scene", "ham", "--model", "m", "--time-limit-s", "nan"], r"\(0, 3600\] s, found 'nan'"),
        (["plan", "--scene", "ham", "--model", "m", "--seed", "-1"], r"\[0, 9223372036854775807\]"),
        (["plan", "--scene", "ham", "--model", "m", "--trials", "1000000000"], r"\[1, 10000\]"),
        (["plan", "--scene", "ham", "--model", "m", "--beta", "2"], r"\[0, 1\]"),
        (["table1", "--epsilon", "5"], r"\(0, 1\]"),
        (["table1", "--workers", "-3"], r"\[0, 256\]"),
        (["inspect", "m", "--scene", "ham", "--draws", "0"], r"\[1, 100000\]"),
        (["inspect", "m", "--scene", "ham", "--processes", "0"], r"\[1, 256\]"),
        (["retarget", "ham", "-o", "x.traj.npz", "--processes", "-2"], r"\[1, 256\]"),
        (["learn", "ham", "-o", "x.model.npz", "--processes", "1.5"], r"\[1, 256\]"),
        (["quality", "--scene", "ham", "--q", "q.json", "--step-deg", "inf"], r"\[0.05, 20\] deg"),
        (["render", "--scene", "ham", "-o", "x.png", "--width", "1e9"], r"\[16, 4096\] pixels"),
        (["table1", "--scheduler", "foo", "--rows", "ham"], r"tcp://HOST:PORT"),
    ],
)
def test_numbers_out_of_range_are_one_line_with_the_range_and_unit(argv, what, tmp_path, capsys):
    import re

    assert main(argv + (["--db", str(tmp_path / "t.sqlite")] if argv[0] == "table1" else [])) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and re.search(what, err[0]), err


def test_an_unreachable_scheduler_is_one_line(tmp_path, capsys):
    import socket

    with socket.socket() as s:  # a free port with nothing listening
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    argv = ["table1", "--quick", "--scheduler", f"tcp://127.0.0.1:{port}", "--run-dir", str(tmp_path / "r")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no Dask scheduler answered" in err[0], err


def test_a_scheduler_without_workers_is_one_line(tmp_path, capsys):
    from distributed import LocalCluster

    with LocalCluster(
        n_workers=0, processes=False, protocol="tcp", host="127.0.0.1", dashboard_address=None
    ) as cluster:
        argv = [
            "table1",
            "--quick",
            "--scheduler",
            cluster.scheduler_address,
            "--run-dir",
            str(tmp_path / "r"),
        ]
        assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no worker after" in err[0] and "dask worker" in err[0], err
