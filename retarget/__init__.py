"""Kinematics of the SAH and the human hand, and the retargeting of a demonstration (paper section IV).

The public API grows with the package; see the README for the configuration and frame conventions.
"""

from . import human_hand, ik, kinematics, sah
from .demonstration import Demonstration
from .ik import finger_ik, hand_ik
from .kinematics import HandModel
from .lie import local, pose_from_q, q_from_pose, retract, se3_exp, se3_inverse, se3_log, so3_exp, so3_log
from .retargeting import RetargetConfig, RetargetResult, retarget_demonstration, retarget_fingertips
from .rosenbrock import RosenbrockResult, minimize_rosenbrock
from .virtual_fingers import VirtualFingers, choose_virtual_fingers

__all__ = [
    "Demonstration",
    "HandModel",
    "finger_ik",
    "hand_ik",
    "human_hand",
    "ik",
    "kinematics",
    "sah",
    "local",
    "pose_from_q",
    "q_from_pose",
    "retract",
    "se3_exp",
    "se3_inverse",
    "se3_log",
    "so3_exp",
    "so3_log",
    "RetargetConfig",
    "RetargetResult",
    "retarget_demonstration",
    "retarget_fingertips",
    "RosenbrockResult",
    "minimize_rosenbrock",
    "VirtualFingers",
    "choose_virtual_fingers",
]
