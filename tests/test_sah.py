"""SAH model: FK against pybullet, mimic coupling, limits, self-collision, fingertip Jacobian."""

import numpy as np
import pybullet as pb
import pytest
from scipy.spatial.transform import Rotation

import assets
from assets import sah
from assets import se3 as lie

FK_TOL_M = 1e-6
FK_TOL_RAD = 1e-6
JAC_TOL = 1e-6  # [m per unit tangent], central differences with h = 1e-6


@pytest.fixture(scope="module")
def bullet():
    cid = pb.connect(pb.DIRECT)
    rid = pb.loadURDF(str(assets.hand_urdf("sah")), flags=pb.URDF_USE_SELF_COLLISION, physicsClientId=cid)
    index = {}
    for i in range(pb.getNumJoints(rid, physicsClientId=cid)):
        info = pb.getJointInfo(rid, i, physicsClientId=cid)
        index[info[1].decode()] = (i, info[12].decode())
    yield cid, rid, index
    pb.disconnect(cid)


def _set(bullet, joints):
    cid, rid, index = bullet
    for name, value in zip(sah.URDF_JOINT_NAMES, sah.expand_mimic(joints), strict=True):
        pb.resetJointState(rid, index[name][0], float(value), physicsClientId=cid)


def _random_joints(rng, n):
    lo, hi = sah.JOINT_LIMITS[:, 0], sah.JOINT_LIMITS[:, 1]
    return lo + (hi - lo) * rng.random((n, 13))


def test_joint_order_and_limits_from_urdf():
    m = sah.model()
    assert m.joint_names == sah.JOINT_NAMES
    assert sah.FINGER_JOINTS["thumb"] == (0, 1, 2, 3) and sah.FINGER_JOINTS["ring"] == (10, 11, 12)
    d = np.deg2rad
    expect = {"abd": (-15, 15), "prox": (-4, 75), "mid": (4, 75)}
    for i, n in enumerate(sah.JOINT_NAMES):
        lo, hi = (0, 90) if n == "thumb_base" else expect[n.split("_")[1]]
        np.testing.assert_allclose(sah.JOINT_LIMITS[i], [d(lo), d(hi)], atol=1e-6)
    distal = {j.name: j for j in m.joints if j.name.endswith("_dist")}
    assert sorted(distal) == sorted(f"{f}_dist" for f in sah.FINGERS)
    for f in sah.FINGERS:
        assert distal[f"{f}_dist"].mimic == f"{f}_mid" and distal[f"{f}_dist"].multiplier == 1.0
    np.testing.assert_array_equal(sah.clip_joints(np.full(13, 10.0)), sah.JOINT_LIMITS[:, 1])


def test_mimic_coupling_moves_distal_with_mid():
    q = sah.rest_joints()
    full = sah.expand_mimic(q)
    for f in sah.FINGERS:
        assert full[sah.URDF_JOINT_NAMES.index(f"{f}_dist")] == q[sah.JOINT_NAMES.index(f"{f}_mid")]
    poses = sah.fk(q)
    q2 = q.copy()
    q2[sah.JOINT_NAMES.index("index_mid")] += 0.3
    poses2 = sah.fk(q2)
    # the distal phalanx turns by 2 x 0.3 rad relative to the proximal one
    R_rel = poses["index_proximal"][:3, :3].T @ poses["index_distal"][:3, :3]
    R_rel2 = poses2["index_proximal"][:3, :3].T @ poses2["index_distal"][:3, :3]
    angle = np.linalg.norm(lie.so3_log(R_rel.T @ R_rel2))
    assert abs(angle - 0.6) < 1e-9


def test_fk_matches_pybullet(bullet):
    cid, rid, index = bullet
    rng = np.random.default_rng(0)
    # pybullet places the base's inertial frame; the wrist frame is that pose times inertial^-1
    T_world_com = lie.make_pose(lie.so3_exp(rng.normal(size=3)), rng.normal(size=3))
    pb.resetBasePositionAndOrientation(
        rid, T_world_com[:3, 3], Rotation.from_matrix(T_world_com[:3, :3]).as_quat(), physicsClientId=cid
    )
    dyn = pb.getDynamicsInfo(rid, -1, physicsClientId=cid)
    T_wrist_com = lie.make_pose(Rotation.from_quat(dyn[4]).as_matrix(), np.array(dyn[3]))
    T_world_base = T_world_com @ lie.se3_inverse(T_wrist_com)
    joints = _random_joints(rng, 20)
    poses = sah.fk(joints)
    err_m, err_rad = 0.0, 0.0
    for k, q in enumerate(joints):
        _set(bullet, q)
        for i, child in index.values():
            st = pb.getLinkState(rid, i, computeForwardKinematics=True, physicsClientId=cid)
            R = np.array(pb.getMatrixFromQuaternion(st[5])).reshape(3, 3)
            T_world_link = lie.make_pose(R, np.array(st[4]))
            T_base_link = lie.se3_inverse(T_world_base) @ T_world_link
            ours = poses[child][k]
            err_m = max(err_m, np.abs(ours[:3, 3] - T_base_link[:3, 3]).max())
            err_rad = max(err_rad, np.linalg.norm(lie.so3_log(ours[:3, :3].T @ T_base_link[:3, :3])))
    assert err_m < FK_TOL_M, err_m
    assert err_rad < FK_TOL_RAD, err_rad
    pb.resetBasePositionAndOrientation(rid, [0, 0, 0], [0, 0, 0, 1], physicsClientId=cid)


def _self_contacts(bullet, joints):
    cid, rid, index = bullet
    _set(bullet, joints)
    pb.performCollisionDetection(physicsClientId=cid)
    names = {i: child for i, child in index.values()} | {-1: "wrist"}
    excluded = {frozenset(p) for p in sah.SELF_COLLISION_EXCLUDED_PAIRS}
    pairs = set()
    for c in pb.getContactPoints(rid, rid, physicsClientId=cid):
        pair = frozenset((names[c[3]], names[c[4]]))
        if c[8] < 0 and pair not in excluded:
            pairs.add(tuple(sorted(pair)))
    return pairs


def test_rest_pose_is_self_collision_free(bullet):
    assert _self_contacts(bullet, sah.rest_joints()) == set()
    q = np.zeros(13)
    q[[3, 6, 9, 12]] = sah.JOINT_LIMITS[[3, 6, 9, 12], 0]
    assert _self_contacts(bullet, q) == set()  # flat hand, thumb in the palm plane


def test_fingers_pushed_together_collide(bullet):
    q = sah.rest_joints()
    q[sah.JOINT_NAMES.index("index_abd")] = sah.JOINT_LIMITS[4, 0]  # towards the middle finger (-y)
    q[sah.JOINT_NAMES.index("middle_abd")] = sah.JOINT_LIMITS[7, 1]  # towards the index (+y)
    pairs = _self_contacts(bullet, q)
    assert any("index" in a and "middle" in b for a, b in pairs), pairs


def test_fingertip_positions_in_frame():
    rng = np.random.default_rng(1)
    joints = _random_joints(rng, 5)
    T = lie.make_pose(lie.so3_exp(rng.normal(size=(5, 3))), rng.normal(size=(5, 3)))
    p_obj = sah.fingertip_positions_in(T, joints)
    p_wrist = sah.fingertip_positions(joints)
    ref = np.einsum("nij,nkj->nki", T[:, :3, :3], p_wrist) + T[:, None, :3, 3]
    assert np.abs(p_obj - ref).max() < 1e-12


def test_fingertip_jacobian_matches_central_differences():
    rng = np.random.default_rng(2)
    joints = _random_joints(rng, 4)
    T = lie.make_pose(lie.so3_exp(rng.normal(size=(4, 3))), rng.normal(size=(4, 3)))
    J = sah.fingertip_jacobian(T, joints)
    assert J.shape == (4, 12, 19)
    h = 1e-6
    num = np.zeros_like(J)
    for k in range(19):
        d = np.zeros(19)
        d[k] = h
        Tp, Tm = lie.retract(T, d[:6]), lie.retract(T, -d[:6])
        fp = sah.fingertip_positions_in(Tp, joints + d[6:]).reshape(4, 12)
        fm = sah.fingertip_positions_in(Tm, joints - d[6:]).reshape(4, 12)
        num[..., k] = (fp - fm) / (2 * h)
    assert np.abs(J - num).max() < JAC_TOL


def test_config_cov_is_pseudo_inverse_mapping():
    rng = np.random.default_rng(3)
    q = sah.rest_joints()
    T = lie.make_pose(lie.so3_exp(rng.normal(size=3)), rng.normal(size=3))
    J = sah.fingertip_jacobian(T, q)
    cov_tips = (0.008**2) * np.eye(12)
    cov = sah.config_cov_from_fingertip_cov(J, cov_tips)
    assert cov.shape == (19, 19)
    np.testing.assert_allclose(cov, cov.T, atol=1e-15)
    eig = np.linalg.eigvalsh(cov)
    assert eig.min() > -1e-12 * eig.max()
    assert np.linalg.matrix_rank(cov, tol=1e-9 * eig.max()) <= 12  # degenerate by design
    # mapped back through J it recovers the fingertip covariance (J has full row rank here)
    np.testing.assert_allclose(J @ cov @ J.T, cov_tips, atol=1e-9 * 0.008**2 * 1e3)


def test_finger_joint_cov_holds_the_wrist_and_maps_back_to_the_fingertip_covariance():
    rng = np.random.default_rng(4)
    q = sah.rest_joints()
    flex = np.array([n.endswith(("_prox", "_mid")) for n in sah.JOINT_NAMES])
    q[flex] += 0.4  # flexed fingers: each finger's joints reach every direction of its fingertip
    T = lie.make_pose(lie.so3_exp(rng.normal(size=3)), rng.normal(size=3))
    J = sah.fingertip_jacobian(T, q)
    A = rng.normal(size=(12, 12)) * 0.005
    cov_tips = A @ A.T
    cov = sah.config_cov_from_fingertip_cov(J, cov_tips, through="finger_joints")
    assert not cov[:6].any() and not cov[:, :6].any()  # the wrist is held
    np.testing.assert_allclose(J @ cov @ J.T, cov_tips, atol=1e-9 * np.abs(cov_tips).max())
    # the closed form of the minimum-norm joint change: Jq^T (Jq Jq^T)^-1, the joint columns alone
    Jq = J[:, 6:]
    P = Jq.T @ np.linalg.inv(Jq @ Jq.T)
    np.testing.assert_allclose(cov[6:, 6:], P @ cov_tips @ P.T, atol=1e-9 * np.abs(cov[6:, 6:]).max())
    with pytest.raises(assets.InputError, match="through: expected one of configuration, finger_joints"):
        sah.config_cov_from_fingertip_cov(J, cov_tips, through="wrist")


@pytest.mark.parametrize("thumb_base_deg", [0.0, 45.0, 90.0])
def test_thumb_knuckle_frame_matches_cisst(thumb_base_deg):
    """The thumb's knuckle frame against cisst's ``robSAHThumb`` (``Rb1`` turned by the base rotation).

    cisst's thumb frame at thumb_base = 0 has the thumb along (0, 0.57358, 0.81915) and its flexion closing
    towards (0, -0.81915, 0.57358): in the palm plane, towards the index. The base turns it about -z, so
    at 90 deg the thumb closes towards (-0.81915, 0, 0.57358), back towards the palm (opposition).
    """
    j = sah.rest_joints()
    j[sah.JOINT_NAMES.index("thumb_base")] = np.deg2rad(thumb_base_deg)
    j[sah.JOINT_NAMES.index("thumb_abd")] = 0.0
    R = sah.fk(j)["thumb_knuckle"][:3, :3]
    turn = Rotation.from_rotvec([0.0, 0.0, -np.deg2rad(thumb_base_deg)]).as_matrix()
    along = turn @ [0.0, 0.57358, 0.81915]
    closing = turn @ [0.0, -0.81915, 0.57358]
    tol = 0.005  # the URDF tilts the thumb 35.2 deg (libmove3d), cisst 35.0 deg
    assert np.abs(R[:, 2] - along).max() < tol  # the thumb's axis
    assert np.abs(R[:, 0] - closing).max() < tol  # a positive thumb_prox (about +y) closes towards +x
