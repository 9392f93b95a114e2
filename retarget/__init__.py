"""The retargeting of a human demonstration to the SAH (paper section IV).

The hand models and SE(3) helpers it uses live in :mod:`assets` (:mod:`assets.sah`,
:mod:`assets.human_hand`, :mod:`assets.kinematics`, :mod:`assets.se3`); the configuration layout in
:mod:`assets.q_layout`.
"""

from . import ik
from .demonstration import Demonstration
from .ik import finger_ik, hand_ik
from .retargeting import RetargetConfig, RetargetResult, retarget_demonstration, retarget_fingertips
from .rosenbrock import RosenbrockResult, minimize_rosenbrock
from .virtual_fingers import VirtualFingers, choose_virtual_fingers

__all__ = [
    "Demonstration",
    "finger_ik",
    "hand_ik",
    "ik",
    "RetargetConfig",
    "RetargetResult",
    "retarget_demonstration",
    "retarget_fingertips",
    "RosenbrockResult",
    "minimize_rosenbrock",
    "VirtualFingers",
    "choose_virtual_fingers",
]
