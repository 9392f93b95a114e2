"""Malformed inputs: every file of ``tests/data/bad`` through the CLI, and hypothesis fuzzing of every loader.

The CLI must answer each bad file with exit status 2 and exactly one line ``error: <file>: <what is
wrong>`` on stderr (the regex of ``manifest.yaml``); a loader fed arbitrary bytes or arbitrary structures
may raise :class:`assets.errors.InputError` and nothing else.
"""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from assets.errors import InputError
from assets.io import is_finite_number, is_number
from inference.model import VariationModel
from inference.params import VariationParams
from pbdgrasp.cli import main
from planning.qfile import load_q
from planning.scene import load_scene
from retarget.demonstration import Demonstration
from retarget.trajectory import Trajectory

BAD = Path(__file__).parent / "data" / "bad"
MANIFEST = yaml.safe_load((BAD / "manifest.yaml").read_text())
GOOD_TRAJ = BAD / "good" / "small.traj.npz"


def test_the_shipped_corpus_is_what_its_generator_makes(tmp_path, monkeypatch):
    """``make_corpus.py`` run afresh writes the shipped files byte for byte, and no others: the corpus
    cannot drift from its generator unnoticed."""
    import importlib

    monkeypatch.syspath_prepend(str(BAD))
    importlib.import_module("make_corpus").main(tmp_path)

    def files(root: Path) -> set[Path]:
        return {
            p.relative_to(root)
            for p in root.rglob("*")
            if p.is_file() and p.suffix != ".py" and "__pycache__" not in p.parts
        }

    assert files(tmp_path) == files(BAD)
    differ = [str(f) for f in sorted(files(BAD)) if not _same_file(tmp_path / f, BAD / f)]
    assert differ == []


def _arrays(path: Path) -> dict | None:
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in f.files}
    except Exception:
        return None


def _same_file(made: Path, shipped: Path) -> bool:
    """Byte for byte, except that an archive's float arrays may differ in their last bits (another
    numpy or GTSAM build solves the models a little differently) and an unreadable archive (a truncated
    one) need only stay unreadable."""
    if made.read_bytes() == shipped.read_bytes():
        return True
    if not made.name.endswith(".npz"):
        return False
    a, b = _arrays(made), _arrays(shipped)
    if a is None or b is None:
        return a is None and b is None
    if a.keys() != b.keys():
        return False
    for k in a:
        x, y = a[k], b[k]
        if x.dtype.kind == "f" and y.dtype.kind == "f":
            if x.shape != y.shape or not np.allclose(x, y, rtol=1e-9, atol=1e-12, equal_nan=True):
                return False
        elif x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y):
            return False
    return True


def _argv(kind: str, path: Path, tmp: Path) -> list[str]:
    """The CLI command that reads a file of this kind (the first thing it does)."""
    return {
        "demo": ["retarget", str(path), "-o", str(tmp / "out.traj.npz"), "--no-collision", "--no-progress"],
        "traj": ["infer", str(path), "-o", str(tmp / "out.model.npz")],
        "model": ["plan", "--scene", "ham", "--model", str(path), "--no-progress"],
        "scene": ["render", "--scene", str(path), "-o", str(tmp / "out.png")],
        "params": ["infer", str(GOOD_TRAJ), "--params", str(path), "-o", str(tmp / "out.model.npz")],
        "q": ["quality", "--scene", "ham", "--q", str(path)],
        "db": ["quality", "--from-db", str(path), "--trial", "0"],
    }[kind]


def test_the_corpus_covers_every_file_the_cli_reads():
    kinds = {entry["kind"] for entry in MANIFEST.values()}
    assert kinds == {"demo", "traj", "model", "scene", "params", "q", "db"}
    on_disk = {
        str(p.relative_to(BAD))
        for p in BAD.rglob("*")
        if p.is_file() and p.parent != BAD and p.parent.name not in ("good", "meshes")
    }
    assert on_disk == set(MANIFEST)


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_bad_file_gives_exit_2_and_one_line_naming_the_file(name, tmp_path, capsys):
    entry = MANIFEST[name]
    path = BAD / name
    status = main(_argv(entry["kind"], path, tmp_path))
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert status == 2, err
    assert len(lines) == 1, err
    assert lines[0].startswith(f"error: {path}: "), lines[0]
    assert re.search(entry["expect"], lines[0]), (entry["expect"], lines[0])
    assert not list(tmp_path.iterdir())  # no output, not even a partial one


@pytest.mark.parametrize(
    ("value", "number", "finite"),
    [
        (0, True, True),
        (-2.5, True, True),
        (float("inf"), True, False),
        (float("nan"), True, False),
        (True, False, False),
        (False, False, False),
        ("1", False, False),
        (None, False, False),
        ([1.0], False, False),
    ],
)
def test_a_number_field_takes_ints_and_floats_never_bools(value, number, finite):
    """The one test every loader applies to a scalar field (YAML's ``true`` is not 1)."""
    assert is_number(value) is number
    assert is_finite_number(value) is finite


def test_the_good_trajectory_is_accepted(tmp_path):
    assert main(["infer", str(GOOD_TRAJ), "-o", str(tmp_path / "m.model.npz")]) == 0


# -- fuzzing ------------------------------------------------------------------------------------------
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])

_scalars = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**30), max_value=10**30),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=8),
)
_json = st.recursive(
    _scalars,
    lambda kids: st.one_of(
        st.lists(kids, max_size=20),
        st.dictionaries(st.one_of(st.text(max_size=12), st.integers(-3, 3)), kids, max_size=6),
    ),
    max_leaves=40,
)


def _expect_only_input_error(load, path):
    try:
        load(path)
    except InputError:
        pass


def _mutate(good: dict, rng: np.random.Generator, data) -> dict:
    """Replace, drop, reshape or corrupt one or two arrays of a valid archive."""
    arrays = dict(good)
    for key in data.draw(st.lists(st.sampled_from(sorted(arrays)), min_size=1, max_size=2, unique=True)):
        a = np.asarray(arrays[key])
        how = data.draw(st.sampled_from(["drop", "nan", "scale", "reshape", "text", "empty", "int", "noise"]))
        if how == "drop":
            arrays.pop(key)
        elif how == "nan" and a.dtype.kind == "f" and a.size:
            a = a.copy()
            a.flat[rng.integers(a.size)] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf, 1e308]))
            arrays[key] = a
        elif how == "scale" and a.dtype.kind == "f":
            arrays[key] = a * data.draw(st.sampled_from([-1.0, 0.0, 1e3, 1e-12]))
        elif how == "reshape" and a.size:
            arrays[key] = a.reshape(-1)[: max(1, a.size - data.draw(st.integers(0, 5)))]
        elif how == "text":
            arrays[key] = np.str_(data.draw(st.text(max_size=20)))
        elif how == "empty":
            arrays[key] = np.zeros((0,) + a.shape[1:]) if a.ndim else np.zeros(0)
        elif how == "int":
            arrays[key] = np.asarray(data.draw(st.integers(-5, 5)))
        elif how == "noise" and a.dtype.kind == "f":
            arrays[key] = a + rng.normal(size=a.shape) * data.draw(st.sampled_from([1e-3, 1.0]))
    return arrays


def _write_npz(path: Path, arrays: dict) -> None:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    path.write_bytes(buf.getvalue())


def _archive(path: Path) -> dict:
    with np.load(path, allow_pickle=False) as f:
        return {k: f[k] for k in f.files}


GOOD_ARCHIVES = {
    "demo": _archive(BAD.parent.parent.parent / "assets" / "demonstrations" / "ham.npz"),
    "traj": _archive(GOOD_TRAJ),
}


@pytest.fixture(scope="module")
def good_model_archive(tmp_path_factory):
    from inference.solve import solve

    path = tmp_path_factory.mktemp("m") / "good.model.npz"
    solve(Trajectory.load(GOOD_TRAJ)).save(path)
    return _archive(path)


@pytest.mark.parametrize("kind", ["demo", "traj", "model"])
@pytest.mark.filterwarnings("ignore:overflow encountered:RuntimeWarning")  # 1e308 entries: still refused
@FUZZ
@given(data=st.data())
def test_npz_loaders_raise_only_input_error(kind, good_model_archive, tmp_path, data):
    load = {"demo": Demonstration.load, "traj": Trajectory.load, "model": VariationModel.load}[kind]
    good = good_model_archive if kind == "model" else GOOD_ARCHIVES[kind]
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    path = tmp_path / f"fuzz.{kind}.npz"
    if data.draw(st.booleans()):
        _write_npz(path, _mutate(good, rng, data))
    else:
        buf = io.BytesIO()
        np.savez(buf, **good)
        raw = bytearray(buf.getvalue())
        for _ in range(data.draw(st.integers(1, 8))):
            raw[rng.integers(len(raw))] = rng.integers(256)
        path.write_bytes(bytes(raw[: data.draw(st.integers(0, len(raw)))]))
    _expect_only_input_error(load, path)


@FUZZ
@given(doc=_json)
def test_text_loaders_raise_only_input_error_on_any_structure(tmp_path, doc):
    text = yaml.safe_dump(doc)
    for name, load in (("s.yaml", load_scene), ("p.yaml", VariationParams.from_yaml)):
        (tmp_path / name).write_text(text)
        _expect_only_input_error(load, tmp_path / name)
    (tmp_path / "q.json").write_text(json.dumps(doc))
    _expect_only_input_error(load_q, tmp_path / "q.json")


@FUZZ
@given(raw=st.binary(max_size=200))
def test_text_loaders_raise_only_input_error_on_any_bytes(tmp_path, raw):
    for name, load in (("s.yaml", load_scene), ("p.yaml", VariationParams.from_yaml), ("q.json", load_q)):
        (tmp_path / name).write_bytes(raw)
        _expect_only_input_error(load, tmp_path / name)


@FUZZ
@given(data=st.data())
def test_scene_loader_raises_only_input_error_on_edited_scenes(tmp_path, data):
    """A valid scene with one field replaced by an arbitrary value (deeper than random documents get)."""
    doc = yaml.safe_load((BAD.parent.parent.parent / "assets" / "scenes" / "jam_hole.yaml").read_text())
    node = doc
    path = []
    while isinstance(node, dict) and node and data.draw(st.booleans()):
        key = data.draw(st.sampled_from(sorted(node)))
        path.append(key)
        if not isinstance(node[key], dict):
            break
        node = node[key]
    target = doc
    for key in path[:-1]:
        target = target[key]
    if path:
        target[path[-1]] = data.draw(_json)
    (tmp_path / "s.yaml").write_text(yaml.safe_dump(doc))
    _expect_only_input_error(load_scene, tmp_path / "s.yaml")


@FUZZ
@given(q=st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=19, max_size=19))
def test_any_19_numbers_are_a_configuration_in_range_or_an_input_error(q):
    """The range checks of Q.json (wrist within 2 m, rotation vector within 2 pi, joints within limits)."""
    from planning.hand_urdf import hand_joint_limits
    from planning.qfile import MAX_WRIST_DISTANCE_M, q_from_dict

    try:
        got = q_from_dict({"q": q})
    except InputError:
        return
    limits = hand_joint_limits("sah")
    assert np.linalg.norm(got[:3]) <= MAX_WRIST_DISTANCE_M and np.linalg.norm(got[3:6]) <= 2 * np.pi + 1e-9
    assert np.all(got[6:] >= limits[:, 0] - 1e-6) and np.all(got[6:] <= limits[:, 1] + 1e-6)


def _sqlite_page_of(raw: bytes) -> bytes:
    """A file that starts like SQLite (so that the header check passes) and continues with ``raw``."""
    return b"SQLite format 3\x00" + raw


@FUZZ
@given(raw=st.binary(max_size=4096), headed=st.booleans())
def test_the_results_database_opener_raises_only_input_error_on_any_bytes(tmp_path, raw, headed):
    from pbdgrasp.results_db import open_db

    path = tmp_path / "r.sqlite"
    path.write_bytes(_sqlite_page_of(raw) if headed else raw)
    try:
        open_db(path, create=False, lock_timeout_s=0.1).close()
    except InputError:
        pass
    for extra in tmp_path.glob("r.sqlite-*"):
        extra.unlink()
