"""pbdgrasp's data: hands, objects, scenes and demonstrations, reached only through these helpers.

Layout (each folder has a README saying where its data came from)::

    assets/hands/<hand>/<hand>.urdf            sah (13 joints), human (20 joints)
    assets/objects/<object>/<object>.urdf      + <object>.obj (watertight mesh, m) + object.yaml
    assets/scenes/<scene>.yaml                 one per Table I row
    assets/demonstrations/<object>.npz         the recorded human demonstrations

``assets`` is the bottom of the dependency stack; it also holds the shared error type
(:mod:`assets.errors`) and the atomic-write and validation helpers (:mod:`assets.io`).
"""

from __future__ import annotations

from pathlib import Path

import yaml

from .errors import InputError

__all__ = [
    "ROOT",
    "InputError",
    "hands",
    "hand_urdf",
    "hand_dir",
    "objects",
    "object_dir",
    "object_urdf",
    "object_mesh",
    "object_metadata",
    "scenes",
    "scene_path",
    "demonstration_names",
    "demonstration_path",
]

ROOT = Path(__file__).resolve().parent


def _names(folder: str, pattern: str) -> list[str]:
    base = ROOT / folder
    if pattern == "dir":
        return sorted(p.name for p in base.iterdir() if p.is_dir() and not p.name.startswith(("_", ".")))
    return sorted(p.stem for p in base.glob(pattern) if not p.name.startswith(("_", ".")))


def _check(kind: str, name: str, valid: list[str]) -> str:
    if name not in valid:
        raise InputError(f"unknown {kind} {name!r}; valid names: {', '.join(valid) or '(none)'}")
    return name


def hands() -> list[str]:
    """Names of the hand models."""
    return _names("hands", "dir")


def hand_dir(name: str) -> Path:
    return ROOT / "hands" / _check("hand", name, hands())


def hand_urdf(name: str) -> Path:
    """Path of a hand's URDF (its base link is the wrist frame)."""
    return hand_dir(name) / f"{name}.urdf"


def objects() -> list[str]:
    """Names of the objects."""
    return _names("objects", "dir")


def object_dir(name: str) -> Path:
    return ROOT / "objects" / _check("object", name, objects())


def object_urdf(name: str) -> Path:
    return object_dir(name) / f"{name}.urdf"


def object_mesh(name: str) -> Path:
    """Path of an object's watertight triangle mesh (metres, object frame)."""
    return object_dir(name) / f"{name}.obj"


def object_collision_mesh(name: str) -> Path:
    """Path of an object's collision geometry: its exact convex decomposition, one OBJ object per piece."""
    return object_dir(name) / f"{name}_collision.obj"


def object_metadata(name: str) -> dict:
    """An object's ``object.yaml``: dimensions, mass, friction, centre of mass, max radius, source."""
    with open(object_dir(name) / "object.yaml") as f:
        return yaml.safe_load(f)


def scenes() -> list[str]:
    """Names of the shipped scenes."""
    return _names("scenes", "*.yaml")


def scene_path(name_or_path: str | Path) -> Path:
    """A shipped scene by name, or a user's scene file by path."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise InputError("no such scene file", p)
        return p
    return ROOT / "scenes" / f"{_check('scene', str(name_or_path), scenes())}.yaml"


def demonstration_names() -> list[str]:
    """Names of the shipped demonstrations."""
    return _names("demonstrations", "*.npz")


def demonstration_path(name_or_path: str | Path) -> Path:
    """A shipped demonstration by name, or a user's demonstration file by path."""
    p = Path(name_or_path)
    if p.suffix == ".npz" or p.exists():
        if not p.is_file():
            raise InputError("no such demonstration file", p)
        return p
    return (
        ROOT / "demonstrations" / f"{_check('demonstration', str(name_or_path), demonstration_names())}.npz"
    )
