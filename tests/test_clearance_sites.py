"""The clearance in the marginals by expectation propagation (inference.clearance_sites), against rejection
sampling of the exact posterior, and the parts of a hand clearance against the whole."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from inference.factors import clearance_error
from inference.params import VariationParams
from inference.solve import solve


def _chain(make_traj, independent_joints_traj, n=6):
    traj = independent_joints_traj(make_traj, np.full(13, 0.3), n)
    joints = traj.joints.copy()
    joints[:, 0] = np.linspace(-0.015, 0.02, n)  # crossing the wall J_0 >= 0
    return dataclasses.replace(traj, joints=joints)


def test_sites_on_a_chain_agree_with_rejection_sampling_of_the_truncated_posterior(
    make_traj, ep_exact, independent_joints_traj, dense_joint_chain, planes
):
    """Six steps of joint 0 coupled by smoothness, a wall ``margin = J_0 >= 0`` that the demonstration
    crosses. The exact posterior is the Gaussian chain times the hinge factors, truncated to ``J_0 >= 0`` at
    every step: sampled by rejection and weighted by the hinges' likelihood. The sites' marginal means and
    stds of J_0 agree with it to a few hundredths of the chain's std; the hinges alone leave the means more
    than half a std off."""
    n = 6
    params = dataclasses.replace(ep_exact, smoothness_std_config=[0.01] * 19, clearance_sites=True)
    traj = _chain(make_traj, independent_joints_traj, n)
    wall = planes(joint_rows=[(0, 1.0, 0.0)])
    hinges = solve(traj, dataclasses.replace(params, clearance_sites=False), clearance=wall)
    held = solve(traj, dataclasses.replace(params, clearance_site_tolerance=1e-4), clearance=wall)
    assert held.converged
    rng = np.random.default_rng(0)
    mean0, cov_all = dense_joint_chain(traj, params, {}, full=True)
    cov6 = cov_all[0::13, 0::13]
    draws = rng.multivariate_normal(mean0[:, 0], cov6, size=1_000_000)
    kept = draws[np.all(draws >= 0.0, axis=1)]
    e = clearance_error(kept, params.hinge_smoothing_mm * 1e-3)[0]
    weight = np.exp(-0.5 * np.sum((e / (params.constraint_std_mm * 1e-3)) ** 2, axis=1))
    mean = np.average(kept, axis=0, weights=weight)
    std = np.sqrt(np.average((kept - mean) ** 2, axis=0, weights=weight))
    sd = np.sqrt(np.diag(cov6))
    got_mean = held.joints_mean[:, 0]
    got_std = np.sqrt(held.cov[:, 6, 6])
    assert len(kept) > 100_000
    # measured: means within 0.005 sd, stds within 0.017 sd (sampling error ~0.003 sd)
    np.testing.assert_array_less(np.abs(got_mean - mean), 0.02 * sd)
    np.testing.assert_array_less(np.abs(got_std - std), 0.04 * sd)
    assert np.all(got_mean > 0.0)
    # the hinges alone: measured 0.54-0.89 sd from the posterior's means
    assert np.all(np.abs(hinges.joints_mean[:, 0] - mean) > 0.4 * sd)


def test_sites_are_inactive_far_from_the_wall(make_traj, ep_exact, independent_joints_traj, planes):
    """With the wall 10 sigma below every mean no row gets a site: the marginals are the hinges' alone."""
    params = dataclasses.replace(ep_exact, smoothness_std_config=[0.01] * 19, clearance_sites=True)
    traj = _chain(make_traj, independent_joints_traj)
    wall = planes(joint_rows=[(0, 1.0, -5.0)])
    off = solve(traj, dataclasses.replace(params, clearance_sites=False), clearance=wall)
    on = solve(traj, params, clearance=wall)
    np.testing.assert_allclose(on.joints_mean, off.joints_mean, atol=1e-9)
    np.testing.assert_allclose(on.cov, off.cov, rtol=1e-6, atol=1e-10)  # one more warm solve: 6e-11


def test_the_parts_of_a_hand_clearance_give_its_margins(ham_arc_clearance):
    """Each part is one constraint source; the rows' minimum over the parts is the whole's margin (exact
    rows), and a part's rows are at least the whole's everywhere."""
    clearance, T_world_object, W, J = ham_arc_clearance
    whole = clearance(T_world_object, W, J)
    parts = clearance.parts()
    assert len(parts) == len(clearance.environment) + 2  # the fields, the object, the self pairs
    ns = clearance.n_spheres
    low = np.full_like(whole, np.inf)
    for part in parts:
        m = part(T_world_object, W, J)
        rows = slice(0, ns) if part.dim == ns else slice(None)
        low[..., rows] = np.minimum(low[..., rows], m)
    exact = whole < clearance.active_margin_m
    np.testing.assert_allclose(low[exact], whole[exact], atol=1e-12)
    assert np.all(low[~exact] >= clearance.active_margin_m - 1e-12)
    assert len(clearance.parts(with_object=False)) == len(parts) - 1


@pytest.fixture(scope="module")
def ham_arc_clearance():
    from assets.sah import rest_joints
    from pbdgrasp.scene_model import scene_clearance
    from planning.scene import load_scene

    scene = load_scene("ham_arc")
    clearance = scene_clearance(scene, VariationParams(), grasp_type="precision")
    rng = np.random.default_rng(1)
    W = np.tile(np.eye(4), (20, 1, 1))
    W[:, :3, 3] = rng.uniform([-0.1, -0.1, 0.05], [0.1, 0.15, 0.25], size=(20, 3))
    J = rest_joints() + rng.normal(0, 0.2, size=(20, 13))
    return clearance, scene.T_world_object, W, J


def test_a_links_soft_minimum_and_its_jacobian():
    """The group margin is the soft minimum of its exact rows (brute force), within ``s log k`` below their
    minimum, and its Jacobian is the soft minimum's derivative along any direction (central differences of
    rows linear in a 19-vector); a group without an exact row gets the reach and no Jacobian."""
    from inference.clearance_sites import _softmin

    rng = np.random.default_rng(3)
    group = np.array([0, 0, 0, 1, 2, 2])
    m0 = np.array([[0.004, 0.006, 0.02, 0.3, 0.001, 0.5]])  # row 3 and row 5 beyond the reach (0.1)
    H = rng.normal(size=(1, 6, 19))
    s, reach = 0.002, 0.1
    m_g, H_g = _softmin(m0, H, group, 3, s, reach)
    brute = -s * np.log(np.exp(-m0[0, :3] / s).sum())
    assert m_g[0, 0] == pytest.approx(brute, abs=1e-15)
    assert m0[0, :3].min() - s * np.log(3) <= m_g[0, 0] <= m0[0, :3].min()
    assert m_g[0, 1] == reach and not H_g[0, 1].any()
    assert m_g[0, 2] == pytest.approx(0.001, abs=1e-15)  # one exact row: itself
    d = rng.normal(size=19)
    h = 1e-7
    plus = _softmin(m0 + h * (H @ d), H, group, 3, s, reach)[0]
    minus = _softmin(m0 - h * (H @ d), H, group, 3, s, reach)[0]
    np.testing.assert_allclose((plus - minus)[0, [0, 2]] / (2 * h), (H_g @ d)[0, [0, 2]], rtol=1e-6)
