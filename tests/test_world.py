"""The pybullet world: hand placement, collisions with the table/object/obstacles/itself, distances,
pictures, Q.json files and the two CLI subcommands."""

import json
import subprocess
import sys

import numpy as np
import pybullet as pb
import pytest

from assets import sah
from assets.errors import InputError
from assets.se3 import pose_from_q, retract
from planning.qfile import load_q, q_from_dict, save_q
from planning.world import World

FK_TOL_M = 1e-6  # pybullet's link frames vs assets.sah FK
AABB_MARGIN_M = 0.006  # pybullet pads link AABBs by its collision margin (~5 mm measured)
SHIFT_TOL_M = 1e-4  # the table is a plane: lowering the hand by dz lowers the distance by dz


def q_down(xyz, joints=None):
    """The SAH pointing down (wrist z towards -z world) with its wrist at xyz."""
    q = np.zeros(19)
    q[:3] = xyz
    q[3:6] = [np.pi, 0, 0]
    q[6:] = sah.rest_joints() if joints is None else joints
    return q


@pytest.fixture(scope="module")
def ham_arc():
    with World("ham_arc") as w:
        yield w


def test_set_q_places_links_as_the_kinematics_says(ham_arc):
    w = ham_arc
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(5):
        q = np.concatenate([rng.uniform(-0.3, 0.3, 3), rng.normal(size=3), rng.uniform(*sah.JOINT_LIMITS.T)])
        w.set_q(q)
        T_world_link = pose_from_q(q) @ np.stack([sah.fk(q[6:])[t] for t in sah.TIP_LINKS])
        for k, tip in enumerate(sah.TIP_LINKS):
            state = pb.getLinkState(
                w.hand_id, w.link_index(tip), computeForwardKinematics=True, physicsClientId=w.client
            )
            worst = max(worst, np.abs(np.array(state[4]) - T_world_link[k, :3, 3]).max())
        # the distal joints copy the middle ones
        for f in sah.FINGERS:
            dist = pb.getJointState(
                w.hand_id,
                w.link_index(f"{f}_distal")
                if f"{f}_distal" in w.link_names
                else _joint_index(w, f"{f}_dist"),
                physicsClientId=w.client,
            )[0]
            assert dist == pytest.approx(q[6 + sah.JOINT_NAMES.index(f"{f}_mid")], abs=1e-12)
    assert worst < FK_TOL_M


def _joint_index(w, name):
    for i in range(pb.getNumJoints(w.hand_id, physicsClientId=w.client)):
        if pb.getJointInfo(w.hand_id, i, physicsClientId=w.client)[1].decode() == name:
            return i
    raise KeyError(name)


def test_far_away_is_free_and_through_the_object_is_not(ham_arc):
    w = ham_arc
    far = q_down([0.0, 0.0, 0.8])
    assert w.is_free(far)
    assert w.hand_contacts(far) == []
    through = q_down([0.0, 0.0, 0.12])  # fingers reach ~0.2 m below the wrist: into the can
    assert not w.is_free(through)
    others = {c.other for c in w.hand_contacts(through)}
    assert "ham" in others
    assert all(c.distance_m <= 0 for c in w.hand_contacts(through))


def test_table_contact(ham_arc):
    w = ham_arc
    q = q_down([0.3, 0.2, 0.3])  # beside the obstacles, within 5 cm of the table
    d = w.signed_distance(q)
    assert 0 < d < 0.05
    q[2] -= d + 0.004  # the lowest point 4 mm below the table top
    contacts = w.hand_contacts(q)
    assert not w.is_free(q)
    assert {c.other for c in contacts} == {"table"}
    assert len(contacts) >= 1 and min(c.distance_m for c in contacts) == pytest.approx(
        -0.004, abs=SHIFT_TOL_M
    )
    for c in contacts:  # the reported points are on the hand, at or below the table top
        assert c.point_world[2] < 1e-3 and c.normal_world[2] > 0.99


def test_penetration_depth_sums_the_deepest_point_of_each_pair(ham_arc):
    w = ham_arc
    q = q_down([0.3, 0.2, 0.3])
    d = w.signed_distance(q)
    assert w.penetration_m(q) == 0.0
    q[2] -= d + 0.004
    depth = w.penetration_m(q)
    # the hand's contacts, independently: the deepest point of each (link, body) pair
    deepest = {}
    for c in w.hand_contacts(q):
        deepest[(c.link, c.other)] = max(deepest.get((c.link, c.other), 0.0), -c.distance_m)
    assert depth == pytest.approx(sum(deepest.values()), abs=1e-9)
    assert depth >= 0.004 - SHIFT_TOL_M
    # 2 mm lower, every pair already in goes 2 mm deeper
    q2 = q.copy()
    q2[2] -= 0.002
    assert w.penetration_m(q2) >= depth + len(deepest) * (0.002 - SHIFT_TOL_M)


def test_obstacle_contact(ham_arc):
    w = ham_arc
    (wall,) = [o for o in w.scene.obstacles if o.label == "wall_left"]
    q = q_down([0.0, wall.position_m[1], 0.3])  # above the left wall, fingers into it
    q[2] = 0.16 + 0.18
    assert not w.is_free(q)
    assert "wall_left" in {c.other for c in w.hand_contacts(q)}


def test_rest_pose_free_of_self_collision_and_converging_fingers_collide(ham_arc):
    w = ham_arc
    assert w.is_free(q_down([0.0, 0.0, 1.0]))
    # index and middle abducted 15 deg towards each other: the fingers cross, far from everything else
    j = sah.rest_joints()
    j[sah.JOINT_NAMES.index("index_abd")] = np.deg2rad(-15)
    j[sah.JOINT_NAMES.index("middle_abd")] = np.deg2rad(15)
    q = q_down([0.0, 0.0, 1.0], j)
    assert not w.is_free(q)
    pairs = {(c.link.split("_")[0], c.other) for c in w.hand_contacts(q)}
    assert pairs and all(other.startswith("self:") for _, other in pairs)
    assert ("index", "self:middle_middle") in pairs or ("index", "self:middle_distal") in pairs


def test_signed_distance_sign_and_value(ham_arc):
    w = ham_arc
    assert w.signed_distance(q_down([0.3, 0.2, 1.0])) == pytest.approx(0.05)
    # clearance of the lowest point of the hand (pointing down) above the table
    q = q_down([0.3, 0.2, 1.0])
    w.set_q(q)
    links = (w.base_name, *w.link_names)
    low = min(pb.getAABB(w.hand_id, w.link_index(n), physicsClientId=w.client)[0][2] for n in links)
    q[2] -= low - 0.02
    d0 = w.signed_distance(q)
    assert 0 < d0 and abs(d0 - 0.02) < AABB_MARGIN_M
    for dz in (0.005, 0.015, 0.03):
        q1 = q.copy()
        q1[2] -= dz
        assert abs(w.signed_distance(q1) - (d0 - dz)) < SHIFT_TOL_M
    assert w.signed_distance(q) > 0 and w.is_free(q)
    # the object counts only when asked
    through = q_down([0.0, 0.0, 0.12])
    assert w.signed_distance(through, include_object=True) < 0


def test_link_distances_to_given_bodies_split_the_scene(ham_arc):
    """Per link, the distance to the whole scene is the smaller of the distances to the object alone and to
    the table and obstacles (the default)."""
    w = ham_arc
    through = q_down([0.0, 0.0, 0.12])
    env = w.link_signed_distances(through)
    obj = w.link_signed_distances(through, bodies=(w.object_id,))
    both = w.link_signed_distances(through, include_object=True)
    np.testing.assert_allclose(both, np.minimum(env, obj), atol=1e-9)
    assert obj.min() < 0 and not np.allclose(env, both)  # the object is the nearest body of some link


def test_link_distance_gradients_match_central_differences(ham_arc):
    """The analytic gradient (contact normal through the hand's kinematics) against central differences
    of the distances themselves (step 0.01 mm, in the same tangent), near the ham and the table, for the
    table and obstacles and for the object alone; links with nothing in range have zero rows."""
    from assets.se3 import q_from_pose

    w = ham_arc
    rng = np.random.default_rng(0)
    checked = 0
    for z in (0.16, 0.14, 0.13):
        q = q_down([0.0, 0.01, z])
        q[3:6] += rng.normal(0.0, 0.1, 3)
        q[6:] += rng.normal(0.0, 0.1, 13)
        for bodies in (None, (w.object_id,)):
            phi, grad = w.link_signed_distance_gradients(q, 0.05, bodies=bodies)
            np.testing.assert_array_equal(phi, w.link_signed_distances(q, 0.05, bodies=bodies))

            T0, h = pose_from_q(q), 1e-5
            numeric = np.empty((len(phi), 19))
            for k in range(19):  # central differences in the tangent [omega, v] of T0 @ Exp(xi), then joints
                ends = []
                for sign in (1.0, -1.0):
                    xi = np.zeros(19)
                    xi[k] = sign * h
                    T = retract(T0, xi[:6])
                    q_k = np.r_[q_from_pose(T), q[6:] + xi[6:]]
                    ends.append(w.link_signed_distances(q_k, 0.05, bodies=bodies))
                numeric[:, k] = (ends[0] - ends[1]) / (2 * h)
            near = phi < 0.05
            assert grad.shape == (len(phi), 19) and near.sum() >= 6
            np.testing.assert_allclose(np.linalg.norm(grad[near, 3:6], axis=1), 1.0, atol=1e-6)  # unit normal
            # pybullet's closest points sit up to ~1 mm off the exact ones: 2e-3 m/rad on the rotations
            assert np.abs(grad[near] - numeric[near]).max() < 3e-3
            assert not grad[~near].any()
            checked += near.sum()
    assert checked >= 30


def test_set_q_validates(ham_arc):
    with pytest.raises(InputError, match=r"q: expected shape \(19,\)"):
        ham_arc.set_q(np.zeros(18))
    for bad in (np.nan, np.inf, -np.inf):
        q = np.zeros(19)
        q[7] = bad
        with pytest.raises(InputError, match="non-finite"):
            ham_arc.set_q(q)


def test_the_floating_joints_put_the_wrist_at_its_pose(ham_arc):
    """The wrist's link frame against pose_from_q, rotations up to pi (the hand hangs on floating joints)."""
    w, rng = ham_arc, np.random.default_rng(3)
    axes = rng.normal(size=(20, 3))
    angles = np.r_[rng.uniform(0, np.pi, 17), 0.0, 1e-9, np.pi - 1e-9]
    for axis, angle in zip(axes, angles, strict=True):
        q = np.r_[rng.uniform(-0.5, 0.5, 3), angle * axis / np.linalg.norm(axis), sah.rest_joints()]
        w.set_q(q)
        state = pb.getLinkState(w.hand_id, w.link_index(w.base_name), physicsClientId=w.client)
        T = pose_from_q(q)
        assert np.abs(np.array(state[4]) - T[:3, 3]).max() < FK_TOL_M
        R = np.array(pb.getMatrixFromQuaternion(state[5])).reshape(3, 3)
        assert np.abs(R - T[:3, :3]).max() < FK_TOL_M
    assert w.link_name(w.link_index("index_distal")) == "index_distal"
    with pytest.raises(ValueError, match="floating"):
        w.link_name(w.link_index(w.base_name) - 1)


def test_floating_urdf_needs_one_root(tmp_path):
    from planning.hand_urdf import floating_urdf

    path = tmp_path / "two_roots.urdf"
    path.write_text('<robot name="r"><link name="a"/><link name="b"/></robot>')
    with pytest.raises(InputError, match="one root link"):
        floating_urdf(path)


def test_render_returns_an_image_showing_the_scene(ham_arc):
    img = ham_arc.render(q_down([0.0, 0.0, 0.45]), width=160, height=120)
    assert img.shape == (120, 160, 3) and img.dtype == np.uint8
    assert img.std() > 10  # not a blank picture
    top = ham_arc.render(width=160, height=120, camera="top")
    assert top.shape == (120, 160, 3)


@pytest.mark.parametrize("scene", ["jam_hole", "chips_between_cans", "chips_flat"])
def test_obstacle_scenes_build_and_far_hand_is_free(scene):
    with World(scene) as w:
        assert w.is_free(q_down([0.0, 0.0, 1.0]))
        assert len(w.obstacle_ids) == {"jam_hole": 1, "chips_between_cans": 2, "chips_flat": 0}[scene]
        # the hand pushed down through the target's position hits something
        assert not w.is_free(q_down([0.0, 0.0, 0.15]))


def test_jam_hole_block_is_solid_around_the_hole():
    with World("jam_hole") as w:
        # a finger-sized probe: the hand lowered at 10 cm from the jar's axis hits the block
        hits = {c.other for c in w.hand_contacts(q_down([0.0, 0.1, 0.19]))}
        assert "block_with_hole" in hits


def test_qfile_round_trip_and_errors(tmp_path):
    q = q_down([0.1, -0.2, 0.3])
    for named in (False, True):
        p = save_q(tmp_path / f"q{named}.json", q, named=named)
        assert np.abs(load_q(p) - q).max() < 1e-12
    d = {"wrist_position_m": [0, 0, 0.3], "wrist_rotvec_rad": [0, 0, 0], "joints_deg": {"index_prox": 30}}
    q2 = q_from_dict(d)
    expected = sah.rest_joints()
    expected[sah.JOINT_NAMES.index("index_prox")] = np.deg2rad(30)
    assert np.allclose(q2[6:], expected)
    with pytest.raises(InputError, match="joints_deg.pinky_prox: unknown joint; valid: thumb_base"):
        q_from_dict({**d, "joints_deg": {"pinky_prox": 3}})
    with pytest.raises(InputError, match=r"q: expected a list of 19 numbers"):
        q_from_dict({"q": [0] * 18})
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(InputError, match="bad.json: not valid JSON"):
        load_q(bad)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "pbdgrasp.cli", *args], capture_output=True, text=True)


def test_cli_render_writes_a_png(tmp_path):
    out = tmp_path / "ham.png"
    res = run_cli(
        "render", "--scene", "ham", "--view", "both", "--width", "160", "--height", "120", "-o", str(out)
    )
    assert res.returncode == 0, res.stderr
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert "hand free" in res.stdout
    qf = tmp_path / "q.json"
    qf.write_text(json.dumps({"q": [0.0] * 18}))
    res = run_cli("render", "--scene", "ham", "--q", str(qf), "-o", str(tmp_path / "x.png"))
    assert res.returncode == 2
    lines = [ln for ln in res.stderr.splitlines() if not ln.startswith("pybullet build time")]
    assert len(lines) == 1 and lines[0].startswith("error: ") and "19 numbers" in lines[0]


def test_cli_assets_lists_everything():
    res = run_cli("assets")
    assert res.returncode == 0, res.stderr
    assert "objects (7):" in res.stdout and "scenes (11):" in res.stdout
    assert "sah" in res.stdout and " 13 joints" in res.stdout
    for name in ("ham_arc", "chips_between_cans", "chips_flat", "jam_hole", "big_cup", "bottle"):
        assert name in res.stdout


def test_human_hand_world_with_excluded_pairs():
    # the human URDF's wrist overlaps its little-finger and thumb bases by construction: the default
    # exclusions come from assets.human_hand.SELF_COLLISION_EXCLUDED_PAIRS
    with World("ham", hand="human") as w:
        assert w.dof == 26
        q = np.concatenate([[0, 0, 0.6, 0, 0, 0], w.rest_q()[6:]])
        assert w.is_free(q)
        q[2] = 0.05
        assert not w.is_free(q)
        assert w.render(q, 64, 48).shape == (48, 64, 3)
    with pytest.raises(InputError, match="unknown link"):
        World("ham", hand="human", self_collision_excluded=(("wrist", "pinky"),))
