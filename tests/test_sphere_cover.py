"""The SAH's sphere cover: it contains every link's collision surface at any joints, bulges no more than
promised, and its Jacobians are the derivatives of its centres."""

import numpy as np
import pytest

import assets
from assets import sah
from assets.errors import InputError
from assets.sphere_cover import (
    DEFAULT_BOX_MAX_BULGE_M,
    DEFAULT_MAX_BULGE_M,
    SphereCover,
    collision_shapes,
    hand_sphere_cover,
    sphere_cover_of,
)


def _surface_points(shape, rng, n=400):
    """Points (n, 3) uniformly spread on a primitive's surface, in its link frame."""
    if shape.type == "box":
        half = np.asarray(shape.size_m) / 2
        p = rng.uniform(-half, half, size=(n, 3))
        axis = rng.integers(0, 3, size=n)
        p[np.arange(n), axis] = half[axis] * rng.choice([-1.0, 1.0], size=n)
    elif shape.type == "sphere":
        u = rng.normal(size=(n, 3))
        p = shape.size_m[0] * u / np.linalg.norm(u, axis=1, keepdims=True)
    else:  # capsule: the side and both caps
        r, length = shape.size_m
        u = rng.normal(size=(n, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        z = rng.uniform(-length / 2, length / 2, size=n)
        side = np.column_stack([r * u[:, :2] / np.linalg.norm(u[:, :2], axis=1, keepdims=True), z])
        cap = r * u + np.column_stack([np.zeros((n, 2)), np.sign(u[:, 2]) * length / 2])
        p = np.where((rng.random(n) < 0.5)[:, None], side, cap)
    T = shape.T_link_shape
    return p @ T[:3, :3].T + T[:3, 3]


def _shape_distance(shape, p_link):
    """Signed distance of link-frame points to the primitive (closed forms)."""
    T = shape.T_link_shape
    p = (p_link - T[:3, 3]) @ T[:3, :3]
    if shape.type == "box":
        q = np.abs(p) - np.asarray(shape.size_m) / 2
        return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(axis=-1), 0)
    if shape.type == "sphere":
        return np.linalg.norm(p, axis=-1) - shape.size_m[0]
    r, length = shape.size_m
    z = np.clip(p[..., 2], -length / 2, length / 2)
    return np.linalg.norm(p - np.stack([0 * z, 0 * z, z], -1), axis=-1) - r


def test_every_link_surface_is_inside_the_spheres_at_random_joints():
    cover = hand_sphere_cover("sah")
    shapes = collision_shapes(assets.hand_urdf("sah"))
    assert {s.link for s in shapes} == set(cover.links)
    rng = np.random.default_rng(0)
    lo, hi = sah.JOINT_LIMITS.T
    for joints in [sah.rest_joints(), lo, hi, *rng.uniform(lo, hi, size=(5, 13))]:
        poses = cover.model.fk(joints)
        centers = cover.centers(joints)
        for shape in shapes:
            T = poses[shape.link]
            p = _surface_points(shape, rng) @ T[:3, :3].T + T[:3, 3]
            own = np.array(cover.links) == shape.link
            d = np.linalg.norm(p[:, None] - centers[None, own], axis=-1) - cover.radii_m[own]
            assert d.min(axis=1).max() <= 1e-12, shape.link


@pytest.mark.parametrize("shape_index", range(len(collision_shapes(assets.hand_urdf("sah")))))
def test_a_cover_leaves_its_shape_by_no_more_than_its_bulge(shape_index):
    shape = collision_shapes(assets.hand_urdf("sah"))[shape_index]
    centers, radii = sphere_cover_of(shape)
    bulge = DEFAULT_BOX_MAX_BULGE_M if shape.type == "box" else DEFAULT_MAX_BULGE_M
    rng = np.random.default_rng(shape_index)
    u = rng.normal(size=(2000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    for c, r in zip(centers, radii, strict=True):
        assert _shape_distance(shape, c + r * u).max() <= bulge + 1e-12


def test_centre_jacobians_are_the_central_differences_of_the_centres():
    cover = hand_sphere_cover("sah")
    rng = np.random.default_rng(1)
    joints = rng.uniform(*sah.JOINT_LIMITS.T)
    c, J = cover.centers_and_jacobians(joints)
    np.testing.assert_allclose(c, cover.centers(joints), atol=1e-15)
    h = 1e-6
    numeric = np.stack(
        [(cover.centers(joints + h * e) - cover.centers(joints - h * e)) / (2 * h) for e in np.eye(13)], -1
    )
    assert np.abs(J - numeric).max() < 1e-8
    # the batch form agrees with one configuration at a time
    batch = rng.uniform(*sah.JOINT_LIMITS.T, size=(4, 13))
    np.testing.assert_allclose(cover.centers(batch)[2], cover.centers(batch[2]), atol=1e-15)


def test_self_pairs_join_phalanges_of_different_fingers_that_are_apart_at_rest():
    cover = hand_sphere_cover("sah")
    pairs = cover.self_pairs(sah.rest_joints())
    links = np.array(cover.links)
    finger = np.array([name.split("_")[0] for name in links])
    a, b = links[pairs[:, 0]], links[pairs[:, 1]]
    assert len(pairs) > 0
    assert not np.isin(np.r_[a, b], ["wrist", "thumb_module"]).any()
    assert np.all(finger[pairs[:, 0]] != finger[pairs[:, 1]])
    # every pair of phalanges on different fingers is there: 4 choose 2 finger pairs, all their spheres
    per_finger = {
        f: int(np.sum((finger == f) & ~np.isin(links, ["wrist", "thumb_module"]))) for f in sah.FINGERS
    }
    expected = sum(
        per_finger[f] * per_finger[g] for i, f in enumerate(sah.FINGERS) for g in sah.FINGERS[i + 1 :]
    )
    assert len(pairs) == expected
    c = cover.centers(sah.rest_joints())
    gaps = np.linalg.norm(c[pairs[:, 0]] - c[pairs[:, 1]], axis=1) - cover.radii_m[pairs].sum(axis=1)
    assert gaps.min() > 0


def test_a_urdf_with_a_mesh_collision_is_refused(tmp_path):
    urdf = tmp_path / "h.urdf"
    urdf.write_text(
        '<robot name="h"><link name="base"><collision><geometry><mesh filename="x.obj"/></geometry>'
        "</collision></link></robot>"
    )
    with pytest.raises(InputError, match="is not a primitive"):
        SphereCover.from_urdf(urdf)


def test_gathered_centres_bounds_and_jacobians_agree_with_the_dense_ones():
    """centers_at / jacobians_at at (batch, sphere) entries equal the dense centres and Jacobians; every
    sphere lies inside its link's bounding sphere."""
    cover = hand_sphere_cover("sah")
    rng = np.random.default_rng(5)
    lo, hi = sah.JOINT_LIMITS.T
    joints = rng.uniform(lo, hi, size=(4, 13))
    c_dense, J_dense = cover.centers_and_jacobians(joints)
    state = cover.state(joints)
    b = rng.integers(0, 4, 500)
    s = rng.integers(0, len(cover), 500)
    c = cover.centers_at(state, b, s)
    np.testing.assert_allclose(c, c_dense[b, s], atol=1e-14)
    np.testing.assert_allclose(cover.jacobians_at(state, b, s, c), J_dense[b, s], atol=1e-14)
    bounds = cover.bounds(state)[:, cover.bound_of]  # (4, n, 3) each sphere's bound
    gap = np.linalg.norm(c_dense - bounds, axis=-1) + cover.radii_m - cover.bound_radii_m[cover.bound_of]
    assert gap.max() < 1e-12
    assert np.all(cover.group_of == cover.bound_group[cover.bound_of])  # a bound holds one link's spheres
