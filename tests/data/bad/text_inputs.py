"""The corpus's text inputs: scenes (``scene/*.yaml``), parameter files (``params/*.yaml``) and configurations
(``q/*.json``); written by ``make_corpus.py``."""

from __future__ import annotations

import json

import numpy as np
import yaml
from corpus_io import Corpus

import assets


def scenes(corpus: Corpus) -> None:
    good = yaml.safe_load(assets.scene_path("ham").read_text())

    def variant(name, change, expect):
        d = json.loads(json.dumps(good))
        change(d)
        corpus.put("scene", f"{name}.yaml", yaml.safe_dump(d, sort_keys=False), expect)

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
    corpus.put("scene", "empty.yaml", "", r"expected a mapping, found NoneType")
    corpus.put("scene", "truncated.yaml", text[: text.index("rpy_deg")] + "rpy_deg: [0, 0", r"not valid YAML")
    corpus.put("scene", "not_yaml.yaml", "name: [ham\nhand: sah\n", r"not valid YAML")
    corpus.put("scene", "a_list.yaml", "- ham\n- jam\n", r"expected a mapping, found list")
    corpus.put(
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
    corpus.put(
        "scene", "meshes/not_a_mesh.obj", "this is text, not a mesh\n", None
    )  # read by mesh_not_a_mesh.yaml
    variant(
        "mesh_not_a_mesh",
        assign([{"type": "mesh", "position_m": [0.3, 0, 0], "file": "meshes/not_a_mesh.obj"}], "obstacles"),
        r"obstacles: mesh0: not_a_mesh.obj .*is not a mesh",
    )


def params(corpus: Corpus) -> None:
    corpus.put(
        "params",
        "unknown_name.yaml",
        "precision_fingertip_std_mm: 8\nsigma_m: 3\n",
        r"unknown parameters \['sigma_m'\]",
    )
    corpus.put(
        "params",
        "wrong_type.yaml",
        "smooth_position_std_mm: ten\n",
        r"smooth_position_std_mm: expected a number",
    )
    corpus.put(
        "params", "nan.yaml", "constraint_std_mm: .nan\n", r"constraint_std_mm: expected a finite number"
    )
    corpus.put("params", "inf.yaml", "clearance_mm: .inf\n", r"clearance_mm: expected a finite number")
    corpus.put(
        "params",
        "negative.yaml",
        "smooth_joint_std_deg: -5\n",
        r"smooth_joint_std_deg: expected a finite number > 0",
    )
    corpus.put("params", "not_integer.yaml", "max_iterations: 2.5\n", r"max_iterations: expected an integer")
    corpus.put("params", "a_list.yaml", "- 1\n- 2\n", r"expected a mapping")
    corpus.put("params", "truncated.yaml", "sigma_m_std_config: [0.03, 0.03,\n", r"not valid YAML")
    corpus.put(
        "params",
        "config_wrong_length.yaml",
        "sigma_m_std_config: [0.01, 0.01, 0.01]\n",
        r"sigma_m_std_config: expected 19 numbers",
    )
    corpus.put(
        "params",
        "config_zero_std.yaml",
        "smoothness_std_config: [" + ", ".join(["0.01"] * 18 + ["0"]) + "]\n",
        r"smoothness_std_config: every std must be finite and > 0",
    )
    corpus.put("params", "boolean.yaml", "self_clearance_mm: true\n", r"self_clearance_mm: expected a number")


def configurations(corpus: Corpus) -> None:
    corpus.put("q", "empty.json", "", r"not valid JSON")
    corpus.put("q", "truncated.json", '{"q": [0.0, 0.1, 0.3, ', r"not valid JSON")
    corpus.put("q", "short.json", json.dumps({"q": [0.0] * 18}), r"q: expected a list of 19 numbers")
    corpus.put(
        "q",
        "nan.json",
        '{"q": [0, 0, 0.3, 0, 0, NaN' + ", 0" * 13 + "]}",
        r"q\[5\]: expected a finite number",
    )
    corpus.put(
        "q",
        "text_value.json",
        json.dumps({"q": [0.0] * 6 + ["open"] + [0.0] * 12}),
        r"q\[6\]: expected a finite",
    )
    corpus.put("q", "a_list.json", json.dumps([0.0] * 19), r"expected a JSON object, found list")
    corpus.put(
        "q",
        "unknown_joint.json",
        json.dumps(
            {"wrist_position_m": [0, 0, 0.3], "wrist_rotvec_rad": [0, 0, 0], "joints_deg": {"pinky_prox": 10}}
        ),
        r"joints_deg.pinky_prox: unknown joint",
    )
    corpus.put(
        "q",
        "missing_rotation.json",
        json.dumps({"wrist_position_m": [0, 0, 0.3]}),
        r"wrist_rotvec_rad: missing",
    )
    corpus.put(
        "q", "both_forms.json", json.dumps({"q": [0.0] * 19, "wrist_position_m": [0, 0, 0]}), r"use one form"
    )
    corpus.put("q", "binary.json", b"\xff\xfe\x00garbage", r"not valid JSON")
    q = [0.0, 0.0, 0.3, np.pi, 0.0, 0.0] + [0.0] * 13
    corpus.put(
        "q", "joint_100_rad.json", json.dumps({"q": q[:8] + [100.0] + q[9:]}), r"joint .* outside its limits"
    )
    corpus.put(
        "q", "wrist_1km.json", json.dumps({"q": [1000.0] + q[1:]}), r"wrist position: 1e\+03 m from the world"
    )
    corpus.put(
        "q", "rotvec_1e300.json", json.dumps({"q": q[:3] + [1e300] + q[4:]}), r"rotation vector: norm 1e\+300"
    )
    corpus.put("q", "nested_deep.json", "[" * 100_000 + "]" * 100_000, r"nested too deeply")
