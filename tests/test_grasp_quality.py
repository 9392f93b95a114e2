"""epsilon_l1 against an independent oracle: brute-force facet enumeration without Qhull."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from assets.errors import InputError
from planning.grasp_quality import contact_wrenches, epsilon_l1, tangent_basis

EPS_ABS_TOL = 1e-7  # agreement of epsilon with the oracle (unitless; Qhull's joggle is ~1e-11)
MU = 0.6  # rubber against plastic, GraspIt!'s 1.0 reduced by 0.4
RADIUS_M = 0.04  # sphere radius of the symmetric grasps; also the torque radius


def oracle_epsilon(w: np.ndarray, tol: float = 1e-9) -> float:
    """Smallest origin-to-facet distance of conv(w) by enumerating every 6-subset of points.

    Every facet of a 6-D polytope is the hyperplane through 6 affinely independent points of it, and a
    hyperplane through 6 points is a facet hyperplane exactly when all points lie on one side.
    Returns -inf when the origin is outside some facet (no force closure).
    """
    m = w.shape[0]
    best = np.inf
    combos = np.array(list(itertools.combinations(range(m), 6)))
    for chunk in np.array_split(combos, max(1, len(combos) // 20000)):
        base = w[chunk[:, 0]]
        diffs = w[chunk[:, 1:]] - base[:, None, :]  # (c, 5, 6)
        _, s, vt = np.linalg.svd(diffs)
        ok = s[:, 4] > 1e-9 * np.maximum(s[:, 0], 1e-300)
        normal, base = vt[ok, 5, :], base[ok]
        offset = np.einsum("ij,ij->i", normal, base)
        side = normal @ w.T - offset[:, None]  # (c, m)
        below = np.all(side <= tol, axis=1)
        above = np.all(side >= -tol, axis=1)
        dist = np.concatenate([offset[below], -offset[above]])  # outward normals: points on the <= side
        if dist.size:
            best = min(best, float(dist.min()))
    return best


def equator_grasp(radius_m: float = RADIUS_M):
    """Three contacts 120 deg apart on a sphere's equator, normals towards the centre (the origin)."""
    a = np.deg2rad([0.0, 120.0, 240.0])
    p = radius_m * np.stack([np.cos(a), np.sin(a), np.zeros(3)], axis=1)
    return p, -p / radius_m


def tetrahedron_grasp(radius_m: float = RADIUS_M):
    """Four contacts at a regular tetrahedron's vertices on a sphere, normals towards the centre."""
    v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float) / np.sqrt(3.0)
    return radius_m * v, -v


def test_tangent_basis_is_right_handed_orthonormal():
    n = Rotation.random(50, random_state=np.random.default_rng(0)).apply([0.0, 0.0, 1.0])
    t1, t2 = tangent_basis(n)
    frames = np.stack([t1, t2, n], axis=-1)
    err = np.abs(np.swapaxes(frames, 1, 2) @ frames - np.eye(3)).max()
    assert err < 1e-12
    assert np.allclose(np.linalg.det(frames), 1.0)
    # least aligned axis, the first on ties: n = z gives e = x, t1 = z x x = y
    t1, t2 = tangent_basis(np.array([[0.0, 0.0, 1.0]]))
    assert np.allclose(t1, [[0, 1, 0]]) and np.allclose(t2, [[-1, 0, 0]])


def test_antipodal_pair_has_no_force_closure():
    p = np.array([[RADIUS_M, 0, 0], [-RADIUS_M, 0, 0]])
    assert epsilon_l1(p, -p / RADIUS_M, 1.0, np.zeros(3), RADIUS_M) == 0.0


@pytest.mark.parametrize(
    "points, normals",
    [
        (np.array([[0, 0, 0], [0.01, 0, 0], [0.02, 0, 0]]), np.tile([0, 0, -1.0], (3, 1))),  # one line
        (np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.01, 0.01, 0]]), np.tile([0, 0, 1.0], (4, 1))),
        (np.zeros((0, 3)), np.zeros((0, 3))),
        (np.zeros((1, 3)), np.array([[0, 0, 1.0]])),
    ],
    ids=["collinear", "one-face", "none", "single"],
)
def test_degenerate_grasps_score_zero_without_crashing(points, normals):
    assert epsilon_l1(points, normals, MU, np.zeros(3), RADIUS_M) == 0.0


@pytest.mark.parametrize("grasp, edges", [(equator_grasp, 8), (tetrahedron_grasp, 6)], ids=["equator", "tet"])
def test_symmetric_grasps_match_the_brute_force_oracle(grasp, edges):
    p, n = grasp()
    eps = epsilon_l1(p, n, MU, np.zeros(3), RADIUS_M, num_cone_edges=edges)
    ref = oracle_epsilon(contact_wrenches(p, n, MU, np.zeros(3), RADIUS_M, edges))
    assert ref > 0.01  # force closure, by the oracle
    assert abs(eps - ref) < EPS_ABS_TOL, (eps, ref)


def test_epsilon_is_at_most_the_support_function_in_every_direction():
    p, n = tetrahedron_grasp()
    w = contact_wrenches(p, n, MU, np.zeros(3), RADIUS_M)
    eps = epsilon_l1(p, n, MU, np.zeros(3), RADIUS_M)
    u = np.random.default_rng(1).normal(size=(5000, 6))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    support = (u @ w.T).max(axis=1)
    assert eps > 0 and support.min() >= eps - EPS_ABS_TOL


def test_random_grasps_match_the_oracle():
    rng = np.random.default_rng(7)
    worst, closures = 0.0, 0
    for _ in range(6):
        p = rng.normal(size=(4, 3))
        p = RADIUS_M * p / np.linalg.norm(p, axis=1, keepdims=True)
        n = -p / RADIUS_M + 0.3 * rng.normal(size=(4, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        eps = epsilon_l1(p, n, MU, np.zeros(3), RADIUS_M, num_cone_edges=4)
        ref = max(oracle_epsilon(contact_wrenches(p, n, MU, np.zeros(3), RADIUS_M, 4)), 0.0)
        worst = max(worst, abs(eps - ref))
        closures += ref > 0
    assert worst < EPS_ABS_TOL
    assert closures >= 2  # the sample exercises force-closure grasps, not only zeros


def _random_grasp(seed: int, count: int = 4):
    rng = np.random.default_rng(seed)
    p = rng.normal(size=(count, 3))
    p = RADIUS_M * p / np.linalg.norm(p, axis=1, keepdims=True)
    n = -p / RADIUS_M + 0.2 * rng.normal(size=(count, 3))
    return p, n / np.linalg.norm(n, axis=1, keepdims=True)


_SIGNED_PERMUTATIONS = [R for R in Rotation.create_group("O").as_matrix()]


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 10_000),
    k=st.integers(0, len(_SIGNED_PERMUTATIONS) - 1),
    shift=st.tuples(*[st.floats(-1.0, 1.0)] * 3),
)
def test_invariant_under_translation_and_axis_permuting_rotation(seed, k, shift):
    """Exact invariance where the fixed tangent basis moves with the grasp (rotations of the cube)."""
    p, n = _random_grasp(seed)
    c = np.array([0.003, -0.002, 0.001])
    R, t = _SIGNED_PERMUTATIONS[k], np.asarray(shift)
    e0 = epsilon_l1(p, n, MU, c, RADIUS_M)
    e1 = epsilon_l1(p @ R.T + t, n @ R.T, MU, R @ c + t, RADIUS_M)
    assert abs(e0 - e1) < EPS_ABS_TOL


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 10_000), rot_seed=st.integers(0, 10_000))
def test_any_rotation_stays_within_the_cone_polygon_bracket(seed, rot_seed):
    """A general rotation turns each 8-gon within its cone: eps(mu cos(pi/8)) <= eps_rot <= eps(mu/cos)."""
    p, n = _random_grasp(seed)
    R = Rotation.random(random_state=np.random.default_rng(rot_seed)).as_matrix()
    c = np.zeros(3)
    shrink = np.cos(np.pi / 8)
    e_rot = epsilon_l1(p @ R.T, n @ R.T, MU, c, RADIUS_M)
    assert epsilon_l1(p, n, MU * shrink, c, RADIUS_M) <= e_rot + EPS_ABS_TOL
    assert e_rot <= epsilon_l1(p, n, MU / shrink, c, RADIUS_M) + EPS_ABS_TOL


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), mu=st.floats(0.05, 1.5), extra=st.floats(0.0, 1.0))
def test_does_not_decrease_with_friction(seed, mu, extra):
    p, n = _random_grasp(seed)
    assert (
        epsilon_l1(p, n, mu + extra, np.zeros(3), RADIUS_M)
        >= epsilon_l1(p, n, mu, np.zeros(3), RADIUS_M) - EPS_ABS_TOL
    )


def test_equator_and_tetrahedron_force_closure_values_are_scale_free():
    """Scaling the object and the torque radius together leaves epsilon unchanged."""
    for grasp in (equator_grasp, tetrahedron_grasp):
        p, n = grasp()
        e1 = epsilon_l1(p, n, MU, np.zeros(3), RADIUS_M)
        e2 = epsilon_l1(3.0 * p, n, MU, np.zeros(3), 3.0 * RADIUS_M)
        assert e1 > 0 and abs(e1 - e2) < EPS_ABS_TOL


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"friction": -0.1}, "friction"),
        ({"torque_radius": 0.0}, "torque_radius"),
        ({"num_cone_edges": 2}, "num_cone_edges"),
        ({"contact_normals": np.zeros((3, 3))}, "zero length"),
        ({"contact_normals": np.ones((2, 3))}, "normals"),
        ({"center": [np.nan, 0, 0]}, "non-finite"),
    ],
)
def test_bad_input_raises(kwargs, match):
    p, n = equator_grasp()
    args = {
        "contact_points": p,
        "contact_normals": n,
        "friction": MU,
        "center": np.zeros(3),
        "torque_radius": RADIUS_M,
    }
    args.update(kwargs)
    with pytest.raises(InputError, match=match):
        epsilon_l1(**args)
