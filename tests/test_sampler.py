"""The sampler P(Y): fast quaternion path vs matrix algebra, marginal statistics, mixture weights, bounds."""

import numpy as np
import pytest

from assets.errors import InputError
from assets.se3 import (
    local,
    pose_from_q,
    pose_rows_compose,
    quat_rows_from_matrix,
    rotvec_rows_from_quat,
    se3_exp,
)
from inference import MixtureSampler, sample, sample_marginal, sample_object, solve

LIMITS = np.array([[-0.3, 1.2]] * 13)
ALGEBRA_ATOL = 1e-12


@pytest.fixture(scope="module")
def models(make_traj, standin_map):
    return [
        solve(make_traj(n=6, seed=11), fingertip_map=standin_map),
        solve(make_traj(n=4, seed=12), fingertip_map=standin_map),
    ]


def test_fast_composition_equals_the_se3_matrices():
    rng = np.random.default_rng(0)
    T = se3_exp(rng.normal(size=(50, 6)))
    xi = rng.normal(size=(50, 6)) * np.r_[[1.0] * 3 + [0.3] * 3]
    xi[:5, :3] *= 1e-7  # the small-angle branch
    quat, p = pose_rows_compose(
        quat_rows_from_matrix(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3].T), xi.T.copy()
    )
    expected = T @ se3_exp(xi)
    got = pose_from_q(np.concatenate([p.T, rotvec_rows_from_quat(quat).T], axis=1))
    assert np.abs(got - expected).max() < ALGEBRA_ATOL


def test_one_marginal_has_the_model_mean_and_covariance(models):
    """1e5 draws: the tangent mean is within 5 standard errors, the covariance within 5 of its errors."""
    model, k, n = models[0], 3, 100_000
    T, joints = sample_marginal(model, k, n, np.random.default_rng(1))
    x = np.concatenate([local(model.T_object_wrist_mean[k], T), joints - model.joints_mean[k]], axis=1)
    C = model.cov[k]
    sd = np.sqrt(np.diag(C))
    assert np.abs(x.mean(0) / sd).max() < 5 / np.sqrt(n)
    emp = np.cov(x.T)
    se = np.sqrt((C**2 + np.outer(np.diag(C), np.diag(C))) / n)  # std error of Gaussian sample covariances
    assert np.abs((emp - C) / se).max() < 5.5
    objects = sample_object(model, 20_000, np.random.default_rng(2))
    xo = local(model.T_world_object_mean, objects)
    np.testing.assert_allclose(
        np.cov(xo.T), model.cov_object, atol=5 * np.sqrt(2 / 20_000) * model.cov_object.max()
    )
    q = sample(model, k, 10, np.random.default_rng(3), joint_limits=LIMITS)
    assert q.shape == (10, 19) and np.all(q[:, 6:] >= -0.3) and np.all(q[:, 6:] <= 1.2)


def test_beta_one_gives_only_uniform_samples_inside_the_bounds(models):
    lo, hi = np.array([-0.5, -0.4, 0.0]), np.array([0.5, 0.4, 0.6])
    out = MixtureSampler(models, lo, hi, beta=1.0, joint_limits=LIMITS).sample(
        20_000, np.random.default_rng(4)
    )
    assert np.all(out.strategy == -1) and np.all(out.k == 0) and np.all(out.is_last)
    assert np.all(out.q[:, :3] >= lo) and np.all(out.q[:, :3] <= hi)
    assert np.all(out.q[:, 6:] >= LIMITS[:, 0]) and np.all(out.q[:, 6:] <= LIMITS[:, 1])
    # uniform rotations: the rotation angle has density (1 - cos a) / pi, mean pi/2 + 2/pi
    angle = np.linalg.norm(out.q[:, 3:6], axis=1)
    assert abs(angle.mean() - (np.pi / 2 + 2 / np.pi)) < 5 * 0.75 / np.sqrt(20_000)
    assert np.all(angle <= np.pi + 1e-12)


def test_the_mixture_weights_steps_and_world_frame(models):
    n, beta = 60_000, 0.2
    out = MixtureSampler(models, -np.ones(3), np.ones(3), beta, joint_limits=LIMITS).sample(
        n, np.random.default_rng(5)
    )
    share = np.array([(out.strategy == s).mean() for s in (-1, 0, 1)])
    expected = np.array([beta, (1 - beta) / 2, (1 - beta) / 2])
    assert np.abs(share - expected).max() < 5 * np.sqrt(0.25 / n)
    for s, m in enumerate(models):
        ks = out.k[out.strategy == s]
        assert set(ks) == set(range(m.num_steps))
        np.testing.assert_array_equal(out.is_last[out.strategy == s], ks == m.num_steps - 1)
    assert np.all(out.q[:, 6:] >= LIMITS[:, 0]) and np.all(out.q[:, 6:] <= LIMITS[:, 1])
    # learned samples scatter around o T_k: the mean world wrist position of step k is near mu_o's
    s, k = 0, 2
    sel = (out.strategy == s) & (out.k == k)
    T_mean = models[s].T_world_object_mean @ models[s].T_object_wrist_mean[k]
    spread = np.sqrt(np.linalg.eigvalsh(models[s].cov_object)[-1]) + 0.05
    assert np.linalg.norm(out.q[sel, :3].mean(0) - T_mean[:3, 3]) < 5 * spread / np.sqrt(sel.sum()) + 0.01
    # order is shuffled: strategies interleave
    assert (np.diff(out.strategy) != 0).mean() > 0.3


def test_bad_sampler_input():
    with pytest.raises(InputError, match="beta"):
        MixtureSampler([], np.zeros(3), np.ones(3), 1.5, joint_limits=LIMITS)
    with pytest.raises(InputError, match="at least one learned model"):
        MixtureSampler([], np.zeros(3), np.ones(3), 0.5, joint_limits=LIMITS)
    with pytest.raises(InputError, match="wrist bounds"):
        MixtureSampler([], np.ones(3), np.zeros(3), 1.0, joint_limits=LIMITS)
    with pytest.raises(InputError, match="joint_limits"):
        MixtureSampler([], np.zeros(3), np.ones(3), 1.0, joint_limits=np.zeros((12, 2)))
