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

Collision geometry is an exact convex decomposition of the same loft, one OBJ object per convex piece,
which pybullet loads as a compound of convex hulls (a solid: a hand link wholly inside the object
collides, and penetration depths and normals are those of a solid). A concave triangle mesh is only a
surface to Bullet: a link wholly inside it went unseen (every probe sphere deep inside the salt box read
free), its penetration depths and normals were those of the nearest triangle, and a query cost ~1.3
times more. The
pieces: for a stack of convex contours with rising z (cans, jar, bottle, boxes), the convex hull of each
pair of consecutive contours; for a cup, its solid bottom as such a stack, its wall (a convex profile:
the rectangle and the rounded rim) and the inner fillet swept over each of the N angular segments, and
its handle tube's consecutive ring pairs; for the block with a hole, one convex prism per angular
segment between the hole's polygon and the square (both sampled on the same rays). Each piece's
vertices are mesh vertices, so the union of the pieces is the mesh's solid up to the chord of each
segment's inner arc.

Outputs per object ``assets/objects/<name>/``: ``<name>.obj`` (metres, object frame: origin at the
centre of the bottom face, +z up the object's axis), ``<name>_collision.obj`` (the convex pieces),
``<name>.urdf`` (static, the mesh as visual, the pieces as collision) and ``object.yaml`` (dimensions,
source, mass, material, friction, centre of mass, max radius, grasp-type hint, collision pieces). The
block with a cylindrical through hole of the jam_hole scene goes to
``assets/scenes/meshes/block_with_hole.obj`` and ``block_with_hole_collision.obj``.
"""

from __future__ import annotations

import io
import logging
import sys
from pathlib import Path

import numpy as np
import open3d as o3d
import yaml

HERE = Path(__file__).resolve().parent
log = logging.getLogger("build_objects")
sys.path.insert(0, str(HERE.parents[1]))

from scipy.optimize import linprog  # noqa: E402
from scipy.spatial import ConvexHull, HalfspaceIntersection  # noqa: E402

from assets.io import atomic_write  # noqa: E402
from assets.objects.lofts import block_with_hole, lathe, mug, rounded_box, volume_properties  # noqa: E402

PYBULLET_CONVEX_MARGIN_M = 0.001
"""pybullet gives every convex hull of a mesh a collision margin of 1 mm (its URDF importer's default),
which inflates the hull by that much in every query (measured: a probe 5.0 mm from a hull reads 4.0 mm,
from a box primitive 5.0 mm). The pieces are written inset by it, so that the shape Bullet sees is the
solid's."""
RUBBER_MU = {"plastic": 0.6, "glass": 0.6, "metal": 0.6, "cardboard": 0.6}
"""Coulomb friction of the SAH's rubber fingertips: GraspIt!'s static table (src/world.cpp initCof,
``Cof[rubber][plastic|glass|metal|wood] = 1.0``) minus 0.4 as in the paper; cardboard as wood."""


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
    <collision>
      <geometry><mesh filename="{name}_collision.obj"/></geometry>
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


def inset(points: np.ndarray, margin_m: float) -> np.ndarray:
    """The vertices of the convex hull of ``points`` with every face moved inwards (scipy's half-space
    intersection, Qhull) by ``margin_m``, or by 80 % of the largest inscribed ball's radius for a piece
    too thin for that (the mugs' 4 mm inner fillets, which keep ~0.2 mm of the margin)."""
    hull = ConvexHull(points)
    eq = hull.equations  # n . x + d <= 0 inside, |n| = 1
    # Chebyshev centre: max r subject to n . x + d + r <= 0 (a linear program)
    res = linprog([0, 0, 0, -1], A_ub=np.c_[eq[:, :3], np.ones(len(eq))], b_ub=-eq[:, 3],
                  bounds=[(None, None)] * 3 + [(0, None)])  # fmt: skip
    if not res.success:
        raise RuntimeError(f"inset: no inscribed ball ({res.message})")
    centre, radius = res.x[:3], res.x[3]
    shifted = eq.copy()
    shifted[:, 3] += min(margin_m, 0.8 * radius)
    return HalfspaceIntersection(shifted, centre).intersections


def write_pieces(path: Path, pieces: list[np.ndarray], comment: str) -> None:
    """The convex pieces as one OBJ object each (the triangles of its convex hull inset by
    :data:`PYBULLET_CONVEX_MARGIN_M`), for pybullet's compound of convex hulls."""
    buf = io.StringIO()
    buf.write(f"# {comment}\n# {len(pieces)} convex pieces, one object each, inset by pybullet's "
              f"{PYBULLET_CONVEX_MARGIN_M * 1e3:g} mm convex margin; metres; "
              "generated by assets/objects/build_objects.py\n")  # fmt: skip
    offset = 1
    for k, points in enumerate(pieces):
        pts = inset(points, PYBULLET_CONVEX_MARGIN_M)
        hull = ConvexHull(pts)
        v = pts[hull.vertices]
        index = {int(i): j for j, i in enumerate(hull.vertices)}
        buf.write(f"o piece{k}\n")
        for p in v:
            buf.write(f"v {p[0]:.6f} {p[1]:.6f} {p[2]:.6f}\n")
        for tri in hull.simplices:
            a, b, c = (index[int(i)] + offset for i in tri)
            buf.write(f"f {a} {b} {c}\n")
        offset += len(v)
    atomic_write(path, lambda f: f.write(buf.getvalue().encode()))


def check(name: str, mesh: o3d.geometry.TriangleMesh, pieces: list[np.ndarray]) -> None:
    """The mesh is watertight and its convex pieces' hull volumes add up to its own (within 0.5 %: the
    pieces tile the solid without overlap or gap)."""
    if not (mesh.is_watertight() and mesh.is_orientable()):
        raise RuntimeError(f"{name}: mesh is not watertight")
    volume = volume_properties(np.asarray(mesh.vertices), np.asarray(mesh.triangles))[0]
    pieces_volume = sum(ConvexHull(p).volume for p in pieces)
    if abs(pieces_volume - volume) > 5e-3 * volume:
        raise RuntimeError(f"{name}: convex pieces hold {pieces_volume:.4e} m^3, the mesh {volume:.4e} m^3")


def build(name: str, spec: dict) -> dict:
    mesh, pieces = spec["build"]()
    check(name, mesh, pieces)
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
        "collision_pieces": len(pieces),
    }
    folder = HERE / name
    write_obj(folder / f"{name}.obj", mesh, spec["source"])
    write_pieces(folder / f"{name}_collision.obj", pieces, f"{name}: collision geometry")
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
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    for name, spec in OBJECTS.items():
        meta = build(name, spec)
        log.info(
            "%-10s dims %s com %s max_radius %s tris %s",
            name,
            meta["dimensions_m"],
            meta["center_of_mass_m"],
            meta["max_radius_m"],
            meta["triangles"],
        )
    block, pieces = block_with_hole(side=0.30, height=0.05, hole_r=0.047)
    check("block_with_hole", block, pieces)
    comment = "jam_hole block: 30 x 30 x 5 cm with a 47 mm-radius cylindrical through hole along z"
    meshes = HERE.parent / "scenes" / "meshes"
    write_obj(meshes / "block_with_hole.obj", block, comment)
    write_pieces(meshes / "block_with_hole_collision.obj", pieces, comment + " (collision)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
