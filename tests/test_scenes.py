"""Scenes: every shipped scene loads; bad scenes raise InputError naming the file and the field."""

import math

import numpy as np
import pytest
import yaml

import assets
from assets.errors import InputError
from planning.scene import load_scene

SCENES = [
    "big_cup",
    "bottle",
    "chips",
    "chips_between_cans",
    "chips_flat",
    "ham",
    "ham_arc",
    "jam",
    "jam_hole",
    "salt",
    "small_cup",
]
STRATEGY = {
    "bottle": "chips",
    "big_cup": "small_cup",
    "ham_arc": "ham",
    "chips_between_cans": "chips",
    "chips_flat": "chips",
    "jam_hole": "jam",
}


def test_eleven_scenes_ship():
    assert assets.scenes() == SCENES


@pytest.mark.parametrize("name", SCENES)
def test_scene_loads(name):
    s = load_scene(name)
    assert s.name == name and s.hand == "sah" and s.description
    assert s.strategy == STRATEGY.get(name, name)
    T = s.T_world_object
    assert np.allclose(T[:3, :3].T @ T[:3, :3], np.eye(3), atol=1e-12)
    # the object stands on (or lies on) the table: its lowest point is at z = 0
    meta = assets.object_metadata(s.object.name)
    bb = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    corners = np.array(meta["bounding_box_m"]["min"]) + bb * (
        np.array(meta["bounding_box_m"]["max"]) - meta["bounding_box_m"]["min"]
    )
    p_world = (T[:3, :3] @ corners.T).T + T[:3, 3]
    assert abs(p_world[:, 2].min()) < 1e-9
    # the wrist bounds surround the object
    lo, hi = s.bounds_array
    assert np.all(lo <= p_world.min(0)) and np.all(p_world.max(0) < hi)


def test_cov_object_is_gtsam_order_rotation_first():
    s = load_scene("ham")
    cov = s.cov_object
    assert cov.shape == (6, 6)
    # the paper's Sigma_o = 3^2 I mm^2 on the position of the centre, 2 deg std on rotation
    assert np.allclose(np.diag(cov)[:3], math.radians(2.0) ** 2, rtol=1e-12)
    assert np.all(np.diag(cov)[3:] >= (3e-3) ** 2 * (1 - 1e-12))
    np.testing.assert_array_equal(cov, cov.T)
    assert np.all(np.linalg.eigvalsh(cov) > 0)


@pytest.mark.parametrize("name", ["chips", "bottle", "small_cup", "chips_flat"])
def test_cov_object_is_the_localization_of_the_centre_of_mass(name):
    """GTSAM's adjoint of the translation to the centre of mass (a second implementation) carries
    diag(rot^2 I, pos^2 I) to the object frame; sampled with GTSAM's Expmap, the centre of mass moves by
    3 mm per coordinate whatever the rotation, the object frame's origin by more."""
    import gtsam

    s = load_scene(name)
    c = np.asarray(assets.object_metadata(s.object.name)["center_of_mass_m"])
    rot, pos = math.radians(s.object.rotation_std_deg), s.object.position_std_mm * 1e-3
    Ad = gtsam.Pose3(gtsam.Rot3(), c).AdjointMap()
    np.testing.assert_allclose(
        s.cov_object, Ad @ np.diag([rot**2] * 3 + [pos**2] * 3) @ Ad.T, rtol=1e-12, atol=1e-18
    )
    xi = np.random.default_rng(3).multivariate_normal(np.zeros(6), s.cov_object, size=20000)
    moved = np.array([gtsam.Pose3.Expmap(x).transformFrom(c) for x in xi]) - c  # in the object frame
    np.testing.assert_allclose(moved.std(axis=0), pos, rtol=0.03)  # rotation adds only O(rot^2 |c|)
    origin = np.array([gtsam.Pose3.Expmap(x).translation() for x in xi])
    assert origin.std(axis=0)[:2].min() > pos * 1.05  # c is above the origin: tilts move the base


def test_chips_flat_lies_along_x():
    s = load_scene("chips_flat")
    axis = s.T_world_object[:3, 2]
    assert np.allclose(axis, [1, 0, 0], atol=1e-12)


@pytest.mark.parametrize("roll_deg", [36.0, 71.0])  # 0: the shipped chips_flat
def test_a_lying_can_rolled_about_its_axis_rests_on_the_table(tmp_path, roll_deg):
    """The placement check takes the can's lowest point, not pybullet's bounding box: a box rotated with
    the can reached 14 mm under the table top at 36 deg of roll and refused a can resting on it."""
    from scipy.spatial.transform import Rotation

    from planning.world import World

    d = yaml.safe_load(open(assets.scene_path("chips_flat")))
    turn = Rotation.from_euler("y", 90, degrees=True) * Rotation.from_euler("z", roll_deg, degrees=True)
    d["object"]["rpy_deg"] = turn.as_euler("xyz", degrees=True).tolist()
    path = tmp_path / "rolled.yaml"
    path.write_text(yaml.safe_dump(d))
    with World(load_scene(path)) as world:  # the check runs here
        assert np.allclose(world.scene.T_world_object[:3, 2], [1, 0, 0], atol=1e-9)  # still along x
    d["object"]["position_m"][2] -= 0.005
    path.write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=r"rolled\.yaml: object: chips is 5 mm inside or under the table"):
        World(load_scene(path))


def _write(tmp_path, mutate):
    d = yaml.safe_load(open(assets.scene_path("ham_arc")))
    mutate(d)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


@pytest.mark.parametrize(
    "mutate, field",
    [
        (lambda d: d["object"].update(name="teapot"), "object.name"),
        (lambda d: d.pop("strategy"), "strategy"),
        (lambda d: d["object"].pop("position_m"), "object.position_m"),
        (lambda d: d["object"].update(position_m=[0, float("nan"), 0]), r"object.position_m\[1\]"),
        (lambda d: d["object"].update(rpy_deg=[0, 0]), "object.rpy_deg"),
        (lambda d: d.update(hand="robotiq"), "hand"),
        (lambda d: d.update(strategy="teapot"), "strategy"),
        (lambda d: d["obstacles"][1].update(size_m=[0.1, -0.02, 0.1]), r"obstacles\[1\].size_m\[1\]"),
        (lambda d: d["obstacles"][0].update(type="cone"), r"obstacles\[0\].type"),
        (lambda d: d["obstacles"][0].pop("size_m"), r"obstacles\[0\].size_m"),
        (lambda d: d["table"].update(size_m="big"), "table.size_m"),
        (lambda d: d["object"].update(position_std_mm=-3), "object.position_std_mm"),
        (lambda d: d.update(colour="red"), "colour"),
        (lambda d: d["wrist_bounds_m"].update(min=[1, 1, 1]), "wrist_bounds_m"),
        (
            lambda d: d["obstacles"].append({"type": "mesh", "file": "nope.obj", "position_m": [0, 0, 0]}),
            r"obstacles\[2\].file",
        ),
    ],
)
def test_bad_scene_names_file_and_field(tmp_path, mutate, field):
    path = _write(tmp_path, mutate)
    with pytest.raises(InputError, match=rf"bad\.yaml: {field}"):
        load_scene(path)


def test_unknown_scene_name_lists_valid_ones():
    with pytest.raises(InputError, match="unknown scene 'nope'.*ham_arc"):
        load_scene("nope")


def test_not_yaml(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("name: [unclosed\n")
    with pytest.raises(InputError, match="not valid YAML"):
        load_scene(p)
    p.write_text("- a list\n")
    with pytest.raises(InputError, match="expected a mapping"):
        load_scene(p)


def assert_free_and_closes_on_the_object_only(world, q, clearance_m):
    """``q`` is collision-free in ``world``; closing the hand there gives a valid grasp (epsilon >= 0.05)
    that touches the target object only, every link more than ``clearance_m`` from the table and the
    obstacles."""
    from planning.autograsp import HandCloser

    assert world.is_free(q)
    res = HandCloser(world).close(q)
    assert res.quality >= 0.05
    assert {c.other for c in world.hand_contacts(res.closed_q)} == {world.scene.object.name}
    assert world.link_signed_distances(res.closed_q).min() > clearance_m


def test_ham_arc_admits_the_ham_strategys_grasp_from_above():
    """The narrow-passage scene must leave room for the grasp its strategy makes (the paper's learned planner
    solved it): the hand-placed ham grasp from above (pbdgrasp.bench.HAM_GRASP_Q, epsilon 0.17 on the bare
    can) is collision-free between the walls, and closing it there still gives a valid grasp, its fingers
    in the 40 mm slot. With the thumb-side wall 40 mm from the can (until 2026-12-01) it was 66 mm inside
    that wall: every valid grasp of the ham strategy put the SAH's thumb module 31-40 mm into it."""
    from pbdgrasp.bench_fixtures import HAM_GRASP_Q
    from planning.world import World

    with World("ham_arc") as w:
        walls = {o.label: o.position_m[1] for o in w.scene.obstacles}
        assert_free_and_closes_on_the_object_only(w, np.array(HAM_GRASP_Q), clearance_m=0.005)
    # the fingers' slot stays 40 mm wide (can half-width 27.5 mm, wall half-thickness 10 mm)
    assert walls["wall_right"] == pytest.approx(-(0.0275 + 0.040 + 0.010))


#: A valid grasp of the chips strategy on the bare chips can (Table I's chips row, goal-tree trial 77,
#: epsilon 0.055): the palm on the can's -x side, the fingers round its -y side, the thumb round its +y side.
CHIPS_GRASP_Q = (-0.1538, 0.1508, 0.1205, 1.3668, 0.5797, 0.0997,
                 1.5102, -0.1348, -0.0479, 0.7469, -0.1155, 0.1005, 0.096,
                 -0.2031, 0.3673, 0.0698, -0.0982, 0.5113, 0.0857)  # fmt: skip


def test_chips_between_cans_admits_the_chips_strategys_grasp(tmp_path):
    """As for the ham arc: the three-cans scene must leave room for a grasp of its strategy. A valid chips
    grasp is collision-free there and closes to a valid grasp touching the chips can only, its fingers in
    the 45 mm gap to the right can. With the thumb-side can 45 mm away too (until 2026-12-02) the same
    grasp is in collision: of the 216 valid grasps of Table I's chips row none fitted, the thumb's proximal
    phalanx 18-43 mm inside that can."""
    from planning.world import World

    q = np.array(CHIPS_GRASP_Q)
    with World("chips_between_cans") as w:
        cans = {o.label: o.position_m[1] for o in w.scene.obstacles}
        assert_free_and_closes_on_the_object_only(w, q, clearance_m=0.0)
    # gaps between the cans (radius 37.5 mm): 45 mm on the fingers' side, 80 mm on the thumb's
    assert cans["can_right"] == pytest.approx(-(0.0375 + 0.045 + 0.0375))
    assert cans["can_left"] == pytest.approx(0.0375 + 0.080 + 0.0375)
    d = yaml.safe_load(open(assets.scene_path("chips_between_cans")))
    left = next(o for o in d["obstacles"] if o["label"] == "can_left")
    left["position_m"][1] = 0.12
    narrow = tmp_path / "narrow.yaml"
    narrow.write_text(yaml.safe_dump(d))
    with World(narrow) as w:
        assert not w.is_free(q)
        assert w.link_signed_distances(q).min() < -0.02  # the thumb, > 20 mm inside the can
