"""The variation model: graph, solve and marginals vs closed forms, dense computations and hand values."""

import dataclasses
import math

import gtsam
import numpy as np
import pytest

from assets.errors import InputError
from assets.se3 import local
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


def _dense_joint_chain(traj, params, extra):
    """Means and covariances (n, 13) and (n, 13, 13) of the joints' linear-Gaussian chain (block-diagonal
    f_1t, smoothness S_t) with extra scalar priors ``extra[(t, i)] = [(value, variance), ...]`` on J_t,i."""
    mean, cov = _dense_joint_chain_full(traj, params, extra)
    n = traj.num_steps
    return mean, np.stack([cov[13 * t : 13 * t + 13, 13 * t : 13 * t + 13] for t in range(n)])


def _dense_joint_chain_full(traj, params, extra):
    """:func:`_dense_joint_chain` with the whole (13 n, 13 n) covariance, index ``13 t + i`` for J_t,i."""
    n = traj.num_steps
    cov_f1 = factor_covariances(traj, params)
    D = np.linalg.inv(np.diag(params.smoothness_stds()[6:] ** 2))
    Lam, eta = np.zeros((13 * n, 13 * n)), np.zeros(13 * n)
    for t in range(n):
        P = np.linalg.inv(cov_f1[t][6:, 6:])
        Lam[13 * t : 13 * t + 13, 13 * t : 13 * t + 13] += P
        eta[13 * t : 13 * t + 13] += P @ traj.joints[t]
    for t in range(n - 1):
        a, b = slice(13 * t, 13 * t + 13), slice(13 * t + 13, 13 * t + 26)
        Lam[a, a] += D
        Lam[b, b] += D
        Lam[a, b] -= D
        Lam[b, a] -= D
    for (t, i), priors in extra.items():
        for value, variance in priors:
            Lam[13 * t + i, 13 * t + i] += 1.0 / variance
            eta[13 * t + i] += value / variance
    cov = np.linalg.inv(Lam)
    return (cov @ eta).reshape(n, 13), cov


def test_joint_marginals_equal_the_dense_closed_form_of_the_linear_gaussian_chain(make_traj):
    """Block-diagonal covariances: the joints form a linear-Gaussian chain, solved densely with numpy."""
    n = 8
    traj = make_traj(n=n, coupled=False, seed=3)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19))
    model = solve(traj, params)
    mean, blocks = _dense_joint_chain(traj, params, {})
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


class _Planes:
    """A toy clearance function: margins ``n_k . p - b_k`` of the wrist position p [m] (rows k), or, with
    ``joint_rows``, ``slope_k (J[i_k] - w_k)`` of single joints; analytic Jacobians; batched over leading
    axes like :class:`inference.clearance.HandClearance`."""

    def __init__(self, normals=(), offsets=(), joint_rows=()):
        self.normals = np.asarray(normals, dtype=float).reshape(-1, 3)
        self.offsets = np.asarray(offsets, dtype=float)
        self.joint_rows = list(joint_rows)  # (joint index, slope, wall)
        self.dim = len(self.normals) + len(self.joint_rows)
        self.active_margin_m = np.inf  # every margin exact, with its Jacobian

    def __call__(self, T_world_object, T_world_wrist, joints, jacobians=False):
        p, R = T_world_wrist[..., :3, 3], T_world_wrist[..., :3, :3]
        rows = [k * (joints[..., i] - w) for i, k, w in self.joint_rows]
        margins = np.concatenate(
            [p @ self.normals.T - self.offsets, np.stack(rows, -1) if rows else p[..., :0]], -1
        )
        if not jacobians:
            return margins
        batch = margins.shape[:-1]
        H_W, H_J = np.zeros(batch + (self.dim, 6)), np.zeros(batch + (self.dim, 13))
        H_W[..., : len(self.normals), 3:] = self.normals @ R  # a body twist v moves p by R v
        for r, (i, k, _) in enumerate(self.joint_rows):
            H_J[..., len(self.normals) + r, i] = k
        return margins, np.zeros(batch + (self.dim, 6)), H_W, H_J


def _ends_near_the_floor(make_traj):
    n = 10
    s = np.linspace(0, 1, n)
    xi = np.zeros((n, 6))
    xi[:, 5] = 0.003 + 0.15 * np.clip(1 - s / 0.6, 0, None)  # flat at 3 mm for the last four steps
    return make_traj(n=n, T_world_object=np.eye(4), xi_path=xi, seed=6, cov_scale=0.003), xi


def test_a_clearance_moves_the_mean_and_shrinks_the_variance_along_its_gradient(make_traj, standin_map):
    """margin = wrist height - 10 mm; the trajectory ends 3 mm above the plane z = 0."""
    traj, xi = _ends_near_the_floor(make_traj)
    floor = _Planes([[0, 0, 1]], [0.010])
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


def test_every_violated_row_pushes_out(make_traj, standin_map):
    """A floor z = 0 and a wall x = x0, both 3 mm from the last steps, 10 mm clearance each: each row acts
    on its own, and both distances move towards the clearance."""
    traj, _ = _ends_near_the_floor(make_traj)
    free = solve(traj, fingertip_map=standin_map)
    x0 = free.T_object_wrist_mean[-1, 0, 3] - 0.003
    held = solve(
        traj, fingertip_map=standin_map, clearance=_Planes([[0, 0, 1], [1, 0, 0]], [0.010, x0 + 0.010])
    )
    assert held.converged
    for axis, plane in ((2, 0.0), (0, x0)):
        d_free = free.T_object_wrist_mean[:, axis, 3] - plane
        d_held = held.T_object_wrist_mean[:, axis, 3] - plane
        near = np.flatnonzero(d_free < 0.005)
        assert len(near) >= 2
        assert np.all(d_held[near] - d_free[near] > 0.3 * (0.010 - d_free[near])), (axis, d_free, d_held)


@pytest.mark.parametrize("wall", [0.05, -10.0])
def test_joint_0_against_a_wall_gives_the_gaussian_update_or_nothing(make_traj, wall):
    """Joint 0 with a Gaussian prior whose mean lies inside a wall (margin = J_0 - w, w above the means):
    the active hinge is a linear Gaussian observation J_0 = w of std sigma_c on each step, so the solve gives
    the dense closed form of the joints' chain with those priors added; with the wall far below the means
    every row is inactive and the marginals are the chain's own. (A hinge smoothing of 1e-9 makes the
    smooth hinge the plain one here.)"""
    traj = make_traj(n=3, coupled=False, seed=11)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19), hinge_smoothing_mm=1e-6)
    w = traj.joints[:, 0].max() + wall if wall > 0 else wall
    model = solve(traj, params, clearance=_Planes(joint_rows=[(0, 1.0, w)]))
    assert model.converged
    sigma_c = params.constraint_std_mm * 1e-3
    extra = {(t, 0): [(w, sigma_c**2)] for t in range(traj.num_steps)} if wall > 0 else {}
    mean, cov = _dense_joint_chain(traj, params, extra)
    if wall > 0:
        assert model.constrained.all() and np.all(mean[:, 0] < w)  # the soft hinge stays active
    np.testing.assert_allclose(model.joints_mean, mean, atol=1e-7)
    np.testing.assert_allclose(model.cov[:, 6:, 6:], cov, rtol=1e-6, atol=1e-12)


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


EP_EXACT = VariationParams(
    sigma_m_std_config=[0.02] * 6 + list(np.linspace(0.02, 0.08, 13)),
    smoothness_std_config=[1e3] * 19,  # steps independent: one site per joint and step, EP exact
    joint_floor_std_deg=0.0,
    joint_limit_tolerance=1e-12,
    joint_limit_max_iterations=500,
)


def _independent_joints_traj(make_traj, joints, n=2):
    """n steps at the joint values ``joints`` (13,), no retargeting covariance: with ``EP_EXACT`` every
    joint's f_1t is an independent N(joints_i, sigma_i^2)."""
    traj = make_traj(n=n, coupled=False, seed=3)
    return dataclasses.replace(traj, joints=np.tile(joints, (n, 1)), cov_retarget=np.zeros((n, 19, 19)))


def test_joint_limits_give_the_truncated_normal_moments_for_independent_joints(make_traj):
    """Steps without smoothness coupling, independent joints N(tau_i, sigma_i^2): the posterior of each joint
    under the limits is that normal truncated to [lo, hi], and expectation propagation with one site per
    joint is exact. Joint 0 sits 0.2 sigma inside its lower limit, joint 1 half a sigma beyond its upper
    one, joint 2 two sigma beyond its lower one; the others are far inside and untouched."""
    from scipy.stats import truncnorm

    sigma = np.array(EP_EXACT.sigma_m_std_config[6:])
    lo, hi = np.full(13, -1.0), np.full(13, 1.0)
    lo[:3], hi[:3] = [0.0, -0.5, 0.1], [0.6, 0.2, 0.9]
    tau = np.full(13, 0.3)
    tau[:3] = [lo[0] + 0.2 * sigma[0], hi[1] + 0.5 * sigma[1], lo[2] - 2.0 * sigma[2]]
    model = solve(_independent_joints_traj(make_traj, tau), EP_EXACT, joint_limits=np.stack([lo, hi], axis=1))
    mean, var = truncnorm.stats((lo - tau) / sigma, (hi - tau) / sigma, loc=tau, scale=sigma, moments="mv")
    for t in range(2):
        np.testing.assert_allclose(model.joints_mean[t], mean, rtol=0, atol=1e-9)
        np.testing.assert_allclose(np.diag(model.cov[t])[6:], var, rtol=1e-8, atol=0)
    assert model.converged and model.constrained.all()
    # the limits narrow a joint at a limit but keep its spread away from it (a tenth of a sigma near the
    # lower limit of joint 0 still leaves 0.6 sigma)
    assert 0.55 * sigma[0] < math.sqrt(model.cov[0][6, 6]) < sigma[0]


def test_joint_limits_on_a_chain_agree_with_rejection_sampling(make_traj):
    """Six steps of joint 0 coupled by the smoothness factors, its demonstrated values crossing the lower
    limit; the true posterior is the Gaussian chain truncated to [lo, hi] at every step, sampled here by
    rejection (2e5 accepted draws). Expectation propagation's marginal means and stds agree with it to a
    few hundredths of the chain's std; without the limits the means cross the limit."""
    n, lo0 = 6, 0.0
    tau = np.full(13, 0.3)
    params = dataclasses.replace(EP_EXACT, smoothness_std_config=[0.01] * 19)
    traj = _independent_joints_traj(make_traj, tau, n)
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
    mean0, cov_all = _dense_joint_chain_full(traj, params, {})
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


def test_joint_limits_keep_a_constraint_from_bending_a_joint_past_its_limit(make_traj):
    """A 'wall' that joint 0 can clear only by going 50 mrad past its lower limit (phi = 0.1 m/rad x
    (lo + 0.2 - J_0), clearance 25 mm): without the limits the means leave them by tens of mrad, as the
    scenes' link constraints bent the SAH's fingers backwards; with them every mean stays inside."""
    n, lo0, slope = 6, -0.02, 0.1
    traj = make_traj(n=n, coupled=False, seed=3)
    params = VariationParams(sigma_m_std_config=np.linspace(0.01, 0.05, 19))

    # margin = slope (lo + 0.2 - J_0) - 25 mm = -slope (J_0 - (lo + 0.2 - 0.25))
    kw = dict(clearance=_Planes(joint_rows=[(0, -slope, lo0 + 0.2 - 0.025 / slope)]))
    limits = np.tile([-10.0, 10.0], (13, 1))
    limits[0, 0] = lo0
    bent = solve(traj, params, **kw)
    held = solve(traj, params, joint_limits=limits, **kw)
    assert bent.joints_mean[:, 0].min() < lo0 - 0.03
    assert held.joints_mean[:, 0].min() > lo0
    assert held.constrained.all()


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
