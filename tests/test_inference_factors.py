"""Factors of the variation model: analytic Jacobians vs one numerical-derivative helper, Sigma_m, params."""

import math

import gtsam
import numpy as np
import pytest

from assets import sah
from assets.distance_fields import BoxField, GridField, SphereField
from assets.errors import InputError
from assets.se3 import make_pose, se3_exp
from assets.sphere_cover import hand_sphere_cover
from inference.clearance import HandClearance
from inference.factors import (
    HINGE_CUTOFF,
    clearance_error,
    clearance_factor,
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


SMOOTHING_M = 0.0005  # the hinge's smoothing length in these tests
ACTIVE_M = HINGE_CUTOFF * SMOOTHING_M


def _hand_in_a_scene():
    """The SAH's cover against a table (closed-form box) and a ball-shaped object (a grid field in the
    object frame), with a 50 mm self clearance so that self rows are violated too; a configuration with
    the fingers through the table and the object, and the object moved off the origin."""
    cover = hand_sphere_cover("sah")
    table = BoxField(np.array([0.6, 0.4, 0.025]), make_pose(np.eye(3), [0, 0, -0.025]))
    ball = SphereField(0.04, np.array([0.0, 0.0, 0.05]))
    ball_grid = GridField.from_function(lambda p: ball.distance(p)[0], [-0.1] * 3, [0.1, 0.1, 0.2], 0.004)
    clearance = HandClearance(
        cover,
        [table],
        ball_grid,
        self_clearance_m=0.05,
        self_pairs=cover.self_pairs(),
        active_margin_m=ACTIVE_M,
    )
    rng = np.random.default_rng(9)
    O = gtsam.Pose3(se3_exp(np.r_[0.05 * rng.normal(size=3), 0.01 * rng.normal(size=3)]))
    R_down = np.diag([1.0, -1.0, -1.0])  # fingers (+z of the wrist) pointing down
    W = gtsam.Pose3(make_pose(R_down, [0.06, 0.0, 0.2]) @ se3_exp(0.02 * rng.normal(size=6)))
    J = sah.rest_joints() + np.deg2rad(rng.uniform(-5, 5, size=13))
    return clearance, O, W, J


@pytest.mark.parametrize("fixed", [False, True])
def test_clearance_factor_jacobians_match_numerical_through_o_w_and_j(numerical_jacobian, fixed):
    clearance, O, W, J = _hand_in_a_scene()
    margins = clearance(O.matrix(), W.matrix(), J)
    n = clearance.n_spheres
    env, obj, pairs = _dense_margins(clearance, O.matrix(), W.matrix(), J)
    assert np.sum((env < 0) & (env < obj)) >= 3 and np.sum((obj < 0) & (obj < env)) >= 3
    assert np.sum(pairs < 0) >= 3 and np.sum(margins[n:] < 0) >= 3  # table, object, self rows all active
    factor = clearance_factor(
        None if fixed else 0,
        1,
        2,
        clearance,
        0.002,
        SMOOTHING_M,
        T_world_object=O.matrix() if fixed else None,
    )
    values = gtsam.Values()
    if not fixed:
        values.insert(0, O)
    values.insert(1, W)
    values.insert(2, J)
    _check_factor(factor, values, numerical_jacobian)
    expected = clearance_error(margins, SMOOTHING_M)[0]
    np.testing.assert_allclose(factor.unwhitenedError(values), expected, atol=1e-15)


def _dense_margins(clearance, T_world_object, T_world_wrist, joints):
    """The reference without a broad phase: every sphere against every field, every self pair; the
    environment's and the object's margins (n,) and the pairs' (p,)."""
    c_wrist = clearance.cover.centers(joints)
    c_world = c_wrist @ T_world_wrist[:3, :3].T + T_world_wrist[:3, 3]
    r = clearance.cover.radii_m
    env = np.min([f.distance(c_world)[0] for f in clearance.environment], axis=0) - clearance.clearance_m - r
    c_object = (c_world - T_world_object[:3, 3]) @ T_world_object[:3, :3]
    obj = clearance.object_field.distance(c_object)[0] - clearance.object_clearance_m - r
    i, j = clearance.self_pairs.T
    pairs = np.linalg.norm(c_wrist[i] - c_wrist[j], axis=1) - r[i] - r[j] - clearance.self_clearance_m
    return env, obj, pairs


def test_broad_phase_margins_are_exact_where_violated_and_lower_bounds_elsewhere():
    """Batched margins of many configurations near the table and the object against the dense reference:
    equal wherever the reference is below the active margin, never above it, and never below the active
    margin where the reference is not."""
    clearance, O, W, J = _hand_in_a_scene()
    rng = np.random.default_rng(4)
    Ws = W.matrix() @ se3_exp(np.c_[0.3 * rng.normal(size=(12, 3)), 0.04 * rng.normal(size=(12, 3))])
    Js = J + np.deg2rad(rng.uniform(-20, 20, size=(12, 13)))
    got = clearance(O.matrix(), Ws, Js)
    assert got.shape == (12, clearance.dim)
    violated, bounded = 0, 0
    for k in range(12):
        env, obj, pairs = _dense_margins(clearance, O.matrix(), Ws[k], Js[k])
        ref = np.r_[np.minimum(env, obj), pairs]
        neg = ref < ACTIVE_M
        np.testing.assert_allclose(got[k][neg], ref[neg], atol=1e-12)
        assert np.all(got[k] <= ref + 1e-12) and np.all(got[k][~neg] >= ACTIVE_M)
        violated += neg.sum()
        bounded += np.sum(got[k] < ref - 1e-9)
    assert violated > 100 and bounded > 1000  # both phases are exercised
    _, H_O, H_W, H_J = clearance(O.matrix(), Ws, Js, jacobians=True)
    for k in (0, 5):  # the batched Jacobians are the single configuration's
        single = clearance(O.matrix(), Ws[k], Js[k], jacobians=True)
        for a, b in zip((H_O[k], H_W[k], H_J[k]), single[1:], strict=True):
            np.testing.assert_allclose(a, b, atol=1e-12)


def test_clearance_factor_of_a_free_configuration_is_zero_and_refuses_a_bad_std():
    clearance, O, W, J = _hand_in_a_scene()
    far = gtsam.Pose3(make_pose(np.eye(3), [0.0, 0.0, 1.0]))
    free = HandClearance(
        clearance.cover, clearance.environment, clearance.object_field, active_margin_m=ACTIVE_M
    )
    factor = clearance_factor(None, 1, 2, free, 0.002, SMOOTHING_M, T_world_object=O.matrix())
    values = gtsam.Values()
    values.insert(1, far)
    values.insert(2, J)
    assert factor.error(values) == 0.0
    assert np.all(factor.linearize(values).jacobian()[0] == 0.0)
    with pytest.raises(InputError, match="std must be > 0"):
        clearance_factor(None, 1, 2, free, 0.0, SMOOTHING_M, T_world_object=O.matrix())
    with pytest.raises(InputError, match="smoothing must be > 0"):
        clearance_factor(None, 1, 2, free, 0.002, np.nan, T_world_object=O.matrix())
    with pytest.raises(InputError, match="below the hinge's cutoff"):
        clearance_factor(None, 1, 2, free, 0.002, 2 * SMOOTHING_M, T_world_object=O.matrix())


def test_smooth_hinge_limits_slope_and_cutoff():
    """e(m) = -s softplus(-m/s): m deep in violation, -s ln 2 at the clearance, zero far from it; its slope
    against central differences; the jump at the cutoff is below 5e-5 s."""
    s = SMOOTHING_M
    m = np.array([-0.02, -0.002, 0.0, 0.0004, 0.003])
    e, slope = clearance_error(m, s)
    assert e[0] == pytest.approx(-0.02, abs=1e-15) and e[1] == pytest.approx(
        -0.002 - s * np.exp(-4), rel=1e-3
    )
    assert e[2] == pytest.approx(-s * np.log(2.0), rel=1e-15) and slope[2] == pytest.approx(0.5)
    assert np.all(np.diff(e) > 0) and np.all((slope > 0) & (slope <= 1))
    h = 1e-9
    numeric = (clearance_error(m + h, s)[0] - clearance_error(m - h, s)[0]) / (2 * h)
    np.testing.assert_allclose(slope, numeric, rtol=1e-6, atol=1e-9)
    below, at, far = clearance_error(np.array([ACTIVE_M * (1 - 1e-12), ACTIVE_M, 1.0]), s)[0]
    assert at == far == 0.0 and 0 < -below < 5e-5 * s


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


def test_the_object_clearance_follows_the_grasp_type():
    """Each grasp type has its own clearance from the grasped object (3 mm by default for both,
    params.py); the scene's clearance takes the strategy's."""
    from pbdgrasp.scene_model import scene_clearance
    from planning.scene import load_scene

    p = VariationParams()
    assert p.object_clearance_m("precision") == pytest.approx(0.003)
    wider = VariationParams(precision_object_clearance_mm=6.0)
    assert wider.object_clearance_m("precision") == pytest.approx(0.006)
    assert wider.object_clearance_m("power") == pytest.approx(0.003)
    with pytest.raises(InputError, match="grasp_type"):
        p.object_clearance_m("pinch")
    scene = load_scene("ham")
    params = VariationParams(precision_object_clearance_mm=4.5)
    assert scene_clearance(scene, params, grasp_type="precision").object_clearance_m == pytest.approx(0.0045)
    assert scene_clearance(scene, params, grasp_type="power").object_clearance_m == pytest.approx(0.003)
    with pytest.raises(InputError, match="power_object_clearance_mm"):
        VariationParams(power_object_clearance_mm=-1.0)
    legacy = VariationParams.from_dict({"object_clearance_mm": 3.0})  # files written before the split
    assert legacy.object_clearance_m("precision") == pytest.approx(0.003)
    assert legacy.object_clearance_m("power") == pytest.approx(0.003)


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
