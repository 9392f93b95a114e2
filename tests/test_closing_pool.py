"""ClosingPool: a batch closed on two processes gives, row by row, what one HandCloser gives closing the rows
one at a time (a second implementation of the batch: the plain loop in a fresh world)."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from assets.errors import InputError
from pbdgrasp.bench_fixtures import HAM_GRASP_Q
from planning.autograsp import HandCloser
from planning.closing_pool import ClosingPool
from planning.scene import load_scene
from planning.world import World


@pytest.fixture(scope="module")
def ham():
    scene = load_scene("ham")
    rng = np.random.default_rng(3)
    # about the ham grasp: some draws in collision, some without force closure, most closing to a grasp
    std = np.r_[np.full(3, 0.02), np.full(3, 0.006), np.full(13, 0.06)]
    qs = np.array(HAM_GRASP_Q) + rng.normal(size=(13, 19)) * std
    with World(scene) as world:
        closer = HandCloser(world)
        expected = [closer.close(q) for q in qs[::-1]][::-1]  # in reverse: no order dependence either
    return scene, qs, expected


def _assert_same(got, expected):
    assert len(got) == len(expected)
    for g, e in zip(got, expected, strict=True):
        assert g.quality == e.quality
        assert g.in_collision == e.in_collision
        assert g.contact_links == e.contact_links
        np.testing.assert_array_equal(g.closed_q, e.closed_q)
        np.testing.assert_array_equal(g.contact_points_world, e.contact_points_world)


@pytest.mark.parametrize("processes", [1, 2, 3])
def test_pool_closes_as_one_closer_does(ham, processes):
    scene, qs, expected = ham
    assert any(e.in_collision for e in expected) and any(e.quality > 0 for e in expected)
    with ClosingPool(scene, processes=processes) as pool:
        assert pool.processes == processes
        _assert_same(pool.close_many(qs), expected)
        _assert_same(pool.close_many(qs[:1]), expected[:1])  # fewer rows than processes


def _free_and_deepest(closer, rows):
    world = closer.world
    return [(world.is_free(q), world.penetration_m(q)) for q in rows]


def test_map_rows_runs_any_function_of_the_rows_in_order(ham):
    scene, qs, _ = ham
    with World(scene) as world:
        expected = _free_and_deepest(HandCloser(world), qs)
    with ClosingPool(scene, processes=2) as pool:
        assert pool.map_rows(_free_and_deepest, qs) == expected
    assert any(free for free, _ in expected) and not all(free for free, _ in expected)


def test_pool_closes_here_when_its_workers_are_gone(ham):
    scene, qs, expected = ham
    with World(scene) as world:
        with ClosingPool(scene, processes=2, world=world) as pool:
            pool._pool.shutdown(wait=True)  # as after a worker's death: the chunks are closed here
            _assert_same(pool.close_many(qs), expected)
        assert HandCloser(world).close(qs[0]).quality == expected[0].quality  # the caller's world stays open


def test_a_worker_ignores_ctrl_c(ham):
    """Ctrl-C reaches the whole process group: the caller handles it; the workers go on to the pool's end."""
    scene, qs, expected = ham
    with ClosingPool(scene, processes=2) as pool:
        pool.close_many(qs[:2])  # the worker is up
        workers = list(pool._pool._processes.values())
        for proc in workers:
            os.kill(proc.pid, signal.SIGINT)
        time.sleep(0.3)
        assert all(proc.is_alive() for proc in workers)
        _assert_same(pool.close_many(qs), expected)


def test_pool_refuses_bad_input(ham):
    scene, qs, _ = ham
    with pytest.raises(InputError, match="processes"):
        ClosingPool(scene, processes=0)
    with ClosingPool(scene, processes=1) as pool:
        with pytest.raises(InputError, match=r"\(n, 19\)"):
            pool.close_many(qs[:, :18])
        with pytest.raises(InputError, match="finite"):
            pool.close_many(np.full((2, 19), np.nan))
