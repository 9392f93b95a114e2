"""Signed distance fields of rigid shapes (negative inside), for many points at once, with their gradients.

The smooth scene model of the variation model's clearance factors, as GPMP2's ``SignedDistanceField``:

* :class:`BoxField`, :class:`CylinderField`, :class:`SphereField`: closed forms, exact;
* :class:`GridField`: samples on a regular grid in a local frame (e.g. an object's, built from its mesh
  with Open3D's ``RaycastingScene.compute_signed_distance``), trilinear interpolation and its analytic
  gradient, posed rigidly in the world.

Every field has ``distance(points_world (n, 3)) -> (d (n,) [m], grad (n, 3))``, the gradient w.r.t. the
point in the world frame (unit length for the closed forms away from their medial axes).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from assets.errors import InputError
from assets.io import atomic_write

__all__ = ["BoxField", "CylinderField", "SphereField", "GridField", "min_distance"]


def _pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=float)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise InputError(f"{name}: expected a finite (4, 4) pose, found shape {T.shape}")
    return T


def _positive(value: float, name: str) -> float:
    value = float(value)
    if not (np.isfinite(value) and value > 0):
        raise InputError(f"{name}: expected a finite number > 0, found {value!r}")
    return value


class BoxField:
    """A solid box of half extents ``half_extents_m`` (3,) [m], centred at the origin of ``T_world_box``."""

    lipschitz = 1.0  #: |d(x) - d(y)| <= lipschitz |x - y|

    def __init__(self, half_extents_m: np.ndarray, T_world_box: np.ndarray):
        self.half_extents_m = np.array([_positive(h, "half_extents_m") for h in np.ravel(half_extents_m)])
        if self.half_extents_m.shape != (3,):
            raise InputError(f"half_extents_m: expected 3 numbers, found {self.half_extents_m.size}")
        self.T_world_box = _pose(T_world_box, "T_world_box")

    def distance(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = self.T_world_box[:3, :3], self.T_world_box[:3, 3]
        p = (np.asarray(points_world, dtype=float) - t) @ R
        q = np.abs(p) - self.half_extents_m
        outside = np.maximum(q, 0.0)
        norm = np.linalg.norm(outside, axis=-1)
        inside = np.minimum(q.max(axis=-1), 0.0)
        d = norm + inside
        sign = np.where(p < 0, -1.0, 1.0)
        g_out = outside / np.maximum(norm, 1e-300)[:, None]
        g_in = np.zeros_like(p)
        g_in[np.arange(len(p)), np.argmax(q, axis=-1)] = 1.0
        g = np.where((norm > 0)[:, None], g_out, g_in) * sign
        return d, g @ R.T


class CylinderField:
    """A solid cylinder of radius ``radius_m`` and half height ``half_height_m`` [m] along the z axis of
    ``T_world_cylinder``, centred at its origin (pybullet's ``GEOM_CYLINDER``)."""

    lipschitz = 1.0  #: |d(x) - d(y)| <= lipschitz |x - y|

    def __init__(self, radius_m: float, half_height_m: float, T_world_cylinder: np.ndarray):
        self.radius_m = _positive(radius_m, "radius_m")
        self.half_height_m = _positive(half_height_m, "half_height_m")
        self.T_world_cylinder = _pose(T_world_cylinder, "T_world_cylinder")

    def distance(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = self.T_world_cylinder[:3, :3], self.T_world_cylinder[:3, 3]
        p = (np.asarray(points_world, dtype=float) - t) @ R
        rho = np.hypot(p[:, 0], p[:, 1])
        radial = np.where(rho > 0, 1.0, 0.0)[:, None] * p[:, :2] / np.maximum(rho, 1e-300)[:, None]
        radial[rho == 0] = [1.0, 0.0]  # on the axis: any radial direction
        # the 2-D box (radius, half height) in (rho, |z|)
        q = np.stack([rho - self.radius_m, np.abs(p[:, 2]) - self.half_height_m], axis=-1)
        outside = np.maximum(q, 0.0)
        norm = np.linalg.norm(outside, axis=-1)
        d = norm + np.minimum(q.max(axis=-1), 0.0)
        g2 = np.where(
            (norm > 0)[:, None],
            outside / np.maximum(norm, 1e-300)[:, None],
            np.eye(2)[np.argmax(q, axis=-1)],
        )
        sz = np.where(p[:, 2] < 0, -1.0, 1.0)
        g = np.column_stack([g2[:, 0:1] * radial, g2[:, 1] * sz])
        return d, g @ R.T


class SphereField:
    """A solid ball of radius ``radius_m`` [m] centred at ``center_world_m`` (3,)."""

    lipschitz = 1.0  #: |d(x) - d(y)| <= lipschitz |x - y|

    def __init__(self, radius_m: float, center_world_m: np.ndarray):
        self.radius_m = _positive(radius_m, "radius_m")
        self.center_world_m = np.asarray(center_world_m, dtype=float).reshape(3)

    def distance(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        v = np.asarray(points_world, dtype=float) - self.center_world_m
        r = np.linalg.norm(v, axis=-1)
        g = np.where((r > 0)[:, None], v / np.maximum(r, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
        return r - self.radius_m, g


class GridField:
    """Samples ``values`` (nx, ny, nz) [m] at the nodes ``origin_m + cell_m * (i, j, k)`` of a grid in its
    own frame, posed by ``T_world_grid`` (rigid); trilinear interpolation and its gradient.

    Outside the grid's box a point gets the value at its nearest point of the box plus the distance to the
    box, and that point's gradient plus the unit vector away from the box: a continuous continuation that
    only matters for grids too small for their use (build them with enough padding).
    """

    #: a bound of |d(x) - d(y)| / |x - y| for samples of a distance field: sqrt(3) for the trilinear
    #: interpolation (each partial derivative is an interpolated finite difference, <= 1), plus 1 outside
    lipschitz = math.sqrt(3.0) + 1.0

    def __init__(
        self, origin_m: np.ndarray, cell_m: float, values: np.ndarray, T_world_grid: np.ndarray | None = None
    ):
        self.origin_m = np.asarray(origin_m, dtype=float).reshape(3)
        self.cell_m = _positive(cell_m, "cell_m")
        self.values = np.asarray(values)
        if self.values.ndim != 3 or min(self.values.shape) < 2 or not np.all(np.isfinite(self.values)):
            raise InputError(
                f"values: expected finite (nx, ny, nz) samples, >= 2 per axis, found {self.values.shape}"
            )
        self.T_world_grid = np.eye(4) if T_world_grid is None else _pose(T_world_grid, "T_world_grid")
        self._upper = self.origin_m + self.cell_m * (np.array(self.values.shape) - 1)
        self._flat = self.values.reshape(-1).astype(float)
        _, ny, nz = self.values.shape
        self._corner_offsets = np.array(
            [(a * ny + b) * nz + e for a in (0, 1) for b in (0, 1) for e in (0, 1)]
        )

    @classmethod
    def from_function(
        cls,
        fn: Callable[[np.ndarray], np.ndarray],
        lower_m: Sequence[float],
        upper_m: Sequence[float],
        cell_m: float,
        T_world_grid: np.ndarray | None = None,
    ) -> GridField:
        """Sample ``fn(points_grid (n, 3)) -> (n,)`` on nodes from ``lower_m`` covering ``upper_m``."""
        lower = np.asarray(lower_m, dtype=float)
        shape = np.maximum(
            2, np.ceil((np.asarray(upper_m, dtype=float) - lower) / cell_m - 1e-9).astype(int) + 1
        )
        axes = [lower[i] + cell_m * np.arange(shape[i]) for i in range(3)]
        nodes = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        values = np.asarray(fn(nodes), dtype=float).reshape(tuple(shape))
        return cls(lower, cell_m, values, T_world_grid)

    @classmethod
    def from_mesh(
        cls,
        vertices: np.ndarray,
        triangles: np.ndarray,
        cell_m: float,
        padding_m: float,
        T_world_grid: np.ndarray | None = None,
    ) -> GridField:
        """The field of a watertight triangle mesh (vertices (V, 3) [m] and triangles (F, 3) in the grid
        frame) on its bounding box padded by ``padding_m``, by Open3D's ``RaycastingScene`` (the sign from
        its inside test, which needs a closed mesh; float32 precision)."""
        import open3d as o3d  # imported late: Open3D is slow to import

        vertices = np.asarray(vertices, dtype=np.float32)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(
            o3d.core.Tensor(vertices), o3d.core.Tensor(np.asarray(triangles, dtype=np.uint32))
        )

        def sdf(points: np.ndarray) -> np.ndarray:
            query = o3d.core.Tensor(points.astype(np.float32))
            return scene.compute_signed_distance(query).numpy().astype(float)

        lo, hi = vertices.min(axis=0) - padding_m, vertices.max(axis=0) + padding_m
        return cls.from_function(sdf, lo, hi, cell_m, T_world_grid)

    def with_pose(self, T_world_grid: np.ndarray) -> GridField:
        """The same samples posed by ``T_world_grid`` (shares ``values``)."""
        return GridField(self.origin_m, self.cell_m, self.values, T_world_grid)

    def distance(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R, t = self.T_world_grid[:3, :3], self.T_world_grid[:3, 3]
        p = (np.asarray(points_world, dtype=float) - t) @ R
        clamped = np.clip(p, self.origin_m, self._upper)
        s = (clamped - self.origin_m) / self.cell_m
        i = np.minimum(s.astype(int), np.array(self.values.shape) - 2)
        f = s - i
        nx, ny, nz = self.values.shape
        flat = (i[:, 0] * ny + i[:, 1]) * nz + i[:, 2]
        corners = self._flat[flat[:, None] + self._corner_offsets]  # (n, 8), corner (a, b, e) at 4a + 2b + e
        c = [[[corners[:, 4 * a + 2 * b + e] for e in (0, 1)] for b in (0, 1)] for a in (0, 1)]
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]
        # interpolate along z, then y, then x; the gradient from the same partial sums
        cz = [[c[a][b][0] + fz * (c[a][b][1] - c[a][b][0]) for b in (0, 1)] for a in (0, 1)]
        dz = [[c[a][b][1] - c[a][b][0] for b in (0, 1)] for a in (0, 1)]
        cy = [cz[a][0] + fy * (cz[a][1] - cz[a][0]) for a in (0, 1)]
        dy = [cz[a][1] - cz[a][0] for a in (0, 1)]
        dzy = [dz[a][0] + fy * (dz[a][1] - dz[a][0]) for a in (0, 1)]
        d = cy[0] + fx * (cy[1] - cy[0])
        g = (
            np.stack([cy[1] - cy[0], dy[0] + fx * (dy[1] - dy[0]), dzy[0] + fx * (dzy[1] - dzy[0])], axis=-1)
            / self.cell_m
        )
        out = p - clamped
        gap = np.linalg.norm(out, axis=-1)
        away = gap > 0
        if np.any(away):
            d = d + gap
            g[away] += out[away] / gap[away, None]
        return d, g @ R.T

    def save(self, path: str | os.PathLike) -> Path:
        """Write the field as ``.npz`` (atomically, :func:`assets.io.atomic_write`)."""
        return atomic_write(
            path,
            lambda f: np.savez(
                f,
                origin_m=self.origin_m,
                cell_m=self.cell_m,
                values=self.values,
                T_world_grid=self.T_world_grid,
            ),
        )

    @classmethod
    def load(cls, path: str | os.PathLike) -> GridField:
        """Read a field written by :meth:`save`.

        Raises:
            InputError: not such a file.
        """
        try:
            with np.load(path) as z:
                return cls(z["origin_m"], float(z["cell_m"]), z["values"], z["T_world_grid"])
        except (OSError, KeyError, ValueError) as exc:
            raise InputError(f"not a distance field file ({exc})", path) from None


def min_distance(fields: Sequence, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The pointwise minimum distance over ``fields`` (n,) and the minimizing field's gradient (n, 3);
    +inf and zero gradients for no fields."""
    points_world = np.asarray(points_world, dtype=float)
    d = np.full(len(points_world), np.inf)
    g = np.zeros((len(points_world), 3))
    for field in fields:
        df, gf = field.distance(points_world)
        closer = df < d
        d = np.where(closer, df, d)
        g = np.where(closer[:, None], gf, g)
    return d, g
