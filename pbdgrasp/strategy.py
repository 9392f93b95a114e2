"""Retargeting in a scene: the one place where section IV meets the pybullet world.

* :func:`retarget_in_scene`: section IV with d6 checked in the demonstration's scene (the SAH against the
  object and the table), giving tau_r and Sigma_r(t) as a :class:`~retarget.trajectory.Trajectory`;
* :func:`object_frame_is_free`, :func:`object_frame_penetration`: the world's queries with q in the object
  frame, as the retargeting asks them;
* :func:`grasp_shape`: how a configuration holds the object (the palm's distance, the links touching), which
  tells a wrap from a fingertip grasp.

The variation model in a scene (sections V-VI) is :func:`pbdgrasp.scene_model.learn_in_scene`. The CLI
(``retarget``), the Table I runner and the bench retarget through here.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from assets.q_layout import POSE
from assets.se3 import pose_from_q, q_from_pose
from planning.scene import Scene
from planning.world import World
from retarget.demonstration import Demonstration
from retarget.retargeting import RetargetConfig, RetargetResult, retarget_demonstration
from retarget.trajectory import Trajectory

__all__ = [
    "object_frame_is_free",
    "object_frame_penetration",
    "grasp_shape",
    "retarget_in_scene",
]


def object_frame_is_free(world: World, T_world_object: np.ndarray) -> Callable[[np.ndarray], bool]:
    """``is_free(q_object)`` for retargeting, from a world whose ``is_free`` takes q in the world frame.

    Args:
        world: the pybullet world.
        T_world_object: (4, 4) the object's pose in that world.
    """
    T_world_object = np.asarray(T_world_object, dtype=float)

    def is_free(q_object: np.ndarray) -> bool:
        return bool(world.is_free(_world_q(T_world_object, q_object)))

    return is_free


def object_frame_penetration(world: World, T_world_object: np.ndarray) -> Callable[[np.ndarray], float]:
    """``penetration(q_object)`` [m] for retargeting: :meth:`World.penetration_m` with q in the object frame.

    Args:
        world: the pybullet world.
        T_world_object: (4, 4) the object's pose in that world.
    """
    T_world_object = np.asarray(T_world_object, dtype=float)

    def penetration(q_object: np.ndarray) -> float:
        return world.penetration_m(_world_q(T_world_object, q_object))

    return penetration


TOUCH_M = 0.003
"""A link this close to the object [m] touches it (:func:`grasp_shape`)."""


def grasp_shape(world: World, T_world_object: np.ndarray, q_object: np.ndarray) -> dict:
    """How the SAH at ``q_object`` (19,) (object frame) holds the object of ``world``.

    Returns:
        ``palm_to_object_mm``: the palm's (the wrist link's collision shape) signed distance to the
        object [mm]; ``contact_links``: the number of hand links within :data:`TOUCH_M` of it.
    """
    d = world.link_signed_distances(_world_q(T_world_object, q_object), 0.2, bodies=(world.object_id,))
    return {"palm_to_object_mm": 1e3 * float(d[0]), "contact_links": int(np.sum(d <= TOUCH_M))}


def _world_q(T_world_object: np.ndarray, q_object: np.ndarray) -> np.ndarray:
    """q (19,) with its wrist pose moved from the object frame into the world frame; joints unchanged."""
    q_world = np.array(q_object, dtype=float)
    q_world[POSE] = q_from_pose(T_world_object @ pose_from_q(q_object))
    return q_world


def retarget_in_scene(
    demo: Demonstration,
    scene: Scene | None,
    config: RetargetConfig | None = None,
    progress: bool = False,
    meta: dict | None = None,
) -> tuple[Trajectory, RetargetResult]:
    """Retarget ``demo`` with d6 checked in ``scene`` (None: no collision term), as a trajectory.

    Returns:
        The trajectory (object prior and rate of the demonstration; ``meta`` plus the scene name, the
        retargeting time and, in a scene, the last step's :func:`grasp_shape` as ``last_step``) and the
        full :class:`~retarget.retargeting.RetargetResult`.
    """
    start = time.perf_counter()
    if scene is None:
        result = retarget_demonstration(demo, is_free=None, config=config, progress=progress)
    else:
        with World(scene, hand="sah") as world:
            penetration = object_frame_penetration(world, scene.T_world_object)
            result = retarget_demonstration(demo, config=config, progress=progress, penetration=penetration)
            shape = grasp_shape(world, scene.T_world_object, result.q[-1])
        result = RetargetResult(**{**result.__dict__, "meta": {**result.meta, "last_step": shape}})
    traj = result.to_trajectory(
        T_world_object_mean=demo.T_world_object_mean,
        cov_object=demo.cov_object,
        dt_s=demo.dt_s,
        object_name=demo.object,
        grasp_type=demo.grasp_type,
        meta=dict(meta or {}, scene=None if scene is None else scene.name,
                  retarget_time_s=time.perf_counter() - start),
    )  # fmt: skip
    return traj, result
