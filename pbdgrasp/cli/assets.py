"""``pbdgrasp assets``: list the hands, objects, scenes and demonstrations with their key figures."""

from __future__ import annotations

import zipfile

import assets
from assets.errors import InputError

NAME = "assets"
HELP = "list hands, objects, scenes and demonstrations with their key figures"
ORDER = 10


def add_arguments(p) -> None:
    p.add_argument(
        "--kind",
        choices=["hands", "objects", "scenes", "demonstrations"],
        action="append",
        help="only these sections (repeatable; default all)",
    )


def _hands() -> list[str]:
    from planning.hand_urdf import hand_joint_names

    rows = []
    for h in assets.hands():
        try:
            names = hand_joint_names(h)
            rows.append(f"  {h:10s} {len(names):2d} joints  {assets.hand_urdf(h).relative_to(assets.ROOT)}")
        except (OSError, InputError) as exc:
            rows.append(f"  {h:10s} unavailable ({type(exc).__name__}: {exc})")
    return rows


def _objects() -> list[str]:
    rows = [f"  {'name':10s} {'dimensions (mm)':20s} {'mass':>6s} {'mu':>4s} {'max r':>6s}  material   grasp"]
    for o in assets.objects():
        m = assets.object_metadata(o)
        dims = " x ".join(f"{1000 * x:.0f}" for x in m["dimensions_m"])
        rows.append(
            f"  {o:10s} {dims:20s} {m['mass_kg']:5.2f}kg {m['friction']:4.2f}"
            f" {1000 * m['max_radius_m']:4.0f}mm"
            f"  {m['material']:10s} {m['grasp_type']}"
        )
    return rows


def _scenes() -> list[str]:
    from planning.scene import load_scene

    rows = [f"  {'name':20s} {'object':10s} {'strategy':10s} obstacles"]
    for s in assets.scenes():
        sc = load_scene(s)
        rows.append(f"  {s:20s} {sc.object.name:10s} {sc.strategy:10s} {len(sc.obstacles)}")
    return rows


def _demonstrations() -> list[str]:
    rows = []
    for d in assets.demonstration_names():
        path = assets.demonstration_path(d)
        try:
            with zipfile.ZipFile(path) as z:
                keys = sorted(n.removesuffix(".npy") for n in z.namelist())
            rows.append(f"  {d:10s} {path.stat().st_size / 1024:7.1f} kB  arrays: {', '.join(keys)}")
        except zipfile.BadZipFile:
            rows.append(f"  {d:10s} unreadable archive")
    return rows or ["  (none yet)"]


def run(args) -> int:
    sections = {"hands": _hands, "objects": _objects, "scenes": _scenes, "demonstrations": _demonstrations}
    for kind in args.kind or list(sections):
        rows = sections[kind]()
        names = {"hands": assets.hands, "objects": assets.objects, "scenes": assets.scenes}
        count = len(names.get(kind, assets.demonstration_names)())
        print(f"{kind} ({count}):")
        print("\n".join(rows))
    return 0
