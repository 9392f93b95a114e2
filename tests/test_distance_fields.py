"""Signed distance fields (assets.distance_fields) against independent references: brute-force distances to
densely sampled surfaces, central differences, the trilinear interpolation bound, Open3D meshes of the
same primitives."""

from __future__ import annotations

import numpy as np
import pytest

from assets.distance_fields import BoxField, CylinderField, GridField, SphereField, min_distance
from assets.errors import InputError
from assets.se3 import make_pose, so3_exp

T_POSED = make_pose(so3_exp(np.array([0.3, -0.5, 0.8])), np.array([0.1, -0.2, 0.05]))
HALF = np.array([0.04, 0.025, 0.06])
RADIUS, HALF_HEIGHT = 0.03, 0.05


def _box_surface(half: np.ndarray, step: float) -> np.ndarray:
    """Points on the six faces of the box |x_i| <= half_i, at most ``step`` apart."""
    points = []
    for axis in range(3):
        u, v = [a for a in range(3) if a != axis]
        gu = np.linspace(-half[u], half[u], int(np.ceil(2 * half[u] / step)) + 1)
        gv = np.linspace(-half[v], half[v], int(np.ceil(2 * half[v] / step)) + 1)
        U, V = np.meshgrid(gu, gv, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((U.size, 3))
            p[:, axis], p[:, u], p[:, v] = sign * half[axis], U.ravel(), V.ravel()
            points.append(p)
    return np.concatenate(points)


def _cylinder_surface(radius: float, half_height: float, step: float) -> np.ndarray:
    """Points on the side and both caps of the z-axis cylinder, at most about ``step`` apart."""
    phi = np.linspace(0, 2 * np.pi, int(np.ceil(2 * np.pi * radius / step)), endpoint=False)
    z = np.linspace(-half_height, half_height, int(np.ceil(2 * half_height / step)) + 1)
    P, Z = np.meshgrid(phi, z, indexing="ij")
    side = np.column_stack([radius * np.cos(P.ravel()), radius * np.sin(P.ravel()), Z.ravel()])
    g = np.linspace(-radius, radius, int(np.ceil(2 * radius / step)) + 1)
    X, Y = np.meshgrid(g, g, indexing="ij")
    disc = np.column_stack([X.ravel(), Y.ravel()])[np.hypot(X.ravel(), Y.ravel()) <= radius]
    caps = [np.column_stack([disc, np.full(len(disc), s * half_height)]) for s in (-1.0, 1.0)]
    return np.concatenate([side, *caps])


def _brute(points: np.ndarray, surface: np.ndarray, inside: np.ndarray) -> np.ndarray:
    d = np.sqrt(((points[:, None, :] - surface[None]) ** 2).sum(-1)).min(axis=1)
    return np.where(inside, -d, d)


def _central_gradient(field, points: np.ndarray, h: float = 1e-6) -> np.ndarray:
    g = np.empty_like(points)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        g[:, k] = (field.distance(points + e)[0] - field.distance(points - e)[0]) / (2 * h)
    return g


def _world(points_local: np.ndarray) -> np.ndarray:
    return points_local @ T_POSED[:3, :3].T + T_POSED[:3, 3]


@pytest.fixture(scope="module")
def local_points():
    return np.random.default_rng(0).uniform(-0.09, 0.09, (400, 3))


def test_box_matches_the_brute_force_distance_to_its_sampled_surface(local_points):
    step = 5e-4
    field = BoxField(HALF, T_POSED)
    inside = np.all(np.abs(local_points) < HALF, axis=1)
    brute = _brute(local_points, _box_surface(HALF, step), inside)
    d, _ = field.distance(_world(local_points))
    assert inside.sum() > 20 and (~inside).sum() > 200
    assert np.abs(d - brute).max() < step  # the surface samples are at most step / sqrt(2) from any point


def test_cylinder_matches_the_brute_force_distance_to_its_sampled_surface(local_points):
    step = 5e-4
    field = CylinderField(RADIUS, HALF_HEIGHT, T_POSED)
    p = local_points
    inside = (np.hypot(p[:, 0], p[:, 1]) < RADIUS) & (np.abs(p[:, 2]) < HALF_HEIGHT)
    brute = _brute(p, _cylinder_surface(RADIUS, HALF_HEIGHT, step), inside)
    d, _ = field.distance(_world(p))
    assert inside.sum() > 10
    assert np.abs(d - brute).max() < step


def test_sphere_is_the_distance_to_the_centre_minus_the_radius(local_points):
    c = np.array([0.01, -0.02, 0.03])
    d, g = SphereField(0.04, c).distance(local_points)
    v = local_points - c
    np.testing.assert_allclose(d, np.linalg.norm(v, axis=1) - 0.04, atol=1e-15)
    np.testing.assert_allclose(g, v / np.linalg.norm(v, axis=1)[:, None], atol=1e-12)


@pytest.mark.parametrize(
    "field",
    [
        BoxField(HALF, T_POSED),
        CylinderField(RADIUS, HALF_HEIGHT, T_POSED),
        SphereField(0.04, [0.0, 0.01, 0.0]),
    ],
    ids=["box", "cylinder", "sphere"],
)
def test_closed_form_gradients_match_central_differences(field, local_points):
    points = _world(local_points)
    d, g = field.distance(points)
    numeric = _central_gradient(field, points)
    # off the medial axes (where the nearest feature switches) the gradient is the derivative
    ok = np.linalg.norm(numeric, axis=1) > 0.999
    assert ok.sum() > 300
    np.testing.assert_allclose(g[ok], numeric[ok], atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), 1.0, atol=1e-9)


@pytest.fixture(scope="module")
def box_grid():
    exact = BoxField(HALF, np.eye(4))
    return exact, GridField.from_function(lambda p: exact.distance(p)[0], -HALF - 0.03, HALF + 0.03, 0.004)


def test_grid_is_exact_at_its_nodes(box_grid):
    exact, grid = box_grid
    idx = np.random.default_rng(1).integers(0, np.array(grid.values.shape), (200, 3))
    nodes = grid.origin_m + grid.cell_m * idx
    np.testing.assert_allclose(grid.distance(nodes)[0], exact.distance(nodes)[0], atol=1e-15)


def test_grid_error_is_within_the_trilinear_bound_of_a_1_lipschitz_field(box_grid):
    """|f(x) - sum_i w_i f(x_i)| <= sum_i w_i |x - x_i| for a distance field (1-Lipschitz)."""
    exact, grid = box_grid
    rng = np.random.default_rng(2)
    x = rng.uniform(grid.origin_m, grid.origin_m + grid.cell_m * (np.array(grid.values.shape) - 1), (2000, 3))
    s = (x - grid.origin_m) / grid.cell_m
    f = s - np.floor(s)
    bound = np.zeros(len(x))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        w = np.prod(np.where(c, f, 1 - f), axis=1)
        bound += w * grid.cell_m * np.linalg.norm(f - c, axis=1)
    err = np.abs(grid.distance(x)[0] - exact.distance(x)[0])
    assert np.all(err <= bound + 1e-12)
    assert err.max() > 1e-4  # the test can fail: the grid is not exact off its nodes


def test_grid_gradient_is_the_derivative_of_its_interpolation(box_grid):
    _, grid = box_grid
    rng = np.random.default_rng(3)
    idx = rng.integers(1, np.array(grid.values.shape) - 2, (300, 3))
    x = grid.origin_m + grid.cell_m * (idx + rng.uniform(0.05, 0.95, (300, 3)))  # inside cells, off faces
    np.testing.assert_allclose(grid.distance(x)[1], _central_gradient(grid, x, 1e-7), atol=1e-6)


def test_posed_grid_is_the_local_field_moved_rigidly(box_grid, local_points):
    _, grid = box_grid
    posed = grid.with_pose(T_POSED)
    d_local, g_local = grid.distance(local_points)
    d, g = posed.distance(_world(local_points))
    np.testing.assert_allclose(d, d_local, atol=1e-12)
    np.testing.assert_allclose(g, g_local @ T_POSED[:3, :3].T, atol=1e-12)


def test_grid_outside_its_box_is_continuous_and_grows_with_the_distance_to_it(box_grid):
    _, grid = box_grid
    upper = grid.origin_m + grid.cell_m * (np.array(grid.values.shape) - 1)
    edge = np.array([0.0, 0.0, upper[2]])
    d_edge = grid.distance(edge[None])[0][0]
    d_out = grid.distance(np.array([edge + [0, 0, 1e-9], edge + [0, 0, 0.05]]))[0]
    assert abs(d_out[0] - d_edge) < 1e-8
    assert d_out[1] == pytest.approx(d_edge + 0.05, abs=1e-12)


def test_open3d_mesh_fields_match_the_closed_forms_of_the_same_primitives():
    """Open3D's signed distance of a box mesh (exact geometry) and of a 128-sided cylinder mesh (faceted
    by r (1 - cos(pi / 128)) = 0.009 mm) at the grid's nodes, against the closed forms."""
    import open3d as o3d

    box = o3d.geometry.TriangleMesh.create_box(*(2 * HALF)).translate(-HALF)
    cyl = o3d.geometry.TriangleMesh.create_cylinder(RADIUS, 2 * HALF_HEIGHT, resolution=128, split=1)
    cases = (
        (box, BoxField(HALF, np.eye(4)), 2e-6),
        (cyl, CylinderField(RADIUS, HALF_HEIGHT, np.eye(4)), RADIUS * (1 - np.cos(np.pi / 128)) + 2e-6),
    )
    for mesh, exact, tol in cases:
        assert mesh.is_watertight()
        grid = GridField.from_mesh(np.asarray(mesh.vertices), np.asarray(mesh.triangles), 0.005, 0.02)
        shape = np.array(grid.values.shape)
        nodes = grid.origin_m + grid.cell_m * np.stack(np.meshgrid(*map(np.arange, shape), indexing="ij"), -1)
        nodes = nodes.reshape(-1, 3)
        err = np.abs(grid.values.reshape(-1) - exact.distance(nodes)[0])
        assert err.max() < tol, (type(exact).__name__, err.max())
        assert (grid.values < 0).sum() > 20  # the sign: inside nodes exist and are negative


def test_grid_save_and_load_round_trip(tmp_path, box_grid):
    _, grid = box_grid
    posed = grid.with_pose(T_POSED)
    path = posed.save(tmp_path / "box.npz")
    back = GridField.load(path)
    np.testing.assert_array_equal(back.values, posed.values)
    np.testing.assert_array_equal(back.T_world_grid, T_POSED)
    assert back.cell_m == posed.cell_m and np.array_equal(back.origin_m, posed.origin_m)
    (tmp_path / "bad.npz").write_bytes(b"not a field")
    with pytest.raises(InputError, match="not a distance field file"):
        GridField.load(tmp_path / "bad.npz")


def test_min_distance_takes_the_nearest_field_and_its_gradient(local_points):
    a, b = SphereField(0.02, [0.03, 0, 0]), SphereField(0.01, [-0.03, 0, 0])
    d, g = min_distance([a, b], local_points)
    (da, ga), (db, gb) = a.distance(local_points), b.distance(local_points)
    np.testing.assert_array_equal(d, np.minimum(da, db))
    np.testing.assert_array_equal(g, np.where((da <= db)[:, None], ga, gb))
    d0, g0 = min_distance([], local_points)
    assert np.all(np.isinf(d0)) and not g0.any()


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: BoxField([0.1, 0.0, 0.1], np.eye(4)), "half_extents_m"),
        (lambda: BoxField([0.1, 0.1], np.eye(4)), "expected 3 numbers"),
        (lambda: CylinderField(0.1, np.nan, np.eye(4)), "half_height_m"),
        (lambda: SphereField(-1.0, [0, 0, 0]), "radius_m"),
        (lambda: GridField([0, 0, 0], 0.01, np.zeros((1, 3, 3))), ">= 2 per axis"),
        (lambda: GridField([0, 0, 0], 0.01, np.zeros((3, 3, 3)), np.eye(3)), "T_world_grid"),
    ],
)
def test_bad_field_parameters_are_input_errors(make, message):
    with pytest.raises(InputError, match=message):
        make()
