"""The backward sweep (inference.sweep): ham's strategy in the ham-on-an-arc scene, where the solve from
tau_r leaves the index finger inside a wall, checked against pybullet's collision test of the means."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inference.params import VariationParams
from pbdgrasp.scene_model import learn_in_scene, scene_clearance
from pbdgrasp.strategy import retarget_in_scene
from planning.scene import load_scene
from retarget.demonstration import Demonstration
from retarget.retargeting import RetargetConfig


@pytest.fixture(scope="module")
def ham_arc_models():
    """ham's strategy (retargeted in its own scene) solved in ham_arc with and without the sweep, with the
    paper's last step and Sigma_r and Sigma_m through the whole configuration, as measured when the sweep
    was written (the refined last step, or the finger-joint covariances, leave no mean in a wall there)."""
    demo = Demonstration.load("ham")
    config = RetargetConfig(final_grasp="paper", covariance_map="configuration")
    traj, _ = retarget_in_scene(demo, load_scene("ham"), config)
    scene = load_scene("ham_arc")
    params = VariationParams(fingertip_cov_map="configuration")
    plain = learn_in_scene(traj, scene, dataclasses.replace(params, backward_sweep=False))
    swept = learn_in_scene(traj, scene, params)
    return scene, plain, swept


def test_the_sweep_takes_the_means_out_of_the_wall(ham_arc_models, wall_steps):
    """From tau_r a mean collides with a wall in pybullet (measured: step 48, the index in the right
    wall); from the sweep none does, the solve converges and the last step (the grasp) stays put."""
    scene, plain, swept = ham_arc_models
    stuck = wall_steps(scene, plain)
    print("steps in the walls from tau_r:", stuck)
    assert len(stuck) and 48 in stuck
    assert len(wall_steps(scene, swept)) == 0
    assert swept.converged
    clearance = scene_clearance(scene, grasp_type=swept.grasp_type)
    W = scene.T_world_object @ swept.T_object_wrist_mean
    assert clearance.penetration(scene.T_world_object, W, swept.joints_mean).min() > -2e-3
    moved = np.linalg.norm(swept.T_object_wrist_mean[-1, :3, 3] - plain.T_object_wrist_mean[-1, :3, 3])
    assert moved < 0.005


def test_no_sweep_where_nothing_penetrates(make_traj, planes):
    """A clearance that nothing penetrates: the model is the same with and without the sweep."""
    from inference.solve import solve

    traj = make_traj(n=4, seed=2)
    floor = planes([[0, 0, 1]], [-10.0])
    a = solve(traj, VariationParams(), clearance=floor)
    b = solve(traj, dataclasses.replace(VariationParams(), backward_sweep=False), clearance=floor)
    np.testing.assert_array_equal(a.cov, b.cov)
    np.testing.assert_array_equal(a.joints_mean, b.joints_mean)
