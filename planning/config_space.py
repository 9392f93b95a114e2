"""Metrics and interpolation on configuration spaces, vectorized for nearest-neighbour queries.

The planner sees a configuration space only through this small interface, so the same RRT code runs on
the 19-D hand space and on a toy 2-D space in the tests:

* ``features(q (N, d)) -> (N, F)``: a representation in which :meth:`distance_to` is cheap;
* ``distance_to(features (N, F), q (d,)) -> (N,)`` and ``distance(q_a, q_b) -> float``;
* ``interpolate(q_a, q_b, s) -> q``, ``s`` in [0, 1].

Distances are dimensionless: one unit is one "step" of the planner.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from retarget.lie import quat_from_rotvec, slerp_rotvec

__all__ = ["EuclideanSpace", "HandConfigSpace"]


@dataclass(frozen=True)
class EuclideanSpace:
    """R^d with a per-coordinate scale: ``distance = |(q_a - q_b) / scale|``.

    Args:
        scale: (d,) the length of one unit along each coordinate.
    """

    scale: tuple[float, ...]

    def features(self, q: np.ndarray) -> np.ndarray:
        return np.atleast_2d(q) / np.asarray(self.scale)

    def distance_to(self, features: np.ndarray, q: np.ndarray) -> np.ndarray:
        return np.linalg.norm(features - self.features(q)[0], axis=1)

    def distance(self, q_a: np.ndarray, q_b: np.ndarray) -> float:
        return float(np.linalg.norm((np.asarray(q_a) - np.asarray(q_b)) / np.asarray(self.scale)))

    def interpolate(self, q_a: np.ndarray, q_b: np.ndarray, s: float) -> np.ndarray:
        return np.asarray(q_a) + s * (np.asarray(q_b) - np.asarray(q_a))


@dataclass(frozen=True)
class HandConfigSpace:
    """The 19-D hand configuration ``q = [p (m), rotation vector (rad), 13 joints (rad)]``.

    ``distance = sqrt((|dp| / position_step_m)^2 + (angle / rotation_step_rad)^2 + |dj / joint_step_rad|^2)``
    where ``angle`` is the geodesic angle between the two wrist orientations. One unit is one planner
    step: with the defaults 1 cm of wrist travel, 5 deg of wrist rotation or 10 deg of one joint.
    Interpolation is linear in position and joints and a slerp in orientation.
    """

    position_step_m: float = 0.01
    rotation_step_rad: float = np.deg2rad(5.0)
    joint_step_rad: float = np.deg2rad(10.0)

    def features(self, q: np.ndarray) -> np.ndarray:
        q = np.atleast_2d(q)
        quat = quat_from_rotvec(q[:, 3:6])
        return np.concatenate([q[:, :3] / self.position_step_m, quat, q[:, 6:] / self.joint_step_rad], axis=1)

    def distance_to(self, features: np.ndarray, q: np.ndarray) -> np.ndarray:
        f = self.features(q)[0]
        dp = features[:, :3] - f[:3]
        dj = features[:, 7:] - f[7:]
        # geodesic angle 4 atan2(|a - b|, |a + b|) on the hemisphere of a, accurate near 0 (unlike acos)
        qa = features[:, 3:7] * np.where(features[:, 3:7] @ f[3:7] < 0, -1.0, 1.0)[:, None]
        angle = 4.0 * np.arctan2(np.linalg.norm(qa - f[3:7], axis=1), np.linalg.norm(qa + f[3:7], axis=1))
        angle /= self.rotation_step_rad
        return np.sqrt(np.einsum("ij,ij->i", dp, dp) + angle * angle + np.einsum("ij,ij->i", dj, dj))

    def distance(self, q_a: np.ndarray, q_b: np.ndarray) -> float:
        return float(self.distance_to(self.features(q_a), q_b)[0])

    def interpolate(self, q_a: np.ndarray, q_b: np.ndarray, s: float) -> np.ndarray:
        q_a = np.asarray(q_a, dtype=float)
        q_b = np.asarray(q_b, dtype=float)
        out = q_a + s * (q_b - q_a)
        out[3:6] = slerp_rotvec(q_a[3:6], q_b[3:6], s)[0]
        return out
