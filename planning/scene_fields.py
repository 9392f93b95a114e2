"""The signed distance fields of a scene, for the variation model's clearance factors.

* the table, box and cylinder obstacles: their closed forms (:class:`assets.distance_fields.BoxField`,
  :class:`~assets.distance_fields.CylinderField`), exact;
* the grasped object and object obstacles: the object's watertight mesh (``assets.object_mesh``, the same
  solid as its exact convex decomposition that pybullet collides with) sampled by Open3D's
  ``RaycastingScene`` on a grid in the object frame (:meth:`~assets.distance_fields.GridField.from_mesh`),
  interpolated trilinearly; an object obstacle is the same field posed elsewhere;
* mesh obstacles: their ``file`` mesh, sampled the same way in the mesh frame (scaled); it must be
  watertight for the sign.

Mesh fields are cached per mesh file: in memory for the process, and as ``.npz`` files under ``cache_dir``
when one is given, keyed by the SHA-256 of the mesh file, its scale, the grid settings and
:data:`FIELD_VERSION`.
"""

from __future__ import annotations

import hashlib
import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import assets
from assets.distance_fields import BoxField, CylinderField, GridField
from assets.errors import InputError

from .scene import Scene

__all__ = ["FIELD_VERSION", "CELL_M", "PADDING_M", "SceneFields", "scene_fields", "mesh_field"]

log = logging.getLogger(__name__)

FIELD_VERSION = 1
"""Bump to invalidate cached mesh fields."""
CELL_M = 0.003
"""Grid cell of mesh fields [m]: the interpolation error of a 1-Lipschitz field is below ~1 mm."""
PADDING_M = 0.08
"""How far a mesh field's grid reaches beyond the mesh's bounding box [m]: far beyond the largest sphere
(14 mm) plus the clearance (10 mm), where a margin can be negative."""

_MEMORY: dict[str, GridField] = {}


@dataclass(frozen=True)
class SceneFields:
    """The fields of a scene.

    Attributes:
        environment: the table's and the obstacles' fields, world frame.
        object_field: the grasped object's field in the object frame.
        labels: the name of each environment field (``table`` and the obstacles' labels).
    """

    environment: tuple
    object_field: GridField
    labels: tuple[str, ...]


def mesh_field(
    mesh_path: str | os.PathLike, scale: float = 1.0, cache_dir: str | os.PathLike | None = None
) -> GridField:
    """The signed distance field of a watertight mesh file in its own frame (scaled by ``scale``).

    Raises:
        InputError: the file cannot be read as a triangle mesh, or the mesh is not watertight.
    """
    path = Path(mesh_path)
    try:
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError as exc:
        raise InputError(f"cannot read mesh ({exc.strerror})", path) from None
    key = hashlib.sha256(
        f"field v{FIELD_VERSION} {digest} {scale!r} {CELL_M!r} {PADDING_M!r}".encode()
    ).hexdigest()
    cached = None if cache_dir is None else Path(cache_dir) / f"{path.stem}-{key[:16]}.field.npz"
    if key in _MEMORY:
        field = _MEMORY[key]
        if cached is not None and not cached.is_file():  # built in memory earlier, without this cache
            cached.parent.mkdir(parents=True, exist_ok=True)
            field.save(cached)
        return field
    if cached is not None and cached.is_file():
        field = GridField.load(cached)
    else:
        import open3d as o3d  # imported late: Open3D is slow to import

        mesh = o3d.io.read_triangle_mesh(str(path))
        if len(mesh.triangles) == 0:
            raise InputError("not a triangle mesh (no triangles read)", path)
        if not mesh.is_watertight():
            raise InputError("the mesh is not watertight: its signed distance is undefined", path)
        vertices = np.asarray(mesh.vertices, dtype=float) * scale
        log.info("building the distance field of %s", path.name)
        field = GridField.from_mesh(vertices, np.asarray(mesh.triangles), CELL_M, PADDING_M)
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            field.save(cached)
    _MEMORY[key] = field
    return field


def scene_fields(scene: Scene, cache_dir: str | os.PathLike | None = None) -> SceneFields:
    """The table's, the obstacles' and the grasped object's fields of ``scene`` (module docstring)."""
    table = scene.table
    environment = [BoxField(np.asarray(table.size_m) / 2, table.T_world_table)]
    labels = ["table"]
    for ob in scene.obstacles:
        T = ob.T_world_obstacle
        if ob.type == "box":
            environment.append(BoxField(np.asarray(ob.size_m) / 2, T))
        elif ob.type == "cylinder":
            environment.append(CylinderField(ob.radius_m, ob.height_m / 2, T))
        elif ob.type == "object":
            environment.append(mesh_field(assets.object_mesh(ob.name), 1.0, cache_dir).with_pose(T))
        else:
            environment.append(mesh_field(ob.file, ob.scale, cache_dir).with_pose(T))
        labels.append(ob.label)
    object_field = mesh_field(assets.object_mesh(scene.object.name), 1.0, cache_dir)
    return SceneFields(tuple(environment), object_field, tuple(labels))
