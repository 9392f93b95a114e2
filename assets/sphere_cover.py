"""A conservative cover of a hand's collision geometry by spheres, generated from the URDF's primitives.

The smooth distance model of the variation model's constraint factors (as GPMP2's ``BodySphere``): every
``<collision>`` shape of every link is replaced by spheres fixed to that link whose union contains it, so
a sphere's clearance to an obstacle is a lower bound of the shape's. Supported primitives (those of the
shipped hands): ``sphere`` (itself), ``capsule`` and ``cylinder`` (spheres on the axis), ``box`` (one sphere
per cell of a grid over it). Each cover bulges out of its shape by at most a given margin:

* capsule / cylinder of radius r and length L: centres spaced d <= 2 sqrt((r + b)^2 - r^2) along the
  segment, ends included, radius ``sqrt(r^2 + (d/2)^2) <= r + b``: a point within r of the segment
  projects within d/2 of a centre (the caps are within r of an end centre). A cylinder's flat ends bulge
  by the radius; no shipped link has one.
* box: a grid of cells of half-sizes ``h`` with ``|h| - min(h) <= b``, each covered by its circumscribed
  sphere (radius ``|h|``), which leaves the box by at most ``|h| - min(h)``. Only the cells on the box's
  surface are kept: the cover contains the shape's surface, and a shape's clearance to anything outside
  it is its surface's.

Pairs for self-collision (:meth:`SphereCover.self_pairs`): spheres of two phalanges on different fingers
(links two or more moving joints from the base, neither an ancestor of the other), the crossings the
scene's constraints can push fingers into; the palm and the thumb's base module are not paired.

Frames: sphere centres are given in their link's frame and returned in the hand's base (wrist) frame.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from assets.errors import InputError

from .kinematics import HandModel, _floats, _rpy_matrix
from .se3 import make_pose

__all__ = [
    "CollisionShape",
    "collision_shapes",
    "sphere_cover_of",
    "CoverState",
    "SphereCover",
    "hand_sphere_cover",
]

DEFAULT_MAX_BULGE_M = 0.002
"""Largest distance [m] by which a capsule's or sphere's cover leaves the shape."""
BOUND_MAX_RADIUS_M = 0.04
"""The largest radius [m] of a bounding sphere of the broad phase (see :attr:`SphereCover.bound_of`)."""
DEFAULT_BOX_MAX_BULGE_M = 0.005
"""The same for boxes (their corners need many small spheres: 2 mm would take ~1300 for the SAH's palm)."""


@dataclass(frozen=True)
class CollisionShape:
    """One URDF ``<collision>`` primitive.

    Attributes:
        link: the link it belongs to.
        type: ``box``, ``sphere``, ``capsule`` or ``cylinder``.
        size_m: box: full extents (3,); sphere: (radius,); capsule, cylinder: (radius, length) along z.
        T_link_shape: (4, 4) the shape's frame in the link frame.
    """

    link: str
    type: str
    size_m: tuple[float, ...]
    T_link_shape: np.ndarray


def collision_shapes(path: str | Path, element: str = "collision") -> list[CollisionShape]:
    """Every ``<collision>`` primitive of a URDF, in file order (``element="visual"``: the ``<visual>`` ones).

    Raises:
        InputError: unreadable XML, or a geometry that is not a box, sphere, capsule or cylinder.
    """
    if element not in ("collision", "visual"):
        raise ValueError(f"element: expected 'collision' or 'visual', found {element!r}")
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (OSError, ET.ParseError) as exc:
        raise InputError(f"cannot read URDF ({exc})", path) from None
    shapes = []
    for link in root.findall("link"):
        name = link.get("name")
        for col in link.findall(element):
            geom = list(col.find("geometry") if col.find("geometry") is not None else [])
            if len(geom) != 1:
                raise InputError(f"link {name!r}: a <{element}> needs exactly one geometry", path)
            g, org = geom[0], col.find("origin")
            where = f"{path}: link {name} {element}"
            xyz = _floats(None if org is None else org.get("xyz"), 3, 0.0, f"{where} xyz")
            rpy = _floats(None if org is None else org.get("rpy"), 3, 0.0, f"{where} rpy")
            if g.tag == "box":
                size = tuple(_floats(g.get("size"), 3, math.nan, f"{where} box size"))
            elif g.tag == "sphere":
                size = (float(g.get("radius", "nan")),)
            elif g.tag in ("capsule", "cylinder"):
                size = (float(g.get("radius", "nan")), float(g.get("length", "nan")))
            else:
                raise InputError(f"link {name!r}: {element} geometry {g.tag!r} is not a primitive", path)
            if not all(math.isfinite(s) and s > 0 for s in size):
                raise InputError(f"link {name!r}: {g.tag} dimensions must be > 0, found {size}", path)
            shapes.append(CollisionShape(name, g.tag, size, make_pose(_rpy_matrix(rpy), xyz)))
    return shapes


def sphere_cover_of(
    shape: CollisionShape,
    max_bulge_m: float = DEFAULT_MAX_BULGE_M,
    box_max_bulge_m: float = DEFAULT_BOX_MAX_BULGE_M,
) -> tuple[np.ndarray, np.ndarray]:
    """Spheres containing ``shape``: centres (k, 3) in its link frame [m] and radii (k,) [m]."""
    if shape.type == "sphere":
        local, radii = np.zeros((1, 3)), np.array([shape.size_m[0]])
    elif shape.type in ("capsule", "cylinder"):
        r, length = shape.size_m
        half_gap = math.sqrt((r + max_bulge_m) ** 2 - r**2)
        n = max(1, math.ceil(length / (2 * half_gap)))
        z = np.linspace(-length / 2, length / 2, n + 1)
        local = np.column_stack([np.zeros_like(z), np.zeros_like(z), z])
        radii = np.full(n + 1, math.sqrt(r**2 + (length / n / 2) ** 2))
    else:  # box
        half = np.asarray(shape.size_m) / 2
        h_max = box_max_bulge_m / (math.sqrt(3.0) - 1.0)
        cells = np.maximum(1, np.ceil(half / h_max)).astype(int)
        while np.linalg.norm(half / cells) - np.min(half / cells) > box_max_bulge_m:  # elongated cells
            cells[np.argmax(half / cells)] += 1
        h = half / cells
        axes = [-half[i] + h[i] * (2 * np.arange(cells[i]) + 1) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        idx = np.stack(np.meshgrid(*[np.arange(c) for c in cells], indexing="ij"), axis=-1).reshape(-1, 3)
        local = grid[np.any((idx == 0) | (idx == cells - 1), axis=1)]  # the cells on the surface
        radii = np.full(len(local), float(np.linalg.norm(h)))
    centers = local @ shape.T_link_shape[:3, :3].T + shape.T_link_shape[:3, 3]
    return centers, radii


@dataclass(frozen=True)
class CoverState:
    """A hand's kinematic state for its sphere cover (:meth:`SphereCover.state`), batch shape (B,).

    Attributes:
        link_T: (B, G, 4, 4) the poses of the links with spheres, base frame.
        axes, origins: (B, M, 3) each moving joint's axis and origin, base frame.
    """

    link_T: np.ndarray
    axes: np.ndarray
    origins: np.ndarray


@dataclass(frozen=True)
class SphereCover:
    """The spheres of a hand, with their positions and Jacobians in the base (wrist) frame.

    Attributes:
        model: the hand's kinematic tree.
        links: (n,) the link of each sphere.
        centers_link_m: (n, 3) each centre in its link's frame [m].
        radii_m: (n,) [m].
        bound_of: (n,) each sphere's bounding sphere: the spheres of each link, split in halves along
            their widest axis until each part fits in a sphere of :data:`BOUND_MAX_RADIUS_M` (the broad
            phase of :class:`inference.clearance.HandClearance`).
        bound_group: (K,) the link (index into :attr:`group_links`) of each bounding sphere.
        bound_centers_link_m, bound_radii_m: (K, 3), (K,) the bounding spheres in their link's frame [m].
    """

    model: HandModel
    links: tuple[str, ...]
    centers_link_m: np.ndarray
    radii_m: np.ndarray
    _groups: tuple = field(repr=False, compare=False, default=())
    _moving: tuple = field(repr=False, compare=False, default=())
    _group_of: np.ndarray = field(repr=False, compare=False, default=None)

    def __post_init__(self):
        c, r = self.centers_link_m, self.radii_m
        chunks = [ch for _, idx in self._groups for ch in _bisect(c, r, idx, BOUND_MAX_RADIUS_M)]
        bound_of = np.empty(len(r), dtype=int)
        for k, idx in enumerate(chunks):
            bound_of[idx] = k
        bc = np.array([c[idx].mean(axis=0) for idx in chunks])
        br = np.array(
            [np.max(np.linalg.norm(c[idx] - bc[k], axis=1) + r[idx]) for k, idx in enumerate(chunks)]
        )
        moves = np.zeros((len(self.links), len(self._moving)))
        select = np.zeros((len(self._moving), self.model.n))
        for m, (_, column, multiplier, moved) in enumerate(self._moving):
            moves[moved, m] = 1.0
            select[m, column] = multiplier
        for name, value in (("bound_of", bound_of), ("bound_group", self._group_of[[ch[0] for ch in chunks]]),
                            ("bound_centers_link_m", bc), ("bound_radii_m", br), ("_moves", moves),
                            ("_select", select)):  # fmt: skip
            object.__setattr__(self, name, value)

    @property
    def group_links(self) -> tuple[str, ...]:
        """The links with spheres, in the order of the groups (:meth:`state`, :attr:`group_of`)."""
        return tuple(name for name, _ in self._groups)

    @property
    def group_of(self) -> np.ndarray:
        """(n,) each sphere's group (index into :attr:`group_links`)."""
        return self._group_of

    def state(self, joints: np.ndarray) -> CoverState:
        """The kinematic state at joints (B, n_joints) [rad] that :meth:`centers_at`, :meth:`bounds` and
        :meth:`jacobians_at` read (one forward kinematics for all of them)."""
        joints = np.asarray(joints, dtype=float)
        poses = self.model.fk(joints)
        batch = joints.shape[:-1]
        link_T = np.stack(
            [np.broadcast_to(poses[link], batch + (4, 4)) for link in self.group_links], axis=-3
        )
        axes = np.stack([poses[j.child][..., :3, :3] @ j.axis for j, *_ in self._moving], axis=-2)
        origins = np.stack([poses[j.child][..., :3, 3] for j, *_ in self._moving], axis=-2)
        return CoverState(link_T, axes, origins)

    def bounds(self, state: CoverState) -> np.ndarray:
        """The bounding spheres' centres (B, K, 3) [m] in the base frame (radii :attr:`bound_radii_m`)."""
        T = state.link_T[..., self.bound_group, :, :]
        return np.einsum("...kij,kj->...ki", T[..., :3, :3], self.bound_centers_link_m) + T[..., :3, 3]

    def centers_at(self, state: CoverState, b: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Centres (k, 3) [m], base frame, of spheres ``s`` (k,) at the batch entries ``b`` (k,)."""
        T = state.link_T[b, self._group_of[s]]
        return np.einsum("kij,kj->ki", T[:, :3, :3], self.centers_link_m[s]) + T[:, :3, 3]

    def jacobians_at(self, state: CoverState, b: np.ndarray, s: np.ndarray, c: np.ndarray) -> np.ndarray:
        """Jacobians (k, 3, n_joints) [m/rad] of the centres ``c`` (k, 3) of spheres ``s`` at batch ``b``."""
        lever = c[:, None, :] - state.origins[b]  # (k, M, 3)
        columns = np.cross(state.axes[b], lever) * self._moves[s][:, :, None]
        return np.einsum("kmi,mj->kij", columns, self._select)

    @classmethod
    def from_urdf(
        cls,
        path: str | Path,
        max_bulge_m: float = DEFAULT_MAX_BULGE_M,
        box_max_bulge_m: float = DEFAULT_BOX_MAX_BULGE_M,
    ) -> SphereCover:
        """The cover of every collision primitive of a URDF (see the module docstring)."""
        model = HandModel.from_urdf(path)
        links, centers, radii = [], [], []
        for shape in collision_shapes(path):
            c, r = sphere_cover_of(shape, max_bulge_m, box_max_bulge_m)
            links += [shape.link] * len(r)
            centers.append(c)
            radii.append(r)
        if not links:
            raise InputError("no collision shapes to cover", path)
        links_t = tuple(links)
        groups = tuple((name, np.flatnonzero(np.array(links_t) == name)) for name in dict.fromkeys(links_t))
        return cls(
            model,
            links_t,
            np.vstack(centers),
            np.concatenate(radii),
            groups,
            _moving_joints(model, links_t),
            np.array([[name for name, _ in groups].index(ln) for ln in links_t]),
        )

    def __len__(self) -> int:
        return len(self.links)

    def centers(self, joints: np.ndarray, poses: dict | None = None) -> np.ndarray:
        """Sphere centres in the base frame [m]: joints (..., n_joints) [rad] -> (..., n, 3)."""
        joints = np.asarray(joints, dtype=float)
        poses = self.model.fk(joints) if poses is None else poses
        batch = joints.shape[:-1]
        T = np.stack([np.broadcast_to(poses[link], batch + (4, 4)) for link, _ in self._groups], axis=-3)
        T = T[..., self._group_of, :, :]  # (..., n, 4, 4): each sphere's link pose
        return np.einsum("...ij,...j->...i", T[..., :3, :3], self.centers_link_m) + T[..., :3, 3]

    def centers_and_jacobians(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Centres (..., n, 3) in the base frame [m] and their Jacobians (..., n, 3, n_joints) [m/rad] at
        joints (..., n_joints) [rad]; a mimic joint adds its multiplier times its column to the joint it
        copies."""
        joints = np.asarray(joints, dtype=float)
        poses = self.model.fk(joints)
        c = self.centers(joints, poses)
        J = np.zeros(joints.shape[:-1] + (len(self), 3, self.model.n))
        for joint, column, multiplier, moved in self._moving:
            T = poses[joint.child]
            axis = (T[..., :3, :3] @ joint.axis)[..., None, :]
            column_view = J[..., column]  # (..., n, 3), a view into J
            column_view[..., moved, :] += multiplier * np.cross(axis, c[..., moved, :] - T[..., None, :3, 3])
        return c, J

    def self_pairs(self, rest_joints: np.ndarray | None = None) -> np.ndarray:
        """Sphere index pairs (p, 2) for self-collision: phalanges of different fingers (module docstring).

        Args:
            rest_joints: if given, link pairs whose spheres overlap at these joints are left out (they touch
                by construction).
        """
        m = self.model
        ancestors = {link: _ancestors(m, link) for link, _ in self._groups}
        phalanx = {link: len(m.chain(link)) >= 2 for link, _ in self._groups}
        c = None if rest_joints is None else self.centers(rest_joints)
        pairs = []
        groups = list(self._groups)
        for a, (la, ia) in enumerate(groups):
            for lb, ib in groups[a + 1 :]:
                if not (phalanx[la] and phalanx[lb]) or la in ancestors[lb] or lb in ancestors[la]:
                    continue
                ii, jj = np.meshgrid(ia, ib, indexing="ij")
                ii, jj = ii.ravel(), jj.ravel()
                if c is not None:
                    gap = np.linalg.norm(c[ii] - c[jj], axis=-1) - self.radii_m[ii] - self.radii_m[jj]
                    if np.any(gap < 0):
                        continue
                pairs.append(np.column_stack([ii, jj]))
        return np.vstack(pairs) if pairs else np.zeros((0, 2), dtype=int)


def _bisect(c: np.ndarray, r: np.ndarray, idx: np.ndarray, max_radius_m: float) -> list[np.ndarray]:
    """Split the spheres ``idx`` in halves along their widest axis until each part's bounding sphere (about
    its mean centre) has a radius <= ``max_radius_m`` or one sphere is left."""
    centre = c[idx].mean(axis=0)
    if len(idx) == 1 or np.max(np.linalg.norm(c[idx] - centre, axis=1) + r[idx]) <= max_radius_m:
        return [idx]
    axis = np.argmax(np.ptp(c[idx], axis=0))
    order = idx[np.argsort(c[idx, axis], kind="stable")]
    half = len(order) // 2
    return _bisect(c, r, order[:half], max_radius_m) + _bisect(c, r, order[half:], max_radius_m)


def _moving_joints(model: HandModel, links: tuple[str, ...]) -> tuple:
    """Per moving joint: (joint, its actuated column, multiplier, indices of the spheres it moves)."""
    out = []
    names = np.array(links)
    for joint in model.joints:
        if joint.type == "fixed":
            continue
        moved = np.flatnonzero([joint.child == ln or joint.child in _ancestors(model, ln) for ln in names])
        if len(moved):
            column = model.joint_names.index(joint.mimic or joint.name)
            out.append((joint, column, joint.multiplier if joint.mimic else 1.0, moved))
    return tuple(out)


def _ancestors(model: HandModel, link: str) -> set[str]:
    parent = {j.child: j.parent for j in model.joints}
    out, cur = set(), link
    while cur in parent:
        cur = parent[cur]
        out.add(cur)
    return out


@lru_cache(maxsize=4)
def hand_sphere_cover(hand: str = "sah") -> SphereCover:
    """The cover of a shipped hand (``assets.hands()``) with the default bulges, built once per process."""
    import assets

    return SphereCover.from_urdf(assets.hand_urdf(hand))
