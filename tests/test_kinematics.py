"""Generic URDF parser and FK: a two-link arm with a mimic joint, against closed form; bad files."""

import numpy as np
import pytest

from assets.errors import InputError
from assets.kinematics import HandModel

TOL = 1e-12

ARM = """<?xml version="1.0"?>
<robot name="arm">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="tip"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.1" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-1" upper="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit lower="-2" upper="2"/>
    <mimic joint="j1" multiplier="2" offset="0.1"/></joint>
  <joint name="t" type="fixed"><parent link="l2"/><child link="tip"/><origin xyz="0.2 0 0"/></joint>
</robot>
"""


@pytest.fixture
def arm(tmp_path):
    p = tmp_path / "arm.urdf"
    p.write_text(ARM)
    return HandModel.from_urdf(p)


def test_parse(arm):
    assert arm.joint_names == ("j1",) and arm.n == 1
    assert arm.link_names == ("base", "l1", "l2", "tip")
    np.testing.assert_array_equal(arm.limits, [[-1.0, 1.0]])
    np.testing.assert_allclose(arm.expand(np.array([0.5])), [0.5, 1.1, 0.0])


def test_fk_planar_closed_form_and_batch(arm):
    q = np.linspace(-1, 1, 7)[:, None]
    poses = arm.fk(q)
    a1, a12 = q[:, 0], q[:, 0] + (2 * q[:, 0] + 0.1)
    expected = np.stack(
        [0.3 * np.cos(a1) + 0.2 * np.cos(a12), 0.3 * np.sin(a1) + 0.2 * np.sin(a12), np.full(7, 0.1)], -1
    )
    assert np.abs(poses["tip"][:, :3, 3] - expected).max() < TOL
    np.testing.assert_allclose(poses["base"], np.broadcast_to(np.eye(4), (7, 4, 4)))
    R = poses["tip"][:, :3, :3]
    assert np.abs(R[:, 0, 0] - np.cos(a12)).max() < TOL


def test_point_jacobian_includes_mimic(arm):
    q = np.array([0.3])
    J = arm.point_jacobian(q, "tip")
    h = 1e-6
    num = (arm.fk(q + h)["tip"][:3, 3] - arm.fk(q - h)["tip"][:3, 3]) / (2 * h)
    assert np.abs(J[:, 0] - num).max() < 1e-8


def test_point_jacobian_of_a_point_fixed_to_a_link(arm):
    """A point 5 cm along l1's x axis and 2 cm up: its Jacobian (given the point's base-frame position)
    equals the central difference of the point carried by l1's frame; at the origin it is the default."""
    q = np.array([0.4])
    r_l1 = np.array([0.05, 0.0, 0.02, 1.0])  # the point in l1's frame
    point = (arm.fk(q)["l1"] @ r_l1)[:3]
    J = arm.point_jacobian(q, "l1", point=point)
    h = 1e-6
    num = ((arm.fk(q + h)["l1"] @ r_l1)[:3] - (arm.fk(q - h)["l1"] @ r_l1)[:3]) / (2 * h)
    assert np.abs(J[:, 0] - num).max() < 1e-8
    # closed form: the point turns about z through (0, 0, 0.1) at radius 0.05
    np.testing.assert_allclose(J[:, 0], [-0.05 * np.sin(0.4), 0.05 * np.cos(0.4), 0.0], atol=TOL)
    origin = arm.fk(q)["tip"][:3, 3]
    at_origin = arm.point_jacobian(q, "tip", point=origin)
    np.testing.assert_allclose(at_origin, arm.point_jacobian(q, "tip"), atol=TOL)


def test_rpy_convention(tmp_path):
    urdf = ARM.replace('<origin xyz="0 0 0.1" rpy="0 0 0"/>', '<origin xyz="0 0 0" rpy="0.3 -0.2 0.5"/>')
    p = tmp_path / "a.urdf"
    p.write_text(urdf)
    T = HandModel.from_urdf(p).fk(np.zeros(1))["l1"]
    from scipy.spatial.transform import Rotation

    expected = Rotation.from_euler("xyz", [0.3, -0.2, 0.5]).as_matrix()  # extrinsic x, y, z = URDF rpy
    assert np.abs(T[:3, :3] - expected).max() < TOL


@pytest.mark.parametrize(
    ("old", "new", "match"),
    [
        (
            'type="revolute"><parent link="base"/>',
            'type="prismatic"><parent link="base"/>',
            "unsupported type",
        ),
        ('<child link="l1"/>', '<child link="nope"/>', "unknown link"),
        ('<mimic joint="j1"', '<mimic joint="zz"', "not an actuated joint"),
        ('<axis xyz="0 0 1"/><limit lower="-1" upper="1"/>', '<axis xyz="0 0 1"/>', "no <limit>"),
        ('xyz="0.3 0 0"', 'xyz="0.3 0"', "expected 3 numbers"),
        ("</robot>", "", "cannot read URDF"),
    ],
)
def test_bad_urdf(tmp_path, old, new, match):
    p = tmp_path / "bad.urdf"
    p.write_text(ARM.replace(old, new, 1))
    with pytest.raises(InputError, match=match):
        HandModel.from_urdf(p)


def test_unknown_link_and_wrong_joint_count(arm):
    with pytest.raises(InputError, match="unknown link"):
        arm.chain("nope")
    with pytest.raises(InputError, match="expected 1 joint values"):
        arm.fk(np.zeros(3))
