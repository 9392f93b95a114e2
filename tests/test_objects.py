"""Object meshes: watertight, at their stated sizes, with metadata consistent with the mesh."""

import numpy as np
import open3d as o3d
import pybullet as pb
import pytest

import assets

DIMENSION_TOL_M = 0.002  # the issue: stated dimensions within 2 mm
COM_TOL_M = 1e-5  # object.yaml rounds to 0.01 mm, the OBJ to 1 um
RADIUS_TOL_M = 2e-5

# the stated sizes (x, y, z) [m]; mugs: body diameter along y and height (handle along +x)
STATED = {
    "ham": (0.100, 0.055, 0.080),
    "jam": (0.070, 0.070, 0.090),
    "chips": (0.075, 0.075, 0.230),
    "salt": (0.090, 0.060, 0.140),
    "small_cup": (None, 0.080, 0.090),
    "big_cup": (None, 0.100, 0.120),
    "bottle": (0.065, 0.065, 0.200),
}


def test_the_seven_objects_exist():
    assert assets.objects() == sorted(STATED)


def _mesh(name):
    mesh = o3d.io.read_triangle_mesh(str(assets.object_mesh(name)))
    return mesh, np.asarray(mesh.vertices), np.asarray(mesh.triangles)


@pytest.mark.parametrize("name", sorted(STATED))
def test_mesh_is_watertight_with_stated_dimensions(name):
    mesh, v, t = _mesh(name)
    assert len(t) > 100
    assert mesh.is_watertight() and mesh.is_orientable()
    lo, hi = v.min(0), v.max(0)
    # object frame: bottom face at z = 0, centred on the axis
    assert abs(lo[2]) < 1e-9
    for axis, stated in enumerate(STATED[name]):
        if stated is not None:
            assert abs((hi - lo)[axis] - stated) <= DIMENSION_TOL_M, (axis, hi - lo)
    if name.endswith("cup"):  # body centred on z, handle towards +x
        assert abs(lo[0] + STATED[name][1] / 2) <= DIMENSION_TOL_M


def _volume_centroid(v, t):
    # independent of the builder: divergence theorem with the signed tetrahedra of a reference point
    ref = v.mean(0)
    a, b, c = (v[t[:, i]] - ref for i in range(3))
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6
    return vol.sum(), ref + (vol[:, None] * (a + b + c)).sum(0) / (4 * vol.sum())


@pytest.mark.parametrize("name", sorted(STATED))
def test_metadata_consistent_with_mesh(name):
    meta = assets.object_metadata(name)
    _, v, t = _mesh(name)
    volume, com = _volume_centroid(v, t)
    assert volume > 0  # outward normals
    bb = v.max(0) - v.min(0)
    assert volume < np.prod(bb)
    assert np.abs(np.array(meta["center_of_mass_m"]) - com).max() <= COM_TOL_M
    assert abs(meta["max_radius_m"] - np.linalg.norm(v - com, axis=1).max()) <= RADIUS_TOL_M
    assert np.allclose(meta["dimensions_m"], bb, atol=1e-4)
    assert meta["material"] in ("plastic", "glass", "metal", "cardboard")
    assert meta["friction"] == pytest.approx(0.6)  # GraspIt! rubber 1.0 minus 0.4
    assert meta["mass_kg"] > 0 and meta["source"]


def test_symmetric_objects_have_com_on_the_axis():
    for name in ("ham", "jam", "chips", "salt", "bottle"):
        com = np.array(assets.object_metadata(name)["center_of_mass_m"])
        assert np.abs(com[:2]).max() < 1e-6
    # a box's centroid is at half height
    assert assets.object_metadata("salt")["center_of_mass_m"][2] == pytest.approx(0.07, abs=1e-5)


@pytest.mark.parametrize("name", sorted(STATED))
def test_urdf_loads_static_in_pybullet(name):
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(assets.object_urdf(name)), useFixedBase=True, physicsClientId=c)
        lo, hi = pb.getAABB(body, physicsClientId=c)
        bb = np.array(hi) - np.array(lo)
        # pybullet pads AABBs by its collision margin; a few mm
        assert np.abs(bb - np.array(assets.object_metadata(name)["dimensions_m"])).max() < 0.01
    finally:
        pb.disconnect(c)


SOLID_PROBE_RADIUS_M = 0.002
SOLID_MARGIN_M = 0.004  # probe centres this far inside (or outside) the mesh, by Open3D's signed distance


def _mesh_signed_distance(name, points):
    """Signed distance (negative inside) of points to the watertight visual mesh: Open3D's ray casting,
    independent of the collision pieces and of pybullet."""
    mesh, _, _ = _mesh(name)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
    return scene.compute_signed_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


def _sample_around(name, grow_m, n, seed):
    """``n`` uniform points (n, 3) in the object's bounding box grown by ``grow_m``, and their signed
    distances (n,) to the mesh."""
    meta = assets.object_metadata(name)
    lo, hi = (np.array(meta["bounding_box_m"][k]) for k in ("min", "max"))
    lo, hi = lo - grow_m, hi + grow_m
    points = lo + (hi - lo) * np.random.default_rng(seed).random((n, 3))
    return points, _mesh_signed_distance(name, points)


def _probe_distances(name, points):
    """pybullet's distance (n,) from a probe sphere at each point to the object loaded from its URDF
    (inf where nothing is within 5 cm)."""
    c = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(assets.object_urdf(name)), useFixedBase=True, physicsClientId=c)
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=SOLID_PROBE_RADIUS_M, physicsClientId=c)
        probe = pb.createMultiBody(0.0, shape, -1, [1.0, 1.0, 1.0], physicsClientId=c)
        d = []
        for p in points:
            pb.resetBasePositionAndOrientation(probe, p.tolist(), [0, 0, 0, 1], physicsClientId=c)
            cps = pb.getClosestPoints(body, probe, 0.05, physicsClientId=c)
            d.append(min(cp[8] for cp in cps) if cps else np.inf)
        return np.array(d)
    finally:
        pb.disconnect(c)


@pytest.mark.parametrize("name", sorted(STATED))
def test_collision_shape_is_the_solid(name):
    """Points deep inside the mesh collide with the object's collision shape (a concave triangle mesh, a
    surface to Bullet, missed them), points well outside it (a mug's hollow, a bottle's shoulder) do not."""
    # grown by 1 cm: outside probes for the convex objects too
    points, sd = _sample_around(name, 0.01, 20000, seed=0)
    inside, outside = points[sd < -SOLID_MARGIN_M][:40], points[sd > SOLID_MARGIN_M][:40]
    assert len(inside) >= 20 and len(outside) >= 20
    d_in, d_out = _probe_distances(name, inside), _probe_distances(name, outside)
    assert d_in.max() < 0.0, f"{name}: {np.sum(d_in >= 0)} probes inside the solid are free"
    assert d_out.min() > 0.0, f"{name}: {np.sum(d_out <= 0)} probes outside the solid collide"


DISTANCE_TOL_M = 3e-4  # pybullet's distance to the collision shape against the mesh's (chords, float32)


@pytest.mark.parametrize("name", sorted(STATED))
def test_collision_distances_are_the_meshs(name):
    """pybullet's distance from a probe sphere to the object (its convex pieces, inset by pybullet's 1 mm
    convex margin) equals Open3D's distance to the watertight mesh minus the probe radius: the margin is
    compensated and the pieces leave no gap (a gap would read larger, an overlap of the hollow smaller)."""
    points, sd = _sample_around(name, 0.02, 5000, seed=1)
    keep = (sd > 0.003) & (sd < 0.03)
    points, sd = points[keep][:60], sd[keep][:60]
    d = _probe_distances(name, points)
    pieces = sum(1 for line in open(assets.object_collision_mesh(name)) if line.startswith("o "))
    assert pieces == assets.object_metadata(name)["collision_pieces"]
    err = np.abs(d - (sd - SOLID_PROBE_RADIUS_M))
    assert err.max() < DISTANCE_TOL_M, f"{name}: worst distance error {err.max() * 1e3:.2f} mm"
