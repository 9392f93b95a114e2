"""Sigma_m's map chosen per step by the scene (``fingertip_cov_map: by_scene``, inference/params.py): the
weights against a hand computation on a toy clearance, the blend against the two maps it blends, and the
solve at the two ends against the solves with either map alone."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from assets import sah
from assets.errors import InputError
from assets.se3 import pose_from_q, se3_exp
from inference.factors import modeling_covariance
from inference.graph import configuration_weights
from inference.params import VariationParams
from inference.solve import solve
from pbdgrasp import bench_fixtures as bench
from pbdgrasp.scene_model import scene_clearance
from planning.scene import load_scene

BY_SCENE = VariationParams(fingertip_cov_map="by_scene")


def test_weights_are_the_depth_of_tau_r_in_the_scene_dilated_over_steps(make_traj, planes):
    """A floor under the wrist's path: w_t = clip((b - z_t) / depth, 0, 1), then the largest over k steps
    either side, with z_t the height of tau_r's wrist placed at the object's pose (the margin n.p - b)."""
    traj = make_traj(n=9, seed=1)
    z = (traj.T_world_object_mean @ traj.T_object_wrist)[:, 2, 3]
    b = float(np.sort(z)[3])  # four steps on or under the floor, the rest above it
    floor = planes([[0.0, 0.0, 1.0]], [b])
    for depth_mm, k in ((20.0, 0), (20.0, 1), (5.0, 2)):
        params = dataclasses.replace(BY_SCENE, by_scene_depth_mm=depth_mm, by_scene_steps=k)
        raw = np.clip((b - z) / (depth_mm * 1e-3), 0.0, 1.0)
        expected = [max(raw[max(0, t - k) : t + k + 1]) for t in range(9)]
        got = configuration_weights(traj, params, floor, traj.T_world_object_mean)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-15)
    assert 0 < got.max() <= 1 and got.min() == 0
    assert not configuration_weights(traj, BY_SCENE, None, traj.T_world_object_mean).any()


def test_environment_only_keeps_the_table_and_obstacle_rows():
    """The SAH at ham's grasp, shaken, in ham on an arc: ``environment_only()`` equals the minimum over the
    environment parts of ``parts()`` wherever that is exact, and it has no object or self rows."""
    scene = load_scene("ham_arc")
    clearance = scene_clearance(scene, grasp_type="precision")
    environment = clearance.environment_only()
    assert environment.dim == environment.n_spheres == clearance.n_spheres
    assert environment.object_field is None and environment.environment == clearance.environment
    rng = np.random.default_rng(3)
    q = np.asarray(bench.HAM_GRASP_Q)
    W = pose_from_q(q) @ se3_exp(np.c_[0.3 * rng.normal(size=(40, 3)), 0.08 * rng.normal(size=(40, 3))])
    J = q[6:] + np.deg2rad(rng.uniform(-20, 20, size=(40, 13)))
    O = scene.T_world_object
    got = environment(O, W, J)
    parts = [p for p in clearance.parts(with_object=False) if p.environment]
    reference = np.min([p(O, W, J)[..., : p.n_spheres] for p in parts], axis=0)
    exact = reference < clearance.active_margin_m
    assert exact.sum() > 50  # the walls and the table are reached
    np.testing.assert_allclose(got[exact], reference[exact], rtol=0, atol=1e-12)


def test_sigma_m_blends_the_two_maps_step_by_step():
    """w = 1 is the configuration map's Sigma_m, w = 0 the finger joints', and between them the convex
    blend (the wrist stds and the joint floor are the same in both)."""
    joints = np.tile(np.mean(np.asarray(sah.JOINT_LIMITS), axis=1), (3, 1))
    T = se3_exp(np.zeros((3, 6)))
    coupled = modeling_covariance(
        T, joints, "power", dataclasses.replace(BY_SCENE, fingertip_cov_map="configuration")
    )
    held = modeling_covariance(
        T, joints, "power", dataclasses.replace(BY_SCENE, fingertip_cov_map="finger_joints")
    )
    w = np.array([1.0, 0.3, 0.0])
    got = modeling_covariance(T, joints, "power", BY_SCENE, configuration_weight=w)
    np.testing.assert_allclose(got[0], coupled[0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(got[1], 0.3 * coupled[1] + 0.7 * held[1], rtol=0, atol=1e-15)
    np.testing.assert_allclose(got[2], held[2], rtol=0, atol=1e-15)
    np.testing.assert_array_equal(modeling_covariance(T, joints, "power", BY_SCENE), held)
    assert not np.allclose(coupled[0], held[0])  # the two maps differ here
    with pytest.raises(InputError, match="configuration_weight"):
        modeling_covariance(T, joints, "power", BY_SCENE, configuration_weight=np.array([0.0, 1.5, 0.0]))


def test_by_scene_solves_as_either_map_at_the_two_ends(make_traj, planes):
    """No scene, or a floor far below: the finger-joint model; a floor above every step by more than the
    depth: the configuration model (means and marginals the same to the bit)."""
    traj = make_traj(n=4, seed=2)
    z = (traj.T_world_object_mean @ traj.T_object_wrist)[:, 2, 3]
    far, deep = planes([[0, 0, 1]], [z.min() - 1.0]), planes([[0, 0, -1]], [-z.min() + 0.05])
    held = dataclasses.replace(BY_SCENE, fingertip_cov_map="finger_joints")
    coupled = dataclasses.replace(BY_SCENE, fingertip_cov_map="configuration")
    for clearance, same in ((None, held), (far, held), (deep, coupled)):
        a, b = solve(traj, BY_SCENE, clearance=clearance), solve(traj, same, clearance=clearance)
        np.testing.assert_array_equal(a.cov, b.cov)
        np.testing.assert_array_equal(a.joints_mean, b.joints_mean)
        np.testing.assert_array_equal(a.T_object_wrist_mean, b.T_object_wrist_mean)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("by_scene_steps", -1, "expected an integer >= 0"),
        ("by_scene_steps", 1.5, "expected an integer >= 0"),
        ("by_scene_steps", float("inf"), "expected an integer >= 0"),
        ("by_scene_depth_mm", 0.0, "expected a finite number > 0"),
        ("fingertip_cov_map", "wrist", "expected one of configuration, finger_joints, by_scene"),
    ],
)
def test_by_scene_parameters_are_checked(field, value, message):
    with pytest.raises(InputError, match=message):
        VariationParams(**{field: value})
    assert VariationParams(by_scene_steps=0).by_scene_steps == 0
