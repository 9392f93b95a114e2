"""The variation model: graph, solve and marginals vs closed forms, dense computations and hand values."""

import dataclasses
import math

import gtsam
import numpy as np
import pytest
import yaml

import inference.params
from assets.errors import InputError
from assets.se3 import local, pose_from_q
from inference import VariationModel, VariationParams, build_graph, factor_covariances, initial_values, solve
from inference.graph import key_j, key_o, key_w
from retarget.trajectory import Trajectory

REL_TOL_EXACT = 1e-9  # linear-Gaussian parts: closed form vs GTSAM
REL_TOL_LINEARIZED = 1e-6  # Pose3 parts: dense numerical linearization vs GTSAM's analytic one
MEAN_ATOL = 1e-6  # [rad, m] the solves stop on a relative error change of 1e-8 (means to ~1e-7)

UNIT = VariationParams(
    sigma_m_std_config=[1.0] * 19, smoothness_std_config=[1.0] * 19, joint_floor_std_deg=0.0
)


def _solve_full(traj, params, fingertip_map):
    """The full graph P(O) P(X | O), solved by Gauss-Newton to convergence."""
    cov_f1 = factor_covariances(traj, params, fingertip_map)
    graph = build_graph(traj, params, cov_f1, traj.T_world_object_mean, traj.cov_object)
    gn = gtsam.GaussNewtonParams()
    gn.setRelativeErrorTol(1e-15)
    gn.setAbsoluteErrorTol(0.0)
    gn.setMaxIterations(10)
    values = gtsam.GaussNewtonOptimizer(graph, initial_values(traj, traj.T_world_object_mean), gn).optimize()
    return graph, values


def test_three_step_chain_of_unit_variances_has_the_hand_computed_marginals(standin_map):
    """O ~ N(0, I); W_t - O ~ N(0, I) and J_t ~ N(0, I) per step; unit smoothness; everything at identity.

    Given O, each coordinate is the chain with information [[2,-1,0],[-1,3,-1],[0,-1,2]], whose inverse has
    diagonal (5/8, 1/2, 5/8). Unconditionally W_t = O + (W_t - O) adds O's unit variance: (13/8, 3/2, 13/8).
    """
    traj = Trajectory(
        T_object_wrist=np.tile(np.eye(4), (3, 1, 1)),
        joints=np.zeros((3, 13)),
        cov_retarget=np.zeros((3, 19, 19)),
        fingertip_rmse_mm=np.zeros(3),
        T_world_object_mean=np.eye(4),
        cov_object=np.eye(6),
        dt_s=0.05,
        object="x",
        grasp_type="precision",
    )
    model = solve(traj, UNIT)
    for t, var in enumerate((5 / 8, 1 / 2, 5 / 8)):
        np.testing.assert_allclose(model.cov[t], var * np.eye(19), rtol=0, atol=1e-12)
    graph, values = _solve_full(traj, UNIT, standin_map)
    marginals = gtsam.Marginals(graph, values)
    np.testing.assert_allclose(marginals.marginalCovariance(key_o()), np.eye(6), atol=1e-12)
    for t, var in enumerate((13 / 8, 3 / 2, 13 / 8)):
        np.testing.assert_allclose(marginals.marginalCovariance(key_w(t)), var * np.eye(6), atol=1e-12)
    for t, var in enumerate((5 / 8, 1 / 2, 5 / 8)):
        np.testing.assert_allclose(marginals.marginalCovariance(key_j(t)), var * np.eye(13), atol=1e-12)


def test_joint_marginals_equal_the_dense_closed_form_of_the_linear_gaussian_chain(
    make_traj, dense_joint_chain
):
    """Block-diagonal covariances: the joints form a linear-Gaussian chain, solved densely with numpy."""
    n = 8
    traj = make_traj(n=n, coupled=False, seed=3)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19))
    model = solve(traj, params)
    mean, blocks = dense_joint_chain(traj, params, {})
    worst = 0.0
    for t in range(n):
        block = blocks[t]
        worst = max(worst, np.abs(model.cov[t][6:, 6:] - block).max() / np.abs(block).max())
        # wrist and joints are independent when every covariance is block diagonal
        assert np.abs(model.cov[t][:6, 6:]).max() < 1e-12 * np.abs(model.cov[t]).max()
    assert worst < REL_TOL_EXACT, worst
    assert np.abs(model.joints_mean - mean).max() < REL_TOL_EXACT * np.abs(mean).max()


@pytest.mark.parametrize("coupled", [False, True])
def test_marginals_equal_a_dense_numerical_linearization_at_the_mean(
    make_traj, numerical_jacobian, standin_map, coupled
):
    n = 5
    traj = make_traj(n=n, coupled=coupled, seed=4)
    # converged far below the default 1e-5, so that the mean is the optimum to MEAN_ATOL
    model = solve(traj, VariationParams(relative_error_tolerance=1e-12), fingertip_map=standin_map)
    params = model.params
    cov_f1 = factor_covariances(traj, params, standin_map)
    graph = build_graph(traj, params, cov_f1, traj.T_world_object_mean, None, fixed_object=True)
    values = gtsam.Values()
    T_world_wrist = traj.T_world_object_mean @ model.T_object_wrist_mean
    keys = []
    for t in range(n):
        values.insert(key_w(t), gtsam.Pose3(T_world_wrist[t]))
        values.insert(key_j(t), np.array(model.joints_mean[t]))
        keys += [(key_w(t), 6), (key_j(t), 13)]
    offset = dict(zip([k for k, _ in keys], np.cumsum([0] + [d for _, d in keys])[:-1], strict=True))
    Lam = np.zeros((19 * n, 19 * n))
    for i in range(graph.size()):
        f = graph.at(i)
        A = np.zeros((f.dim(), 19 * n))
        for key in f.keys():
            H = numerical_jacobian(f.whitenedError, values, key)
            A[:, offset[key] : offset[key] + H.shape[1]] = H
        Lam += A.T @ A
    cov = np.linalg.inv(Lam)
    worst = max(
        np.abs(model.cov[t] - cov[19 * t : 19 * t + 19, 19 * t : 19 * t + 19]).max()
        / np.abs(model.cov[t]).max()
        for t in range(n)
    )
    assert worst < REL_TOL_LINEARIZED, worst
    # the mean is the optimum: more Gauss-Newton iterations do not move it
    params = gtsam.GaussNewtonParams()
    params.setRelativeErrorTol(0.0)
    params.setAbsoluteErrorTol(0.0)
    params.setMaxIterations(3)
    again = gtsam.GaussNewtonOptimizer(graph, values, params).optimize()
    for t in range(n):
        assert (
            np.abs(local(values.atPose3(key_w(t)).matrix(), again.atPose3(key_w(t)).matrix())).max()
            < MEAN_ATOL
        )
        assert np.abs(values.atVector(key_j(t)) - again.atVector(key_j(t))).max() < MEAN_ATOL


def test_conditioning_on_the_object_equals_the_schur_complement_of_the_joint_marginals(
    make_traj, standin_map
):
    n = 5
    traj = make_traj(n=n, coupled=True, seed=5)
    model = solve(traj, VariationParams(relative_error_tolerance=1e-12), fingertip_map=standin_map)
    graph, values = _solve_full(traj, model.params, standin_map)
    marginals = gtsam.Marginals(graph, values)
    # a dense joint computation: the full information matrix, inverted with numpy
    order = gtsam.Ordering()
    for k in [key_o()] + [key_w(t) for t in range(n)] + [key_j(t) for t in range(n)]:
        order.push_back(k)
    Sigma = np.linalg.inv(graph.linearize(values).hessian(order)[0])
    # the conditioned graph (O held at mu_o), linearized at exactly the full graph's solution
    fixed = build_graph(
        traj,
        model.params,
        factor_covariances(traj, model.params, standin_map),
        traj.T_world_object_mean,
        None,
        fixed_object=True,
    )
    values_x = gtsam.Values()
    for t in range(n):
        values_x.insert(key_w(t), values.atPose3(key_w(t)))
        values_x.insert(key_j(t), values.atVector(key_j(t)))
    conditioned = gtsam.Marginals(fixed, values_x)
    idx_o = np.arange(6)
    for t in range(n):
        S = marginals.jointMarginalCovariance([key_o(), key_w(t), key_j(t)]).fullMatrix()
        schur = S[6:, 6:] - S[6:, :6] @ np.linalg.solve(S[:6, :6], S[:6, 6:])
        idx_x = np.concatenate([6 + 6 * t + np.arange(6), 6 + 6 * n + 13 * t + np.arange(13)])
        idx = np.concatenate([idx_o, idx_x])
        D = Sigma[np.ix_(idx, idx)]
        dense = D[6:, 6:] - D[6:, :6] @ np.linalg.solve(D[:6, :6], D[:6, 6:])
        cond = conditioned.jointMarginalCovariance([key_w(t), key_j(t)]).fullMatrix()
        scale = np.abs(cond).max()
        # the Schur complement cancels Sigma_o's part (~10x larger here): allow that many digits
        assert np.abs(cond - schur).max() < REL_TOL_EXACT * 100 * scale
        assert np.abs(cond - dense).max() < REL_TOL_EXACT * 100 * scale
        # the model was solved to its own tolerance: its linearization point differs by ~MEAN_ATOL
        assert np.abs(model.cov[t] - schur).max() < REL_TOL_LINEARIZED * 10 * scale
        # without constraints the full graph's O is mu_o and its W_t is mu_o times the model's mean
        W_full = values.atPose3(key_w(t)).matrix()
        assert (
            np.abs(local(traj.T_world_object_mean @ model.T_object_wrist_mean[t], W_full)).max() < MEAN_ATOL
        )
    assert np.abs(local(values.atPose3(key_o()).matrix(), traj.T_world_object_mean)).max() < MEAN_ATOL


def test_world_means_place_the_wrist_means_at_the_object_pose(make_traj, standin_map):
    """The configurations map back (pose_from_q) to T_world_object @ T_object_wrist_mean, the joints as
    they are."""
    model = solve(make_traj(n=4, seed=3), fingertip_map=standin_map)
    T_world_object = pose_from_q(np.array([0.1, -0.2, 0.75, 0.3, -1.2, 2.0]))
    q = model.world_means(T_world_object)
    assert q.shape == (4, 19)
    np.testing.assert_allclose(pose_from_q(q), T_world_object @ model.T_object_wrist_mean, atol=1e-12)
    np.testing.assert_array_equal(q[:, 6:], model.joints_mean)


def test_save_load_roundtrip(make_traj, standin_map, tmp_path):
    traj = make_traj(n=4, seed=7)
    model = solve(traj, fingertip_map=standin_map)
    path = model.save(tmp_path / "m.model.npz")
    back = VariationModel.load(path)
    for name in (
        "T_object_wrist_mean",
        "joints_mean",
        "cov",
        "T_world_object_mean",
        "cov_object",
        "constrained",
    ):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name))
    assert back.params == model.params and back.iterations == model.iterations
    assert (back.grasp_type, back.object) == ("precision", "testobj")
    np.testing.assert_array_equal(back.source.cov_retarget, traj.cov_retarget)


def _fields(model):
    return {f.name: getattr(model, f.name) for f in dataclasses.fields(model)}


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda d: d.update(cov=d["cov"] * np.array([1.0] * 18 + [-1.0])), "not symmetric|positive definite"),
        (
            lambda d: d.update(cov=np.where(np.eye(19, dtype=bool), -1.0, 0.0) + d["cov"] * 0),
            "positive definite",
        ),
        (lambda d: d.update(joints_mean=np.full_like(d["joints_mean"], np.nan)), "non-finite"),
        (lambda d: d.update(joints_mean=d["joints_mean"][:, :12]), "expected shape"),
        (
            lambda d: d.update(
                T_object_wrist_mean=d["T_object_wrist_mean"][:1],
                joints_mean=d["joints_mean"][:1],
                cov=d["cov"][:1],
                constrained=None,
            ),
            "at least 2 steps",
        ),
    ],
)
def test_bad_models_are_refused_and_never_written(make_traj, standin_map, tmp_path, change, message):
    model = solve(make_traj(n=3, seed=8), fingertip_map=standin_map)
    d = _fields(model)
    d["cov"] = np.array(d["cov"])
    change(d)
    with pytest.raises(InputError, match=message):
        VariationModel(**d)
    # a bad file on disk is refused by load
    good = model.save(tmp_path / "good.model.npz")
    raw = dict(np.load(good))
    raw["cov"] = np.full_like(raw["cov"], np.nan)
    np.savez(tmp_path / "bad.model.npz", **raw)
    with pytest.raises(InputError, match="non-finite"):
        VariationModel.load(tmp_path / "bad.model.npz")


def test_a_failed_save_leaves_no_partial_file(make_traj, standin_map, tmp_path, monkeypatch):
    model = solve(make_traj(n=3, seed=9), fingertip_map=standin_map)

    def boom(*args, **kwargs):
        raise OSError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(OSError):
        model.save(tmp_path / "m.model.npz")
    assert list(tmp_path.iterdir()) == []


def test_a_singular_factor_covariance_is_a_clear_error(make_traj):
    traj = make_traj(n=3, seed=10)
    params = VariationParams(sigma_m_std_config=[1e-3] * 19, joint_floor_std_deg=0.0)
    # Sigma_r is rank 6 and the override is tiny but positive: still positive definite
    solve(traj, params)
    with pytest.raises(InputError, match="not positive definite"):
        factor_covariances(traj, VariationParams(), lambda T, j, c: np.zeros((len(T), 19, 19)) - 1.0)
    with pytest.raises(InputError, match="cov_object"):
        solve(traj, params, cov_object=-np.eye(6))
    assert math.isfinite(solve(traj, params).solve_time_s)


def test_the_documented_parameter_file_states_every_default():
    """The module docstring's YAML is a parameter file: it names every field, with its default."""
    doc = inference.params.__doc__
    block = doc.split("::\n\n", 1)[1].split("\n\n", 1)[0]
    documented = yaml.safe_load(block)
    defaults = {f.name: getattr(VariationParams(), f.name) for f in dataclasses.fields(VariationParams)}
    assert documented == defaults
    assert VariationParams.from_dict(documented) == VariationParams()
