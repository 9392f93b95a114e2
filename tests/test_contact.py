"""The demonstrated contacts held at the grasp (:mod:`inference.contact`): the rows against a dense
computation of the spheres' margins to a ball, the factor's Jacobians against central differences, and
the solved marginal of a one-step model against the closed form of a linear-Gaussian update."""

from __future__ import annotations

import dataclasses

import gtsam
import numpy as np
import pytest

from assets.distance_fields import BoxField, SphereField
from assets.errors import InputError
from assets.se3 import se3_exp
from assets.sphere_cover import hand_sphere_cover
from inference.clearance import HandClearance
from inference.contact import contact_factors, contact_plan
from inference.graph import key_j, key_w
from inference.params import VariationParams
from inference.solve import solve

PARAMS = VariationParams(precision_contact_steps=15)  # make_traj's trajectories are precision grasps
OBJECT_CLEARANCE_M = 0.003


def _margins(cover, ball, T_world_object, T_world_wrist, joints):
    """(n,) every sphere's margin to the ball, dense: distance - object clearance - radius."""
    c_world = cover.centers(joints) @ T_world_wrist[:3, :3].T + T_world_wrist[:3, 3]
    c_object = (c_world - T_world_object[:3, 3]) @ T_world_object[:3, :3]
    return ball.distance(c_object)[0] - OBJECT_CLEARANCE_M - cover.radii_m


def _ball_beside(traj, t, gap_m, radius_m=0.02):
    """A ball in the object frame beside tau_r(t)'s sphere 0, ``gap_m`` beyond its clearance, on the side
    away from the hand's centroid."""
    cover = hand_sphere_cover("sah")
    c = cover.centers(traj.joints[t]) @ traj.T_object_wrist[t][:3, :3].T + traj.T_object_wrist[t][:3, 3]
    out = (c[0] - c.mean(axis=0)) / np.linalg.norm(c[0] - c.mean(axis=0))
    centre = c[0] + out * (cover.radii_m[0] + radius_m + OBJECT_CLEARANCE_M + gap_m)
    return cover, SphereField(radius_m, centre)


def _clearance(cover, ball):
    return HandClearance(cover, (), ball, object_clearance_m=OBJECT_CLEARANCE_M, active_margin_m=0.005)


def test_rows_are_the_spheres_of_tau_r_within_reach_of_the_object(make_traj):
    """The last ``precision_contact_steps`` steps, the spheres whose dense margin is below the reach, the
    targets clipped to [0, reach], the std ``contact_std``."""
    traj = make_traj(n=8, seed=4)
    cover, ball = _ball_beside(traj, 7, 0.004)
    clearance, O = _clearance(cover, ball), traj.T_world_object_mean
    params = dataclasses.replace(PARAMS, precision_contact_steps=4, contact_reach_mm=10.0, contact_std_mm=2.0)
    plan = contact_plan(traj, params, clearance, O)
    expected_steps = []
    for t in range(4, 8):  # the last four
        m = _margins(cover, ball, O, O @ traj.T_object_wrist[t], traj.joints[t])
        near = np.flatnonzero(m < 0.010)
        if len(near):
            k = len(expected_steps)
            expected_steps.append(t)
            np.testing.assert_array_equal(plan.rows[k], near)
            np.testing.assert_allclose(plan.targets_m[k], np.clip(m[near], 0, 0.010), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(plan.steps, expected_steps)
    assert 7 in expected_steps and plan.num_rows >= 1
    np.testing.assert_allclose(plan.stds_m, 0.002)
    # nothing to hold: no object field, or no steps
    assert contact_plan(traj, params, None, O) is None
    no_object = HandClearance(cover, (ball,), None, self_pairs=np.zeros((0, 2), dtype=int))
    assert contact_plan(traj, params, no_object, O) is None
    assert contact_plan(traj, dataclasses.replace(params, precision_contact_steps=0), clearance, O) is None
    # by default the power grasps hold their last 15 steps, the precision grasps none
    default = VariationParams()
    assert contact_plan(traj, default, clearance, O) is None
    power = contact_plan(dataclasses.replace(traj, grasp_type="power"), default, clearance, O)
    assert power is not None and 7 in power.steps and power.steps.min() >= 0


def _held_at_the_last_step(make_traj, params):
    """A 4-step trajectory, a ball beside its last hand: the cover, the ball, the object pose, the cover's
    world centres at the last step and the sphere rows held there without a table."""
    traj = make_traj(n=4, seed=4)
    cover, ball = _ball_beside(traj, 3, 0.004)
    O = traj.T_world_object_mean
    W, J = O @ traj.T_object_wrist[3], traj.joints[3]
    centres = cover.centers(J) @ W[:3, :3].T + W[:3, 3]
    return traj, cover, ball, O, centres, contact_plan(traj, params, _clearance(cover, ball), O).rows[0]


def _under_a_table(cover, ball, centres, top_m):
    """The clearance with a table (a box) whose top is at ``top_m``, and each sphere's dense margin to its
    10 mm clearance [m]."""
    T_world_box = np.eye(4)
    T_world_box[2, 3] = top_m - 0.05
    box = BoxField(np.array([1.0, 1.0, 0.05]), T_world_box)
    clearance = HandClearance(
        cover, (box,), ball, clearance_m=0.010, object_clearance_m=OBJECT_CLEARANCE_M, active_margin_m=0.005
    )
    return clearance, box.distance(centres)[0] - 0.010 - cover.radii_m


def test_a_contact_where_the_scene_is_gives_way(make_traj):
    """A table (a box) under tau_r's last hand, its top placed so that half the held spheres come within
    ``contact_release_mm`` of its 10 mm clearance: exactly the spheres whose dense distance to the box is
    beyond the release stay held (for a release of 20 mm and of 0; the sphere rule)."""
    params = dataclasses.replace(
        PARAMS, precision_contact_steps=1, contact_reach_mm=10.0, precision_contact_release="sphere"
    )
    traj, cover, ball, O, centres, held_all = _held_at_the_last_step(make_traj, params)
    bottoms = centres[held_all, 2] - cover.radii_m[held_all] - 0.010  # lowest point less the clearance
    for release_mm in (20.0, 0.0):
        clearance, to_box = _under_a_table(cover, ball, centres, np.median(bottoms) - release_mm * 1e-3)
        plan = contact_plan(traj, dataclasses.replace(params, contact_release_mm=release_mm), clearance, O)
        kept = held_all[to_box[held_all] > release_mm * 1e-3]
        assert 0 < len(kept) < len(held_all)
        np.testing.assert_array_equal(plan.rows[0], kept)


def test_a_precision_step_whose_contact_the_scene_occupies_holds_none(make_traj):
    """The table of the test above, released by step (precision grasps): with its top where the lowest held
    sphere is 1 mm inside its 10 mm clearance the step holds nothing; 1 mm lower, every held sphere outside
    the clearance, the step holds all of them, those within ``contact_release_mm`` of it too."""
    params = dataclasses.replace(PARAMS, precision_contact_steps=1, contact_reach_mm=10.0)
    assert params.contact_release("precision") == "step" and params.contact_release("power") == "sphere"
    traj, cover, ball, O, centres, held_all = _held_at_the_last_step(make_traj, params)
    lowest = np.min(centres[held_all, 2] - cover.radii_m[held_all]) - 0.010  # its point less the clearance
    for inside_mm in (1.0, -1.0):
        clearance, to_box = _under_a_table(cover, ball, centres, lowest + inside_mm * 1e-3)
        assert (to_box[held_all].min() < 0) == (inside_mm > 0)
        plan = contact_plan(traj, params, clearance, O)
        if inside_mm > 0:
            assert plan is None
        else:
            assert np.any(to_box[held_all] < params.contact_release_mm * 1e-3)  # the sphere rule drops these
            np.testing.assert_array_equal(plan.rows[0], held_all)


def test_a_strategy_on_another_object_holds_the_contacts_it_demonstrated(make_traj):
    """The scene's object a smaller ball than the demonstration's, at the same centre: the rows and targets
    are tau_r's margins to the demonstrated ball, the factors' margins those to the scene's ball, so the
    solved hand touches the smaller ball as tau_r touched the larger one (chips' strategy on the bottle)."""
    traj = make_traj(n=6, seed=4)
    cover, big = _ball_beside(traj, 5, 0.004, radius_m=0.03)
    small = SphereField(0.025, big.center_world_m)  # 5 mm smaller radius, as the bottle against the chips can
    O = traj.T_world_object_mean
    params = dataclasses.replace(PARAMS, precision_contact_steps=3)
    scene_clearance = _clearance(cover, small)
    demonstrated = scene_clearance.with_object(big)
    assert demonstrated.object_field is big and scene_clearance.object_field is small
    plan = contact_plan(traj, params, scene_clearance, O, demonstrated)
    on_its_own = contact_plan(traj, params, _clearance(cover, big), O)
    for a, b in zip(
        (plan.steps, *plan.rows, *plan.targets_m),
        (on_its_own.steps, *on_its_own.rows, *on_its_own.targets_m),
        strict=True,
    ):
        np.testing.assert_array_equal(a, b)
    t, rows = plan.steps[-1], plan.rows[-1]
    W = O @ traj.T_object_wrist[t]
    held = plan.clearance(O, W[None], traj.joints[t][None])[0, rows]
    np.testing.assert_allclose(held, _margins(cover, small, O, W, traj.joints[t])[rows], atol=1e-12)
    # solved: the held spheres come about 5 mm nearer the smaller ball than tau_r is
    model = solve(traj, params, clearance=scene_clearance, demonstrated=demonstrated)
    W_solved = O @ model.T_object_wrist_mean[t]
    moved = _margins(cover, small, O, W_solved, model.joints_mean[t])[rows]
    assert np.median(_margins(cover, small, O, W, traj.joints[t])[rows] - moved) > 0.003


@pytest.mark.parametrize("fixed", [False, True])
def test_contact_factor_jacobians_match_numerical_through_o_w_and_j(make_traj, numerical_jacobian, fixed):
    traj = make_traj(n=3, seed=5)
    cover, ball = _ball_beside(traj, 2, 0.002)
    O = traj.T_world_object_mean
    plan = contact_plan(traj, PARAMS, _clearance(cover, ball), O)
    assert plan.num_rows >= 2
    steps = [(key_w(t), key_j(t)) for t in range(3)]
    factors = contact_factors(plan, None if fixed else 0, steps, O if fixed else None)
    rng = np.random.default_rng(6)
    values = gtsam.Values()
    if not fixed:
        values.insert(0, gtsam.Pose3(O @ se3_exp(0.003 * rng.normal(size=6))))
    for t in range(3):  # moved off tau_r, so that the errors are not zero
        values.insert(key_w(t), gtsam.Pose3(O @ traj.T_object_wrist[t] @ se3_exp(0.004 * rng.normal(size=6))))
        values.insert(key_j(t), traj.joints[t] + 0.02 * rng.normal(size=13))
    for factor, t, rows, target in zip(factors, plan.steps, plan.rows, plan.targets_m, strict=True):
        A, _ = factor.linearize(values).jacobian()
        H_num = np.hstack([numerical_jacobian(factor.whitenedError, values, k) for k in factor.keys()])
        np.testing.assert_allclose(A, H_num, rtol=0, atol=1e-6 * max(1.0, np.abs(A).max()))
        O_now = values.atPose3(0).matrix() if not fixed else O
        W, J = values.atPose3(key_w(t)).matrix(), values.atVector(key_j(t))
        expected = _margins(cover, ball, O_now, W, J)[rows] - target
        np.testing.assert_allclose(factor.unwhitenedError(values), expected, rtol=0, atol=1e-12)
        assert np.abs(expected).max() > 1e-4


def test_a_held_contact_narrows_the_marginal_as_a_linear_gaussian_update(make_traj):
    """Two equal steps (the smoothness is satisfied), the last held, its contact margins between the
    hinge's cutoff and the reach (the hinge adds nothing), so that tau_r is the optimum with and without
    the contact: the held step's marginal information is the one without plus ``G^T G / sigma^2``, with G
    the rows' Jacobian (central differences on the dense margins, GTSAM's right perturbation of W)."""
    plain = make_traj(n=2, seed=7)
    traj = dataclasses.replace(
        plain,
        T_object_wrist=np.repeat(plain.T_object_wrist[1:], 2, axis=0),
        joints=np.repeat(plain.joints[1:], 2, axis=0),
        cov_retarget=np.repeat(plain.cov_retarget[1:], 2, axis=0),
    )
    cover, ball = _ball_beside(traj, 1, 0.007)
    O = traj.T_world_object_mean
    W0, J0 = O @ traj.T_object_wrist[1], traj.joints[1]
    m0 = _margins(cover, ball, O, W0, J0)
    rows = np.flatnonzero(m0 < 0.010)
    assert len(rows) >= 1 and m0.min() > 0.005  # held rows, none inside the hinge's reach
    clearance = _clearance(cover, ball)
    held = dataclasses.replace(PARAMS, precision_contact_steps=1)
    model = solve(traj, held, clearance=clearance)
    without = solve(traj, dataclasses.replace(PARAMS, precision_contact_steps=0), clearance=clearance)
    h, G = 1e-6, np.zeros((len(rows), 19))
    for k in range(19):
        d = np.zeros(19)
        d[k] = h
        plus = _margins(cover, ball, O, W0 @ se3_exp(d[:6]), J0 + d[6:])[rows]
        minus = _margins(cover, ball, O, W0 @ se3_exp(-d[:6]), J0 - d[6:])[rows]
        G[:, k] = (plus - minus) / (2 * h)
    std = held.contact_std_mm * 1e-3
    expected = np.linalg.inv(np.linalg.inv(without.cov[1]) + G.T @ G / std**2)
    np.testing.assert_allclose(model.cov[1], expected, rtol=1e-5, atol=1e-12)
    for m in (model, without):  # tau_r is the optimum of both
        np.testing.assert_allclose(m.T_object_wrist_mean, traj.T_object_wrist, atol=1e-9)
        np.testing.assert_allclose(m.joints_mean, traj.joints, atol=1e-9)
    # the margins' spread along G shrinks to below the contact std, from well above it
    assert np.all(np.sqrt(np.diag(G @ model.cov[1] @ G.T)) < std)
    assert np.any(np.sqrt(np.diag(G @ without.cov[1] @ G.T)) > 2 * std)


@pytest.mark.parametrize(
    "field, value, message",
    [
        ("precision_contact_steps", -1, "expected an integer >= 0"),
        ("power_contact_steps", 2.5, "expected an integer >= 0"),
        ("contact_std_mm", 0.0, "expected a finite number > 0"),
        ("contact_reach_mm", float("nan"), "expected a finite number > 0"),
        ("contact_release_mm", -1.0, "expected a finite number >= 0"),
        ("precision_contact_release", "all", "expected one of sphere, step"),
    ],
)
def test_contact_parameters_are_checked(field, value, message):
    with pytest.raises(InputError, match=message):
        VariationParams(**{field: value})
