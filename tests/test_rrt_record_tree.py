"""The optional tree record of RRT-CONNECT (``PlannerConfig(record_tree=True)``), used by the notebooks."""

import numpy as np
from test_rrt_connect import edge_free, plan, plan_without_grasp

from planning.rrt_connect import PlannerConfig

STEP_TOL = 1e-9  # edge length in scaled units may exceed the step by rounding only


def test_tree_is_off_by_default():
    assert "tree_q" not in plan(0).extra


def test_recorded_tree_holds_the_path_and_valid_edges():
    on = plan(0, record_tree=True)
    off = plan(0)
    assert on.success and off.success
    np.testing.assert_array_equal(on.path, off.path)  # recording changes nothing else
    q, parent = on.extra["tree_q"], on.extra["tree_parent"]
    assert q.shape == (on.nodes, 2) and parent.shape == (on.nodes,)
    np.testing.assert_array_equal(q[:2], [[0.1, 0.1], [0.1, 0.5]])  # roots first, no parent
    assert np.all(parent[:2] == -1) and np.all((parent[2:] >= 0) & (parent[2:] < np.arange(2, on.nodes)))
    scaled = np.linalg.norm((q[2:] - q[parent[2:]]) / 0.02, axis=1)
    assert scaled.max() <= 1.0 + STEP_TOL
    for i in np.flatnonzero(parent >= 0)[:200]:
        assert edge_free(q[parent[i]], q[i])
    # every path node is a tree node
    assert all(np.any(np.all(q == p, axis=1)) for p in on.path)


def test_failure_result_carries_the_tree_too():
    res = plan_without_grasp(PlannerConfig(time_limit_s=30, max_nodes=50, record_tree=True))
    assert not res.success and res.extra["tree_q"].shape == (50, 2)
