"""The static bodies of a scene in a pybullet client: the table, the target object and the obstacles.

All are static (mass 0). Objects are loaded from their URDFs (compounds of their exact convex pieces, so
solids: ``assets/objects/build_objects.py``); box and cylinder obstacles are pybullet primitives; mesh
obstacles are their convex pieces when the scene gives a collision file, else a concave surface.
:class:`planning.world.World` builds its scene with these functions.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

import assets
from assets.errors import InputError

from ._pybullet import pb

__all__ = ["COLORS", "load_object", "load_obstacle", "load_table"]

#: RGBA of the scene's parts in pybullet's pictures
COLORS = {"table": (0.55, 0.42, 0.3, 1.0), "obstacle": (0.45, 0.55, 0.45, 1.0)}


def _quat_xyzw(R: np.ndarray) -> list[float]:
    return list(Rotation.from_matrix(R).as_quat())


def load_table(client: int, table) -> int:
    """The table (a box of ``table.size_m`` [m] centred at ``table.T_world_table``'s origin): its body id."""
    half = (np.array(table.size_m) / 2).tolist()
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    vis = pb.createVisualShape(
        pb.GEOM_BOX, halfExtents=half, rgbaColor=COLORS["table"], physicsClientId=client
    )
    return pb.createMultiBody(0.0, shape, vis, table.T_world_table[:3, 3].tolist(), physicsClientId=client)


def load_object(client: int, name: str, T_world: np.ndarray, color=None) -> int:
    """The object ``name`` (``assets.object_urdf``) at the pose ``T_world`` (4, 4): its body id."""
    body = pb.loadURDF(
        str(assets.object_urdf(name)),
        T_world[:3, 3].tolist(),
        _quat_xyzw(T_world[:3, :3]),
        useFixedBase=True,
        physicsClientId=client,
    )
    if color is not None:
        pb.changeVisualShape(body, -1, rgbaColor=color, physicsClientId=client)
    return body


def load_obstacle(client: int, ob, scene_path: Path | None = None) -> int:
    """An obstacle of a scene (:class:`planning.scene.Obstacle`): its body id.

    Raises:
        InputError: pybullet cannot build its shape or read its mesh (``scene_path`` names the scene).
    """
    T = ob.T_world_obstacle
    pos, quat = T[:3, 3].tolist(), _quat_xyzw(T[:3, :3])
    rgba = COLORS["obstacle"]
    if ob.type == "object":
        return load_object(client, ob.name, T, color=rgba)
    if ob.type == "box":
        half = (np.array(ob.size_m) / 2).tolist()
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
        vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=rgba, physicsClientId=client)
    elif ob.type == "cylinder":
        col = pb.createCollisionShape(
            pb.GEOM_CYLINDER, radius=ob.radius_m, height=ob.height_m, physicsClientId=client
        )
        vis = pb.createVisualShape(
            pb.GEOM_CYLINDER, radius=ob.radius_m, length=ob.height_m, rgbaColor=rgba, physicsClientId=client
        )
    else:
        return _load_mesh_obstacle(client, ob, pos, quat, rgba, scene_path)
    if col < 0:
        raise InputError(f"obstacle {ob.label}: pybullet could not build its shape")
    return pb.createMultiBody(0.0, col, vis, pos, quat, physicsClientId=client)


def _load_mesh_obstacle(client: int, ob, pos, quat, rgba, scene_path) -> int:
    scale = [ob.scale] * 3
    try:
        if ob.collision_file is not None:  # convex pieces, one OBJ object each: a solid compound
            col = pb.createCollisionShape(
                pb.GEOM_MESH, fileName=str(ob.collision_file), meshScale=scale, physicsClientId=client
            )
        else:  # a surface only: links wholly inside it are not seen
            col = pb.createCollisionShape(
                pb.GEOM_MESH,
                fileName=str(ob.file),
                meshScale=scale,
                flags=pb.GEOM_FORCE_CONCAVE_TRIMESH,
                physicsClientId=client,
            )
        vis = pb.createVisualShape(
            pb.GEOM_MESH, fileName=str(ob.file), meshScale=scale, rgbaColor=rgba, physicsClientId=client
        )
    except pb.error:
        raise InputError(
            f"obstacles: {ob.label}: {ob.file.name} (or its collision file) is not a mesh pybullet can "
            "read (OBJ, STL or DAE)",
            scene_path,
        ) from None
    return pb.createMultiBody(0.0, col, vis, pos, quat, physicsClientId=client)
