"""Build the seven Table I objects (and the jam_hole block) as watertight triangle meshes.

Run from the repository root::

    .venv/bin/python assets/objects/build_objects.py

Every shape is a *loft*: a stack of closed horizontal contours with the same number of points, joined
ring to ring by triangle strips and closed by a pole vertex (a fan) at each end, or closed on itself
into a torus-like loop. A loft of a simple profile is a closed 2-manifold by construction (no boolean
operations), which Open3D confirms (``is_watertight``) before anything is written. Cylinders and cups
are lathe profiles (circular contours), the cans and boxes rounded-rectangle contours inset towards the
top and bottom edges, the mug handles a tube swept along a half circle, kept 1 mm off the cup wall so
that the union of the two closed components stays manifold.

Outputs per object ``assets/objects/<name>/``: ``<name>.obj`` (metres, object frame: origin at the
centre of the bottom face, +z up the object's axis), ``<name>.urdf`` (static, the mesh as visual and
concave collision) and ``object.yaml`` (dimensions, source, mass, material, friction, centre of mass,
max radius, grasp-type hint). The block with a cylindrical through hole of the jam_hole scene goes to
``assets/scenes/meshes/block_with_hole.obj``.
"""

from __future__ import annotations

import io
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import yaml

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))

from assets.io import atomic_write  # noqa: E402

N_AROUND = 64  # points per contour (a multiple of 8 so that square corners are exact)
RUBBER_MU = {"plastic": 0.6, "glass": 0.6, "metal": 0.6, "cardboard": 0.6}
"""Coulomb friction of the SAH's rubber fingertips: GraspIt!'s static table (src/world.cpp initCof,
``Cof[rubber][plastic|glass|metal|wood] = 1.0``) minus 0.4 as in the paper; cardboard as wood."""


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


def tube_along(path: np.ndarray, radius: float, n: int = 24) -> o3d.geometry.TriangleMesh:
    """A tube of circular section swept along ``path`` (M, 3) in the xz-plane, capped by two fans."""
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
    return mesh


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
    return loft(rings)


def lathe(profile: list[tuple[float, float]]):
    """Revolve a profile of (radius, z) about z; radius 0 at the ends makes poles."""
    return loft([(None if r == 0 else circle(r), z) for r, z in profile])


def mug(outer_r: float, height: float, wall: float, bottom: float, handle_r: float, tube_r: float):
    """A cup: thick wall, open top with a rounded rim, and a half-ring handle 1 mm off the wall."""
    rim = [
        (outer_r - wall / 2 + wall / 2 * np.cos(a), height - wall / 2 + wall / 2 * np.sin(a))
        for a in np.linspace(0, np.pi, 7)
    ]
    body = lathe(
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
    gap = 0.001
    a = np.linspace(-np.pi / 2, np.pi / 2, 25)
    zc = 0.55 * height
    # the tube ends are discs in the plane x = outer_r + gap, so they stay gap off the wall everywhere
    path = np.stack([outer_r + gap + handle_r * np.cos(a), np.zeros_like(a), zc + handle_r * np.sin(a)], -1)
    handle = tube_along(path, tube_r)
    return body + handle


def block_with_hole(side: float, height: float, hole_r: float):
    """A square block with a cylindrical through hole along z (a genus-1 loft, no poles)."""
    sq, ci = square_by_rays(side / 2), circle(hole_r)
    return loft([(sq, 0.0), (sq, height), (ci, height), (ci, 0.0)], closed_loop=True)


# ----------------------------------------------------------------------------------------------------
OBJECTS = {
    "ham": dict(
        build=lambda: rounded_box(0.100, 0.055, 0.080, corner_r=0.012, edge_r=0.004),
        source="rectangular ham tin, about 10 x 5.5 x 8 cm (issue 2; paper Fig. 6), 12 mm corner radius",
        mass_kg=0.34,
        material="metal",
        grasp_type="precision",
    ),
    "jam": dict(
        build=lambda: lathe(
            [
                (0, 0.0),
                (0.031, 0.0),
                (0.034, 0.003),
                (0.034, 0.066),
                (0.031, 0.072),
                (0.030, 0.074),
                (0.035, 0.075),
                (0.035, 0.088),
                (0.033, 0.090),
                (0, 0.090),
            ]
        ),
        source="jam jar about 7 cm diameter, 9 cm high with a 35 mm-radius metal lid (issue 2; Fig. 6)",
        mass_kg=0.45,
        material="glass",
        grasp_type="precision",
    ),
    "chips": dict(
        build=lambda: lathe(
            [(0, 0.0), (0.036, 0.0), (0.0375, 0.0015), (0.0375, 0.228), (0.0365, 0.230), (0, 0.230)]
        ),
        source="Pringles-like chips can, 7.5 cm diameter, 23 cm high (issue 2; Fig. 6)",
        mass_kg=0.20,
        material="cardboard",
        grasp_type="power",
    ),
    "salt": dict(
        build=lambda: rounded_box(0.090, 0.060, 0.140, corner_r=0.003, edge_r=0.002),
        source="salt carton about 9 x 6 x 14 cm (issue 2; Fig. 6)",
        mass_kg=0.55,
        material="cardboard",
        grasp_type="power",
    ),
    "small_cup": dict(
        build=lambda: mug(0.040, 0.090, wall=0.005, bottom=0.008, handle_r=0.025, tube_r=0.006),
        source="mug about 8 cm diameter, 9 cm high, handle 50 mm tall (issue 2; Fig. 6)",
        mass_kg=0.30,
        material="glass",
        grasp_type="precision",
    ),
    "big_cup": dict(
        build=lambda: mug(0.050, 0.120, wall=0.006, bottom=0.010, handle_r=0.032, tube_r=0.007),
        source="mug about 10 cm diameter, 12 cm high (issue 2; the paper's generalization test)",
        mass_kg=0.40,
        material="glass",
        grasp_type="precision",
    ),
    "bottle": dict(
        build=lambda: lathe(
            [
                (0, 0.0),
                (0.030, 0.0),
                (0.0325, 0.003),
                (0.0325, 0.120),
                (0.028, 0.145),
                (0.016, 0.165),
                (0.013, 0.175),
                (0.015, 0.176),
                (0.015, 0.199),
                (0.014, 0.200),
                (0, 0.200),
            ]
        ),
        source="small plastic bottle about 6.5 cm diameter, 20 cm high with a 30 mm cap (issue 2)",
        mass_kg=0.25,
        material="plastic",
        grasp_type="power",
    ),
}

URDF = """<?xml version="1.0"?>
<!-- generated by assets/objects/build_objects.py; static body (mass 0 when loaded with useFixedBase) -->
<robot name="{name}">
  <link name="{name}">
    <contact><lateral_friction value="{mu}"/></contact>
    <inertial>
      <origin xyz="{com}"/>
      <mass value="{mass}"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/>
    </inertial>
    <visual>
      <geometry><mesh filename="{name}.obj"/></geometry>
      <material name="{material}"><color rgba="{rgba}"/></material>
    </visual>
    <collision concave="yes">
      <geometry><mesh filename="{name}.obj"/></geometry>
    </collision>
  </link>
</robot>
"""
COLORS = {
    "metal": "0.75 0.75 0.8 1",
    "glass": "0.85 0.55 0.35 1",
    "cardboard": "0.9 0.3 0.2 1",
    "plastic": "0.3 0.5 0.9 1",
}


def write_obj(path: Path, mesh: o3d.geometry.TriangleMesh, comment: str) -> None:
    buf = io.StringIO()
    buf.write(f"# {comment}\n# metres, object frame; generated by assets/objects/build_objects.py\n")
    for v in np.asarray(mesh.vertices):
        buf.write(f"v {v[0]:.6f} {v[1]:.6f} {v[2]:.6f}\n")
    for t in np.asarray(mesh.triangles) + 1:
        buf.write(f"f {t[0]} {t[1]} {t[2]}\n")
    atomic_write(path, lambda f: f.write(buf.getvalue().encode()))


def check(name: str, mesh: o3d.geometry.TriangleMesh) -> None:
    if not (mesh.is_watertight() and mesh.is_orientable()):
        raise RuntimeError(f"{name}: mesh is not watertight")


def build(name: str, spec: dict) -> dict:
    mesh = spec["build"]()
    check(name, mesh)
    v, t = np.asarray(mesh.vertices), np.asarray(mesh.triangles)
    volume, com = volume_properties(v, t)
    lo, hi = v.min(0), v.max(0)
    meta = {
        "name": name,
        "dimensions_m": [round(float(x), 4) for x in hi - lo],
        "bounding_box_m": {"min": [round(float(x), 5) for x in lo], "max": [round(float(x), 5) for x in hi]},
        "source": spec["source"],
        "mass_kg": spec["mass_kg"],
        "material": spec["material"],
        "friction": RUBBER_MU[spec["material"]],
        "volume_m3": float(f"{volume:.6e}"),
        "center_of_mass_m": [round(float(x), 5) for x in com],
        "max_radius_m": round(float(np.linalg.norm(v - com, axis=1).max()), 5),
        "grasp_type": spec["grasp_type"],
        "vertices": len(v),
        "triangles": len(t),
    }
    folder = HERE / name
    write_obj(folder / f"{name}.obj", mesh, spec["source"])
    urdf = URDF.format(
        name=name,
        mu=meta["friction"],
        com=" ".join(map(str, meta["center_of_mass_m"])),
        mass=meta["mass_kg"],
        material=meta["material"],
        rgba=COLORS[meta["material"]],
    )
    atomic_write(folder / f"{name}.urdf", lambda f: f.write(urdf.encode()))
    text = "# generated by assets/objects/build_objects.py; do not edit by hand\n" + yaml.safe_dump(
        meta, sort_keys=False
    )
    atomic_write(folder / "object.yaml", lambda f: f.write(text.encode()))
    return meta


def main() -> int:
    for name, spec in OBJECTS.items():
        meta = build(name, spec)
        print(
            f"{name:10s} dims {meta['dimensions_m']} com {meta['center_of_mass_m']} "
            f"max_radius {meta['max_radius_m']} tris {meta['triangles']}"
        )
    block = block_with_hole(side=0.30, height=0.05, hole_r=0.047)
    check("block_with_hole", block)
    write_obj(
        HERE.parent / "scenes" / "meshes" / "block_with_hole.obj",
        block,
        "jam_hole block: 30 x 30 x 5 cm with a 47 mm-radius cylindrical through hole along z",
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
