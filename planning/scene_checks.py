"""Physical checks of a scene's placement, run when a :class:`~planning.world.World` is built.

A scene file can be well-formed and still impossible: an object sunk into the table, floating above it or
beside it, or overlapped by an obstacle. These checks use the pybullet bodies of the world (the shapes the
planner collides with) and raise :class:`~assets.errors.InputError` naming the scene file.
"""

from __future__ import annotations

from functools import cache

import numpy as np
import trimesh

import assets
from assets.errors import InputError

from ._pybullet import pb

__all__ = ["MAX_PENETRATION_M", "MAX_SUPPORT_GAP_M", "check_placement"]

MAX_PENETRATION_M = 0.002
"""The object may sink this deep into the table or an obstacle (contact margins, mesh facets) [m]."""
MAX_SUPPORT_GAP_M = 0.005
"""The object must rest within this gap on the table or on an obstacle [m]."""
_QUERY_M = 0.5
_CONVEX_MARGIN_M = 0.001  # the collision pieces are inset by pybullet's convex margin (assets/objects)


def _distance(world, a: int, b: int) -> float:
    points = pb.getClosestPoints(a, b, _QUERY_M, physicsClientId=world.client)
    return min((p[8] for p in points), default=np.inf)


def check_placement(world) -> None:
    """Check the object of ``world.scene`` against its table and obstacles.

    Raises:
        InputError: the object's centre is not above the table top; it reaches below the top or
            penetrates an obstacle by more than :data:`MAX_PENETRATION_M`; or it rests on neither (a gap over
            :data:`MAX_SUPPORT_GAP_M`).
    """
    scene = world.scene
    path = scene.path
    lo, hi = (np.asarray(v) for v in pb.getAABB(world.object_id, physicsClientId=world.client))
    centre_xy = (lo[:2] + hi[:2]) / 2
    half = np.asarray(scene.table.size_m[:2]) / 2
    offset = np.abs(centre_xy - np.asarray(scene.table.center_xy_m))
    if np.any(offset > half):
        raise InputError(
            f"object: {scene.object.name} at x, y = {centre_xy.round(3).tolist()} m is off the table "
            f"(its top spans {half.round(3).tolist()} m about {list(scene.table.center_xy_m)})",
            path,
        )
    d_table = _distance(world, world.object_id, world.table_id)
    below = -_lowest_point_z(scene)  # how far the object's lowest point is below the table top z = 0
    if d_table < -MAX_PENETRATION_M or below > MAX_PENETRATION_M:
        raise InputError(
            f"object: {scene.object.name} is {max(-d_table, below) * 1e3:.0f} mm inside or under the table "
            "(its bottom should rest on the top, z = 0)",
            path,
        )
    gaps = [d_table]
    for ob, body in zip(scene.obstacles, world.obstacle_ids, strict=True):
        d = _distance(world, world.object_id, body)
        if d < -MAX_PENETRATION_M:
            raise InputError(f"obstacles: {ob.label} overlaps the object by {-d * 1e3:.0f} mm", path)
        gaps.append(d)
    if min(gaps) > MAX_SUPPORT_GAP_M:
        shown = "more than 0.5 m" if not np.isfinite(min(gaps)) else f"{min(gaps) * 1e3:.0f} mm"
        raise InputError(
            f"object: {scene.object.name} floats {shown} above the table and every obstacle "
            f"(expected to rest on one, within {MAX_SUPPORT_GAP_M * 1e3:.0f} mm)",
            path,
        )


def _lowest_point_z(scene) -> float:
    """The height [m] of the object's lowest point in the world: its collision pieces' lowest vertex, less
    the convex margin they were inset by. Exact for any orientation, where pybullet's bounding box of a
    rotated hull is the rotated box of its local one (a can rolled 36 deg about its axis read 14 mm low)."""
    T = scene.T_world_object
    return float((_collision_vertices(scene.object.name) @ T[2, :3] + T[2, 3]).min()) - _CONVEX_MARGIN_M


@cache
def _collision_vertices(name: str) -> np.ndarray:
    """(n, 3) the vertices of an object's collision pieces [m], object frame."""
    return np.asarray(trimesh.load(assets.object_collision_mesh(name), force="mesh").vertices, dtype=float)
