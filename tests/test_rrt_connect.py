"""RRT-CONNECT on a toy 2-D problem with a narrow passage, checked independently of the planner."""

import numpy as np
import pytest

from planning.config_space import EuclideanSpace, HandConfigSpace
from planning.rrt_connect import PlannerConfig, rrt_connect

# A wall at x in [0.45, 0.55] with a gap y in [0.48, 0.52]; start left, goal region right.
WALL = (0.45, 0.55)
GAP = (0.48, 0.52)
GOAL = np.array([0.9, 0.9])
GOAL_RADIUS = 0.05
RESOLUTION = 0.002


def point_free(p):
    x, y = p
    if not (0 <= x <= 1 and 0 <= y <= 1):
        return False
    return not (WALL[0] <= x <= WALL[1] and not (GAP[0] <= y <= GAP[1]))


def edge_free(a, b):
    n = max(2, int(np.ceil(np.linalg.norm(b - a) / RESOLUTION)) + 1)
    return all(point_free(a + s * (b - a)) for s in np.linspace(0, 1, n))


def sample_fn(rng):
    if rng.random() < 0.1:
        return GOAL + rng.normal(scale=0.02, size=2), True
    return rng.uniform(0, 1, size=2), False


def quality_fn(q):
    # 1 at the goal centre, 0 outside the goal disc: valid when within GOAL_RADIUS / 2.
    return max(0.0, 1.0 - np.linalg.norm(q - GOAL) / GOAL_RADIUS), None


def plan(seed, **kw):
    cfg = PlannerConfig(time_limit_s=30, max_nodes=20000, quality_threshold=0.5, **kw)
    roots = np.array([[0.1, 0.1], [0.1, 0.5]])
    return rrt_connect(
        roots,
        sample_fn,
        edge_free,
        quality_fn,
        EuclideanSpace((0.02, 0.02)),
        np.random.default_rng(seed),
        cfg,
    )


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_path_through_narrow_passage_is_valid(seed):
    res = plan(seed)
    assert res.success, res.message
    path = res.path
    assert any(np.allclose(path[0], r) for r in ([0.1, 0.1], [0.1, 0.5]))
    assert np.linalg.norm(path[-1] - GOAL) <= GOAL_RADIUS / 2 + 1e-12
    assert res.quality >= 0.5
    for a, b in zip(path[:-1], path[1:], strict=True):
        assert edge_free(a, b)  # independent re-check, finer than the planner's step
        assert np.linalg.norm((b - a) / 0.02) <= 1.0 + 1e-9
    # the path crosses the wall through the gap
    crossing = [p for p in path if WALL[0] <= p[0] <= WALL[1]]
    assert crossing and all(GAP[0] <= p[1] <= GAP[1] for p in crossing)
    assert res.collision_checks > 0 and res.quality_evaluations >= 1


def test_same_seed_same_result():
    a, b = plan(5), plan(5)
    np.testing.assert_array_equal(a.path, b.path)
    assert (a.nodes, a.iterations, a.quality_evaluations) == (b.nodes, b.iterations, b.quality_evaluations)


def plan_without_grasp(config):
    """The toy problem from one root with a quality that is never valid: the search runs to its limits."""
    return rrt_connect(
        np.array([[0.1, 0.1]]),
        sample_fn,
        edge_free,
        lambda q: (0.0, None),
        EuclideanSpace((0.02, 0.02)),
        np.random.default_rng(0),
        config,
    )


def test_node_limit_is_a_failure_result_not_none():
    res = plan_without_grasp(PlannerConfig(time_limit_s=30, max_nodes=300))
    assert not res.success and "node limit" in res.message and res.nodes == 300
    assert res.path.shape == (0, 2)


def test_hand_space_distance_and_interpolation():
    space = HandConfigSpace()
    a = np.zeros(19)
    b = np.zeros(19)
    b[0] = 0.03  # 3 cm
    b[3] = np.deg2rad(20.0)  # 20 deg about x
    b[10] = np.deg2rad(30.0)
    expected = np.sqrt(3.0**2 + 4.0**2 + 3.0**2)
    assert space.distance(a, b) == pytest.approx(expected, rel=1e-9)
    mid = space.interpolate(a, b, 0.5)
    assert space.distance(a, mid) == pytest.approx(expected / 2, rel=1e-9)
    feats = space.features(np.stack([a, b]))
    np.testing.assert_allclose(space.distance_to(feats, b), [expected, 0.0], atol=1e-7)


def test_hand_space_fast_paths_equal_scipy_rotations():
    """distance, distance_to and interpolate work on plain floats (and distance_to through |a|^2 + |b|^2
    - 2 a.b); they must equal the metric and the slerp computed with scipy, for pairs from 1e-9 apart
    (where both shortcuts lose digits unless they fall back) to far apart."""
    from scipy.spatial.transform import Rotation, Slerp

    space = HandConfigSpace()
    rng = np.random.default_rng(7)
    scale = np.r_[[space.position_step_m] * 3, [space.joint_step_rad] * 13]
    a_all, b_all, ref_d = [], [], []
    for spread in (1e-9, 1e-5, 1e-2, 0.3, 2.0):
        for _ in range(40):
            a = rng.normal(size=19) * 0.5
            b = a + rng.normal(size=19) * spread
            ra, rb = Rotation.from_rotvec(a[3:6]), Rotation.from_rotvec(b[3:6])
            angle = (ra.inv() * rb).magnitude()
            lin = (np.r_[a[:3], a[6:]] - np.r_[b[:3], b[6:]]) / scale
            d = np.sqrt(lin @ lin + (angle / space.rotation_step_rad) ** 2)
            assert space.distance(a, b) == pytest.approx(d, rel=1e-9, abs=1e-7)
            s = rng.uniform()
            mid = space.interpolate(a, b, s)
            lin_mid = np.r_[a[:3], a[6:]] - s * lin * scale  # lin is (a - b) / scale
            np.testing.assert_allclose(np.r_[mid[:3], mid[6:]], lin_mid, atol=1e-12)
            slerp = Slerp([0.0, 1.0], Rotation.concatenate([ra, rb]))([s])[0]
            assert (slerp.inv() * Rotation.from_rotvec(mid[3:6])).magnitude() < 1e-9
            many = space.interpolate_many(a, b, np.array([0.0, s, 1.0]))
            np.testing.assert_allclose(many[1], mid, atol=1e-9)
            a_all.append(a)
            b_all.append(b)
            ref_d.append(d)
    feats = space.features(np.array(a_all))
    for i, b in enumerate(b_all):
        row = space.distance_to(feats, b)  # every node against b: entry i is the pair's distance
        assert row[i] == pytest.approx(ref_d[i], rel=1e-9, abs=1e-7)
        if i % 40 == 0:
            np.testing.assert_allclose(row, [space.distance(a, b) for a in a_all], rtol=1e-9, atol=1e-7)


def test_hand_space_nearest_is_the_brute_force_argmin():
    """``nearest`` prunes by a lower bound (no arccos for most nodes); it must return exactly the first
    argmin of ``distance_to`` over every node, for trees from one node to thousands, with coincident
    nodes (ties), queries on a node, 1e-6 from one, and far from all."""
    space = HandConfigSpace()
    rng = np.random.default_rng(3)
    for _ in range(120):
        n = int(rng.integers(1, 2000))
        spread = rng.choice([1e-3, 0.05, 0.5, 3.0])
        q = rng.normal(size=(n, 19)) * spread
        q[rng.integers(n, size=n // 10)] = q[0]  # ties: the first index must win
        feats = space.features(q)
        query = q[rng.integers(n)] + rng.normal(size=19) * spread * rng.choice([0.0, 1e-6, 0.1, 1.0])
        assert space.nearest(feats, query) == int(np.argmin(space.distance_to(feats, query)))


def test_hand_space_steer_is_distance_then_interpolate():
    space = HandConfigSpace()
    rng = np.random.default_rng(4)
    for step in (0.5, 1.0, 3.0):
        for _ in range(50):
            a = rng.normal(size=19) * 0.3
            b = a + rng.normal(size=19) * rng.choice([0.001, 0.02, 0.3])
            q, reached = space.steer(a, b, step)
            d = space.distance(a, b)
            assert reached == (d <= step)
            expected = b if reached else space.interpolate(a, b, step / d)
            np.testing.assert_array_equal(q, expected)
            if not reached:
                assert space.distance(a, q) == pytest.approx(step, rel=1e-9)


def test_goal_samples_inside_the_object_are_evaluated_where_the_extension_stops():
    """Last-step samples of a grasp lie partly inside the object; an extension towards one stops at the
    surface, which is where closing the hand makes a grasp. ``goal_radius`` admits that node."""
    centre, radius, step = np.array([0.8, 0.8]), 0.02, 0.02

    def free(a, b):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / RESOLUTION)) + 1)
        return all(np.linalg.norm(a + s * (b - a) - centre) > radius for s in np.linspace(0, 1, n))

    def goal_inside(rng):
        if rng.random() < 0.1:
            return centre + rng.normal(scale=0.004, size=2).clip(-0.01, 0.01), True  # inside the disc
        return rng.uniform(0, 1, size=2), False

    def touching(q):  # 1 on the surface, 0 from 4 cm away
        return max(0.0, 1.0 - (np.linalg.norm(q - centre) - radius) / 0.04), None

    def run(goal_radius):
        return rrt_connect(
            np.array([[0.1, 0.1]]),
            goal_inside,
            free,
            touching,
            EuclideanSpace((step, step)),
            np.random.default_rng(3),
            PlannerConfig(time_limit_s=30, max_nodes=3000, quality_threshold=0.5, goal_radius=goal_radius),
        )

    strict = run(0.0)
    assert not strict.success and strict.quality_evaluations == 0  # no sample can ever be reached
    res = run(3.0)
    assert res.success, res.message
    end = res.path[-1]
    assert radius < np.linalg.norm(end - centre) <= radius + step  # stopped within a step of the surface
    assert all(free(a, b) for a, b in zip(res.path[:-1], res.path[1:], strict=True))


def test_an_extension_blocked_at_its_first_step_scores_its_nearest_node_once():
    """A jar in a hole, in 2-D: the block (y < 0.5) has a hole whose grasp sample sits at its bottom, out of
    reach. The only node is a root on the rim straight above it; every extension towards the sample is
    blocked at its first step. Closing the hand on the rim is the grasp (quality 1 within 1 cm of the
    rim): ``score_stalled`` scores the root, once, and the path is the root alone; without it no node is
    ever scored."""
    rim, sample = np.array([0.5, 0.505]), np.array([0.5, 0.48])

    def free(a, b):  # the block y < 0.5; the hole is too narrow for the tree
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / RESOLUTION)) + 1)
        return all((a + s * (b - a))[1] >= 0.5 for s in np.linspace(0, 1, n))

    def at_rim(q):
        return float(0.5 <= q[1] <= 0.51), None

    def run(score_stalled, quality_fn=at_rim):
        return rrt_connect(
            rim[None, :],
            lambda rng: (sample.copy(), True),
            free,
            quality_fn,
            EuclideanSpace((0.02, 0.02)),
            np.random.default_rng(0),
            PlannerConfig(
                time_limit_s=0.2, max_nodes=100, quality_threshold=0.5, score_stalled=score_stalled
            ),
        )

    res = run(True)
    assert res.success and res.quality_evaluations == 1 and res.nodes == 1
    np.testing.assert_array_equal(res.path, rim[None, :])
    assert res.quality == 1.0
    old = run(False)
    assert not old.success and old.quality_evaluations == 0 and old.nodes == 1
    never = run(True, lambda q: (0.0, None))  # a node is scored once, however often it stalls
    assert not never.success and never.quality_evaluations == 1 and never.iterations > 10


def _in_l_pocket_problem():
    """A solid block (y in [0.2, 0.5]) with an L-shaped pocket: a shaft down at x = 0.2, then a gallery
    to x = 0.6 with the grasp at its far end. A start tree grows its nodes above the block next to the
    grasp, and every extension from them towards it hits the block's top."""

    def point_free(p):
        x, y = p
        if not (0 <= x <= 1 and 0 <= y <= 1):
            return False
        if not (0.05 <= x <= 0.95 and 0.2 <= y <= 0.5):
            return True
        return (0.18 <= x <= 0.22 and y >= 0.26) or (0.18 <= x <= 0.6 and 0.26 <= y <= 0.30)

    def free(a, b):
        n = max(2, int(np.ceil(np.linalg.norm(b - a) / RESOLUTION)) + 1)
        return all(point_free(a + s * (b - a)) for s in np.linspace(0, 1, n))

    goal = np.array([0.58, 0.28])

    def sample(rng):
        if rng.random() < 0.2:
            return goal + rng.normal(scale=0.01, size=2), True
        return rng.uniform(0, 1, size=2), False

    def quality(q):
        return max(0.0, 1.0 - np.linalg.norm(q - goal) / 0.05), None

    return free, sample, quality, goal


POCKET_STEP = 0.02
POCKET_ROOT = np.array([0.5, 0.9])


def _plan_in_pocket(problem, sample, seed, goal_sample_fn=None, **config):
    """rrt_connect on the L-pocket problem from ``POCKET_ROOT`` with ``sample`` as P(Y)."""
    free, _, quality, _ = problem
    return rrt_connect(
        POCKET_ROOT[None, :],
        sample,
        free,
        quality,
        EuclideanSpace((POCKET_STEP, POCKET_STEP)),
        np.random.default_rng(seed),
        PlannerConfig(time_limit_s=60, max_nodes=4000, quality_threshold=0.5, **config),
        goal_sample_fn=goal_sample_fn,
    )


def _assert_joined_path_to_the_grasp(r, problem):
    """A goal tree joined: the path runs from the start root to a valid grasp, every edge free (re-checked
    finer than the planner's step) and at most one step long."""
    free, _, quality, _ = problem
    assert r.success and r.message == "valid grasp found (goal tree joined)"
    path = r.path
    np.testing.assert_array_equal(path[0], POCKET_ROOT)  # from the start root ...
    assert quality(path[-1])[0] >= 0.5 and r.quality == quality(path[-1])[0]  # ... to the valid grasp
    for a, b in zip(path[:-1], path[1:], strict=True):
        assert free(a, b)  # independent re-check, finer than the planner's step
        assert np.linalg.norm(b - a) <= POCKET_STEP + 1e-12


def test_goal_trees_join_a_valid_grasp_in_a_pocket_the_single_tree_struggles_with():
    problem = _in_l_pocket_problem()
    sample = problem[1]

    def run(seed, goal_trees):
        return _plan_in_pocket(problem, sample, seed, goal_trees=goal_trees)

    single = [run(seed, False) for seed in range(5)]
    both = [run(seed, True) for seed in range(5)]
    assert sum(not r.success for r in single) >= 1  # the paper's single tree hits the node limit
    for r in both:
        _assert_joined_path_to_the_grasp(r, problem)
        assert r.nodes <= 1000
        assert any(0.18 <= x <= 0.22 and 0.3 < y < 0.5 for x, y in r.path)  # down the shaft
    assert run(2, True).nodes == both[2].nodes  # the same seed, the same search


def test_goal_region_roots_goal_trees_from_its_own_draws():
    """With goal_region_tries the goal trees get roots from goal_sample_fn (OMPL's RRTConnect rule), even
    when P(Y) never draws a goal sample; without it such a search never scores anything."""
    problem = _in_l_pocket_problem()
    goal = problem[3]

    def no_goal_samples(rng):
        return rng.uniform(0, 1, size=2), False

    def near_goal(rng):
        return goal + rng.normal(scale=0.01, size=2)

    def run(tries, seed=0, goal_sample_fn=near_goal):
        return _plan_in_pocket(
            problem, no_goal_samples, seed, goal_sample_fn, goal_trees=True, goal_region_tries=tries
        )

    for seed in range(3):
        _assert_joined_path_to_the_grasp(run(20, seed), problem)
    off = run(0)
    assert not off.success and off.quality_evaluations == 0
    with pytest.raises(ValueError, match="goal_sample_fn"):
        run(5, goal_sample_fn=None)


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
