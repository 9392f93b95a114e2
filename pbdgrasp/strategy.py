"""A learned strategy from a demonstration, in scenes: the one place where retargeting and the variation
model meet the pybullet world.

* :func:`retarget_in_scene`: section IV with d6 checked in the demonstration's scene (the SAH against the
  object and the table), giving tau_r and Sigma_r(t) as a :class:`~retarget.trajectory.Trajectory`;
* :func:`learn_in_scene`: sections V-VI in a planning scene: the scene's object pose and localization
  covariance as P(O), and the signed distance of the hand to the scene's table and obstacles as the
  constraint of the linearized constraint factors.

The CLI (``retarget``, ``infer``), the Table I runner and the bench all build strategies through here.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from assets.q_layout import POSE
from assets.sah import JOINT_LIMITS
from assets.se3 import pose_from_q, q_from_pose
from inference.model import VariationModel
from inference.params import VariationParams
from inference.solve import solve
from planning.scene import Scene
from planning.world import World
from retarget.demonstration import Demonstration
from retarget.retargeting import RetargetConfig, RetargetResult, retarget_demonstration
from retarget.trajectory import Trajectory

__all__ = [
    "object_frame_is_free",
    "object_frame_penetration",
    "signed_distance_fn",
    "signed_distance_gradient_fn",
    "retarget_in_scene",
    "learn_in_scene",
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


def _world_q(T_world_object: np.ndarray, q_object: np.ndarray) -> np.ndarray:
    """q (19,) with its wrist pose moved from the object frame into the world frame; joints unchanged."""
    q_world = np.array(q_object, dtype=float)
    q_world[POSE] = q_from_pose(T_world_object @ pose_from_q(q_object))
    return q_world


def signed_distance_fn(
    world: World, include_object: bool = False, object_max_distance_m: float = 0.05
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """phi(T_world_wrist (4, 4), joints (13,)) -> each hand link's signed distance [m] to the table and the
    obstacles (:meth:`~planning.world.World.link_signed_distances`): one constraint per link; with
    ``include_object``, followed by each link's signed distance to the object alone (2 per link), capped at
    ``object_max_distance_m`` (the object's triangle mesh makes that query cost ~1 ms per 35 mm of range
    on the chips can, against ~15 us for the table)."""

    def signed_distance(T_world_wrist: np.ndarray, joints: np.ndarray) -> np.ndarray:
        q = np.concatenate([q_from_pose(T_world_wrist), joints])
        phi = world.link_signed_distances(q)
        if include_object:
            obj = world.link_signed_distances(q, object_max_distance_m, bodies=(world.object_id,))
            phi = np.concatenate([phi, obj])
        return phi

    return signed_distance


def signed_distance_gradient_fn(
    world: World, include_object: bool = False, object_max_distance_m: float = 0.05
) -> Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]:
    """``(T_world_wrist, joints) -> (phi, grad)``: :func:`signed_distance_fn`'s phi and its analytic gradient
    (m, 19) in the tangent ``[omega, v, joints]`` of ``T_world_wrist @ Exp(xi)``
    (:meth:`~planning.world.World.link_signed_distance_gradients`): one distance query where central
    differences make 2 x 19 more (on the ham: 10-20 ms per step instead of ~0.5 s)."""

    def phi_and_gradient(T_world_wrist: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.concatenate([q_from_pose(T_world_wrist), joints])
        phi, grad = world.link_signed_distance_gradients(q)
        if include_object:
            phi_o, grad_o = world.link_signed_distance_gradients(
                q, object_max_distance_m, bodies=(world.object_id,)
            )
            phi, grad = np.concatenate([phi, phi_o]), np.vstack([grad, grad_o])
        return phi, grad

    return phi_and_gradient


def retarget_in_scene(
    demo: Demonstration,
    scene: Scene | None,
    config: RetargetConfig | None = None,
    progress: bool = False,
    meta: dict | None = None,
) -> tuple[Trajectory, RetargetResult]:
    """Retarget ``demo`` with d6 checked in ``scene`` (None: no collision term), as a trajectory.

    Returns:
        The trajectory (object prior and rate of the demonstration; ``meta`` plus the scene name and the
        retargeting time) and the full :class:`~retarget.retargeting.RetargetResult`.
    """
    start = time.perf_counter()
    if scene is None:
        result = retarget_demonstration(demo, is_free=None, config=config, progress=progress)
    else:
        with World(scene, hand="sah") as world:
            penetration = object_frame_penetration(world, scene.T_world_object)
            result = retarget_demonstration(demo, config=config, progress=progress, penetration=penetration)
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


def learn_in_scene(traj: Trajectory, scene: Scene, params: VariationParams | None = None) -> VariationModel:
    """The variation model of ``traj`` with the scene's object prior, signed-distance constraints and the
    SAH's joint limits.

    Each hand link has two constraints: its distance to the table and the obstacles, held at least
    ``params.clearance_mm`` away, and its distance to the grasped object, held at least
    ``params.object_clearance_mm`` away (our addition: the paper constrains the environment; without the
    object the smoothing pulls the last steps' fingers into it, chips' last mean 2 mm deep, and most draws of
    the last marginal collide).
    """
    params = params or VariationParams()
    with World(scene) as world:
        n_links = 1 + len(world.link_names)
        clearance_mm = np.r_[
            np.full(n_links, params.clearance_mm), np.full(n_links, params.object_clearance_mm)
        ]
        # beyond the activation distance a component is never constrained: 5 mm more is enough
        object_range_m = 1e-3 * (params.activation_distance_mm + 5.0)
        return solve(
            traj,
            params,
            T_world_object=scene.T_world_object,
            cov_object=scene.cov_object,
            constraint_fn=signed_distance_fn(world, True, object_range_m),
            constraint_gradient_fn=signed_distance_gradient_fn(world, True, object_range_m),
            constraint_clearance_mm=clearance_mm,
            joint_limits=JOINT_LIMITS,
        )
