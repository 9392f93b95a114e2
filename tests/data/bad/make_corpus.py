"""Regenerate the corpus of malformed inputs (``python tests/data/bad/make_corpus.py [ROOT]``, by default
here); byte for byte the same on every run (``tests/test_bad_inputs.py`` checks the shipped corpus is its
output). The text inputs are made in ``text_inputs.py``, the shared helpers are in ``corpus_io.py``.

Every file the CLI reads has its malformed variants here: demonstrations (``demo/*.npz``), trajectories
(``traj/*.traj.npz``), models (``model/*.model.npz``), scenes (``scene/*.yaml``), parameter files
(``params/*.yaml``) and configurations (``q/*.json``). ``manifest.yaml`` lists each file with its kind and a
regular expression the one-line error must match (what is wrong); ``tests/test_bad_inputs.py`` runs each
through the CLI and checks exit status 2 and one line ``error: <the file>: <what is wrong>``.
``good/`` holds the valid trajectory the parameter files are tried with.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
from corpus_io import Corpus, drop_key, in_mm, nan_at, not_pd, npz_bytes, set_key, skew, yaml_header
from text_inputs import configurations, params, scenes

import assets
from inference.solve import solve
from pbdgrasp.bench_fixtures import synthetic_trajectory

HERE = Path(__file__).resolve().parent


def demonstrations(corpus: Corpus) -> None:
    with np.load(assets.demonstration_path("ham"), allow_pickle=False) as f:
        good = {k: f[k] for k in f.files}

    def unknown_object(h):
        h["object"] = "teapot"

    def unknown_joint(h):
        h["joint_names"][3] = "index_flexion_extra"

    def bad_cov(h):
        h["object_prior"]["cov_object"][0][0] = -1.0

    def bad_grasp(h):
        h["grasp_type"] = "pinch"

    def rate_text(h):
        h["rate_hz"] = "fast"

    corpus.npz_variants(
        "demo",
        ".npz",
        good,
        {
            "missing_joints": (drop_key("joints"), r"missing keys \['joints'\]"),
            "missing_header": (drop_key("header_yaml"), r"missing keys \['header_yaml'\]"),
            "joints_wrong_shape": (set_key("joints", lambda a: a[:, :19]), r"joints.*shape"),
            "wrist_nan": (set_key("T_object_wrist", nan_at((3, 0, 3))), r"T_object_wrist.*non-finite"),
            "wrist_not_rotation": (set_key("T_object_wrist", skew), r"T_object_wrist.*not a rotation"),
            "wrist_in_mm": (
                set_key("T_object_wrist", in_mm),
                r"T_object_wrist: wrist .* positions must be in metres",
            ),
            "joints_inf": (set_key("joints", nan_at((0, 0))), r"joints.*non-finite"),
            "joints_text": (set_key("joints", lambda a: np.array("fingers")), r"joints"),
            "header_not_string": (
                set_key("header_yaml", lambda h: np.arange(3.0)),
                r"header_yaml: expected one string",
            ),
            "header_not_yaml": (
                set_key("header_yaml", lambda h: np.str_("a: [b\n")),
                r"header_yaml: not valid YAML",
            ),
            "unknown_object": (set_key("header_yaml", yaml_header(unknown_object)), r"teapot"),
            "unknown_joint": (
                set_key("header_yaml", yaml_header(unknown_joint)),
                r"joint_names.*index_flexion_extra",
            ),
            "cov_not_pd": (set_key("header_yaml", yaml_header(bad_cov)), r"cov_object.*(positive|symmetric)"),
            "grasp_type_unknown": (set_key("header_yaml", yaml_header(bad_grasp)), r"grasp_type.*pinch"),
            "rate_text": (set_key("header_yaml", yaml_header(rate_text)), r"rate_hz"),
        },
    )


def trajectories(corpus: Corpus) -> Path:
    traj = synthetic_trajectory(6, np.random.default_rng(0))
    good_path = corpus.root / "good" / "small.traj.npz"
    traj.save(good_path)
    with np.load(good_path, allow_pickle=False) as f:
        good = {k: f[k] for k in f.files}
    good_path.write_bytes(npz_bytes(good))  # the same arrays, without the time of writing
    corpus.npz_variants(
        "traj",
        ".traj.npz",
        good,
        {
            "missing_cov": (drop_key("cov_retarget"), r"missing keys \['cov_retarget'\]"),
            "joints_wrong_shape": (
                set_key("joints", lambda a: a[:, :12]),
                r"joints: expected shape \(6, 13\)",
            ),
            "cov_wrong_shape": (
                set_key("cov_retarget", lambda a: a[:, :18, :18]),
                r"cov_retarget: expected shape",
            ),
            "wrist_nan": (set_key("T_object_wrist", nan_at((2, 1, 3))), r"T_object_wrist.*non-finite"),
            "joints_inf": (
                set_key("joints", lambda a: np.where(np.arange(13) == 4, np.inf, a)),
                r"joints.*non-finite",
            ),
            "wrist_not_rotation": (set_key("T_object_wrist", skew), r"T_object_wrist.*not a rotation"),
            "cov_not_psd": (set_key("cov_retarget", not_pd), r"cov_retarget.*positive semi-definite"),
            "cov_not_symmetric": (
                set_key("cov_retarget", lambda C: C + np.triu(np.ones((19, 19)), 1) * 1e-3),
                r"cov_retarget.*not symmetric",
            ),
            "object_cov_not_pd": (set_key("cov_object", not_pd), r"cov_object.*positive definite"),
            "one_step": (
                lambda d: {
                    k: (
                        v[:1] if k in ("T_object_wrist", "joints", "cov_retarget", "fingertip_rmse_mm") else v
                    )
                    for k, v in d.items()
                },
                r"at least 2 steps",
            ),
            "dt_text": (set_key("dt_s", lambda a: np.str_("fast")), r"dt_s"),
            "grasp_type_unknown": (set_key("grasp_type", lambda a: np.str_("pinch")), r"grasp_type.*pinch"),
            "object_vector": (
                set_key("object", lambda a: np.array(["ham", "jam"])),
                r"object: expected a scalar",
            ),
            "meta_not_json": (set_key("meta_json", lambda a: np.str_("{oops")), r"meta_json"),
        },
    )
    return good_path


def models(corpus: Corpus) -> None:
    model = solve(synthetic_trajectory(5, np.random.default_rng(1)))
    path = corpus.root / "good" / "_tmp.model.npz"
    model.save(path)
    with np.load(path, allow_pickle=False) as f:
        good = {k: f[k] for k in f.files}
    path.unlink()
    good["solve_time_s"] = np.array(1.0)  # not the wall time: the corpus regenerates byte for byte
    params = json.loads(str(good["params_json"]))
    corpus.npz_variants(
        "model",
        ".model.npz",
        good,
        {
            "missing_cov": (drop_key("cov"), r"missing keys \['cov'\]"),
            "cov_wrong_shape": (set_key("cov", lambda a: a[:, :6, :6]), r"cov.*shape"),
            "cov_nan": (set_key("cov", nan_at((1, 2, 2))), r"cov.*non-finite"),
            "cov_not_pd": (set_key("cov", not_pd), r"cov.*positive definite"),
            "wrist_not_rotation": (
                set_key("T_object_wrist_mean", skew),
                r"T_object_wrist_mean.*not a rotation",
            ),
            "object_prior_nan": (
                set_key("T_world_object_mean", nan_at((0, 3))),
                r"T_world_object_mean.*non-finite",
            ),
            "params_not_json": (set_key("params_json", lambda a: np.str_("{")), r"params_json: not JSON"),
            "params_unknown_name": (
                set_key("params_json", lambda a: np.str_(json.dumps({**params, "sigma": 1}))),
                r"unknown parameters \['sigma'\]",
            ),
            "iterations_text": (set_key("iterations", lambda a: np.str_("many")), r"iterations"),
            "one_step": (
                lambda d: {
                    k: (v[:1] if k in ("T_object_wrist_mean", "joints_mean", "cov", "constrained") else v)
                    for k, v in d.items()
                },
                r"(at least 2|T < 2|2 steps)",
            ),
            "grasp_type_unknown": (set_key("grasp_type", lambda a: np.str_("pinch")), r"grasp_type.*pinch"),
        },
    )


def databases(corpus: Corpus) -> None:
    """Files given as a results database (``quality --from-db``, ``plan -o``, ``table1 --db``)."""
    import sqlite3
    import tempfile

    from pbdgrasp.results_db import open_db

    def made(build) -> bytes:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "x.sqlite"
            conn = sqlite3.connect(path)
            build(conn)
            conn.commit()
            conn.close()
            return path.read_bytes()

    corpus.put("db", "empty.sqlite", b"", r"is not an SQLite database")
    corpus.put("db", "text.sqlite", "trial,success\n0,1\n", r"is not an SQLite database")
    corpus.put("db", "random.sqlite", np.random.default_rng(0).bytes(8192), r"is not an SQLite database")
    other_schema = made(lambda c: c.execute("CREATE TABLE runs (x INTEGER)"))
    corpus.put("db", "other_schema.sqlite", other_schema, r"another schema \(tables: runs")
    other_columns = made(lambda c: c.execute("CREATE TABLE trials (row TEXT, ok INTEGER)"))
    corpus.put("db", "other_columns.sqlite", other_columns, r"'trials' table of another schema")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "x.sqlite"
        conn = open_db(path)
        conn.execute("UPDATE meta SET value='99' WHERE key='schema_version'")
        conn.commit()
        conn.execute("PRAGMA journal_mode=DELETE")
        conn.close()
        newer = path.read_bytes()
        path.unlink()
        conn = open_db(path)
        conn.execute("PRAGMA journal_mode=DELETE")
        conn.executemany("INSERT INTO meta VALUES (?, ?)", [(f"k{i}", "x" * 2000) for i in range(40)])
        conn.commit()
        conn.close()
        full = path.read_bytes()
    corpus.put("db", "newer_version.sqlite", newer, r"schema version 99")
    corpus.put("db", "truncated.sqlite", full[: len(full) // 2], r"not a readable|damaged|malformed")


def main(root: Path = HERE) -> Corpus:
    """Write the whole corpus and its manifest under ``root``."""
    corpus = Corpus(root)
    demonstrations(corpus)
    trajectories(corpus)
    models(corpus)
    scenes(corpus)
    params(corpus)
    configurations(corpus)
    databases(corpus)
    corpus.write_manifest()
    return corpus


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
