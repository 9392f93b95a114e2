"""Factors of the variation model: analytic Jacobians vs one numerical-derivative helper, Sigma_m, params."""

import math

import gtsam
import numpy as np
import pytest

from assets.errors import InputError
from assets.se3 import retract, se3_exp
from inference.factors import (
    constraint_factors,
    constraint_gradient,
    demonstration_error,
    demonstration_factors,
    is_block_diagonal,
    modeling_covariance,
)
from inference.params import VariationParams

JACOBIAN_ATOL = 1e-7  # central differences with h = 1e-6 on O(1) functions
H_STEP = 1e-6


def analytic_jacobians(factor, values) -> list[np.ndarray]:
    """The factor's Jacobian blocks as GTSAM linearizes them (whitened by its noise model)."""
    A, _ = factor.linearize(values).jacobian()
    dims = [
        6 if values.exists(k) and _is_pose(values, k) else values.atVector(k).shape[0] for k in factor.keys()
    ]
    return np.split(A, np.cumsum(dims)[:-1], axis=1)


def _is_pose(values, key) -> bool:
    try:
        values.atPose3(key)
        return True
    except RuntimeError:
        return False


def _random_pose(rng, scale=1.0):
    return gtsam.Pose3(se3_exp(rng.normal(size=6) * scale))


def _check_factor(factor, values, numerical_jacobian):
    for key, A in zip(factor.keys(), analytic_jacobians(factor, values), strict=True):
        H_num = numerical_jacobian(factor.whitenedError, values, key)
        scale = max(1.0, np.abs(A).max())  # whitening by sigma = 1e-5 scales the constraint's rows by 1e5
        err = np.abs(H_num - A).max() / scale
        assert err < JACOBIAN_ATOL, f"key {gtsam.DefaultKeyFormatter(key)}: max error {err:.2e}"


def _spd(rng, n=19, scale=0.01):
    A = rng.normal(size=(n, n)) * scale
    return A @ A.T + 1e-4 * np.eye(n)


def test_demonstration_error_jacobians_match_numerical(numerical_jacobian):
    rng = np.random.default_rng(1)
    for _ in range(5):
        O, W, tau = _random_pose(rng), _random_pose(rng), _random_pose(rng)
        joints, joints_r = rng.normal(size=13), rng.normal(size=13)
        _, H_O, H_W, H_J = demonstration_error(O, W, joints, tau, joints_r, jacobians=True)
        values = gtsam.Values()
        values.insert(0, O)
        values.insert(1, W)
        values.insert(2, joints)

        def err(v, tau=tau, joints_r=joints_r):
            return demonstration_error(v.atPose3(0), v.atPose3(1), v.atVector(2), tau, joints_r)

        for key, H in ((0, H_O), (1, H_W), (2, H_J)):
            assert np.abs(numerical_jacobian(err, values, key) - H).max() < JACOBIAN_ATOL


@pytest.mark.parametrize("fixed", [False, True])
def test_coupled_demonstration_factor_is_one_custom_factor_with_correct_jacobians(numerical_jacobian, fixed):
    rng = np.random.default_rng(2)
    O, tau = _random_pose(rng), _random_pose(rng, 0.3)
    W = O.compose(tau).retract(rng.normal(size=6) * 0.1)
    values = gtsam.Values()
    if not fixed:
        values.insert(0, O)
    values.insert(1, W)
    values.insert(2, rng.normal(size=13))
    factors = demonstration_factors(
        0, 1, 2, tau.matrix(), rng.normal(size=13), _spd(rng), O.matrix() if fixed else None
    )
    assert len(factors) == 1 and isinstance(factors[0], gtsam.CustomFactor)
    _check_factor(factors[0], values, numerical_jacobian)


def test_block_diagonal_demonstration_factor_uses_builtins_with_the_same_error():
    rng = np.random.default_rng(3)
    O, tau, W = _random_pose(rng), _random_pose(rng), _random_pose(rng)
    joints_r, joints = rng.normal(size=13), rng.normal(size=13)
    cov = _spd(rng)
    cov[:6, 6:] = cov[6:, :6] = 0.0
    assert is_block_diagonal(cov)
    values = gtsam.Values()
    values.insert(0, O)
    values.insert(1, W)
    values.insert(2, joints)
    builtin = demonstration_factors(0, 1, 2, tau.matrix(), joints_r, cov)
    assert [type(f).__name__ for f in builtin] == ["BetweenFactorPose3", "PriorFactorVector"]
    expected = demonstration_error(O, W, joints, tau, joints_r)
    np.testing.assert_allclose(builtin[0].unwhitenedError(values), expected[:6], atol=1e-12)
    np.testing.assert_allclose(builtin[1].unwhitenedError(values), expected[6:], atol=1e-12)
    # the squared Mahalanobis errors agree with the full 19x19 Gaussian
    chi2 = 2 * sum(f.error(values) for f in builtin)
    assert math.isclose(chi2, expected @ np.linalg.solve(cov, expected), rel_tol=1e-9)


def test_constraint_factor_jacobians_and_delta_noise(numerical_jacobian):
    rng = np.random.default_rng(4)
    W0 = _random_pose(rng)
    J0 = rng.normal(size=13)
    grad = rng.normal(size=19)
    f3, f4 = constraint_factors(
        7, 1, 2, W0.matrix(), J0, 0.3, grad, r_t=0.01, R_std=0.005, delta_variance=1e-10
    )
    values = gtsam.Values()
    values.insert(7, np.array([0.25]))
    values.insert(1, W0.retract(rng.normal(size=6) * 0.2))
    values.insert(2, J0 + rng.normal(size=13) * 0.1)
    _check_factor(f3, values, numerical_jacobian)
    assert math.isclose(f3.noiseModel().sigmas()[0] ** 2, 1e-10, rel_tol=1e-12)
    # at the linearization point the error is C - phi0
    values.update(1, W0)
    values.update(2, J0)
    np.testing.assert_allclose(f3.unwhitenedError(values), [0.25 - 0.3], atol=1e-12)
    np.testing.assert_allclose(f4.unwhitenedError(values), [0.25 - 0.01], atol=1e-12)


def test_constraint_gradient_of_an_analytic_function():
    """phi = wrist height + 0.1 * joint 3: in the body tangent d phi / d v = R[2, :], d phi / d omega = 0."""
    rng = np.random.default_rng(5)
    T = se3_exp(rng.normal(size=6))
    joints = rng.normal(size=13)

    def phi(T_world_wrist, q):
        return T_world_wrist[2, 3] + 0.1 * q[3]

    value, grad = constraint_gradient(phi, T, joints, 1e-5)
    expected = np.zeros(19)
    expected[3:6] = T[2, :3]
    expected[6 + 3] = 0.1
    assert math.isclose(value, phi(T, joints))
    assert np.abs(grad - expected).max() < 1e-9
    # the tangent convention is GTSAM's retract
    d = np.zeros(6)
    d[3:] = 1e-3 * rng.normal(size=3)
    assert math.isclose(phi(retract(T, d), joints) - value, grad[:6] @ d, rel_tol=1e-6)
    with pytest.raises(InputError, match="non-finite"):
        constraint_gradient(lambda T, q: float("nan"), T, joints, 1e-5)


def test_modeling_covariance_mapping_wrist_terms_and_floor(standin_map):
    T = se3_exp(np.zeros((3, 6)))
    joints = np.zeros((3, 13))
    p = VariationParams()
    cov = modeling_covariance(T, joints, "precision", p, standin_map)
    mapped = standin_map(T, joints, 0.008**2 * np.eye(12))
    extra = np.diag([math.radians(2) ** 2] * 3 + [0.005**2] * 3 + [math.radians(1) ** 2] * 13)
    np.testing.assert_allclose(cov, mapped + extra, rtol=0, atol=1e-15)
    power = modeling_covariance(T, joints, "power", p, standin_map)
    np.testing.assert_allclose(power[0, 3, 3] - mapped[0, 3, 3] * (18 / 8) ** 2, 0.015**2, atol=1e-15)
    # configuration-space override replaces the mapping
    stds = np.linspace(0.01, 0.2, 19)
    over = modeling_covariance(
        T, joints, "power", VariationParams(sigma_m_std_config=stds, joint_floor_std_deg=0)
    )
    np.testing.assert_allclose(over, np.broadcast_to(np.diag(stds**2), (3, 19, 19)), atol=1e-15)


def test_modeling_covariance_with_the_sah_jacobian_is_positive_definite():
    from assets import sah

    joints = np.tile(np.mean(np.asarray(sah.JOINT_LIMITS), axis=1), (2, 1))
    cov = modeling_covariance(se3_exp(np.zeros((2, 6))), joints, "precision", VariationParams())
    assert cov.shape == (2, 19, 19)
    assert np.linalg.eigvalsh(cov).min() > 0


def test_params_yaml_roundtrip_and_errors(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("smooth_position_std_mm: 20\nsmoothness_std_config: null\nmax_iterations: 5\n")
    p = VariationParams.from_yaml(path)
    assert p.smooth_position_std_mm == 20.0 and p.max_iterations == 5
    np.testing.assert_allclose(p.smoothness_stds()[3:6], 0.02)
    assert VariationParams.from_dict(p.to_dict()) == p
    path.write_text("smooth_position_std: 20\n")
    with pytest.raises(InputError, match="unknown parameters"):
        VariationParams.from_yaml(path)
    with pytest.raises(InputError, match="sigma_m_std_config"):
        VariationParams(sigma_m_std_config=[1.0] * 18)
    with pytest.raises(InputError, match="constraint_std_mm"):
        VariationParams(constraint_std_mm=-1)
    with pytest.raises(InputError, match="max_iterations"):
        VariationParams(max_iterations=0)
    with pytest.raises(InputError, match="no such parameter file"):
        VariationParams.from_yaml(tmp_path / "missing.yaml")
