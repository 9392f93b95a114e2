"""The output policy (``assets.io``): every path a command writes is checked before any work, and written
atomically, through symbolic links, never over a directory or a special file.

Each output option of every command that writes is tried with each kind of bad place (a directory, a
missing parent, a place that cannot be written, a FIFO, a device, a wrong extension): one line ``error:``,
exit status 2, nothing created and nothing replaced.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest

from assets.errors import InputError
from assets.io import atomic_write, check_output_dir, check_output_file
from pbdgrasp.cli import main

UNWRITABLE = Path("/proc")  # procfs refuses new files, for root too


# -- the checks themselves -----------------------------------------------------------------------------
def test_a_regular_file_or_a_new_name_in_a_writable_directory_is_accepted(tmp_path):
    assert check_output_file(tmp_path / "a.png", (".png",)) == tmp_path / "a.png"
    (tmp_path / "b.PNG").write_bytes(b"old")
    assert check_output_file(tmp_path / "b.PNG", (".png",)) == tmp_path / "b.PNG"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # the probe left nothing


@pytest.mark.parametrize(
    "kind, expect",
    [
        ("directory", "is a directory"),
        ("missing_parent", "does not exist"),
        ("unwritable", "cannot write in directory"),
        ("fifo", "special file"),
        ("extension", "expected a file name ending in .png"),
        ("read_only_file", "read-only file"),
        ("empty", "empty string"),
    ],
)
def test_bad_output_files_are_refused(kind, expect, tmp_path):
    path = _bad_place(kind, tmp_path, ".png")
    if kind == "read_only_file" and os.geteuid() == 0:
        pytest.skip("root may write a read-only file")
    with pytest.raises(InputError, match=expect):
        check_output_file(path, (".png",))


def test_a_device_is_refused():
    with pytest.raises(InputError, match="special file"):
        check_output_file("/dev/null", ("",))


def test_a_symbolic_link_resolves_to_its_target(tmp_path):
    target = tmp_path / "real" / "out.png"
    target.parent.mkdir()
    link = tmp_path / "link.png"
    link.symlink_to(target)
    assert check_output_file(link, (".png",)) == target
    (tmp_path / "dangling.png").symlink_to(tmp_path / "nowhere" / "x.png")
    with pytest.raises(InputError, match="does not exist"):
        check_output_file(tmp_path / "dangling.png", (".png",))


def test_output_directories(tmp_path):
    assert check_output_dir(tmp_path / "new" / "deeper") == tmp_path / "new" / "deeper"  # created later
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a directory"):
        check_output_dir(tmp_path / "file")
    with pytest.raises(InputError, match="cannot write"):
        check_output_dir(UNWRITABLE / "pbdgrasp-run")


def test_atomic_write_goes_through_a_link_and_keeps_the_mode(tmp_path):
    target = tmp_path / "t.json"
    target.write_text("old")
    target.chmod(0o640)
    link = tmp_path / "l.json"
    link.symlink_to(target)
    atomic_write(link, lambda f: f.write(b"new"))
    assert link.is_symlink() and target.read_text() == "new"
    assert stat.S_IMODE(target.stat().st_mode) == 0o640


def test_atomic_write_refuses_a_fifo_and_a_directory(tmp_path):
    fifo = tmp_path / "f.json"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match="not a regular file"):
        atomic_write(fifo, lambda f: f.write(b"x"))
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    (tmp_path / "d.json").mkdir()
    with pytest.raises(InputError, match="not a regular file"):
        atomic_write(tmp_path / "d.json", lambda f: f.write(b"x"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.json", "f.json"]  # no temporary file left


# -- every command that writes ---------------------------------------------------------------------
def _bad_place(kind: str, tmp: Path, suffix: str) -> Path | str:
    name = f"out{suffix}"
    if kind == "directory":
        (tmp / name).mkdir()
        return tmp / name
    if kind == "missing_parent":
        return tmp / "missing" / name
    if kind == "unwritable":
        return UNWRITABLE / name
    if kind == "fifo":
        os.mkfifo(tmp / name)
        return tmp / name
    if kind == "extension":
        return tmp / "out.jpg"
    if kind == "read_only_file":
        (tmp / name).write_text("keep")
        (tmp / name).chmod(0o444)
        return tmp / name
    if kind == "empty":
        return ""
    raise AssertionError(kind)


# (command line with {out} where the output goes, the output's suffix); inputs need not exist: the
# outputs are checked while the command line is parsed, before any input is read
FILE_OUTPUTS = {
    "render -o": (["render", "--scene", "ham", "-o", "{out}"], ".png"),
    "quality -o": (["quality", "--scene", "ham", "--q", "Q.json", "-o", "{out}"], ".png"),
    "plan -o": (["plan", "--scene", "ham", "--model", "m.model.npz", "-o", "{out}"], ".sqlite"),
    "plan --render": (["plan", "--scene", "ham", "--model", "m.model.npz", "--render", "{out}"], ".png"),
    "plan --best-q": (["plan", "--scene", "ham", "--model", "m.model.npz", "--best-q", "{out}"], ".json"),
    "retarget -o": (["retarget", "ham", "-o", "{out}"], ".traj.npz"),
    "infer -o": (["infer", "t.traj.npz", "-o", "{out}"], ".model.npz"),
    "learn -o": (["learn", "ham", "-o", "{out}"], ".model.npz"),
    "learn --trajectory": (["learn", "ham", "-o", "m.model.npz", "--trajectory", "{out}"], ".traj.npz"),
    "inspect --plot": (["inspect", "m.model.npz", "--scene", "ham", "--plot", "{out}"], ".png"),
    "ceiling -o": (["ceiling", "--scene", "ham", "-o", "{out}"], ".json"),
    "bench -o": (["bench", "--quick", "-o", "{out}"], ".json"),
    "demo import -o": (["demo", "import", "k.npz", "--object", "ham", "-o", "{out}"], ".npz"),
    "table1 --db": (["table1", "--quick", "--db", "{out}"], ".sqlite"),
    "view --screenshot": (
        ["view", "--scene", "ham", "--model", "m.model.npz", "--screenshot", "{out}"],
        ".png",
    ),
}
DIR_OUTPUTS = {
    "demo generate -o": ["demo", "generate", "--object", "ham", "-o", "{out}"],
    "bench --cache-dir": ["bench", "--quick", "--cache-dir", "{out}"],
    "table1 --run-dir": ["table1", "--quick", "--run-dir", "{out}"],
    "table1 --cache-dir": ["table1", "--quick", "--cache-dir", "{out}"],
    "table1 --report-dir": ["table1", "--quick", "--report-dir", "{out}"],
}
FILE_KINDS = ("directory", "missing_parent", "unwritable", "fifo", "extension")


def _refused(argv: list[str], out, capsys) -> str:
    status = main([str(out) if a == "{out}" else a for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith("error: "), err
    return err[0]


@pytest.mark.parametrize("kind", FILE_KINDS)
@pytest.mark.parametrize("option", sorted(FILE_OUTPUTS))
def test_every_file_output_refuses_a_bad_place_before_any_work(option, kind, tmp_path, capsys):
    argv, suffix = FILE_OUTPUTS[option]
    out = _bad_place(kind, tmp_path, suffix)
    before = sorted(tmp_path.rglob("*"))
    line = _refused(argv, out, capsys)
    assert str(out) in line
    assert sorted(tmp_path.rglob("*")) == before  # nothing created, nothing replaced
    if kind == "fifo":
        assert stat.S_ISFIFO(Path(out).stat().st_mode)


@pytest.mark.parametrize("kind", ("file", "unwritable"))
@pytest.mark.parametrize("option", sorted(DIR_OUTPUTS))
def test_every_directory_output_refuses_a_bad_place(option, kind, tmp_path, capsys):
    if kind == "file":
        out = tmp_path / "run"
        out.write_text("keep")
    else:
        out = UNWRITABLE / "pbdgrasp-run"
    line = _refused(DIR_OUTPUTS[option], out, capsys)
    assert str(out) in line
    if kind == "file":
        assert out.read_text() == "keep"


def test_render_writes_through_a_symbolic_link(tmp_path):
    target = tmp_path / "pictures" / "scene.png"
    target.parent.mkdir()
    link = tmp_path / "latest.png"
    link.symlink_to(target)
    assert main(["render", "--scene", "ham", "--width", "64", "--height", "48", "-o", str(link)]) == 0
    assert link.is_symlink() and target.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
