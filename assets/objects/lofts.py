"""Watertight lofts and their exact convex pieces: the shapes of the Table I objects, built by
``assets/objects/build_objects.py`` (its docstring says how a loft and its pieces are made).

Lengths in metres; a contour is an (N, 2) array, closed and counter-clockwise seen from +z; a mesh is an
``open3d.geometry.TriangleMesh``; a convex piece is the (M, 3) array of its vertices.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.spatial import ConvexHull

N_AROUND = 64  # points per contour (a multiple of 8 so that square corners are exact)


# ----------------------------------------------------------------------------------------------------
# contours (closed, counter-clockwise seen from +z, N points)
def circle(r: float, n: int = N_AROUND) -> np.ndarray:
    a = np.arange(n) * 2 * np.pi / n
    return np.stack([r * np.cos(a), r * np.sin(a)], -1)


def rounded_rect(half_x: float, half_y: float, corner_r: float, n: int = N_AROUND) -> np.ndarray:
    """A rounded rectangle sampled at ``n`` points, ``n/4`` per corner arc (straight sides in between)."""
    k = n // 4
    out = []
    centres = [
        (half_x - corner_r, half_y - corner_r),
        (-half_x + corner_r, half_y - corner_r),
        (-half_x + corner_r, -half_y + corner_r),
        (half_x - corner_r, -half_y + corner_r),
    ]
    for i, (cx, cy) in enumerate(centres):
        a = i * np.pi / 2 + np.arange(k) * (np.pi / 2) / (k - 1)
        out.append(np.stack([cx + corner_r * np.cos(a), cy + corner_r * np.sin(a)], -1))
    return np.concatenate(out)


def square_by_rays(half: float, n: int = N_AROUND) -> np.ndarray:
    """A square of half side ``half`` sampled where rays at the angles of :func:`circle` hit it."""
    a = np.arange(n) * 2 * np.pi / n
    d = np.stack([np.cos(a), np.sin(a)], -1)
    return d * (half / np.max(np.abs(d), axis=1))[:, None]


# ----------------------------------------------------------------------------------------------------
def loft(rings: list[tuple[np.ndarray | None, float]], closed_loop: bool = False):
    """Join contours into a closed triangle mesh.

    Args:
        rings: ``(contour (N, 2) or None, z)`` from one end of the profile to the other; ``None`` is a pole
            (the point (0, 0, z)), allowed only first and last.
        closed_loop: join the last ring back to the first (a genus-1 surface, no poles).

    Returns:
        An Open3D mesh with outward normals (positive signed volume).
    """
    verts, index = [], []
    for contour, z in rings:
        start = sum(len(v) for v in verts)
        if contour is None:
            verts.append(np.array([[0.0, 0.0, z]]))
            index.append([start])
        else:
            verts.append(np.column_stack([contour, np.full(len(contour), z)]))
            index.append(list(range(start, start + len(contour))))
    tris = []
    pairs = list(zip(index[:-1], index[1:], strict=True))
    if closed_loop:
        pairs.append((index[-1], index[0]))
    for a, b in pairs:
        if len(a) == 1:
            n = len(b)
            tris += [[a[0], b[(i + 1) % n], b[i]] for i in range(n)]
        elif len(b) == 1:
            n = len(a)
            tris += [[a[i], a[(i + 1) % n], b[0]] for i in range(n)]
        else:
            n = len(a)
            for i in range(n):
                j = (i + 1) % n
                tris += [[a[i], a[j], b[j]], [a[i], b[j], b[i]]]
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.concatenate(verts)), o3d.utility.Vector3iVector(np.array(tris))
    )
    if volume_properties(np.asarray(mesh.vertices), np.asarray(mesh.triangles))[0] < 0:
        mesh.triangles = o3d.utility.Vector3iVector(np.asarray(mesh.triangles)[:, ::-1].copy())
    return mesh


def stack_pieces(rings: list[tuple[np.ndarray | None, float]], rel_tol: float = 1e-4) -> list[np.ndarray]:
    """Convex pieces of a solid loft of convex contours with non-decreasing z (:func:`loft` without
    ``closed_loop``); a pole is the point on the axis. The convex hull of each pair of consecutive rings
    at different heights is a frustum-like slab, and their union the solid; consecutive slabs are merged
    into one piece while the hull of the merged rings adds no volume (``rel_tol``), so a convex solid
    (a can, a box) is one piece and a non-convex one (the jar's groove, the bottle's neck) a few.

    Returns:
        The points (K, 3) of each piece (its convex hull is the piece)."""
    pts = [
        np.array([[0.0, 0.0, z]]) if c is None else np.column_stack([c, np.full(len(c), z)]) for c, z in rings
    ]
    zs = [z for _, z in rings]
    if any(b < a for a, b in zip(zs[:-1], zs[1:], strict=True)):
        raise ValueError("stack_pieces: ring heights must not decrease")
    slabs = [
        (i, ConvexHull(np.vstack(pts[i : i + 2])).volume) for i in range(len(pts) - 1) if zs[i + 1] > zs[i]
    ]
    pieces, start, volume = [], slabs[0][0], slabs[0][1]
    for i, v in slabs[1:]:
        merged = ConvexHull(np.vstack(pts[start : i + 2])).volume
        if merged <= (volume + v) * (1 + rel_tol):
            volume += v
            continue
        pieces.append(np.vstack(pts[start : i + 1]))
        start, volume = i, v
    pieces.append(np.vstack(pts[start : slabs[-1][0] + 2]))
    return pieces


def swept_profile_pieces(profile: list[tuple[float, float]], n: int = N_AROUND) -> list[np.ndarray]:
    """Convex pieces of a convex (radius, z) polygon revolved about z: one per angular segment of
    :func:`circle`, the profile's points at the segment's two angles (the hull is exact for the polygonal
    revolution, whose surface between two angles is the chord)."""
    r = np.array([p[0] for p in profile])
    z = np.array([p[1] for p in profile])
    a = np.arange(n + 1) * 2 * np.pi / n
    return [
        np.vstack([np.column_stack([r * np.cos(t), r * np.sin(t), z]) for t in (a[j], a[j + 1])])
        for j in range(n)
    ]


def tube_along(
    path: np.ndarray, radius: float, n: int = 24
) -> tuple[o3d.geometry.TriangleMesh, list[np.ndarray]]:
    """A tube of circular section swept along ``path`` (M, 3) in the xz-plane, capped by two fans.

    Returns:
        The mesh and its convex pieces (the points of each pair of consecutive rings)."""
    t = np.gradient(path, axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    y = np.array([0.0, 1.0, 0.0])
    a = np.arange(n) * 2 * np.pi / n
    rings = []
    for p, ti in zip(path, t, strict=True):
        u = np.cross(ti, y)
        rings.append(p + radius * (np.cos(a)[:, None] * u + np.sin(a)[:, None] * y))
    verts = [path[0][None]] + rings + [path[-1][None]]
    v = np.concatenate(verts)
    m = len(rings)
    tris = [[0, 1 + (i + 1) % n, 1 + i] for i in range(n)]
    for k in range(m - 1):
        s, e = 1 + k * n, 1 + (k + 1) * n
        for i in range(n):
            j = (i + 1) % n
            tris += [[s + i, s + j, e + j], [s + i, e + j, e + i]]
    last, end = 1 + (m - 1) * n, len(v) - 1
    tris += [[last + i, last + (i + 1) % n, end] for i in range(n)]
    mesh = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(v), o3d.utility.Vector3iVector(np.array(tris))
    )
    if volume_properties(v, np.array(tris))[0] < 0:
        mesh.triangles = o3d.utility.Vector3iVector(np.array(tris)[:, ::-1].copy())
    return mesh, [np.vstack([a, b]) for a, b in zip(rings[:-1], rings[1:], strict=True)]


def volume_properties(vertices: np.ndarray, triangles: np.ndarray) -> tuple[float, np.ndarray]:
    """Signed volume (m^3) and volume centroid (3,) of a closed mesh, by tetrahedra from the origin."""
    a, b, c = (vertices[triangles[:, i]] for i in range(3))
    vol = np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0
    total = float(vol.sum())
    centroid = (vol[:, None] * (a + b + c)).sum(0) / (4.0 * total) if total != 0 else np.zeros(3)
    return total, centroid


# ----------------------------------------------------------------------------------------------------
def rounded_box(size_x: float, size_y: float, height: float, corner_r: float, edge_r: float):
    """A box with vertical edges rounded by ``corner_r`` and top/bottom edges by ``edge_r`` (< corner_r)."""
    rings = [(None, 0.0)]
    arc = np.linspace(0, np.pi / 2, 6)
    for a in arc:  # bottom edge: inset edge_r (1 - sin) at height edge_r (1 - cos)
        d = edge_r * (1 - np.sin(a))
        rings.append((rounded_rect(size_x / 2 - d, size_y / 2 - d, corner_r - d), edge_r * (1 - np.cos(a))))
    for a in arc[::-1]:
        d = edge_r * (1 - np.sin(a))
        contour = rounded_rect(size_x / 2 - d, size_y / 2 - d, corner_r - d)
        rings.append((contour, height - edge_r * (1 - np.cos(a))))
    rings.append((None, height))
    return loft(rings), stack_pieces(rings)


def lathe(profile: list[tuple[float, float]]):
    """Revolve a profile of (radius, z) about z; radius 0 at the ends makes poles.

    Returns:
        The mesh and, for a profile with non-decreasing z (a solid of revolution), its convex pieces
        (:func:`stack_pieces`); ``None`` for other profiles, which need their own decomposition."""
    rings = [(None if r == 0 else circle(r), z) for r, z in profile]
    zs = [z for _, z in profile]
    solid = all(b >= a for a, b in zip(zs[:-1], zs[1:], strict=True))
    return loft(rings), (stack_pieces(rings) if solid else None)


def mug(outer_r: float, height: float, wall: float, bottom: float, handle_r: float, tube_r: float):
    """A cup: thick wall, open top with a rounded rim, and a half-ring handle 1 mm off the wall.

    Returns:
        The mesh and its convex pieces: the solid bottom (a stack), the wall (its convex profile: outer
        side, rim, inner side) and the inner fillet swept over each angular segment, the handle's slabs."""
    rim = [
        (outer_r - wall / 2 + wall / 2 * np.cos(a), height - wall / 2 + wall / 2 * np.sin(a))
        for a in np.linspace(0, np.pi, 7)
    ]
    body, _ = lathe(
        [
            (0, 0.0),
            (outer_r - 0.004, 0.0),
            (outer_r - 0.001, 0.0006),
            (outer_r, 0.004),
            *rim,
            (outer_r - wall, bottom + 0.004),
            (outer_r - wall - 0.004, bottom),
            (0, bottom),
        ]
    )
    foot = [(None, 0.0), (circle(outer_r - 0.004), 0.0), (circle(outer_r - 0.001), 0.0006)]
    foot += [(circle(outer_r), 0.004), (circle(outer_r), bottom)]
    pieces = stack_pieces(foot)
    pieces += swept_profile_pieces([(outer_r, bottom), *rim, (outer_r - wall, bottom)])
    pieces += swept_profile_pieces([(outer_r - wall, bottom), (outer_r - wall, bottom + 0.004),
                                    (outer_r - wall - 0.004, bottom)])  # fmt: skip
    gap = 0.001
    a = np.linspace(-np.pi / 2, np.pi / 2, 25)
    zc = 0.55 * height
    # the tube ends are discs in the plane x = outer_r + gap, so they stay gap off the wall everywhere
    path = np.stack([outer_r + gap + handle_r * np.cos(a), np.zeros_like(a), zc + handle_r * np.sin(a)], -1)
    handle, handle_pieces = tube_along(path, tube_r)
    return body + handle, pieces + handle_pieces


def block_with_hole(side: float, height: float, hole_r: float):
    """A square block with a cylindrical through hole along z (a genus-1 loft, no poles).

    Returns:
        The mesh and its convex pieces: per angular segment, the prism between the hole's chord and the
        square's (points on the same two rays bound a convex quadrilateral)."""
    sq, ci = square_by_rays(side / 2), circle(hole_r)
    n = len(sq)
    pieces = []
    for j in range(n):
        quad = np.array([sq[j], sq[(j + 1) % n], ci[(j + 1) % n], ci[j]])
        pieces.append(np.vstack([np.column_stack([quad, np.full(4, z)]) for z in (0.0, height)]))
    return loft([(sq, 0.0), (sq, height), (ci, height), (ci, 0.0)], closed_loop=True), pieces
