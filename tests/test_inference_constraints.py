"""The variation model's constraint factors and joint limits against closed forms: a toy clearance (planes
of the wrist position, walls on single joints) moves the mean as the Gaussian update says; expectation
propagation gives the truncated normal's moments and agrees with rejection sampling."""

import dataclasses
import math

import numpy as np
import pytest

from assets.errors import InputError
from inference import VariationParams, solve


def _ends_near_the_floor(make_traj):
    n = 10
    s = np.linspace(0, 1, n)
    xi = np.zeros((n, 6))
    xi[:, 5] = 0.003 + 0.15 * np.clip(1 - s / 0.6, 0, None)  # flat at 3 mm for the last four steps
    return make_traj(n=n, T_world_object=np.eye(4), xi_path=xi, seed=6, cov_scale=0.003), xi


def test_a_clearance_moves_the_mean_and_shrinks_the_variance_along_its_gradient(
    make_traj, standin_map, planes
):
    """margin = wrist height - 10 mm; the trajectory ends 3 mm above the plane z = 0."""
    traj, xi = _ends_near_the_floor(make_traj)
    floor = planes([[0, 0, 1]], [0.010])
    free = solve(traj, fingertip_map=standin_map)
    held = solve(traj, fingertip_map=standin_map, clearance=floor)
    assert free.converged and not free.constrained.any()
    assert held.converged and held.iterations <= held.params.max_iterations
    assert held.constrained.all()
    for t in np.flatnonzero(xi[:, 5] < 0.005):
        z_free, z_held = free.T_object_wrist_mean[t, 2, 3], held.T_object_wrist_mean[t, 2, 3]
        gap = 0.010 - z_free
        assert gap > 0
        assert z_held - z_free > 0.3 * gap, (z_free, z_held)
        grad = np.zeros(19)
        grad[3:6] = held.T_object_wrist_mean[t, 2, :3]  # d height / d v in the body frame
        assert grad @ held.cov[t] @ grad < 0.7 * grad @ free.cov[t] @ grad
    # steps far from the plane are not affected: their hinge rows are inactive
    assert abs(held.T_object_wrist_mean[0, 2, 3] - free.T_object_wrist_mean[0, 2, 3]) < 1e-3


def test_every_violated_row_pushes_out(make_traj, standin_map, planes):
    """A floor z = 0 and a wall x = x0, both 3 mm from the last steps, 10 mm clearance each: each row acts
    on its own, and both distances move towards the clearance."""
    traj, _ = _ends_near_the_floor(make_traj)
    free = solve(traj, fingertip_map=standin_map)
    x0 = free.T_object_wrist_mean[-1, 0, 3] - 0.003
    held = solve(
        traj, fingertip_map=standin_map, clearance=planes([[0, 0, 1], [1, 0, 0]], [0.010, x0 + 0.010])
    )
    assert held.converged
    for axis, plane in ((2, 0.0), (0, x0)):
        d_free = free.T_object_wrist_mean[:, axis, 3] - plane
        d_held = held.T_object_wrist_mean[:, axis, 3] - plane
        near = np.flatnonzero(d_free < 0.005)
        assert len(near) >= 2
        assert np.all(d_held[near] - d_free[near] > 0.3 * (0.010 - d_free[near])), (axis, d_free, d_held)


@pytest.mark.parametrize("wall", [0.05, -10.0])
def test_joint_0_against_a_wall_gives_the_gaussian_update_or_nothing(
    make_traj, wall, planes, dense_joint_chain
):
    """Joint 0 with a Gaussian prior whose mean lies inside a wall (margin = J_0 - w, w above the means):
    the active hinge is a linear Gaussian observation J_0 = w of std sigma_c on each step, so the solve gives
    the dense closed form of the joints' chain with those priors added; with the wall far below the means
    every row is inactive and the marginals are the chain's own. (A hinge smoothing of 1e-9 makes the
    smooth hinge the plain one here.)"""
    traj = make_traj(n=3, coupled=False, seed=11)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19), hinge_smoothing_mm=1e-6)
    w = traj.joints[:, 0].max() + wall if wall > 0 else wall
    model = solve(traj, params, clearance=planes(joint_rows=[(0, 1.0, w)]))
    assert model.converged
    sigma_c = params.constraint_std_mm * 1e-3
    extra = {(t, 0): [(w, sigma_c**2)] for t in range(traj.num_steps)} if wall > 0 else {}
    mean, cov = dense_joint_chain(traj, params, extra)
    if wall > 0:
        assert model.constrained.all() and np.all(mean[:, 0] < w)  # the soft hinge stays active
    np.testing.assert_allclose(model.joints_mean, mean, atol=1e-7)
    np.testing.assert_allclose(model.cov[:, 6:, 6:], cov, rtol=1e-6, atol=1e-12)


def test_joint_limits_give_the_truncated_normal_moments_for_independent_joints(
    make_traj, ep_exact, independent_joints_traj
):
    """Steps without smoothness coupling, independent joints N(tau_i, sigma_i^2): the posterior of each joint
    under the limits is that normal truncated to [lo, hi], and expectation propagation with one site per
    joint is exact. Joint 0 sits 0.2 sigma inside its lower limit, joint 1 half a sigma beyond its upper
    one, joint 2 two sigma beyond its lower one; the others are far inside and untouched."""
    from scipy.stats import truncnorm

    sigma = np.array(ep_exact.sigma_m_std_config[6:])
    lo, hi = np.full(13, -1.0), np.full(13, 1.0)
    lo[:3], hi[:3] = [0.0, -0.5, 0.1], [0.6, 0.2, 0.9]
    tau = np.full(13, 0.3)
    tau[:3] = [lo[0] + 0.2 * sigma[0], hi[1] + 0.5 * sigma[1], lo[2] - 2.0 * sigma[2]]
    model = solve(independent_joints_traj(make_traj, tau), ep_exact, joint_limits=np.stack([lo, hi], axis=1))
    mean, var = truncnorm.stats((lo - tau) / sigma, (hi - tau) / sigma, loc=tau, scale=sigma, moments="mv")
    for t in range(2):
        np.testing.assert_allclose(model.joints_mean[t], mean, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.diag(model.cov[t])[6:], var, rtol=1e-8, atol=0)
    assert model.converged and model.constrained.all()
    # the limits narrow a joint at a limit but keep its spread away from it (a tenth of a sigma near the
    # lower limit of joint 0 still leaves 0.6 sigma)
    assert 0.55 * sigma[0] < math.sqrt(model.cov[0][6, 6]) < sigma[0]


def test_joint_limits_on_a_chain_agree_with_rejection_sampling(
    make_traj, dense_joint_chain, ep_exact, independent_joints_traj
):
    """Six steps of joint 0 coupled by the smoothness factors, its demonstrated values crossing the lower
    limit; the true posterior is the Gaussian chain truncated to [lo, hi] at every step, sampled here by
    rejection (2e5 accepted draws). Expectation propagation's marginal means and stds agree with it to a
    few hundredths of the chain's std; without the limits the means cross the limit."""
    n, lo0 = 6, 0.0
    tau = np.full(13, 0.3)
    params = dataclasses.replace(ep_exact, smoothness_std_config=[0.01] * 19)
    traj = independent_joints_traj(make_traj, tau, n)
    joints = traj.joints.copy()
    joints[:, 0] = np.linspace(-0.015, 0.02, n)
    traj = dataclasses.replace(traj, joints=joints)
    limits = np.tile([-1.0, 1.0], (13, 1))
    limits[0] = [lo0, 0.6]
    free = solve(traj, params)
    held = solve(traj, params, joint_limits=limits)
    assert free.joints_mean[:, 0].min() < lo0 and held.converged
    # rejection sampling of joint 0's chain (its f_1t and smoothness factors only: the joints are
    # independent of each other and of the wrist here)
    rng = np.random.default_rng(0)
    chain_cov = np.stack([free.cov[t][6, 6] for t in range(n)])
    mean0, cov_all = dense_joint_chain(traj, params, {}, full=True)
    cov6 = cov_all[0::13, 0::13]  # joint 0 at every step
    draws = rng.multivariate_normal(mean0[:, 0], cov6, size=2_000_000)  # 15 % accepted
    kept = draws[np.all((draws >= lo0) & (draws <= 0.6), axis=1)][:200_000]
    assert len(kept) == 200_000
    np.testing.assert_allclose(np.diag(cov6), chain_cov, rtol=1e-9)  # the oracle's chain is the model's
    sd = np.sqrt(chain_cov)
    # measured: means within 0.004 sd, stds within 0.017 sd (EP's small bias; sampling error ~0.002 sd)
    assert np.all(np.abs(held.joints_mean[:, 0] - kept.mean(axis=0)) < 0.02 * sd)
    assert np.all(np.abs(np.sqrt([held.cov[t][6, 6] for t in range(n)]) - kept.std(axis=0)) < 0.05 * sd)
    assert np.all(held.joints_mean[:, 0] > lo0)


def test_joint_limits_keep_a_constraint_from_bending_a_joint_past_its_limit(make_traj, planes):
    """A 'wall' that joint 0 can clear only by going 50 mrad past its lower limit (phi = 0.1 m/rad x
    (lo + 0.2 - J_0), clearance 25 mm): without the limits the means leave them by tens of mrad, as the
    scenes' link constraints bent the SAH's fingers backwards; with them every mean stays inside."""
    n, lo0, slope = 6, -0.02, 0.1
    traj = make_traj(n=n, coupled=False, seed=3)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19))

    # margin = slope (lo + 0.2 - J_0) - 25 mm = -slope (J_0 - (lo + 0.2 - 0.25))
    kw = dict(clearance=planes(joint_rows=[(0, -slope, lo0 + 0.2 - 0.025 / slope)]))
    limits = np.tile([-10.0, 10.0], (13, 1))
    limits[0, 0] = lo0
    bent = solve(traj, params, **kw)
    held = solve(traj, params, joint_limits=limits, **kw)
    assert bent.joints_mean[:, 0].min() < lo0 - 0.03
    assert held.joints_mean[:, 0].min() > lo0
    assert held.constrained.all()


def test_loose_solves_between_site_updates_reach_the_tight_fixed_point(make_traj, planes):
    """The solves between expectation-propagation updates stop at ``site_solve_tolerance``, the last one at
    ``relative_error_tolerance``: the same joint-limit and constraint setting as above, solved with every
    solve tight (``site_solve_tolerance`` = ``relative_error_tolerance``), gives the same means and
    covariances to well within the tolerances, in fewer iterations."""
    traj = make_traj(n=6, coupled=False, seed=3)
    lo0, slope = -0.02, 0.1
    clearance = planes(joint_rows=[(0, -slope, lo0 + 0.2 - 0.025 / slope)])
    limits = np.tile([-10.0, 10.0], (13, 1))
    limits[0, 0] = lo0
    base = dict(sigma_m_std_config=np.linspace(0.01, 0.05, 19), relative_error_tolerance=1e-9)
    tight = solve(
        traj, VariationParams(**base, site_solve_tolerance=1e-9), clearance=clearance, joint_limits=limits
    )
    loose = solve(
        traj, VariationParams(**base, site_solve_tolerance=1e-2), clearance=clearance, joint_limits=limits
    )
    assert tight.converged and loose.converged
    assert loose.iterations < tight.iterations
    np.testing.assert_allclose(loose.joints_mean, tight.joints_mean, atol=1e-4)
    np.testing.assert_allclose(loose.cov, tight.cov, rtol=1e-3, atol=1e-9)


@pytest.mark.parametrize(
    "limits, message",
    [
        (np.zeros((12, 2)), "joint_limits"),
        (np.tile([0.5, -0.5], (13, 1)), "lower limit must be below"),
        (np.tile([np.nan, 1.0], (13, 1)), "joint_limits"),
    ],
)
def test_bad_joint_limits_are_refused(make_traj, limits, message):
    with pytest.raises(InputError, match=message):
        solve(make_traj(n=3), joint_limits=limits)


def test_truncated_normal_moments_equal_scipys():
    """The vectorized moments behind the joint-limit sites against scipy.stats.truncnorm, bounds within
    30 sigma of the mean, one- and two-sided."""
    from scipy.stats import truncnorm

    from inference.joint_limits import truncated_normal_moments

    rng = np.random.default_rng(0)
    a = rng.uniform(-30, 30, 5000)
    b = a + rng.uniform(1, 40, 5000)
    a[::7], b[::11] = -np.inf, np.inf
    mean, var = truncated_normal_moments(a, b)
    ref_mean, ref_var = truncnorm.stats(a, b, moments="mv")
    np.testing.assert_allclose(mean, ref_mean, rtol=1e-12, atol=1e-12)
    # beyond 20 sigma scipy's variances are off by up to 1e-7 (the quadrature test below is the reference)
    closed_form = (b > -20) & (a < 20)
    assert np.max(np.abs(var - ref_var)[closed_form] / ref_var[closed_form]) < 1e-9


def test_truncated_normal_moments_deep_in_a_tail_match_quadrature():
    """Intervals 20 to 10^4 sigma into either tail (where the closed form cancels to zero variance) against
    scipy's adaptive quadrature of the shifted density exp(-x^2/2 + lo^2/2)."""
    from scipy.integrate import quad

    from inference.joint_limits import truncated_normal_moments

    a = np.array([25.0, 1166.9, 514.2, 9822.6, 40.0, -1217.9, -np.inf])
    b = np.array([np.inf, 1217.9, 514.25, 9858.8, 40.001, -1166.9, -3701.7])
    mean, var = truncated_normal_moments(a, b)
    for k in range(len(a)):
        near = a[k] if abs(a[k]) < abs(b[k]) else b[k]  # the bound nearest the mean
        into = 1.0 if near == a[k] else -1.0  # from the nearest bound into the interval
        far = np.clip(near + into * 80.0 / abs(near), a[k], b[k])  # the density is e^-80 there
        lo_k, hi_k = sorted((near, far))

        def moment(p, near=near, lo_k=lo_k, hi_k=hi_k):
            def f(x):
                return (x - near) ** p * np.exp(-0.5 * (x * x - near * near))

            return quad(f, lo_k, hi_k, epsabs=0, epsrel=1e-13, limit=200)[0]

        z, m1, m2 = moment(0), moment(1), moment(2)
        ref_mean, ref_var = near + m1 / z, m2 / z - (m1 / z) ** 2
        assert mean[k] == pytest.approx(ref_mean, rel=1e-12)
        assert var[k] == pytest.approx(ref_var, rel=1e-10), (a[k], b[k])
        assert var[k] > 0
