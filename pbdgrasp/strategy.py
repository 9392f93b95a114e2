"""Retargeting in a scene: the one place where section IV meets the pybullet world.

* :func:`retarget_in_scene`: section IV with d6 checked in the demonstration's scene (the SAH against the
  object and the table), giving tau_r and Sigma_r(t) as a :class:`~retarget.trajectory.Trajectory`;
* :func:`object_frame_is_free`, :func:`object_frame_penetration`: the world's queries with q in the object
  frame, as the retargeting asks them;
* :func:`grasp_shape`: how a configuration holds the object (the palm's distance, the links touching), which
  tells a wrap from a fingertip grasp;
* :class:`ExpectedQuality`: the objective of the refined final grasp (:mod:`retarget.final_grasp`), the
  mean epsilon of the hand closed at draws of the strategy's last marginal about a candidate.

The variation model in a scene (sections V-VI) is :func:`pbdgrasp.scene_model.learn_in_scene`. The CLI
(``retarget``), the Table I runner and the bench retarget through here.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from contextlib import nullcontext

import numpy as np

from assets import sah
from assets.q_layout import POSE, Q_DIM
from assets.se3 import local, pose_from_q, q_from_pose, se3_exp
from planning.autograsp import HandCloser
from planning.closing_pool import ClosingPool
from planning.scene import Scene
from planning.world import World
from retarget.demonstration import Demonstration
from retarget.final_grasp import refine_final_grasp
from retarget.retargeting import RetargetConfig, RetargetResult, retarget_demonstration
from retarget.trajectory import Trajectory

__all__ = [
    "ExpectedQuality",
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


class ExpectedQuality:
    """``E[phi_o]`` about a configuration: the mean epsilon of the hand closed at ``n`` draws.

    Each draw perturbs the object's pose by ``Sigma_o`` and the configuration, moved by ``offset`` first, by
    ``cov`` (GTSAM's body tangent ``[omega, v, 13 joints]``, right perturbation; joints clipped to the
    limits), the draws' standard normals fixed once (common random numbers), so that the value is a
    deterministic function of the configuration; a draw in collision scores 0. It is
    :data:`retarget.final_grasp.ExpectedQuality`.

    Args:
        closer: closes and scores the draws in the scene the strategy is retargeted in: a
            :class:`~planning.autograsp.HandCloser` or, on several cores, a
            :class:`~planning.closing_pool.ClosingPool`.
        T_world_object, cov_object: the object's pose (4, 4) and its covariance (6, 6) in that scene.
        cov: (19, 19) the configuration's covariance about the candidate (the strategy's last marginal).
        n: draws per evaluation.
        rng: the generator of the standard normals.
        offset: (19,) where the draws are centred relative to the candidate, ``[omega, v, 13 joints]``
            (the model's last mean relative to tau_r's last step: the joint limits and the clearances move
            it); default zero.
    """

    def __init__(
        self,
        closer: HandCloser | ClosingPool,
        T_world_object: np.ndarray,
        cov_object: np.ndarray,
        cov: np.ndarray,
        n: int,
        rng: np.random.Generator,
        offset: np.ndarray | None = None,
    ):
        self.closer = closer
        self.offset = np.zeros(Q_DIM) if offset is None else np.asarray(offset, dtype=float)
        self.T_world_object = np.asarray(T_world_object, dtype=float)
        L_object = np.linalg.cholesky(np.asarray(cov_object, dtype=float) + 1e-15 * np.eye(6))
        L = np.linalg.cholesky(np.asarray(cov, dtype=float) + 1e-12 * np.eye(cov.shape[0]))
        z = rng.standard_normal((n, 6 + cov.shape[0]))
        self.xi_object = z[:, :6] @ L_object.T
        self.dq = z[:, 6:] @ L.T
        self.evaluations = 0

    def draws(self, T_object_wrist: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The draws about ``(T_object_wrist (4, 4), joints (13,))``: world wrist poses (n, 4, 4) and
        joints (n, 13) [rad]."""
        T_mean = np.asarray(T_object_wrist, dtype=float) @ se3_exp(self.offset[:6])
        T_world_wrist = self.T_world_object @ se3_exp(self.xi_object) @ T_mean @ se3_exp(self.dq[:, :6])
        joints_mean = np.asarray(joints, dtype=float) + self.offset[6:]
        return T_world_wrist, sah.clip_joints(joints_mean + self.dq[:, 6:])

    def qualities(self, T_object_wrist: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """(n,) epsilon of each draw about ``(T_object_wrist (4, 4), joints (13,))``."""
        self.evaluations += 1
        T_world_wrist, J = self.draws(T_object_wrist, joints)
        q = np.concatenate([q_from_pose(T_world_wrist), J], axis=-1)
        return np.array([grasp.quality for grasp in self.closer.close_many(q)])

    def __call__(self, T_object_wrist: np.ndarray, joints: np.ndarray) -> float:
        return float(np.mean(self.qualities(T_object_wrist, joints)))


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
    processes: int | None = None,
) -> tuple[Trajectory, RetargetResult]:
    """Retarget ``demo`` with d6 checked in ``scene`` (None: no collision term), as a trajectory.

    ``processes``: processes that close the refined final grasp's draws (default: the machine's cores;
    :class:`~planning.closing_pool.ClosingPool`, the same result on any number).

    Returns:
        The trajectory (object prior and rate of the demonstration; ``meta`` plus the scene name, the
        retargeting time, ``final_grasp_method`` (``paper`` or ``refined``: without a scene, ``paper``)
        and, in a scene, the last step's :func:`grasp_shape` as ``last_step``) and the full
        :class:`~retarget.retargeting.RetargetResult`.
    """
    config = config or RetargetConfig()
    start = time.perf_counter()
    method = config.final_grasp_for(demo.grasp_type) if scene is not None else "paper"
    if scene is None:
        result = retarget_demonstration(demo, is_free=None, config=config, progress=progress)
        info = {}
    else:
        refined = method == "refined"
        with (
            World(scene, hand="sah") as world,
            # made first, so that its workers build their worlds while the fingertips are searched
            ClosingPool(scene, world=world, processes=processes) if refined else nullcontext() as closer,
        ):
            penetration = object_frame_penetration(world, scene.T_world_object)
            result = retarget_demonstration(demo, config=config, progress=progress, penetration=penetration)
            if refined:
                result = _refine_final_grasp(demo, scene, world, closer, result, config)
            info = {"last_step": grasp_shape(world, scene.T_world_object, result.q[-1])}
    info["final_grasp_method"] = method
    result = RetargetResult(**{**result.__dict__, "meta": {**result.meta, **info}})
    traj = _trajectory(demo, result, dict(meta or {}, scene=None if scene is None else scene.name,
                                          retarget_time_s=time.perf_counter() - start))  # fmt: skip
    return traj, result


def _trajectory(demo: Demonstration, result: RetargetResult, meta: dict) -> Trajectory:
    return result.to_trajectory(
        T_world_object_mean=demo.T_world_object_mean,
        cov_object=demo.cov_object,
        dt_s=demo.dt_s,
        object_name=demo.object,
        grasp_type=demo.grasp_type,
        meta=meta,
    )


def _refine_final_grasp(
    demo: Demonstration,
    scene: Scene,
    world: World,
    closer: ClosingPool,
    result: RetargetResult,
    config: RetargetConfig,
) -> RetargetResult:
    """The refined final grasp (:mod:`retarget.final_grasp`): the draws about a candidate come from the last
    marginal of the paper's trajectory's variation model in ``scene`` (default parameters), closed by
    ``closer``; a candidate's blended steps must be collision-free in ``world``."""
    from .scene_model import learn_in_scene

    start = time.perf_counter()
    settings = config.final_grasp_settings
    model = learn_in_scene(_trajectory(demo, result, {}), scene)
    rng = np.random.default_rng(settings.seed)
    offset = np.r_[
        local(result.T_object_wrist[-1], model.T_object_wrist_mean[-1]),
        model.joints_mean[-1] - result.joints[-1],
    ]
    score = ExpectedQuality(
        closer, scene.T_world_object, scene.cov_object, model.cov[-1], settings.draws, rng, offset
    )
    penetration = object_frame_penetration(world, scene.T_world_object)

    def is_free(T_object_wrist: np.ndarray, joints: np.ndarray) -> bool:
        return penetration(np.concatenate([q_from_pose(T_object_wrist), joints])) <= 0.0

    refined = refine_final_grasp(result.T_object_wrist, result.joints, score, settings, is_free)
    out = result.with_final_grasp(refined)
    out.meta["final_grasp"].update(settings=dataclasses.asdict(settings), time_s=time.perf_counter() - start)
    return out
