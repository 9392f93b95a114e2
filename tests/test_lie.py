"""The vectorized SE(3) helpers agree with GTSAM's Pose3 (the library is the oracle)."""

import gtsam
import numpy as np
import pytest

from assets import se3 as lie

ATOL = 1e-10


@pytest.mark.parametrize("scale", [1e-9, 1e-5, 0.3, 2.0, 3.1])
def test_se3_exp_matches_gtsam_expmap(scale):
    rng = np.random.default_rng(0)
    xi = rng.normal(size=(20, 6))
    xi[:, :3] *= scale / np.linalg.norm(xi[:, :3], axis=1, keepdims=True)
    T = lie.se3_exp(xi)
    for k in range(len(xi)):
        np.testing.assert_allclose(T[k], gtsam.Pose3.Expmap(xi[k]).matrix(), atol=ATOL)
        np.testing.assert_allclose(T[k], gtsam.Pose3().retract(xi[k]).matrix(), atol=ATOL)


def test_se3_log_inverts_exp_and_matches_gtsam_logmap():
    rng = np.random.default_rng(1)
    xi = rng.normal(size=(50, 6)) * 0.8
    T = lie.se3_exp(xi)
    np.testing.assert_allclose(lie.se3_log(T), xi, atol=1e-9)
    for k in range(5):
        np.testing.assert_allclose(lie.se3_log(T[k]), gtsam.Pose3.Logmap(gtsam.Pose3(T[k])), atol=1e-9)


def test_local_and_retract_match_gtsam():
    rng = np.random.default_rng(2)
    A = lie.se3_exp(rng.normal(size=6))
    B = lie.se3_exp(rng.normal(size=6))
    xi = lie.local(A, B)
    np.testing.assert_allclose(xi, gtsam.Pose3(A).localCoordinates(gtsam.Pose3(B)), atol=1e-9)
    np.testing.assert_allclose(lie.retract(A, xi), B, atol=1e-9)


def test_pose_q_round_trip():
    rng = np.random.default_rng(3)
    q = np.concatenate([rng.normal(size=(10, 3)), rng.normal(size=(10, 3)) * 0.5], axis=1)
    np.testing.assert_allclose(lie.q_from_pose(lie.pose_from_q(q)), q, atol=1e-12)
    np.testing.assert_allclose(
        lie.se3_inverse(lie.pose_from_q(q)) @ lie.pose_from_q(q),
        np.broadcast_to(np.eye(4), (10, 4, 4)),
        atol=1e-12,
    )


def test_quaternion_helpers_and_slerp_match_scipy():
    from scipy.spatial.transform import Rotation, Slerp

    rng = np.random.default_rng(4)
    r = rng.normal(size=(50, 3))
    r[0] = 0.0
    r[1] = [np.pi - 1e-9, 0, 0]
    quat = lie.quat_from_rotvec(r)
    ref = Rotation.from_rotvec(r).as_quat()
    ref *= np.sign(ref[:, 3:] + 1e-300) * np.sign(quat[:, 3:] + 1e-300)
    np.testing.assert_allclose(quat, ref, atol=1e-12)
    r_small = np.vstack([r, [3e-7, -1e-7, 2e-7]])  # and the Taylor branch of the scalar version
    scalar = np.array([lie.quat_of_rotvec(*v) for v in r_small])
    np.testing.assert_allclose(scalar, lie.quat_from_rotvec(r_small), rtol=0, atol=1e-15)
    np.testing.assert_allclose(lie.so3_exp(lie.rotvec_from_quat(quat)), lie.so3_exp(r), atol=1e-9)
    s = np.linspace(0, 1, 7)
    for a, b in zip(r[2:10], r[10:18], strict=True):
        expected = Slerp([0, 1], Rotation.from_rotvec([a, b]))(s).as_matrix()
        np.testing.assert_allclose(lie.so3_exp(lie.slerp_rotvec(a, b, s)), expected, atol=1e-9)


@pytest.mark.parametrize("angle", [0.0, 1e-12, 1e-6, 0.7, np.pi - 1e-7, np.pi])
def test_so3_log_matches_gtsam_near_identity_and_pi_one_matrix_and_batches(angle):
    rng = np.random.default_rng(5)
    axes = rng.normal(size=(30, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    R = lie.so3_exp(axes * angle)
    batch = lie.so3_log(R)
    for k in range(len(R)):
        one = lie.so3_log(R[k])
        np.testing.assert_allclose(one, batch[k], atol=1e-15)
        ref = gtsam.Rot3.Logmap(gtsam.Rot3(R[k]))
        if angle > np.pi - 1e-6:  # at pi, w and -w are the same rotation: compare the rotations
            np.testing.assert_allclose(lie.so3_exp(one), R[k], atol=1e-12)
        else:
            np.testing.assert_allclose(one, ref, atol=1e-12)


def test_so3_exp_of_one_vector_is_scipys_bit_for_bit():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(6)
    r = rng.normal(size=(2000, 3)) * rng.choice([0.0, 1e-9, 1e-4, 1e-3, 0.5, 3.0], size=(2000, 1))
    ref = Rotation.from_rotvec(r).as_matrix()
    np.testing.assert_array_equal(np.array([lie.so3_exp(v) for v in r]), ref)
