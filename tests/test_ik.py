"""Per-finger IK of the SAH: FK -> IK -> FK round trips, shortened unreachable targets, limits."""

import numpy as np
import pytest

from assets import sah
from assets.errors import InputError
from retarget import ik

ROUND_TRIP_TOL_M = 1e-4  # the 0.1 mm; the closed form reaches ~1e-12 m
NEAREST_SLACK_M = 1e-4  # IK result vs the best of many random in-limit configurations


def _random_joints(rng, n):
    lo, hi = sah.JOINT_LIMITS[:, 0], sah.JOINT_LIMITS[:, 1]
    return lo + (hi - lo) * rng.random((n, 13))


def _tip(finger, q13):
    return sah.fingertip_positions(q13)[..., sah.FINGERS.index(finger), :]


def _finger_at_rest(finger):
    """(geometry, the rest joints, the finger's joint indices, its knuckle position) of one finger."""
    seed = sah.rest_joints()
    knuckle = sah.fk(seed)[f"{finger}_knuckle"][:3, 3]
    return ik.finger_geometry(finger), seed, list(sah.FINGER_JOINTS[finger]), knuckle


@pytest.mark.parametrize("finger", sah.FINGERS)
def test_round_trip_reachable_points(finger):
    rng = np.random.default_rng(10)
    q = _random_joints(rng, 3000)
    idx = list(sah.FINGER_JOINTS[finger])
    target = _tip(finger, q)
    v = ik.finger_ik(finger, target, q[:, idx])
    q2 = q.copy()
    q2[:, idx] = v
    err = np.linalg.norm(_tip(finger, q2) - target, axis=-1)
    assert err.max() < ROUND_TRIP_TOL_M, err.max()
    assert np.all(v >= sah.JOINT_LIMITS[idx, 0] - 1e-12) and np.all(v <= sah.JOINT_LIMITS[idx, 1] + 1e-12)


@pytest.mark.parametrize("finger", sah.FINGERS)
def test_unreachable_target_is_shortened_to_nearest_reachable(finger):
    rng = np.random.default_rng(11)
    g, seed, idx, knuckle = _finger_at_rest(finger)
    samples = _random_joints(rng, 40000)
    samples[:, idx[0]] = seed[idx[0]] if finger == "thumb" else samples[:, idx[0]]
    cloud = _tip(finger, samples)
    targets = knuckle + rng.normal(size=(6, 3)) * 0.3  # mostly far outside the ~12 cm reach
    targets[0] = knuckle + (_tip(finger, seed) - knuckle) * 3.0  # straight out, far
    v = ik.finger_ik(finger, targets, seed[idx])
    q = np.tile(seed, (len(targets), 1))
    q[:, idx] = v
    got = _tip(finger, q)
    assert np.all(v >= sah.JOINT_LIMITS[idx, 0] - 1e-12) and np.all(v <= sah.JOINT_LIMITS[idx, 1] + 1e-12)
    for t, p in zip(targets, got, strict=True):
        d_target = np.linalg.norm(t - knuckle)
        assert np.linalg.norm(p - knuckle) <= d_target + 1e-12  # nearer than the target
        assert np.linalg.norm(p - knuckle) <= g.reach_m[1] + 1e-9  # on or inside the workspace
        best = np.linalg.norm(cloud - t, axis=-1).min()
        assert np.linalg.norm(p - t) <= best + NEAREST_SLACK_M, (np.linalg.norm(p - t), best)
    # straight out along the finger: on the outer boundary (finger stretched), on the ray
    assert abs(np.linalg.norm(got[0] - knuckle) - g.reach_m[1]) < 1e-6


def test_target_too_close_is_moved_out_to_the_workspace():
    g = ik.finger_geometry("middle")
    knuckle = sah.fk(sah.rest_joints())["middle_knuckle"][:3, 3]
    target = knuckle + np.array([0.02, 0.0, 0.0])  # 2 cm from the knuckle, inside the minimum reach
    v = ik.finger_ik("middle", target)
    q = sah.rest_joints()
    q[list(sah.FINGER_JOINTS["middle"])] = v[0]
    assert np.linalg.norm(_tip("middle", q) - knuckle) >= g.reach_m[0] - 1e-9


def test_thumb_keeps_seed_base_rotation():
    rng = np.random.default_rng(12)
    q = _random_joints(rng, 50)
    idx = list(sah.FINGER_JOINTS["thumb"])
    v = ik.finger_ik("thumb", _tip("thumb", q), q[:, idx])
    np.testing.assert_array_equal(v[:, 0], q[:, 0])
    assert ik.finger_ik("thumb", _tip("thumb", sah.rest_joints()))[0, 0] == sah.rest_joints()[0]


def test_hand_ik_round_trip():
    rng = np.random.default_rng(13)
    worst = 0.0
    for q in _random_joints(rng, 20):
        seed = sah.rest_joints()
        seed[0] = q[0]
        out = ik.hand_ik(sah.fingertip_positions(q), seed)
        worst = max(worst, np.abs(sah.fingertip_positions(out) - sah.fingertip_positions(q)).max())
    assert worst < ROUND_TRIP_TOL_M


def test_bad_input():
    with pytest.raises(InputError, match="unknown SAH finger"):
        ik.finger_ik("pinky", np.zeros(3))
    with pytest.raises(InputError, match="shape"):
        ik.finger_ik("index", np.zeros((2, 2)))
    with pytest.raises(InputError, match="non-finite"):
        ik.finger_ik("index", np.array([np.nan, 0, 0]))
    with pytest.raises(InputError, match="hand_ik"):
        ik.hand_ik(np.zeros((3, 3)), np.zeros(13))


@pytest.mark.parametrize("finger", sah.FINGERS)
def test_nearest_reachable_point_beats_a_bounded_quasi_newton_from_many_starts(finger):
    """A second implementation: scipy's L-BFGS-B in the joint limits from 12 starts per target."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(12)
    g, seed, idx, knuckle = _finger_at_rest(finger)
    targets = knuckle + rng.normal(size=(5, 3)) * 0.08  # near and around the workspace
    v = ik.finger_ik(finger, targets, seed[idx])
    k = len(idx) - 3  # the thumb's base joint stays at the seed's

    def tip(x):
        q = seed.copy()
        q[idx[k:]] = x
        return _tip(finger, q)

    for t, vt in zip(targets, v, strict=True):
        ours = np.linalg.norm(tip(vt[k:]) - t)
        starts = g.limits[:, 0] + (g.limits[:, 1] - g.limits[:, 0]) * rng.random((12, 3))

        def cost(x, t=t):
            return np.sum((tip(x) - t) ** 2)

        ref = min(np.linalg.norm(tip(minimize(cost, s, bounds=g.limits).x) - t) for s in starts)
        assert ours <= ref + 1e-6, (ours, ref)


def test_the_ik_forward_kinematics_equals_the_urdf_forward_kinematics():
    rng = np.random.default_rng(13)
    q = _random_joints(rng, 300)
    ref = sah.fingertip_positions(q)
    got = np.stack([ik.fingertips(qk) for qk in q])
    assert np.abs(got - ref).max() < 1e-12
