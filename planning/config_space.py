"""Metrics and interpolation on configuration spaces, vectorized for nearest-neighbour queries.

The planner sees a configuration space only through this small interface, so the same RRT code runs on
the 19-D hand space and on a toy 2-D space in the tests:

* ``features(q (N, d)) -> (N, F)``: a representation in which :meth:`distance_to` is cheap;
* ``distance_to(features (N, F), q (d,)) -> (N,)`` and ``distance(q_a, q_b) -> float``;
* ``nearest(features (N, F), q (d,)) -> int``: the index of the least :meth:`distance_to` (its first on
  ties);
* ``interpolate(q_a, q_b, s) -> q``, ``s`` in [0, 1];
* ``steer(q_a, q_b, step) -> (q, reached)``: ``q_b`` if it is within ``step``, else the configuration
  ``step`` along the way.

Distances are dimensionless: one unit is one "step" of the planner.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from assets.q_layout import JOINTS, POS, ROT
from assets.se3 import quat_of_rotvec, slerp_rotvec

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

    def nearest(self, features: np.ndarray, q: np.ndarray) -> int:
        return int(np.argmin(self.distance_to(features, q)))

    def steer(self, q_a: np.ndarray, q_b: np.ndarray, step: float) -> tuple[np.ndarray, bool]:
        d = self.distance(q_a, q_b)
        return (q_b, True) if d <= step else (self.interpolate(q_a, q_b, step / d), False)

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

    The planner calls :meth:`distance` and :meth:`interpolate` on single configurations ~10^5 times per
    query, so they work on plain floats (numpy's per-call overhead on 3-vectors made them 100-140 us,
    more than a pybullet collision query); :meth:`distance_to` is the vectorized nearest-neighbour scan.
    Features are ``[p / position_step_m, joints / joint_step_rad, unit quaternion [x, y, z, w], |lin|^2]``
    (the last: the squared norm of the first 16).
    """

    position_step_m: float = 0.01
    rotation_step_rad: float = np.deg2rad(5.0)
    joint_step_rad: float = np.deg2rad(10.0)

    def features(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=float)
        if q.ndim == 1:  # one node, as the planner adds them: without the per-row list
            lin = np.concatenate([q[POS] / self.position_step_m, q[JOINTS] / self.joint_step_rad])
            out = np.empty((1, 21))
            out[0, :16], out[0, 16:20], out[0, 20] = lin, quat_of_rotvec(*q[ROT]), (lin * lin).sum()
            return out
        q = np.atleast_2d(q)
        quat = np.array([quat_of_rotvec(*r) for r in q[:, ROT].tolist()]).reshape(-1, 4)
        lin = np.concatenate([q[:, POS] / self.position_step_m, q[:, JOINTS] / self.joint_step_rad], axis=1)
        return np.concatenate([lin, quat, (lin * lin).sum(axis=1, keepdims=True)], axis=1)

    def distance_to(self, features: np.ndarray, q: np.ndarray) -> np.ndarray:
        return self._distance_to(features, self.features(q)[0])

    def _distance_to(self, features: np.ndarray, f: np.ndarray) -> np.ndarray:
        """The distances (N,) from the nodes' ``features`` (N, F) to the features ``f`` (F,) of one q."""
        # where the cancellation in _lin_sq could show, the difference
        lin_sq = _lin_sq(features, f)
        near = np.flatnonzero(lin_sq < 1e-6 * (features[:, -1] + f[-1] + 1.0))
        if near.size:
            diff = features[near, :16] - f[:16]
            lin_sq[near] = np.einsum("ij,ij->i", diff, diff)
        signed_dot = features[:, 16:20] @ f[16:20]
        dot = np.abs(signed_dot)
        angle = 2.0 * np.arccos(np.minimum(dot, 1.0))
        # acos loses digits near dot = 1 (angles below ~3 mrad): there take 4 atan2(|a - b|, |a + b|)
        near = np.flatnonzero(dot > 1.0 - 1e-6)
        if near.size:
            qa = features[near, 16:20] * np.where(signed_dot[near] < 0, -1.0, 1.0)[:, None]
            angle[near] = 4.0 * np.arctan2(
                np.linalg.norm(qa - f[16:20], axis=1), np.linalg.norm(qa + f[16:20], axis=1)
            )
        angle /= self.rotation_step_rad
        return np.sqrt(np.maximum(lin_sq, 0.0) + angle * angle)

    def nearest(self, features: np.ndarray, q: np.ndarray) -> int:
        """The index of the node nearest to ``q``, exactly :meth:`distance_to`'s argmin, by a bound.

        With ``c = |qa . qb|`` the wrist angle is ``2 acos(c) >= sqrt(8 (1 - c))`` (as ``1 - cos x <= x^2 /
        2``), so ``lin^2 + 8 (1 - c) / rotation_step^2`` bounds every squared distance from below without
        an arccos. The exact distance is computed only for the nodes whose bound is below the exact
        distance of the bound's own argmin (a few in a grown tree).
        """
        f = self.features(q)[0]
        cos_half = np.abs(features[:, 16:20] @ f[16:20])
        bound = _lin_sq(features, f) + (8.0 / self.rotation_step_rad**2) * (1.0 - cos_half)
        i0 = int(np.argmin(bound))
        d0 = self._distance_to(features[i0 : i0 + 1], f)[0]
        # the bound's rounding (|a|^2 + |b|^2 - 2 a.b, ~1e-16 of |a|^2 ~ 1e4) is far inside the slack
        candidates = np.flatnonzero(bound <= d0 * d0 + 1e-9 * (1.0 + d0 * d0 + f[-1]))
        return int(candidates[np.argmin(self._distance_to(features[candidates], f))])

    def distance(self, q_a: np.ndarray, q_b: np.ndarray) -> float:
        return self._length(_Geodesic(q_a, q_b))

    def _length(self, edge: _Geodesic) -> float:
        """The edge's length in planner steps (the metric of the class docstring)."""
        dp, dj = edge.delta[POS], edge.delta[JOINTS]
        angle = edge.angle() / self.rotation_step_rad
        return math.sqrt(
            float(dp @ dp) / self.position_step_m**2 + float(dj @ dj) / self.joint_step_rad**2 + angle * angle
        )

    def angle(self, q_a: np.ndarray, q_b: np.ndarray) -> float:
        """The geodesic angle [rad] between the wrist orientations of ``q_a`` and ``q_b``."""
        return _Geodesic(q_a, q_b).angle()

    def steer(self, q_a: np.ndarray, q_b: np.ndarray, step: float) -> tuple[np.ndarray, bool]:
        """``(q_b, True)`` if ``q_b`` is within ``step`` of ``q_a``, else ``(the configuration step units
        along the edge, False)``: :meth:`distance` and :meth:`interpolate` on one :class:`_Geodesic`."""
        edge = _Geodesic(q_a, q_b)
        d = self._length(edge)
        return (q_b, True) if d <= step else (edge.at(step / d), False)

    def interpolate(self, q_a: np.ndarray, q_b: np.ndarray, s: float) -> np.ndarray:
        return _Geodesic(q_a, q_b).at(float(s))

    def edge(self, q_a: np.ndarray, q_b: np.ndarray) -> _Geodesic:
        """The edge from ``q_a`` to ``q_b``: its wrist angle and its points in plain floats, the two
        orientations converted once (a collision check takes several points of one edge)."""
        return _Geodesic(q_a, q_b)

    def interpolate_many(self, q_a: np.ndarray, q_b: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Configurations (n, 19) at fractions ``s`` (n,) of the way from ``q_a`` to ``q_b``."""
        q_a = np.asarray(q_a, dtype=float)
        q_b = np.asarray(q_b, dtype=float)
        s = np.asarray(s, dtype=float).reshape(-1)
        out = q_a + s[:, None] * (q_b - q_a)
        out[:, ROT] = slerp_rotvec(q_a[ROT], q_b[ROT], s)
        return out


def _lin_sq(features: np.ndarray, f: np.ndarray) -> np.ndarray:
    """|a - b|^2 (N,) over the scaled position and joints as |a|^2 + |b|^2 - 2 a.b: two matrix-vector
    products instead of an (N, 16) difference; it cancels where a and b nearly coincide."""
    return features[:, -1] + f[-1] - 2.0 * (features[:, :16] @ f[:16])


class _Geodesic:
    """The edge between two hand configurations (19,): linear in position and joints, a slerp of the wrist
    orientation; the two orientations' quaternions computed once, in plain floats."""

    def __init__(self, q_a: np.ndarray, q_b: np.ndarray):
        self.q_a = np.asarray(q_a, dtype=float)
        self.delta = np.asarray(q_b, dtype=float) - self.q_a
        self.qa = quat_of_rotvec(*self.q_a[ROT])
        self.qb = quat_of_rotvec(*q_b[ROT])
        self.dot = sum(x * y for x, y in zip(self.qa, self.qb, strict=True))

    def angle(self) -> float:
        """The geodesic angle [rad] between the two wrist orientations (4 atan2(|a - b|, |a + b|))."""
        sign = -1.0 if self.dot < 0 else 1.0
        qa, qb = self.qa, self.qb
        minus = math.sqrt(sum((x - sign * y) ** 2 for x, y in zip(qa, qb, strict=True)))
        plus = math.sqrt(sum((x + sign * y) ** 2 for x, y in zip(qa, qb, strict=True)))
        return 4.0 * math.atan2(minus, plus)

    def at(self, s: float) -> np.ndarray:
        """The configuration (19,) at the fraction ``s`` of the way."""
        out = self.q_a + s * self.delta
        qa, qb, dot = self.qa, self.qb, self.dot
        if dot < 0:
            qb, dot = tuple(-y for y in qb), -dot
        if dot > 1.0 - 1e-12:
            quat = [x + s * (y - x) for x, y in zip(qa, qb, strict=True)]
        else:
            omega = math.acos(min(dot, 1.0))
            wa, wb = math.sin((1.0 - s) * omega), math.sin(s * omega)
            quat = [wa * x + wb * y for x, y in zip(qa, qb, strict=True)]
        out[ROT] = _rotvec(*quat)
        return out


def _rotvec(x: float, y: float, z: float, w: float) -> tuple[float, float, float]:
    """The rotation vector [rad], angle in [0, pi], of a quaternion (normalised here), in plain floats."""
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if w < 0:
        norm = -norm
    x, y, z, w = x / norm, y / norm, z / norm, w / norm
    s = math.sqrt(x * x + y * y + z * z)
    k = 2.0 / max(w, 1e-300) if s < 1e-12 else 2.0 * math.atan2(s, w) / s
    return (k * x, k * y, k * z)
