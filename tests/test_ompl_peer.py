"""OMPL's RRTConnect as the peer planner, on a hand-space toy problem without pybullet."""

import numpy as np

from planning.ompl_peer import plan_ompl

LIMITS = np.tile([0.0, 1.0], (13, 1))
BOUNDS = (np.array([-0.3, -0.3, 0.0]), np.array([0.3, 0.3, 0.5]))
GOAL = np.concatenate([[0.0, 0.0, 0.1], [0.0, 0.0, 0.0], np.full(13, 0.5)])


def is_free(q):
    # a slab at 0.25 < z < 0.3 with a hole |x|, |y| < 0.05
    z_in = 0.25 < q[2] < 0.3
    return not (z_in and (abs(q[0]) > 0.05 or abs(q[1]) > 0.05))


def quality_fn(q):
    return max(0.0, 1.0 - np.linalg.norm(q[:3] - GOAL[:3]) / 0.05), None


def goal_sample_fn(rng):
    q = GOAL.copy()
    q[:3] += rng.normal(scale=0.01, size=3)
    return q


def test_ompl_peer_finds_a_valid_path_through_the_hole():
    root = GOAL.copy()
    root[2] = 0.45
    res = plan_ompl(
        root[None],
        goal_sample_fn,
        is_free,
        quality_fn,
        BOUNDS,
        LIMITS,
        np.random.default_rng(0),
        time_limit_s=10.0,
        quality_threshold=0.5,
    )
    assert res.success, res.message
    assert res.quality >= 0.5
    np.testing.assert_allclose(res.path[0], root, atol=1e-6)
    assert np.linalg.norm(res.path[-1][:3] - GOAL[:3]) <= 0.025 + 1e-9
    # every edge checked independently at 1 mm
    for a, b in zip(res.path[:-1], res.path[1:], strict=True):
        n = int(np.ceil(np.linalg.norm(b[:3] - a[:3]) / 0.001)) + 1
        assert all(is_free(a + s * (b - a)) for s in np.linspace(0, 1, n))
    assert res.nodes > 1 and res.collision_checks > 0
