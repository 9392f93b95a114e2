"""A scene's distance fields against pybullet: the distance of a point (a tiny probe sphere) to the same
body in the planner's collision world, outside the bodies; closed forms to pybullet's precision, grid
fields within the trilinear interpolation bound of their cell."""

import numpy as np
import pybullet as pb
import pytest

from assets.distance_fields import GridField
from assets.errors import InputError
from planning.scene import load_scene
from planning.scene_fields import mesh_field, scene_fields
from planning.world import World

PROBE_M = 1e-4
CLOSED_FORM_ATOL = 5e-5  # pybullet's closest points of a box or cylinder and a small sphere
EDGE_ROUNDING_M = 1e-3  # how much farther pybullet's rounded box edges are than the exact box's
MESH_ATOL = 3e-4  # the watertight mesh against pybullet's convex pieces of it, and float32 samples


def _pybullet_distance(world: World, body: int, points: np.ndarray) -> np.ndarray:
    c = world.client
    shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=PROBE_M, physicsClientId=c)
    probe = pb.createMultiBody(0, shape, basePosition=[0, 0, 5], physicsClientId=c)
    out = np.full(len(points), np.inf)
    try:
        for k, p in enumerate(points):
            pb.resetBasePositionAndOrientation(probe, p.tolist(), [0, 0, 0, 1], physicsClientId=c)
            cps = pb.getClosestPoints(probe, body, 0.2, physicsClientId=c)
            if cps:
                out[k] = min(cp[8] for cp in cps) + PROBE_M
    finally:
        pb.removeBody(probe, physicsClientId=c)
    return out


def _trilinear_bound(field: GridField, points_world: np.ndarray) -> np.ndarray:
    """sum_i w_i |x - x_i| over the cell's corners: the interpolation error bound of a 1-Lipschitz field."""
    R, t = field.T_world_grid[:3, :3], field.T_world_grid[:3, 3]
    s = ((points_world - t) @ R - field.origin_m) / field.cell_m
    f = s - np.floor(s)
    bound = np.zeros(len(points_world))
    for corner in np.ndindex(2, 2, 2):
        c = np.array(corner)
        bound += np.prod(np.where(c, f, 1 - f), axis=1) * field.cell_m * np.linalg.norm(f - c, axis=1)
    return bound


def _check(field, world, body, center, half, rng, n=150):
    points = center + rng.uniform(-half, half, (n, 3))
    ref = _pybullet_distance(world, body, points)
    keep = (ref > 1e-3) & (ref < 0.05)  # outside, where pybullet's closest points are distances
    assert keep.sum() > 30
    d, _ = field.distance(points[keep])
    err = d - ref[keep]
    if isinstance(field, GridField):
        assert np.all(np.abs(err) <= _trilinear_bound(field, points[keep]) + MESH_ATOL), np.abs(err).max()
    else:  # exact off the edges; pybullet rounds a box's edges by its collision margin, so ours is smaller
        assert np.median(np.abs(err)) < 1e-9
        assert np.all(err <= CLOSED_FORM_ATOL) and np.all(err >= -EDGE_ROUNDING_M), err.min()


@pytest.mark.parametrize("name", ["ham_arc", "chips_between_cans", "jam_hole"])
def test_scene_fields_agree_with_pybullet_distances(name, tmp_path):
    scene = load_scene(name)
    fields = scene_fields(scene, tmp_path)
    assert fields.labels == ("table", *(ob.label for ob in scene.obstacles))
    rng = np.random.default_rng(len(name))
    with World(scene) as world:
        bodies = (world.table_id, *world.obstacle_ids)
        for field, body, label in zip(fields.environment, bodies, fields.labels, strict=True):
            lo, hi = np.array(pb.getAABB(body, physicsClientId=world.client))
            if label == "table":  # only the top matters: points above it, near the object
                lo, hi = np.r_[-0.2, -0.2, hi[2] - 0.01], np.r_[0.2, 0.2, hi[2] + 0.04]
            _check(field, world, body, (lo + hi) / 2, (hi - lo) / 2 + 0.02, rng)
        # the object's field is in the object frame: posed at the scene's object pose
        posed = fields.object_field.with_pose(scene.T_world_object)
        lo, hi = np.array(pb.getAABB(world.object_id, physicsClientId=world.client))
        _check(posed, world, world.object_id, (lo + hi) / 2, (hi - lo) / 2 + 0.02, rng)
    assert list(tmp_path.glob("*.field.npz"))  # the mesh fields were cached


def test_mesh_field_refuses_a_mesh_that_is_not_watertight(tmp_path):
    path = tmp_path / "open.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\nf 1 3 4\n")  # no fourth face
    with pytest.raises(InputError, match="not watertight"):
        mesh_field(path)
    (tmp_path / "junk.obj").write_text("not a mesh\n")
    with pytest.raises(InputError, match="not a triangle mesh"):
        mesh_field(tmp_path / "junk.obj")
