"""Triangle meshes of a scene and of a hand for the 3-D viewer, and the poses that place them.

Everything here is plain numpy and trimesh (no server), so it is tested on its own. Frames: a mesh is
given in its own frame (a link's, an object's, an obstacle's) and placed by a ``T_world_*`` pose (4, 4);
lengths are metres.

* The hand: one mesh per link from the URDF's ``<visual>`` primitives (:func:`hand_link_meshes`), placed by
  :func:`hand_link_poses` from configurations q (19,) ``[wrist position, rotation vector, 13 joints]``.
* The scene: the table, the target object (its watertight mesh) and every obstacle (:func:`scene_meshes`).
* The fingertip marginals: a 1-sigma ellipsoid is a unit sphere scaled by the square roots of a
  covariance's eigenvalues and rotated by its eigenvectors (:func:`ellipsoid_scale_wxyz`).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

import assets
from assets.errors import InputError
from assets.kinematics import load_hand_model
from assets.se3 import pose_from_q
from assets.sphere_cover import CollisionShape, collision_shapes
from planning.scene import Scene

__all__ = [
    "SceneMesh",
    "shape_mesh",
    "hand_link_meshes",
    "hand_link_poses",
    "scene_meshes",
    "ellipsoid_scale_wxyz",
    "wxyz_of",
]

COLORS = {
    "table": (140, 107, 77),
    "object": (230, 160, 30),
    "obstacle": (115, 140, 115),
    "hand": (158, 161, 168),
}
"""RGB 0-255 of the scene's parts (the table and obstacles as in pybullet's pictures)."""


@dataclass(frozen=True)
class SceneMesh:
    """A static part of a scene: ``name`` (``table``, the object's name, an obstacle's label), ``kind``
    (``table``, ``object``, ``obstacle``), its mesh in its own frame, ``T_world_mesh`` (4, 4) and ``rgb``."""

    name: str
    kind: str
    mesh: trimesh.Trimesh
    T_world_mesh: np.ndarray
    rgb: tuple[int, int, int]


def shape_mesh(shape: CollisionShape, sections: int = 24) -> trimesh.Trimesh:
    """The triangle mesh of one URDF primitive in its link's frame (capsules and cylinders along z, centred).

    A capsule's ``length`` is that of its cylindrical part (URDF and pybullet), its caps add the radius.
    """
    if shape.type == "box":
        mesh = trimesh.creation.box(extents=shape.size_m)
    elif shape.type == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=3, radius=shape.size_m[0])
    elif shape.type == "capsule":
        mesh = trimesh.creation.capsule(
            height=shape.size_m[1], radius=shape.size_m[0], count=[sections, sections]
        )
    elif shape.type == "cylinder":
        mesh = trimesh.creation.cylinder(radius=shape.size_m[0], height=shape.size_m[1], sections=sections)
    else:  # collision_shapes() admits nothing else
        raise InputError(f"link {shape.link!r}: no mesh for a {shape.type}")
    mesh.apply_transform(shape.T_link_shape)
    return mesh


@lru_cache(maxsize=4)
def hand_link_meshes(hand: str = "sah") -> dict[str, trimesh.Trimesh]:
    """link name -> the union of its ``<visual>`` primitives in the link frame (links without one omitted)."""
    parts: dict[str, list[trimesh.Trimesh]] = {}
    for shape in collision_shapes(assets.hand_urdf(hand), element="visual"):
        parts.setdefault(shape.link, []).append(shape_mesh(shape))
    return {link: trimesh.util.concatenate(meshes) for link, meshes in parts.items()}


def hand_link_poses(q: np.ndarray, hand: str = "sah") -> dict[str, np.ndarray]:
    """World poses of every link, ``T_world_link`` (..., 4, 4), of configurations q (..., 19)."""
    q = np.asarray(q, dtype=float)
    model = load_hand_model(str(assets.hand_urdf(hand)))
    if q.shape[-1] != 6 + model.n:
        raise InputError(f"q: expected {6 + model.n} values a configuration for hand {hand}, found {q.shape}")
    T_world_wrist = pose_from_q(q)
    return {link: T_world_wrist @ T for link, T in model.fk(q[..., 6:]).items()}


def _object_mesh(name: str) -> trimesh.Trimesh:
    mesh = trimesh.load(assets.object_mesh(name), force="mesh", process=False)
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise InputError(f"object {name}: {assets.object_mesh(name)} holds no triangles")
    return mesh


def scene_meshes(scene: Scene) -> list[SceneMesh]:
    """The table, the target object and the obstacles of a scene, as :mod:`planning.world` builds them.

    Raises:
        InputError: a mesh obstacle's file holds no triangles trimesh can read.
    """
    out = [
        SceneMesh(
            "table",
            "table",
            trimesh.creation.box(extents=scene.table.size_m),
            scene.table.T_world_table,
            COLORS["table"],
        ),
        SceneMesh(
            scene.object.name,
            "object",
            _object_mesh(scene.object.name),
            scene.T_world_object,
            COLORS["object"],
        ),
    ]
    for ob in scene.obstacles:
        if ob.type == "box":
            mesh = trimesh.creation.box(extents=ob.size_m)
        elif ob.type == "cylinder":
            mesh = trimesh.creation.cylinder(radius=ob.radius_m, height=ob.height_m, sections=48)
        elif ob.type == "object":
            mesh = _object_mesh(ob.name)
        else:
            try:
                mesh = trimesh.load(ob.file, force="mesh", process=False)
            except Exception as exc:  # trimesh raises many types for unreadable files
                raise InputError(
                    f"obstacles: {ob.label}: cannot read {ob.file} ({exc})", scene.path
                ) from None
            if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
                raise InputError(f"obstacles: {ob.label}: {ob.file} holds no triangles", scene.path)
            mesh.apply_scale(ob.scale)
        out.append(SceneMesh(ob.label, "obstacle", mesh, ob.T_world_obstacle, COLORS["obstacle"]))
    return out


def wxyz_of(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``[w, x, y, z]`` (..., 4) of rotation matrices (..., 3, 3) (viser's convention)."""
    xyzw = Rotation.from_matrix(np.asarray(R, dtype=float).reshape(-1, 3, 3)).as_quat()
    return xyzw[:, [3, 0, 1, 2]].reshape(np.shape(R)[:-2] + (4,))


def ellipsoid_scale_wxyz(cov: np.ndarray, n_sigma: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """The n-sigma ellipsoid of a 3-D Gaussian as a unit sphere's axis scales and rotation.

    Args:
        cov: (..., 3, 3) covariances [m^2], symmetric positive semi-definite.

    Returns:
        ``scale`` (..., 3) [m], the semi-axes ``n_sigma sqrt(eigenvalues)``, and ``wxyz`` (..., 4), the
        rotation whose columns are the eigenvectors (a proper rotation: a reflected basis is flipped).
    """
    w, V = np.linalg.eigh(np.asarray(cov, dtype=float))
    V = V.copy()
    V[..., :, 2] *= np.sign(np.linalg.det(V))[..., None]
    return n_sigma * np.sqrt(np.clip(w, 0.0, None)), wxyz_of(V)
