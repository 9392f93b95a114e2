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
