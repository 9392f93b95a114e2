"""``pbdgrasp inspect``: a model whose marginals are points gives the collision state and the grasp of its
means, checked directly in pybullet; a model through the table collides in every draw, with the table."""

import dataclasses
import json

import numpy as np
import pytest

from assets.se3 import q_from_pose
from pbdgrasp.cli import main
from pbdgrasp.inspect import inspect_model
from planning.autograsp import HandCloser
from planning.collision import CollisionChecker
from planning.scene import load_scene
from planning.world import World

STEPS = 8
POINT_COV = 1e-14  # [rad^2, m^2]: draws within 1e-7 of the means


@pytest.fixture(scope="module")
def point_model(ham_top_down_model):
    """The top-down ham approach ending at the hand-placed grasp, its marginals shrunk to points on tau_r."""
    model = ham_top_down_model(STEPS)
    return dataclasses.replace(
        model,
        T_object_wrist_mean=model.source.T_object_wrist,
        joints_mean=model.source.joints,
        cov=np.repeat(POINT_COV * np.eye(19)[None], STEPS, axis=0),
        cov_object=POINT_COV * np.eye(6),
    )


@pytest.fixture(scope="module")
def quiet_ham():
    """The ham scene with its object localized to 1e-9 m and 1e-9 rad (the planner draws O ~ P(O))."""
    scene = load_scene("ham")
    return dataclasses.replace(
        scene, object=dataclasses.replace(scene.object, position_std_mm=1e-6, rotation_std_deg=6e-8)
    )


def _mean_q(model, t):
    return np.r_[q_from_pose(model.T_world_object_mean @ model.T_object_wrist_mean[t]), model.joints_mean[t]]


def test_point_marginals_give_the_collision_state_and_grasp_of_the_means(point_model, quiet_ham):
    scene = quiet_ham
    result = inspect_model(point_model, scene, 6, np.random.default_rng(0))
    with World(scene) as world:
        expected = [float(world.is_free(_mean_q(point_model, t))) for t in range(STEPS)]
        closed = HandCloser(world).close(_mean_q(point_model, STEPS - 1))
    assert result.free_fraction == tuple(expected)
    assert 0.0 < np.mean(expected) and expected[0] == 1.0  # the approach starts free
    with World(scene) as world:
        inside = [
            {c.link for c in world.hand_contacts(_mean_q(point_model, t)) if c.distance_m < 0}
            for t in range(STEPS)
        ]
    for t in range(STEPS):  # a colliding mean collides in every draw, with something named, by its links
        hit = max(result.hits[kind][t] for kind in result.hits)
        assert hit == pytest.approx(1.0 - expected[t])
        assert result.links[t] == dict.fromkeys(sorted(inside[t]), 1.0)
    assert closed.quality >= 0.05
    assert result.valid_fraction == 1.0 and result.best_epsilon == pytest.approx(closed.quality, abs=2e-3)
    assert result.valid_of_free == 1.0
    assert result.converged and result.draws == 6 and len(result.free_fraction) == STEPS
    assert result.blocked_mean_steps == ()  # from above the table onto the ham: only the object is touched


def test_a_mean_moved_through_the_table_blocks_the_path_to_it_and_from_it(point_model, quiet_ham):
    """The means' path (the planner's edges between consecutive means) is blocked exactly on the two edges
    at a mean moved 30 cm down, through the table; the draws of every other step are as before."""
    T = point_model.T_object_wrist_mean.copy()
    T[3, 2, 3] -= 0.3
    dipped = dataclasses.replace(point_model, T_object_wrist_mean=T)
    result = inspect_model(dipped, quiet_ham, 2, np.random.default_rng(2))
    assert result.blocked_mean_steps == (2, 3)
    fresh = []  # each edge in a world of its own: no contact points kept from the edge through the table
    for t in range(STEPS - 1):
        with World(quiet_ham) as world:
            points = CollisionChecker(world).edge_points(_mean_q(dipped, t), _mean_q(dipped, t + 1))
            if any(c.distance_m < 0 and c.other != "ham" for x in points for c in world.hand_contacts(x)):
                fresh.append(t)
    assert tuple(fresh) == result.blocked_mean_steps
    assert result.free_fraction[3] == 0.0 and result.hits["environment"][3] == 1.0
    assert (
        "the means' path passes through the table, an obstacle or the hand from steps 2-3" in result.summary()
    )


def test_a_model_through_the_table_collides_with_the_table_in_every_draw(point_model, quiet_ham):
    T = point_model.T_object_wrist_mean.copy()
    T[:, 2, 3] -= 0.3  # 30 cm down: through the table top
    sunk = dataclasses.replace(point_model, T_object_wrist_mean=T)
    result = inspect_model(sunk, quiet_ham, 4, np.random.default_rng(1))
    assert result.free_fraction == (0.0,) * STEPS
    assert result.hits["environment"] == (1.0,) * STEPS
    assert "environment 100%" in result.summary() and "no draw free" in result.summary()
    z2 = 1.959963984540054**2  # none of n: the Wilson interval is [0, z^2 / (n + z^2)] (closed form)
    assert f"min 0% at step 0 (95 % interval 0%-{z2 / (4 + z2):.0%};" in result.summary()
    assert f"valid grasp (95 % interval 0%-{z2 / (4 + z2):.0%};" in result.summary()
    assert np.isnan(result.valid_of_free) and json.loads(result.to_json())["valid_of_free"] is None
    assert all(result.links[t] and set(result.links[t].values()) == {1.0} for t in range(STEPS))
    assert result.blocked_mean_steps == tuple(range(STEPS - 1))  # every edge inside the table


def test_cli_json_plot_and_a_bad_draw_count(point_model, tmp_path, capsys):
    path = point_model.save(tmp_path / "ham.model.npz")
    plot = tmp_path / "free.png"
    argv = ["inspect", str(path), "--scene", "ham", "--draws", "3", "--json", "--plot", str(plot)]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert len(out["free_fraction"]) == STEPS and set(out["hits"]) == {"object", "environment", "self"}
    assert plot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    for processes in ("1", "3"):  # the same measurements on any number of processes
        assert main(argv[:-2] + ["--processes", processes]) == 0
        assert json.loads(capsys.readouterr().out) == out
    assert main(["inspect", str(path), "--scene", "ham", "--draws", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--draws" in err[0]
