"""The pybullet world of a scene: the hand (teleported), the table, the target object and obstacles.

One :class:`World` owns one pybullet client in DIRECT mode (never the global default client); close it
with :meth:`World.close` or use it as a context manager. Everything but the hand is a static body
(mass 0; the objects and mesh obstacles as compounds of their exact convex pieces, so solids: see
``assets/objects/build_objects.py``). The hand hangs from a fixed anchor on three prismatic joints and a
spherical one (:func:`planning.hand_urdf.floating_urdf`); it is never stepped, only teleported by
:meth:`World.set_q` (one pybullet call for the wrist and the fingers), so Bullet computes its contacts with
the static bodies and, with ``URDF_USE_SELF_COLLISION``, between its own links (parent-child pairs
excluded).

Collision query costs: ``pbdgrasp bench`` (docs/performance.md).
"""

from __future__ import annotations

import logging
import math
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import assets
from assets.errors import InputError
from assets.q_layout import JOINTS, POSE
from assets.se3 import quat_of_rotvec

from ._pybullet import connect_direct, pb
from .camera import default_camera, render_image
from .hand_urdf import (
    FLOATING_JOINTS,
    default_excluded_pairs,
    floating_urdf,
    hand_joint_names,
    hand_rest_joints,
    urdf_joints,
)
from .scene import Scene, load_scene
from .scene_checks import check_placement
from .world_bodies import load_object, load_obstacle, load_table

__all__ = ["Contact", "World"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Contact:
    """A contact (or near contact) of the hand.

    Attributes:
        link: the hand link's name.
        other: ``table``, the object's name, an obstacle's label, or ``self:<link>`` for self-collision.
        point_world: (3,) the point on the hand [m].
        normal_world: (3,) the contact normal, from the other body towards the hand.
        distance_m: signed distance, negative in penetration.
    """

    link: str
    other: str
    point_world: tuple[float, float, float]
    normal_world: tuple[float, float, float]
    distance_m: float


class World:
    """A pybullet world built from a scene, for collision and distance queries and pictures.

    Args:
        scene: a :class:`Scene` or a scene name/path for :func:`load_scene`.
        hand: the hand to load (``sah``: q is (19,); ``human``: q is (6 + 20,)).
        self_collision_excluded: pairs of hand link names whose mutual collisions are ignored (they
            touch by construction); default ``assets.sah.SELF_COLLISION_EXCLUDED_PAIRS`` for the SAH,
            none for other hands.

    Attributes:
        client: the pybullet client id.
        hand_id, object_id, table_id: body ids; obstacle_ids: tuple of body ids (scene order).
        base_name: the hand's root link (the wrist); link_names: its other links in pybullet's order.
            The hand hangs on floating joints (:func:`planning.hand_urdf.floating_urdf`), so pybullet link
            indices on ``hand_id`` are :meth:`link_index`'s, not positions in ``link_names``.
        joint_names: the order of ``q[JOINTS]``.
    """

    def __init__(
        self,
        scene: Scene | str | Path,
        hand: str = "sah",
        self_collision_excluded: tuple[tuple[str, str], ...] | None = None,
    ):
        self.scene = scene if isinstance(scene, Scene) else load_scene(scene)
        self.hand = hand
        self._excluded = self_collision_excluded
        self.client = connect_direct()
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    # --------------------------------------------------------------------------------------------
    def _build(self) -> None:
        c, s = self.client, self.scene
        pb.setAdditionalSearchPath(str(assets.ROOT), physicsClientId=c)
        self.table_id = load_table(c, s.table)
        self._names = {self.table_id: "table"}
        self.object_id = load_object(c, s.object.name, s.T_world_object)
        self._names[self.object_id] = s.object.name
        ids = []
        for ob in s.obstacles:
            ids.append(load_obstacle(c, ob, s.path))
            self._names[ids[-1]] = ob.label
        self.obstacle_ids = tuple(ids)
        check_placement(self)

        urdf = assets.hand_urdf(self.hand)
        flags = pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT
        with tempfile.TemporaryDirectory() as tmp:  # the hand on floating joints (one call sets it all)
            path = Path(tmp) / urdf.name
            path.write_text(floating_urdf(urdf))
            self.hand_id = pb.loadURDF(str(path), useFixedBase=True, flags=flags, physicsClientId=c)
        self._names[self.hand_id] = "hand"
        n = pb.getNumJoints(self.hand_id, physicsClientId=c)
        infos = [pb.getJointInfo(self.hand_id, i, physicsClientId=c) for i in range(n)]
        index = {info[1].decode(): i for i, info in enumerate(infos)}
        self._root_index = index[FLOATING_JOINTS[-1]]  # the root link's pybullet index; its links follow
        self.base_name = infos[self._root_index][12].decode()
        self.link_names = [info[12].decode() for info in infos[self._root_index + 1 :]]
        actuated, mimic = urdf_joints(urdf)
        self.joint_names = hand_joint_names(self.hand)
        self._q_index = np.array([index[name] for name in self.joint_names])
        self._mimic = [
            (index[m], self.joint_names.index(master), k, off) for m, (master, k, off) in mimic.items()
        ]
        self._all_joints = [index[name] for name in FLOATING_JOINTS] + [int(i) for i in self._q_index]
        self._all_joints += [m[0] for m in self._mimic]
        pb.resetJointState(self.hand_id, index[FLOATING_JOINTS[2]], 2.0, physicsClientId=c)  # out of the way
        self._bodies = (self.table_id, self.object_id, *self.obstacle_ids)
        excluded = self._excluded if self._excluded is not None else default_excluded_pairs(self.hand)
        links = {name: self.link_index(name) for name in (self.base_name, *self.link_names)}
        for a, b in excluded:
            if a not in links or b not in links:
                raise InputError(
                    f"self_collision_excluded: unknown link in {(a, b)}; valid: {', '.join(links)}"
                )
            pb.setCollisionFilterPair(self.hand_id, self.hand_id, links[a], links[b], 0, physicsClientId=c)
        self.dof = 6 + len(self.joint_names)
        self.q = None
        self._kin = None
        log.debug(
            "world %s: hand %s with %d joints, %d obstacles",
            s.name,
            self.hand,
            len(self.joint_names),
            len(self.obstacle_ids),
        )

    # --------------------------------------------------------------------------------------------
    def set_q(self, q: np.ndarray) -> None:
        """Teleport the hand to ``q`` (dof,) = [wrist position (m), rotation vector (rad), joints (rad)].

        The coupled (mimic) joints follow their masters as the URDF says (SAH: distal = middle).
        """
        q = np.asarray(q, dtype=float)
        if q.shape != (self.dof,):
            raise InputError(f"q: expected shape ({self.dof},) for hand {self.hand}, found {q.shape}")
        v = q.tolist()
        if not math.isfinite(sum(v)):  # a NaN or an infinity anywhere
            raise InputError("q: non-finite value")
        values = [[v[0]], [v[1]], [v[2]], list(quat_of_rotvec(*v[3:6]))] + [[x] for x in v[6:]]
        values += [[k * v[6 + m] + off] for _, m, k, off in self._mimic]
        pb.resetJointStatesMultiDof(self.hand_id, self._all_joints, values, physicsClientId=self.client)
        self.q = q.copy()

    def _contacts_raw(self, q):
        if q is not None:
            self.set_q(q)
        pb.performCollisionDetection(physicsClientId=self.client)
        return pb.getContactPoints(bodyA=self.hand_id, physicsClientId=self.client)

    def is_free(self, q: np.ndarray) -> bool:
        """Whether the hand at ``q`` penetrates nothing: table, object, obstacles, nor itself (every link)."""
        return not any(cp[8] < 0.0 for cp in self._contacts_raw(q))

    def penetration_m(self, q: np.ndarray) -> float:
        """How deep the hand at ``q`` penetrates the scene and itself [m]; 0 when :meth:`is_free` holds.

        The sum, over the penetrating pairs (hand link, other body and link), of each pair's deepest
        point: it decreases as any one link comes out, so a local search can follow it out of a collision.
        """
        deepest: dict[tuple[int, int, int], float] = {}
        for cp in self._contacts_raw(q):
            if cp[8] < 0.0:
                key = (cp[3], cp[2], cp[4])
                deepest[key] = max(deepest.get(key, 0.0), -cp[8])
        return math.fsum(deepest.values())  # exactly rounded: the same whatever order pybullet reports

    def link_index(self, name: str) -> int:
        """The pybullet link index of the hand's link ``name`` (its root link, :attr:`base_name`, included),
        for pybullet calls on :attr:`hand_id`."""
        if name == self.base_name:
            return self._root_index
        return self._root_index + 1 + self.link_names.index(name)

    def link_name(self, index: int) -> str:
        """The name of the hand's link at pybullet link index ``index`` (:meth:`link_index`'s inverse).

        Raises:
            ValueError: ``index`` is the anchor's or a floating joint's link (they have no geometry).
        """
        if index < self._root_index:
            raise ValueError(
                f"pybullet link {index} of the hand is not one of its links, but its floating joints'"
            )
        return self.base_name if index == self._root_index else self.link_names[index - self._root_index - 1]

    def hand_contacts(self, q: np.ndarray | None = None, max_distance_m: float = 0.0) -> list[Contact]:
        """The hand's contacts at ``q`` (or at the current configuration) with distance <= ``max_distance_m``.

        Self-collision pairs appear with ``other = "self:<link>"``.
        """
        out = []
        for cp in self._contacts_raw(q):
            if cp[8] > max_distance_m:
                continue
            other = (
                f"self:{self.link_name(cp[4])}"
                if cp[2] == self.hand_id
                else self._names.get(cp[2], str(cp[2]))
            )
            out.append(Contact(self.link_name(cp[3]), other, tuple(cp[5]), tuple(cp[7]), float(cp[8])))
        return out

    def signed_distance(
        self, q: np.ndarray, max_distance_m: float = 0.05, include_object: bool = False
    ) -> float:
        """Smallest signed distance [m] between the hand and the table and obstacles (and the object).

        Negative in penetration; ``max_distance_m`` when nothing is closer than that.
        """
        return float(self.link_signed_distances(q, max_distance_m, include_object).min())

    def link_signed_distances(
        self,
        q: np.ndarray,
        max_distance_m: float = 0.05,
        include_object: bool = False,
        bodies: tuple[int, ...] | None = None,
    ) -> np.ndarray:
        """Per hand link, the smallest signed distance [m] to the table and obstacles (and the object), or
        to the given ``bodies`` (pybullet ids) only.

        Returns:
            (1 + number of links,): the wrist (pybullet index -1) first, then the links in
            :attr:`link_names` order; negative in penetration, ``max_distance_m`` when nothing is closer.
        """
        return self._closest_points(q, max_distance_m, include_object, bodies)[0]

    def link_signed_distance_gradients(
        self,
        q: np.ndarray,
        max_distance_m: float = 0.05,
        include_object: bool = False,
        bodies: tuple[int, ...] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`link_signed_distances` and their gradient, from one query.

        A link's distance changes as its closest point ``p`` moves along the contact normal ``n`` (from the
        other body towards the link; the other body is static): ``d phi = n . dp``, with ``dp`` from the
        hand's analytic kinematics (:meth:`assets.kinematics.HandModel.point_jacobian`). Exact to first
        order wherever the closest features do not switch.

        Returns:
            phi (1 + number of links,) [m] and grad (1 + number of links, dof): the columns are the wrist
            tangent ``[omega (rad), v (m)]`` of ``T_world_wrist @ Exp(xi)`` (GTSAM's Pose3 retract, body
            frame), then the joints in ``q[JOINTS]`` order [rad]; a link with nothing within
            ``max_distance_m`` has a zero row.
        """
        from assets.se3 import pose_from_q

        phi, closest = self._closest_points(q, max_distance_m, include_object, bodies)
        kin, perm = self._kinematics()
        joints = np.empty(kin.n)
        joints[perm] = np.asarray(q, dtype=float)[JOINTS]
        poses = kin.fk(joints)
        T_world_wrist = pose_from_q(q[POSE])
        R, t = T_world_wrist[:3, :3], T_world_wrist[:3, 3]
        grad = np.zeros((len(phi), self.dof))
        for i, (p_world, n_world) in closest.items():
            p_wrist, n_wrist = R.T @ (p_world - t), R.T @ n_world
            grad[i, :3] = np.cross(p_wrist, n_wrist)  # n . R (omega x p_wrist)
            grad[i, 3:6] = n_wrist
            if i > 0:
                J = kin.point_jacobian(joints, self.link_names[i - 1], poses, point=p_wrist)
                grad[i, 6:] = (n_wrist @ J)[perm]
        return phi, grad

    def _closest_points(
        self, q: np.ndarray, max_distance_m: float, include_object: bool, bodies: tuple[int, ...] | None
    ) -> tuple[np.ndarray, dict[int, tuple[np.ndarray, np.ndarray]]]:
        """Per link (wrist first), the smallest signed distance and, where within ``max_distance_m``, its
        closest point on the link and the contact normal (both world frame)."""
        self.set_q(q)
        if bodies is None:
            bodies = self._bodies if include_object else (self.table_id, *self.obstacle_ids)
        out = np.full(1 + len(self.link_names), float(max_distance_m))
        closest: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for b in bodies:
            for p in pb.getClosestPoints(self.hand_id, b, max_distance_m, physicsClientId=self.client):
                i = p[3] - self._root_index  # the root link first
                if p[8] < out[i]:
                    out[i] = p[8]
                    closest[i] = (np.asarray(p[5], dtype=float), np.asarray(p[7], dtype=float))
        return out, closest

    def _kinematics(self):
        """The hand's analytic kinematics and, for each joint of ``q[JOINTS]``, its index in the model."""
        if self._kin is None:
            from assets.kinematics import load_hand_model

            kin = load_hand_model(str(assets.hand_urdf(self.hand)))
            self._kin = (kin, np.array([kin.joint_names.index(n) for n in self.joint_names]))
        return self._kin

    def forget_contacts(self) -> None:
        """Move the hand out of every body's reach and run the collision detection, so that pybullet drops
        the contact points it keeps from one query to the next.

        A deep penetration's point can outlive a teleport: 135 mm inside the table, its normal through the
        table's far side, a link read -253 mm at a configuration 25 cm higher that is free in a fresh world.
        Draws of a strategy never showed it (3660 queries of ham on an arc and chips flat in random order, the
        same answers as with this before each); call it before queries that follow a deep one.
        """
        far = self.rest_q()
        far[2] = 1.0e3
        self.set_q(far)
        pb.performCollisionDetection(physicsClientId=self.client)

    def rest_q(self) -> np.ndarray:
        """The open hand (:func:`hand_rest_joints`) with the wrist at the world origin: (dof,)."""
        return np.concatenate([np.zeros(6), hand_rest_joints(self.hand)])

    # --------------------------------------------------------------------------------------------
    def render(
        self, q: np.ndarray | None = None, width: int = 640, height: int = 480, camera: dict | str = "side"
    ) -> np.ndarray:
        """An RGB picture (height, width, 3) uint8 by pybullet's TinyRenderer (no display needed).

        Args:
            q: hand configuration (default: the current one).
            camera: ``side``, ``top`` or a dict as returned by :func:`default_camera`.
        """
        if q is not None:
            self.set_q(q)
        cam = default_camera(self.scene, camera) if isinstance(camera, str) else camera
        return render_image(self.client, cam, width, height)

    # --------------------------------------------------------------------------------------------
    def close(self) -> None:
        """Disconnect the client (idempotent)."""
        if getattr(self, "client", None) is not None and self.client >= 0:
            try:
                pb.disconnect(physicsClientId=self.client)
            except pb.error:  # already disconnected
                pass
            self.client = -1

    def __enter__(self) -> World:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self):  # pragma: no cover - best effort
        self.close()
