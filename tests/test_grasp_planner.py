"""The planners on the real ham scene, with a strategy built in code (``ham_top_down_model`` of conftest.py).

Paths are checked independently of the planner: the first node is a collision-free root, every edge is
re-checked at twice the planner's resolution in a separate world, and the grasp at the end is scored again
by a fresh hand closer.
"""

import numpy as np
import pytest

from planning.autograsp import HandCloser
from planning.collision import CollisionChecker
from planning.grasp_planner import GraspPlanner, PlanningSettings
from planning.world import World

EPSILON = 0.05


@pytest.fixture(scope="module")
def model(ham_top_down_model):
    return ham_top_down_model()


@pytest.fixture(scope="module")
def planner(model):
    with GraspPlanner("ham", [model]) as gp:
        yield gp


@pytest.fixture(scope="module")
def referee():
    with World("ham") as w:
        yield w


def check_plan(res, referee):
    assert res.success, res.message
    assert res.quality >= EPSILON
    path = res.path
    assert path.ndim == 2 and path.shape[1] == 19 and len(path) >= 2
    fine = CollisionChecker(referee, 0.0025, np.deg2rad(1.0), np.deg2rad(2.0))
    assert fine.is_free(path[0])
    for a, b in zip(path[:-1], path[1:], strict=True):
        assert fine.is_edge_free(a, b)
    again = HandCloser(referee).close(path[-1])
    assert again.quality == pytest.approx(res.quality, abs=1e-9)
    np.testing.assert_allclose(res.grasp.closed_q, again.closed_q, atol=1e-12)


def test_learned_planner_solves_the_ham_scene(planner, referee):
    settings = PlanningSettings(planner="learned", beta=0.05, time_limit_s=120.0, max_nodes=20_000)
    res = planner.plan(np.random.default_rng(0), settings)
    check_plan(res, referee)
    assert res.extra["roots"] == 100
    assert res.quality_evaluations >= 1 and res.collision_checks > res.nodes


def test_same_seed_same_plan(planner):
    settings = PlanningSettings(planner="learned", time_limit_s=120.0, max_nodes=20_000)
    a = planner.plan(np.random.default_rng(3), settings)
    b = planner.plan(np.random.default_rng(3), settings)
    assert a.success and b.success
    np.testing.assert_array_equal(a.path, b.path)
    assert (a.nodes, a.iterations, a.quality, a.quality_evaluations) == (
        b.nodes,
        b.iterations,
        b.quality,
        b.quality_evaluations,
    )


@pytest.mark.parametrize("name", ["bidirectional", "goal_region"])
def test_goal_tree_planners_solve_the_ham_scene(planner, referee, name):
    settings = PlanningSettings(planner=name, time_limit_s=120.0, max_nodes=20_000)
    check_plan(planner.plan(np.random.default_rng(4), settings), referee)


def test_baseline_and_ompl_paths_are_valid_when_found(planner, referee):
    for name in ("baseline", "ompl"):
        res = planner.plan(np.random.default_rng(1), PlanningSettings(planner=name, time_limit_s=60.0))
        if res.success:  # the baseline may fail: that is a result, not an error
            check_plan(res, referee)
        else:
            assert res.path.shape == (0, 19) and res.message


def test_roots_come_from_the_first_marginal_and_are_free(planner, model):
    roots = planner.roots(np.random.default_rng(2), 50)
    assert len(roots) == 50
    assert all(planner.world.is_free(q) for q in roots)
    T_world_first = planner.scene.T_world_object @ model.T_object_wrist_mean[0]
    # 3-sigma of the first marginal's wrist position is a few cm at most
    assert np.abs(roots[:, :3] - T_world_first[:3, 3]).max() < 0.08
