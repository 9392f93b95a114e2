"""Human hand model: joint order, limits and fingertip FK at poses computed by hand."""

import numpy as np
import pybullet as pb

import assets
from assets import human_hand as hh

TOL_M = 1e-9
# GraspIt! HumanHand20DOF segment lengths [m] (proximal, middle, distal)
SEGMENTS = {
    "index": (0.04319, 0.02956, 0.02535),
    "middle": (0.04620, 0.03099, 0.02920),
    "ring": (0.03912, 0.02831, 0.02448),
    "little": (0.02991, 0.02110, 0.02316),
}


def test_joint_names_and_limits():
    assert len(hh.JOINT_NAMES) == 20 and hh.JOINT_NAMES[:4] == (
        "thumb_cmc_abd",
        "thumb_cmc_flex",
        "thumb_mcp",
        "thumb_ip",
    )
    d = np.deg2rad
    abd = {"index": 20, "middle": 10, "ring": 20, "little": 30}
    for f in SEGMENTS:
        i = hh.JOINT_NAMES.index(f"{f}_abd")
        np.testing.assert_allclose(hh.JOINT_LIMITS[i], [-d(abd[f]), d(abd[f])], atol=1e-12)
        for j in ("mcp", "pip", "dip"):
            np.testing.assert_allclose(
                hh.JOINT_LIMITS[hh.JOINT_NAMES.index(f"{f}_{j}")], d([-10, 90]), atol=1e-12
            )
    assert np.all(hh.JOINT_LIMITS[:, 0] < hh.JOINT_LIMITS[:, 1])


def _mcp_centre(f):
    return hh.fk(np.zeros(20))[f"{f}_knuckle"][:3, 3]


def _finger_axis(f):
    return hh.fk(np.zeros(20))[f"{f}_knuckle"][:3, 2]


def test_straight_fingers_tip_at_sum_of_segments():
    tips = hh.fingertip_positions(np.zeros(20))
    assert tips.shape == (5, 3)
    for k, f in enumerate(hh.FINGERS[1:], start=1):
        expected = _mcp_centre(f) + sum(SEGMENTS[f]) * _finger_axis(f)
        assert np.abs(tips[k] - expected).max() < TOL_M
        # straight fingers point up the palm (+z), splayed by a few degrees at most
        assert _finger_axis(f)[2] > np.cos(np.deg2rad(10))
    assert np.abs(hh.fingertip_positions(np.zeros(20))[2, :2] - _mcp_centre("middle")[:2]).max() < TOL_M


def test_mcp_flexion_90_moves_tip_along_plus_x():
    q = np.zeros(20)
    q[hh.JOINT_NAMES.index("index_mcp")] = np.pi / 2
    tip = hh.fingertip_positions(q)[1]
    L1, L2, L3 = SEGMENTS["index"]
    base, axis = _mcp_centre("index"), _finger_axis("index")
    x = np.array([1.0, 0.0, 0.0])  # the index splay is about x, so its flexion direction is +x
    expected = base + (L1 + L2 + L3) * x  # the whole finger turned to point out of the palm
    assert np.abs(tip - expected).max() < TOL_M
    # MCP and PIP at 90 deg: proximal along +x, middle and distal back down the finger axis
    q[hh.JOINT_NAMES.index("index_pip")] = np.pi / 2
    tip = hh.fingertip_positions(q)[1]
    expected = base + L1 * x - (L2 + L3) * axis
    assert np.abs(tip - expected).max() < TOL_M


def test_abduction_turns_towards_thumb_side():
    q = np.zeros(20)
    q[hh.JOINT_NAMES.index("middle_abd")] = np.deg2rad(10)
    tip = hh.fingertip_positions(q)[2]
    L = sum(SEGMENTS["middle"])
    expected = _mcp_centre("middle") + L * np.array([0.0, np.sin(np.deg2rad(10)), np.cos(np.deg2rad(10))])
    assert np.abs(tip - expected).max() < TOL_M


def test_palm_size_and_thumb_opposition():
    rng = np.random.default_rng(0)
    centres = np.array([_mcp_centre(f) for f in SEGMENTS])
    width = centres[:, 1].max() - centres[:, 1].min()
    assert 0.05 < width < 0.075  # knuckle centres of an ~85 mm palm
    assert 0.08 < centres[:, 2].max() < 0.10  # ~95 mm palm length
    lo, hi = hh.JOINT_LIMITS[:, 0], hh.JOINT_LIMITS[:, 1]
    tips = hh.fingertip_positions(lo + (hi - lo) * rng.random((20000, 20)))
    gap = np.linalg.norm(tips[:, 0] - tips[:, 1], axis=-1).min()
    assert gap < 0.005  # the thumb can meet the index fingertip


def test_urdf_loads_in_pybullet():
    cid = pb.connect(pb.DIRECT)
    try:
        rid = pb.loadURDF(str(assets.hand_urdf("human")), physicsClientId=cid)
        names = [
            pb.getJointInfo(rid, i, physicsClientId=cid)[1].decode()
            for i in range(pb.getNumJoints(rid, physicsClientId=cid))
        ]
        assert [n for n in names if not n.endswith("_tip_joint")] == list(hh.JOINT_NAMES)
    finally:
        pb.disconnect(cid)
