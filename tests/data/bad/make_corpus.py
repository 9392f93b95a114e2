"""Regenerate the corpus of malformed inputs (``python tests/data/bad/make_corpus.py``); deterministic.

Every file the CLI reads has its malformed variants here: demonstrations (``demo/*.npz``), trajectories
(``traj/*.traj.npz``), models (``model/*.model.npz``), scenes (``scene/*.yaml``), parameter files
(``params/*.yaml``) and configurations (``q/*.json``). ``manifest.yaml`` lists each file with its kind and a
regular expression the one-line error must match (what is wrong); ``tests/test_bad_inputs.py`` runs each
through the CLI and checks exit status 2 and one line ``error: <the file>: <what is wrong>``.
``good/`` holds the valid trajectory the parameter files are tried with.
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import yaml

import assets
from inference.solve import solve
from pbdgrasp.bench_fixtures import synthetic_trajectory

HERE = Path(__file__).resolve().parent
MANIFEST: dict[str, dict] = {}


def _npz_bytes(arrays: dict) -> bytes:
    """The archive ``np.savez_compressed`` writes, with a fixed timestamp on every member (numpy stamps
    them with the time of writing), so that the corpus regenerates byte for byte."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, value in arrays.items():
            info = zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            with archive.open(info, "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)
    return buf.getvalue()


def put(kind: str, name: str, data: bytes | str, expect: str) -> None:
    path = HERE / kind / name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    MANIFEST[f"{kind}/{name}"] = {"kind": kind, "expect": expect}


def npz_variants(kind: str, ext: str, good: dict, variants: dict[str, tuple]) -> None:
    """``variants``: name -> (change(dict) -> dict, expected regex)."""
    raw = _npz_bytes(good)
    put(kind, f"empty{ext}", b"", "not a readable .npz")
    put(kind, f"truncated{ext}", raw[: len(raw) // 2], "not a readable .npz")
    put(kind, f"not_npz{ext}", "this is text, not an archive\n", "not a readable .npz")
    for name, (change, expect) in variants.items():
        arrays = {k: np.array(v) for k, v in good.items()}
        put(kind, f"{name}{ext}", _npz_bytes(change(arrays)), expect)


def _drop(key):
    return lambda d: {k: v for k, v in d.items() if k != key}


def _set(key, fn):
    def change(d):
        d[key] = fn(d[key])
        return d

    return change


def _nan_at(index):
    def fn(a):
        a = a.astype(float).copy()
        a[index] = np.nan
        return a

    return fn


def _skew(T):
    T = T.copy()
    T[..., 0, 1] += 0.2
    return T


def _not_pd(C):
    C = C.copy()
    C[..., 0, 0] = -abs(C[..., 0, 0]) - 1e-3
    return C


def _in_mm(T):
    T = T.copy()
    T[..., :3, 3] *= 1000.0
    return T


def _header(change):
    def fn(h):
        d = yaml.safe_load(str(h))
        change(d)
        return np.str_(yaml.safe_dump(d, sort_keys=False))

    return fn


def demonstrations() -> None:
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

    npz_variants(
        "demo",
        ".npz",
        good,
        {
            "missing_joints": (_drop("joints"), r"missing keys \['joints'\]"),
            "missing_header": (_drop("header_yaml"), r"missing keys \['header_yaml'\]"),
            "joints_wrong_shape": (_set("joints", lambda a: a[:, :19]), r"joints.*shape"),
            "wrist_nan": (_set("T_object_wrist", _nan_at((3, 0, 3))), r"T_object_wrist.*non-finite"),
            "wrist_not_rotation": (_set("T_object_wrist", _skew), r"T_object_wrist.*not a rotation"),
            "wrist_in_mm": (
                _set("T_object_wrist", _in_mm),
                r"T_object_wrist: wrist .* positions must be in metres",
            ),
            "joints_inf": (_set("joints", _nan_at((0, 0))), r"joints.*non-finite"),
            "joints_text": (_set("joints", lambda a: np.array("fingers")), r"joints"),
            "header_not_string": (
                _set("header_yaml", lambda h: np.arange(3.0)),
                r"header_yaml: expected one string",
            ),
            "header_not_yaml": (
                _set("header_yaml", lambda h: np.str_("a: [b\n")),
                r"header_yaml: not valid YAML",
            ),
            "unknown_object": (_set("header_yaml", _header(unknown_object)), r"teapot"),
            "unknown_joint": (
                _set("header_yaml", _header(unknown_joint)),
                r"joint_names.*index_flexion_extra",
            ),
            "cov_not_pd": (_set("header_yaml", _header(bad_cov)), r"cov_object.*(positive|symmetric)"),
            "grasp_type_unknown": (_set("header_yaml", _header(bad_grasp)), r"grasp_type.*pinch"),
            "rate_text": (_set("header_yaml", _header(rate_text)), r"rate_hz"),
        },
    )


def trajectories() -> Path:
    traj = synthetic_trajectory(6, np.random.default_rng(0))
    good_path = HERE / "good" / "small.traj.npz"
    traj.save(good_path)
    with np.load(good_path, allow_pickle=False) as f:
        good = {k: f[k] for k in f.files}
    good_path.write_bytes(_npz_bytes(good))  # the same arrays, without the time of writing
    npz_variants(
        "traj",
        ".traj.npz",
        good,
        {
            "missing_cov": (_drop("cov_retarget"), r"missing keys \['cov_retarget'\]"),
            "joints_wrong_shape": (_set("joints", lambda a: a[:, :12]), r"joints: expected shape \(6, 13\)"),
            "cov_wrong_shape": (
                _set("cov_retarget", lambda a: a[:, :18, :18]),
                r"cov_retarget: expected shape",
            ),
            "wrist_nan": (_set("T_object_wrist", _nan_at((2, 1, 3))), r"T_object_wrist.*non-finite"),
            "joints_inf": (
                _set("joints", lambda a: np.where(np.arange(13) == 4, np.inf, a)),
                r"joints.*non-finite",
            ),
            "wrist_not_rotation": (_set("T_object_wrist", _skew), r"T_object_wrist.*not a rotation"),
            "cov_not_psd": (_set("cov_retarget", _not_pd), r"cov_retarget.*positive semi-definite"),
            "cov_not_symmetric": (
                _set("cov_retarget", lambda C: C + np.triu(np.ones((19, 19)), 1) * 1e-3),
                r"cov_retarget.*not symmetric",
            ),
            "object_cov_not_pd": (_set("cov_object", _not_pd), r"cov_object.*positive definite"),
            "one_step": (
                lambda d: {
                    k: (
                        v[:1] if k in ("T_object_wrist", "joints", "cov_retarget", "fingertip_rmse_mm") else v
                    )
                    for k, v in d.items()
                },
                r"at least 2 steps",
            ),
            "dt_text": (_set("dt_s", lambda a: np.str_("fast")), r"dt_s"),
            "grasp_type_unknown": (_set("grasp_type", lambda a: np.str_("pinch")), r"grasp_type.*pinch"),
            "object_vector": (
                _set("object", lambda a: np.array(["ham", "jam"])),
                r"object: expected a scalar",
            ),
            "meta_not_json": (_set("meta_json", lambda a: np.str_("{oops")), r"meta_json"),
        },
    )
    return good_path


def models() -> None:
    model = solve(synthetic_trajectory(5, np.random.default_rng(1)))
    path = HERE / "good" / "_tmp.model.npz"
    model.save(path)
    with np.load(path, allow_pickle=False) as f:
        good = {k: f[k] for k in f.files}
    path.unlink()
    good["solve_time_s"] = np.array(1.0)  # not the wall time: the corpus regenerates byte for byte
    params = json.loads(str(good["params_json"]))
    npz_variants(
        "model",
        ".model.npz",
        good,
        {
            "missing_cov": (_drop("cov"), r"missing keys \['cov'\]"),
            "cov_wrong_shape": (_set("cov", lambda a: a[:, :6, :6]), r"cov.*shape"),
            "cov_nan": (_set("cov", _nan_at((1, 2, 2))), r"cov.*non-finite"),
            "cov_not_pd": (_set("cov", _not_pd), r"cov.*positive definite"),
            "wrist_not_rotation": (
                _set("T_object_wrist_mean", _skew),
                r"T_object_wrist_mean.*not a rotation",
            ),
            "object_prior_nan": (
                _set("T_world_object_mean", _nan_at((0, 3))),
                r"T_world_object_mean.*non-finite",
            ),
            "params_not_json": (_set("params_json", lambda a: np.str_("{")), r"params_json: not JSON"),
            "params_unknown_name": (
                _set("params_json", lambda a: np.str_(json.dumps({**params, "sigma": 1}))),
                r"unknown parameters \['sigma'\]",
            ),
            "iterations_text": (_set("iterations", lambda a: np.str_("many")), r"iterations"),
            "one_step": (
                lambda d: {
                    k: (v[:1] if k in ("T_object_wrist_mean", "joints_mean", "cov", "constrained") else v)
                    for k, v in d.items()
                },
                r"(at least 2|T < 2|2 steps)",
            ),
            "grasp_type_unknown": (_set("grasp_type", lambda a: np.str_("pinch")), r"grasp_type.*pinch"),
        },
    )


def scenes() -> None:
    good = yaml.safe_load(assets.scene_path("ham").read_text())

    def variant(name, change, expect):
        d = json.loads(json.dumps(good))
        change(d)
        put("scene", f"{name}.yaml", yaml.safe_dump(d, sort_keys=False), expect)

    def delete(*keys):
        def change(d):
            for k in keys[:-1]:
                d = d[k]
            del d[keys[-1]]

        return change

    def assign(value, *keys):
        def change(d):
            for k in keys[:-1]:
                d = d[k]
            d[keys[-1]] = value

        return change

    text = assets.scene_path("ham").read_text()
    put("scene", "empty.yaml", "", r"expected a mapping, found NoneType")
    put("scene", "truncated.yaml", text[: text.index("rpy_deg")] + "rpy_deg: [0, 0", r"not valid YAML")
    put("scene", "not_yaml.yaml", "name: [ham\nhand: sah\n", r"not valid YAML")
    put("scene", "a_list.yaml", "- ham\n- jam\n", r"expected a mapping, found list")
    put(
        "scene",
        "position_nan.yaml",
        text.replace("position_m: [0, 0, 0]", "position_m: [0, .nan, 0]"),
        r"object.position_m\[1\]: non-finite",
    )
    variant("missing_object", delete("object"), r"object: missing field")
    variant("unknown_object", assign("teapot", "object", "name"), r"object.name: unknown name 'teapot'")
    variant("unknown_hand", assign("robotiq", "hand"), r"hand: unknown name 'robotiq'")
    variant("unknown_field", assign(1, "colour"), r"colour: unknown field")
    variant("position_text", assign("origin", "object", "position_m"), r"object.position_m: expected a list")
    variant(
        "position_short", assign([0, 0], "object", "position_m"), r"object.position_m: expected a list of 3"
    )
    variant(
        "negative_std", assign(-3.0, "object", "position_std_mm"), r"position_std_mm: expected a positive"
    )
    variant(
        "table_zero", assign([1.2, 0.0, 0.05], "table", "size_m"), r"table.size_m\[1\]: expected a positive"
    )
    variant(
        "bounds_inverted",
        assign({"min": [0, 0, 0.5], "max": [0.3, 0.3, 0.4]}, "wrist_bounds_m"),
        r"wrist_bounds_m: min",
    )
    variant(
        "obstacle_unknown_type",
        assign([{"type": "sphere", "position_m": [0, 0, 0]}], "obstacles"),
        r"obstacles\[0\].type: unknown name 'sphere'",
    )
    variant(
        "obstacle_missing_size",
        assign([{"type": "box", "position_m": [0.2, 0, 0]}], "obstacles"),
        r"obstacles\[0\].size_m: missing field",
    )
    # well-formed files that describe impossible scenes (planning/scene_checks.py)
    variant("object_in_table", assign([0, 0, -0.5], "object", "position_m"), r"object: ham is \d+ mm inside")
    variant("object_off_table", assign([5, 0, 0], "object", "position_m"), r"object: ham .* is off the table")
    variant("object_floating", assign([0, 0, 5], "object", "position_m"), r"object: ham floats")
    variant(
        "obstacle_overlaps",
        assign([{"type": "box", "position_m": [0, 0, 0.04], "size_m": [0.05, 0.05, 0.05]}], "obstacles"),
        r"obstacles: box0 overlaps the object by \d+ mm",
    )
    put("scene", "meshes/not_a_mesh.obj", "this is text, not a mesh\n", "")  # read by mesh_not_a_mesh.yaml
    MANIFEST.pop("scene/meshes/not_a_mesh.obj")
    variant(
        "mesh_not_a_mesh",
        assign([{"type": "mesh", "position_m": [0.3, 0, 0], "file": "meshes/not_a_mesh.obj"}], "obstacles"),
        r"obstacles: mesh0: not_a_mesh.obj .*is not a mesh",
    )


def params() -> None:
    put(
        "params",
        "unknown_name.yaml",
        "precision_fingertip_std_mm: 8\nsigma_m: 3\n",
        r"unknown parameters \['sigma_m'\]",
    )
    put(
        "params",
        "wrong_type.yaml",
        "smooth_position_std_mm: ten\n",
        r"smooth_position_std_mm: expected a number",
    )
    put("params", "nan.yaml", "constraint_std_mm: .nan\n", r"constraint_std_mm: expected a finite number")
    put("params", "inf.yaml", "clearance_mm: .inf\n", r"clearance_mm: expected a finite number")
    put(
        "params",
        "negative.yaml",
        "smooth_joint_std_deg: -5\n",
        r"smooth_joint_std_deg: expected a finite number > 0",
    )
    put("params", "not_integer.yaml", "max_iterations: 2.5\n", r"max_iterations: expected an integer")
    put("params", "a_list.yaml", "- 1\n- 2\n", r"expected a mapping")
    put("params", "truncated.yaml", "sigma_m_std_config: [0.03, 0.03,\n", r"not valid YAML")
    put(
        "params",
        "config_wrong_length.yaml",
        "sigma_m_std_config: [0.01, 0.01, 0.01]\n",
        r"sigma_m_std_config: expected 19 numbers",
    )
    put(
        "params",
        "config_zero_std.yaml",
        "smoothness_std_config: [" + ", ".join(["0.01"] * 18 + ["0"]) + "]\n",
        r"smoothness_std_config: every std must be finite and > 0",
    )
    put("params", "boolean.yaml", "self_clearance_mm: true\n", r"self_clearance_mm: expected a number")


def configurations() -> None:
    put("q", "empty.json", "", r"not valid JSON")
    put("q", "truncated.json", '{"q": [0.0, 0.1, 0.3, ', r"not valid JSON")
    put("q", "short.json", json.dumps({"q": [0.0] * 18}), r"q: expected a list of 19 numbers")
    put(
        "q",
        "nan.json",
        '{"q": [0, 0, 0.3, 0, 0, NaN' + ", 0" * 13 + "]}",
        r"q\[5\]: expected a finite number",
    )
    put(
        "q",
        "text_value.json",
        json.dumps({"q": [0.0] * 6 + ["open"] + [0.0] * 12}),
        r"q\[6\]: expected a finite",
    )
    put("q", "a_list.json", json.dumps([0.0] * 19), r"expected a JSON object, found list")
    put(
        "q",
        "unknown_joint.json",
        json.dumps(
            {"wrist_position_m": [0, 0, 0.3], "wrist_rotvec_rad": [0, 0, 0], "joints_deg": {"pinky_prox": 10}}
        ),
        r"joints_deg.pinky_prox: unknown joint",
    )
    put(
        "q",
        "missing_rotation.json",
        json.dumps({"wrist_position_m": [0, 0, 0.3]}),
        r"wrist_rotvec_rad: missing",
    )
    put("q", "both_forms.json", json.dumps({"q": [0.0] * 19, "wrist_position_m": [0, 0, 0]}), r"use one form")
    put("q", "binary.json", b"\xff\xfe\x00garbage", r"not valid JSON")
    q = [0.0, 0.0, 0.3, np.pi, 0.0, 0.0] + [0.0] * 13
    put("q", "joint_100_rad.json", json.dumps({"q": q[:8] + [100.0] + q[9:]}), r"joint .* outside its limits")
    put(
        "q", "wrist_1km.json", json.dumps({"q": [1000.0] + q[1:]}), r"wrist position: 1e\+03 m from the world"
    )
    put(
        "q", "rotvec_1e300.json", json.dumps({"q": q[:3] + [1e300] + q[4:]}), r"rotation vector: norm 1e\+300"
    )
    put("q", "nested_deep.json", "[" * 100_000 + "]" * 100_000, r"nested too deeply")


def databases() -> None:
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

    put("db", "empty.sqlite", b"", r"is not an SQLite database")
    put("db", "text.sqlite", "trial,success\n0,1\n", r"is not an SQLite database")
    put("db", "random.sqlite", np.random.default_rng(0).bytes(8192), r"is not an SQLite database")
    put("db", "other_schema.sqlite", made(lambda c: c.execute("CREATE TABLE runs (x INTEGER)")),
        r"another schema \(tables: runs")  # fmt: skip
    put("db", "other_columns.sqlite", made(lambda c: c.execute("CREATE TABLE trials (row TEXT, ok INTEGER)")),
        r"'trials' table of another schema")  # fmt: skip
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
    put("db", "newer_version.sqlite", newer, r"schema version 99")
    put("db", "truncated.sqlite", full[: len(full) // 2], r"not a readable|damaged|malformed")


def main() -> None:
    demonstrations()
    trajectories()
    models()
    scenes()
    params()
    configurations()
    databases()
    header = "# generated by make_corpus.py: file -> kind and the regex its one-line error must match\n"
    (HERE / "manifest.yaml").write_text(header + yaml.safe_dump(MANIFEST, sort_keys=True))


if __name__ == "__main__":
    main()
