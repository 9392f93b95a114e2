"""Configuration and edge validity for the planners, on top of a :class:`planning.world.World`.

``is_free(q)`` asks the world (every link of the hand against the table, the target object and the
obstacles, and the hand against itself). ``is_edge_free(q_a, q_b)`` checks the straight edge (linear in
position and joints, slerp in orientation) at a fixed resolution: consecutive checked configurations
are at most ``position_resolution_m`` of wrist travel, ``rotation_resolution_rad`` of wrist rotation and
``joint_resolution_rad`` of any joint apart. The defaults (5 mm, 2 deg, 4 deg) keep a fingertip's
displacement between checks below about 8 mm for the SAH's ~250 mm wrist-to-fingertip lever, smaller
than its 13 mm fingertip radius. ``q_a`` itself is assumed free (it is a tree node).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from assets.q_layout import JOINTS, POS

from .config_space import HandConfigSpace

__all__ = ["CollisionChecker"]

#: the interpolation of the planner's edges (linear, slerp in orientation), also used to check them
_SPACE = HandConfigSpace()


class CollisionChecker:
    """Counts and answers validity queries for one world.

    Args:
        world: a :class:`planning.world.World` (anything with ``is_free(q) -> bool``).
        position_resolution_m, rotation_resolution_rad, joint_resolution_rad: the edge resolution.
    """

    def __init__(
        self,
        world,
        position_resolution_m: float = 0.005,
        rotation_resolution_rad: float = np.deg2rad(2.0),
        joint_resolution_rad: float = np.deg2rad(4.0),
    ):
        self.world = world
        self.position_resolution_m = position_resolution_m
        self.rotation_resolution_rad = rotation_resolution_rad
        self.joint_resolution_rad = joint_resolution_rad
        self.checks = 0

    def is_free(self, q: np.ndarray) -> bool:
        """Whether the hand at ``q`` (19,) collides with nothing, itself included."""
        self.checks += 1
        return bool(self.world.is_free(q))

    def edge_points(self, q_a: np.ndarray, q_b: np.ndarray) -> np.ndarray:
        """The configurations checked along the edge, excluding ``q_a`` and including ``q_b``: (n, 19)."""
        n, point = self._edge(q_a, q_b)
        return np.array([point(i) for i in range(1, n + 1)])

    def _edge(self, q_a: np.ndarray, q_b: np.ndarray) -> tuple[int, Callable[[int], np.ndarray]]:
        """The number ``n`` of configurations checked along the edge and ``point(i)``, the i-th of them
        (1..n, the n-th at ``q_b``)."""
        q_a = np.asarray(q_a, dtype=float)
        q_b = np.asarray(q_b, dtype=float)
        dp = q_b[POS] - q_a[POS]
        edge = _SPACE.edge(q_a, q_b)
        n = math.ceil(
            max(
                math.sqrt(float(dp @ dp)) / self.position_resolution_m,
                edge.angle() / self.rotation_resolution_rad,
                float(np.max(np.abs(q_b[JOINTS] - q_a[JOINTS]))) / self.joint_resolution_rad,
                1.0,
            )
        )
        if n <= 8:  # most planner steps: 2-3 points, cheaper one by one in plain floats
            return n, lambda i: edge.at(i / n)
        many = _SPACE.interpolate_many(q_a, q_b, np.arange(1, n + 1) / n)
        return n, lambda i: many[i - 1]

    def is_edge_free(self, q_a: np.ndarray, q_b: np.ndarray) -> bool:
        """Whether every configuration along the edge from ``q_a`` to ``q_b`` is free.

        The far end is checked first: an edge from a free node is most often blocked there, so a blocked
        edge usually costs one query instead of all of its points."""
        n, point = self._edge(q_a, q_b)
        return self.is_free(point(n)) and all(self.is_free(point(i)) for i in range(1, n))
