"""Edge resolution of the collision checker, with a stand-in world (the real one is tested in test_world)."""

import numpy as np
import pytest

from planning.collision import CollisionChecker


class HalfSpaceWorld:
    """Free iff the wrist x-coordinate is below 0.1 m."""

    def is_free(self, q):
        return q[0] < 0.1


def test_edge_points_respect_the_resolution():
    cc = CollisionChecker(HalfSpaceWorld())
    a = np.zeros(19)
    b = np.zeros(19)
    b[0] = 0.052  # 52 mm -> 11 checks at 5 mm
    b[5] = np.deg2rad(7.0)  # 7 deg -> 4 checks at 2 deg
    pts = cc.edge_points(a, b)
    assert len(pts) == 11
    np.testing.assert_allclose(pts[-1], b, atol=1e-12)
    steps = np.diff(np.vstack([a, pts]), axis=0)
    assert np.abs(steps[:, 0]).max() <= 0.005 + 1e-12
    assert np.abs(steps[:, 5]).max() <= np.deg2rad(2.0) + 1e-12
    b2 = np.zeros(19)
    b2[8] = np.deg2rad(20.0)
    assert len(cc.edge_points(a, b2)) == 5


@pytest.mark.parametrize("x_end, free", [(0.099, True), (0.2, False)])
def test_edge_blocked_when_it_crosses_the_obstacle(x_end, free):
    cc = CollisionChecker(HalfSpaceWorld())
    b = np.zeros(19)
    b[0] = x_end
    assert cc.is_edge_free(np.zeros(19), b) is free
    assert cc.checks >= 1


class SlabWorld:
    """Free unless the wrist x-coordinate lies in [0.02, 0.03] m."""

    def is_free(self, q):
        return not 0.02 <= q[0] <= 0.03


def test_an_edge_free_at_both_ends_is_blocked_in_between():
    """The far end is checked first, then every point between: a slab crossed mid-edge blocks it."""
    cc = CollisionChecker(SlabWorld())
    b = np.zeros(19)
    b[0] = 0.05
    assert cc.is_edge_free(np.zeros(19), b) is False
    b[0] = 0.015
    assert cc.is_edge_free(np.zeros(19), b) is True


def test_an_edge_blocked_at_its_far_end_costs_one_query():
    cc = CollisionChecker(HalfSpaceWorld())
    b = np.zeros(19)
    b[0] = 0.2  # 40 points at 5 mm; the last is in the half space
    assert cc.is_edge_free(np.zeros(19), b) is False
    assert cc.checks == 1
