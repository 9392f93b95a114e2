"""The variation model in a scene (sections V-VI): the one place where the model meets a scene's geometry.

:func:`learn_in_scene` solves a trajectory's model with the scene's object pose and localization covariance
as P(O), the SAH's joint limits, and clearance factors on the SAH's sphere cover
(:func:`assets.sphere_cover.hand_sphere_cover`) against the scene's distance fields
(:func:`planning.scene_fields.scene_fields`): ``params.clearance_mm`` from the table and the obstacles,
``params.precision_object_clearance_mm`` or ``params.power_object_clearance_mm`` from the grasped object,
by the trajectory's grasp type (our addition: the paper constrains the environment; without the object the
smoothing pulls the last steps' fingers into it) and
``params.self_clearance_mm`` between the phalanges of different fingers. A strategy carried to another
object (the chips strategy on the bottle) holds the contacts it demonstrated on its own object
(:mod:`inference.contact`). The CLI (``infer``, ``inspect``),
the Table I runner and the bench build scene models through here.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import assets
from assets.sah import JOINT_LIMITS, rest_joints
from assets.sphere_cover import hand_sphere_cover
from inference.clearance import HandClearance
from inference.factors import HINGE_CUTOFF
from inference.model import VariationModel
from inference.params import VariationParams
from inference.solve import solve
from planning.scene import Scene
from planning.scene_fields import mesh_field, scene_fields
from retarget.trajectory import Trajectory

__all__ = ["scene_clearance", "learn_in_scene"]


def scene_clearance(
    scene: Scene,
    params: VariationParams | None = None,
    cache_dir: str | os.PathLike | None = None,
    *,
    grasp_type: str,
) -> HandClearance:
    """The SAH's clearance margins in ``scene`` with the clearances of ``params``.

    Args:
        cache_dir: where mesh fields are cached (None: in memory only).
        grasp_type: ``precision`` or ``power``, the strategy's: it selects the object clearance.

    Raises:
        InputError: an unknown grasp type.
    """
    params = params or VariationParams()
    fields = scene_fields(scene, cache_dir)
    return HandClearance(
        hand_sphere_cover("sah"),
        fields.environment,
        fields.object_field,
        clearance_m=params.clearance_mm * 1e-3,
        object_clearance_m=params.object_clearance_m(grasp_type),
        self_clearance_m=params.self_clearance_mm * 1e-3,
        rest_joints=rest_joints(),
        active_margin_m=HINGE_CUTOFF * params.hinge_smoothing_mm * 1e-3,
    )


def learn_in_scene(
    traj: Trajectory,
    scene: Scene,
    params: VariationParams | None = None,
    cache_dir: str | os.PathLike | None = None,
    on_iteration: Callable[[float], None] | None = None,
) -> VariationModel:
    """The variation model of ``traj`` in ``scene`` (module docstring); ``on_iteration`` as
    :func:`inference.solve.solve`'s."""
    params = params or VariationParams()
    clearance = scene_clearance(scene, params, cache_dir, grasp_type=traj.grasp_type)
    demonstrated = None
    if traj.object != scene.object.name and traj.object in assets.objects():  # a strategy carried over
        demonstrated = clearance.with_object(mesh_field(assets.object_mesh(traj.object), 1.0, cache_dir))
    return solve(
        traj,
        params,
        T_world_object=scene.T_world_object,
        cov_object=scene.cov_object,
        clearance=clearance,
        joint_limits=JOINT_LIMITS,
        on_iteration=on_iteration,
        demonstrated=demonstrated,
    )
