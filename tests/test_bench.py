"""``pbdgrasp bench --quick``: it runs, its JSON has every figure, and its cross-checks hold (no timings)."""

import json

import numpy as np
import pytest

from pbdgrasp.bench_fixtures import synthetic_trajectory
from pbdgrasp.cli import main
from pbdgrasp.cli.bench import format_table

DENSE_REL_TOL = 1e-9  # gtsam marginals vs the dense inverse of the information matrix, relative
HAM_GRASP_EPSILON_MIN = 0.05  # the hand-placed ham grasp reaches the paper's threshold


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "bench.json"
    argv = ["bench", "--quick", "--trials", "1", "--time-limit-s", "5", "--json", "-o", str(out)]
    assert main(argv) == 0
    return json.loads(out.read_text())


def test_quick_bench_json_has_every_section_and_key(quick):
    assert set(quick) >= {
        "machine", "config", "inference", "scene_inference", "sampler", "collision", "quality", "retargeting",
        "planning", "memory",
    }  # fmt: skip
    assert set(quick["machine"]) >= {"platform", "cpu_count", "cpu_model"}
    for row in quick["inference"]["rows"]:
        assert set(row) == {"T", "solve_ms", "marginals_ms", "dense_ms", "dense_over_gtsam", "max_rel_diff"}
        assert row["solve_ms"] > 0 and row["dense_ms"] > 0
    assert set(quick["scene_inference"]["ham"]) == {
        "T", "solve_s", "fields_s", "iterations", "converged", "constrained_steps", "scene_grasp_s",
        "scene_grasp_kept",
    }  # fmt: skip
    assert quick["sampler"]["samples_per_s"] > 0 and quick["sampler"]["numpy_normals_19d_per_s"] > 0
    assert set(quick["collision"]) >= {"configs_per_s", "edges_per_s"}
    assert set(quick["quality"]) >= {"epsilon_us", "close_and_score_ms"}
    assert quick["retargeting"]["s_per_step"] > 0
    ham = quick["planning"]["ham"]
    assert set(ham["planners"]) == {"learned", "baseline", "ompl", "bidirectional", "goal_region"}
    for p in ham["planners"].values():
        assert set(p) >= {
            "success_rate", "median_eta_s", "median_nodes", "median_collision_checks",
            "share_collision", "share_quality", "share_overhead",
        }  # fmt: skip
        assert 0.0 <= p["success_rate"] <= 1.0
        shares = [p["share_collision"], p["share_quality"], p["share_overhead"]]
        assert abs(sum(shares) - 1.0) < 1e-9 and min(shares[:2]) >= 0.0
    assert set(ham["ratios"]) == {"learned_over_ompl", "learned_over_baseline"}
    assert quick["memory"]["peak_rss_mib"] > 0


def test_quick_bench_cross_checks(quick):
    """The figures carry their own oracles: the dense marginals agree and the ham grasp scores."""
    worst = max(row["max_rel_diff"] for row in quick["inference"]["rows"])
    assert worst < DENSE_REL_TOL
    ham = quick["scene_inference"]["ham"]
    assert ham["converged"] and ham["constrained_steps"] == ham["T"] == 30
    assert quick["quality"]["ham_grasp_quality"] >= HAM_GRASP_EPSILON_MIN
    assert 0.0 < quick["collision"]["free_fraction"] < 1.0


def test_table_names_the_machine_and_every_section(quick):
    text = format_table(quick)  # from the JSON: the table needs nothing the JSON lacks
    assert text.startswith("machine: ") and quick["machine"]["cpu_model"] in text
    for word in ("inference", "sampler", "collision", "quality", "retargeting", "planning", "peak memory"):
        assert word in text
    assert text.count("ham ") >= 3  # one row per planner


def test_synthetic_trajectory_is_a_valid_top_down_approach():
    traj = synthetic_trajectory(20, np.random.default_rng(0))
    z = traj.T_object_wrist[:, 2, 3]
    assert traj.num_steps == 20 and np.all(np.diff(z) <= 1e-12)  # descends monotonically
    assert np.linalg.matrix_rank(traj.cov_retarget[0]) == 6  # degenerate, as the paper's Sigma_r


def test_bad_bench_arguments_exit_2(capsys):
    assert main(["bench", "--quick", "--trials", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "trials" in err[0]


@pytest.mark.parametrize(
    "argv, what",
    [(["--model", "ham"], "SCENE=M.model.npz"), (["--model", "teapot=x.model.npz"], "unknown scenes")],
)
def test_bad_model_overrides_exit_2(argv, what, capsys):
    assert main(["bench", "--quick", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and what in err[0]
