"""Where the grasp ceiling's poses come from (:mod:`pbdgrasp.ceiling`): about the object's surface, or
draws of a strategy's last marginal with the trust region its refinement keeps to.

About the surface (object frame): a point ``p`` on the object's surface, area-uniform on its visual mesh,
with its outward normal ``n``; the palm's normal (the SAH wrist's +x axis, out of the palm) within
``cone_deg`` of ``-n``, uniformly on that spherical cap; a roll about it uniform; the hand's grasp centre
at ``p + s n`` with the standoff ``s`` uniform in ``standoff_m``, the grasp centre uniform on the hand's
axis from the palm centre (:func:`retarget.objective.palm_centre`) to ``reach_beyond_knuckles_m`` beyond
the knuckles; the fingers at the SAH's rest pose (:func:`assets.sah.rest_joints`) with the thumb's
opposition uniform within its joint limits; then placed in the scene's object pose.

Near a strategy: draws of its last marginal in the scene, as the planner draws them (P(O) the scene's
localization, joints clipped to the limits), and a :class:`Region` about its last mean.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial.transform import Rotation

import assets
from assets import sah
from assets.errors import InputError
from assets.se3 import pose_from_q, q_from_pose
from inference.model import VariationModel
from inference.sampler import sample
from planning.grasp_quality import tangent_basis
from planning.scene import Scene
from retarget.objective import THUMB_BASE, palm_centre

if TYPE_CHECKING:
    from .ceiling import CeilingConfig

__all__ = ["Region", "strategy_draws", "surface_poses", "surface_samples", "wrist_poses"]


@dataclass(frozen=True, eq=False)
class Region:
    """A trust region about a wrist pose (world frame): the wrist within ``max_position_m`` of
    ``T_world_wrist``'s origin along each of its axes and turned by at most ``max_rotation_rad``."""

    T_world_wrist: np.ndarray
    max_position_m: float
    max_rotation_rad: float

    def contains(self, q: np.ndarray) -> bool:
        """Whether the wrist of ``q`` (19,) (world frame) lies in the region."""
        T = pose_from_q(q)
        R0, p0 = self.T_world_wrist[:3, :3], self.T_world_wrist[:3, 3]
        offset = R0.T @ (T[:3, 3] - p0)
        turn = Rotation.from_matrix(R0.T @ T[:3, :3]).magnitude()
        return bool(np.all(np.abs(offset) <= self.max_position_m) and turn <= self.max_rotation_rad)


def strategy_draws(
    scene: Scene, model: VariationModel, config: CeilingConfig, rng: np.random.Generator
) -> tuple[np.ndarray, Region]:
    """``config.samples`` world-frame draws (n, 19) of ``model``'s last marginal in ``scene`` (P(O) the
    scene's, joints clipped to the SAH's limits, as the planner draws them) and the :class:`Region` of the
    refinement about its last mean."""
    in_scene = dataclasses.replace(
        model, T_world_object_mean=scene.T_world_object, cov_object=scene.cov_object
    )
    q = sample(in_scene, model.num_steps - 1, config.samples, rng, joint_limits=sah.JOINT_LIMITS)
    region = Region(
        scene.T_world_object @ model.T_object_wrist_mean[-1],
        config.near_position_m,
        float(np.deg2rad(config.near_rotation_deg)),
    )
    return q, region


def surface_samples(vertices: np.ndarray, triangles: np.ndarray, n: int, rng: np.random.Generator):
    """``n`` area-uniform points (n, 3) on a triangle mesh and their unit outward normals (n, 3).

    The normals are the triangles' (right-handed vertex order, as the shipped meshes are written).
    """
    v = np.asarray(vertices, dtype=float)[np.asarray(triangles)]
    cross = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if not area.sum() > 0:
        raise InputError("surface_samples: the mesh has no area")
    k = rng.choice(len(v), size=n, p=area / area.sum())
    a, b = rng.random((2, n))
    flip = a + b > 1.0
    a[flip], b[flip] = 1.0 - a[flip], 1.0 - b[flip]
    points = v[k, 0] + a[:, None] * (v[k, 1] - v[k, 0]) + b[:, None] * (v[k, 2] - v[k, 0])
    return points, cross[k] / np.linalg.norm(cross[k], axis=1, keepdims=True)


def wrist_poses(points, normals, config: CeilingConfig, rng: np.random.Generator) -> np.ndarray:
    """Object-frame wrist poses (n, 4, 4) whose palm faces the surface ``points`` (n, 3) against their
    outward ``normals`` (n, 3) (module docstring)."""
    points = np.asarray(points, dtype=float)
    approach = -np.asarray(normals, dtype=float)
    n = len(points)
    cos_max = np.cos(np.deg2rad(config.cone_deg))
    c = 1.0 - rng.random(n) * (1.0 - cos_max)  # uniform on the cap: cos uniform in [cos_max, 1]
    phi = rng.uniform(0.0, 2 * np.pi, n)
    e1, e2 = tangent_basis(approach)
    s = np.sqrt(1.0 - c**2)[:, None]
    x_axis = s * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2) + c[:, None] * approach
    u, w = tangent_basis(x_axis)
    roll = rng.uniform(0.0, 2 * np.pi, n)[:, None]
    z_axis = np.cos(roll) * u + np.sin(roll) * w
    R = np.stack([x_axis, np.cross(z_axis, x_axis), z_axis], axis=2)
    standoff = rng.uniform(*config.standoff_m, size=n)
    centre = points - standoff[:, None] * x_axis
    # the hand's grasp centre: on the line from the palm centre to the knuckles (twice the palm centre,
    # see retarget.objective.palm_centre) and up to reach_beyond_knuckles_m beyond them
    palm = palm_centre(sah)
    knuckles = 2.0 * palm
    along = rng.uniform(0.0, 1.0 + config.reach_beyond_knuckles_m / np.linalg.norm(knuckles - palm), n)
    local = palm + along[:, None] * (knuckles - palm)
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = centre - np.einsum("nij,nj->ni", R, local)
    return T


def surface_poses(scene: Scene, config: CeilingConfig, rng: np.random.Generator) -> np.ndarray:
    """``config.samples`` world-frame configurations (n, 19) about the object's surface (module docstring)."""
    import open3d as o3d

    mesh = o3d.io.read_triangle_mesh(str(assets.object_mesh(scene.object.name)))
    points, normals = surface_samples(
        np.asarray(mesh.vertices), np.asarray(mesh.triangles), config.samples, rng
    )
    T_world_wrist = scene.T_world_object @ wrist_poses(points, normals, config, rng)
    joints = np.tile(sah.rest_joints(), (config.samples, 1))
    lo, hi = sah.JOINT_LIMITS[THUMB_BASE]
    joints[:, THUMB_BASE] = rng.uniform(lo, hi, config.samples)
    return np.concatenate([q_from_pose(T_world_wrist), joints], axis=1)
