"""Scenes: a table, the target object with its localization uncertainty, obstacles and the strategy.

A scene file (``assets/scenes/<name>.yaml``, format in ``assets/scenes/README.md``) *names* the hand, the
object and the demonstration (strategy) it uses; it never copies them. :func:`load_scene` validates the
whole file once and returns a frozen :class:`Scene`; every problem is an :class:`InputError` naming the
file and the field (``object.position_m``, ``obstacles[1].size_m``, ...).

Frames: the world's z = 0 is the table top. Orientations are ``rpy_deg``: roll, pitch, yaw in degrees
about the fixed world x, y, z axes, ``R = Rz(yaw) Ry(pitch) Rx(roll)`` (pybullet's Euler convention).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

import assets
from assets.errors import InputError
from assets.io import is_number
from assets.se3 import make_pose, skew

__all__ = [
    "DEMONSTRATED_OBJECTS",
    "Table",
    "SceneObject",
    "Obstacle",
    "Scene",
    "load_scene",
    "pose_from_rpy",
]

DEMONSTRATED_OBJECTS = ("ham", "jam", "chips", "salt", "small_cup")
"""The five objects the paper's operator demonstrated (Fig. 5); a scene's strategy is one of these (or
any demonstration shipped in ``assets/demonstrations``)."""

OBSTACLE_TYPES = ("box", "cylinder", "object", "mesh")
_TOP = {"name", "description", "hand", "table", "object", "strategy", "obstacles", "wrist_bounds_m"}


def pose_from_rpy(position_m, rpy_deg) -> np.ndarray:
    """T_world_frame (4, 4) from a position (3,) [m] and roll, pitch, yaw (3,) [deg] about fixed x, y, z."""
    R = Rotation.from_euler("xyz", np.asarray(rpy_deg, dtype=float), degrees=True).as_matrix()
    return make_pose(R, np.asarray(position_m, dtype=float))


@dataclass(frozen=True)
class Table:
    """A box whose top face is the plane z = 0, centred at ``center_xy_m``.

    Attributes:
        size_m: (3,) full extents x, y, z [m].
        center_xy_m: (2,) centre of the top face in the world [m].
    """

    size_m: tuple[float, float, float]
    center_xy_m: tuple[float, float] = (0.0, 0.0)

    @property
    def T_world_table(self) -> np.ndarray:
        """Pose (4, 4) of the box centre (half its thickness below the top)."""
        return make_pose(np.eye(3), np.array([*self.center_xy_m, -self.size_m[2] / 2]))


@dataclass(frozen=True)
class SceneObject:
    """The target object: a shipped object's name, its pose and its localization uncertainty.

    Attributes:
        name: an object of ``assets.objects()``.
        position_m: (3,) origin of the object frame (centre of its bottom face) in the world [m].
        rpy_deg: (3,) orientation, see the module docstring [deg].
        position_std_mm: standard deviation of each coordinate of the object's position, that of its centre
            of mass (the paper: 3 mm).
        rotation_std_deg: standard deviation of each rotation-vector coordinate, a rotation about the
            centre of mass.
    """

    name: str
    position_m: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    position_std_mm: float
    rotation_std_deg: float


@dataclass(frozen=True)
class Obstacle:
    """A static obstacle.

    Attributes:
        type: ``box`` (``size_m`` full extents, pose of its centre), ``cylinder`` (``radius_m``,
            ``height_m``, pose of its centre, axis along its z), ``object`` (a shipped object ``name``,
            pose of the object frame) or ``mesh`` (``file``, relative to the scene file, ``scale``,
            pose of the mesh frame; optional ``collision_file``, the mesh's convex pieces as one OBJ
            object each, loaded as a solid compound; without it the mesh is a static concave triangle
            mesh, which Bullet treats as a surface: a link wholly inside it goes unseen).
        position_m, rpy_deg: the pose as above.
        label: a name for messages (defaults to ``<type><index>``).
    """

    type: str
    position_m: tuple[float, float, float]
    rpy_deg: tuple[float, float, float]
    label: str
    size_m: tuple[float, float, float] | None = None
    radius_m: float | None = None
    height_m: float | None = None
    name: str | None = None
    file: Path | None = None
    collision_file: Path | None = None
    scale: float = 1.0

    @property
    def T_world_obstacle(self) -> np.ndarray:
        return pose_from_rpy(self.position_m, self.rpy_deg)


@dataclass(frozen=True)
class Scene:
    """A validated scene (see :func:`load_scene`).

    Attributes:
        name, description, hand: the scene's name, one paragraph, the hand (``assets.hands()``).
        table, object, obstacles: the geometry.
        strategy: the demonstration whose variation model plans here.
        wrist_bounds_m: (2, 3) min and max wrist position for uniform sampling [m].
        path: the file it came from.
    """

    name: str
    description: str
    hand: str
    table: Table
    object: SceneObject
    strategy: str
    wrist_bounds_m: tuple[tuple[float, float, float], tuple[float, float, float]]
    obstacles: tuple[Obstacle, ...] = field(default_factory=tuple)
    path: Path | None = None

    @property
    def T_world_object(self) -> np.ndarray:
        """The object's pose (4, 4) in the world."""
        return pose_from_rpy(self.object.position_m, self.object.rpy_deg)

    @property
    def cov_object(self) -> np.ndarray:
        """Localization covariance (6, 6) of the object pose, GTSAM Pose3 tangent [omega (rad), v (m)].

        Body frame, right perturbation ``T = T_world_object @ Exp(xi)``; rotation first, as in GTSAM. A
        localizer estimates where the object is, its centre, and how it is turned about that centre: the
        errors are isotropic (``position_std_mm``, ``rotation_std_deg``) for the centre of mass ``c`` of
        the object's metadata and a rotation about it, ``Sigma_c = diag(rot^2 I, pos^2 I)``, carried to the
        object frame's origin (the centre of its bottom face) by the adjoint of the translation ``c``:
        ``Sigma_o = Ad Sigma_c Ad^T``, ``Ad = [[I, 0], [[c]x, I]]``. So the centre moves by ``pos`` whatever
        the rotation, and a point at distance ``d`` from it by ``rot * d`` more.
        """
        rot = math.radians(self.object.rotation_std_deg) ** 2
        pos = (self.object.position_std_mm * 1e-3) ** 2
        c = np.asarray(assets.object_metadata(self.object.name)["center_of_mass_m"], dtype=float)
        adjoint = np.eye(6)
        adjoint[3:, :3] = skew(c)
        cov = adjoint @ np.diag([rot] * 3 + [pos] * 3) @ adjoint.T
        return 0.5 * (cov + cov.T)

    @property
    def bounds_array(self) -> np.ndarray:
        """``wrist_bounds_m`` as an array (2, 3): row 0 the minimum, row 1 the maximum [m]."""
        return np.array(self.wrist_bounds_m, dtype=float)


# ----------------------------------------------------------------------------------------------------
class _Reader:
    """Typed field access that raises InputError naming the file and the field."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field_name: str, message: str):
        raise InputError(f"{field_name}: {message}", self.path)

    def mapping(self, d, field_name: str, required: set, optional: set = frozenset()) -> dict:
        if not isinstance(d, dict):
            self.fail(field_name, f"expected a mapping, found {type(d).__name__}")
        prefix = f"{field_name}." if field_name else ""
        for key in sorted(required):
            if key not in d:
                self.fail(f"{prefix}{key}", "missing field")
        unknown = sorted(set(d) - required - set(optional), key=str)
        if unknown:
            self.fail(
                f"{prefix}{unknown[0]}", f"unknown field; valid: {', '.join(sorted(required | optional))}"
            )
        return d

    def string(self, value, field_name: str) -> str:
        if not isinstance(value, str) or not value:
            self.fail(field_name, f"expected a non-empty string, found {value!r}")
        return value

    def number(self, value, field_name: str, positive: bool = False, nonneg: bool = False) -> float:
        if not is_number(value):
            self.fail(field_name, f"expected a number, found {type(value).__name__} {value!r}")
        x = float(value)
        if not math.isfinite(x):
            self.fail(field_name, f"non-finite value {value!r}")
        if positive and x <= 0:
            self.fail(field_name, f"expected a positive number, found {x:g}")
        if nonneg and x < 0:
            self.fail(field_name, f"expected a number >= 0, found {x:g}")
        return x

    def vector(self, value, field_name: str, n: int, positive: bool = False) -> tuple[float, ...]:
        if not isinstance(value, (list, tuple)) or len(value) != n:
            self.fail(field_name, f"expected a list of {n} numbers, found {value!r}")
        return tuple(self.number(x, f"{field_name}[{i}]", positive=positive) for i, x in enumerate(value))

    def choice(self, value, field_name: str, valid) -> str:
        value = self.string(value, field_name)
        if value not in valid:
            self.fail(field_name, f"unknown name {value!r}; valid: {', '.join(valid)}")
        return value


def _obstacle(r: _Reader, d, i: int) -> Obstacle:
    f = f"obstacles[{i}]"
    if not isinstance(d, dict):
        r.fail(f, f"expected a mapping, found {type(d).__name__}")
    kind = r.choice(d.get("type"), f"{f}.type", OBSTACLE_TYPES)
    common = {"type", "position_m"}
    extra = {"box": {"size_m"}, "cylinder": {"radius_m", "height_m"}, "object": {"name"}, "mesh": {"file"}}[
        kind
    ]
    optional = {"rpy_deg", "label", "scale", "collision_file"} if kind == "mesh" else {"rpy_deg", "label"}
    r.mapping(d, f, common | extra, optional)
    kw = dict(
        type=kind,
        position_m=r.vector(d["position_m"], f"{f}.position_m", 3),
        rpy_deg=r.vector(d.get("rpy_deg", [0, 0, 0]), f"{f}.rpy_deg", 3),
        label=r.string(d.get("label", f"{kind}{i}"), f"{f}.label"),
    )
    if kind == "box":
        kw["size_m"] = r.vector(d["size_m"], f"{f}.size_m", 3, positive=True)
    elif kind == "cylinder":
        kw["radius_m"] = r.number(d["radius_m"], f"{f}.radius_m", positive=True)
        kw["height_m"] = r.number(d["height_m"], f"{f}.height_m", positive=True)
    elif kind == "object":
        kw["name"] = r.choice(d["name"], f"{f}.name", assets.objects())
    else:
        file = (r.path.parent / r.string(d["file"], f"{f}.file")).resolve()
        if not file.is_file():
            r.fail(f"{f}.file", f"no such mesh file {file}")
        kw["file"] = file
        if "collision_file" in d:
            collision = (r.path.parent / r.string(d["collision_file"], f"{f}.collision_file")).resolve()
            if not collision.is_file():
                r.fail(f"{f}.collision_file", f"no such mesh file {collision}")
            kw["collision_file"] = collision
        kw["scale"] = r.number(d.get("scale", 1.0), f"{f}.scale", positive=True)
    return Obstacle(**kw)


def load_scene(name_or_path: str | Path) -> Scene:
    """Load and validate a scene by name (``assets.scenes()``) or by path.

    Raises:
        InputError: unknown scene, unreadable YAML, a missing or unknown field, a wrong type, a
            non-finite or negative size, or an unknown hand, object or strategy name; the message names
            the file and the field.
    """
    path = assets.scene_path(name_or_path)
    r = _Reader(path)
    try:
        with open(path) as fh:
            d = yaml.safe_load(fh)
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise InputError(f"not valid YAML ({' '.join(str(exc).split())})", path) from None
    r.mapping(d, "", {"name", "hand", "table", "object", "strategy", "wrist_bounds_m"}, _TOP)

    t = r.mapping(d["table"], "table", {"size_m"}, {"center_xy_m"})
    table = Table(
        size_m=r.vector(t["size_m"], "table.size_m", 3, positive=True),
        center_xy_m=r.vector(t.get("center_xy_m", [0, 0]), "table.center_xy_m", 2),
    )
    o = r.mapping(
        d["object"], "object", {"name", "position_m", "rpy_deg", "position_std_mm", "rotation_std_deg"}
    )
    obj = SceneObject(
        name=r.choice(o["name"], "object.name", assets.objects()),
        position_m=r.vector(o["position_m"], "object.position_m", 3),
        rpy_deg=r.vector(o["rpy_deg"], "object.rpy_deg", 3),
        position_std_mm=r.number(o["position_std_mm"], "object.position_std_mm", positive=True),
        rotation_std_deg=r.number(o["rotation_std_deg"], "object.rotation_std_deg", positive=True),
    )
    strategies = sorted(set(DEMONSTRATED_OBJECTS) | set(assets.demonstration_names()))
    obstacles = d.get("obstacles") or []
    if not isinstance(obstacles, list):
        r.fail("obstacles", f"expected a list, found {type(obstacles).__name__}")
    wb = d["wrist_bounds_m"]
    wb = r.mapping(wb, "wrist_bounds_m", {"min", "max"})
    lo = r.vector(wb["min"], "wrist_bounds_m.min", 3)
    hi = r.vector(wb["max"], "wrist_bounds_m.max", 3)
    if any(a >= b for a, b in zip(lo, hi, strict=True)):
        r.fail("wrist_bounds_m", f"min {lo} must be below max {hi} in every coordinate")
    return Scene(
        name=r.string(d["name"], "name"),
        description=str(d.get("description", "")).strip(),
        hand=r.choice(d["hand"], "hand", assets.hands()),
        table=table,
        object=obj,
        strategy=r.choice(d["strategy"], "strategy", strategies),
        wrist_bounds_m=(lo, hi),
        obstacles=tuple(_obstacle(r, ob, i) for i, ob in enumerate(obstacles)),
        path=path,
    )
