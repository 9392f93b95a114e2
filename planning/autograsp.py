"""phi_o(q): close the hand until contact (GraspIt!'s autoGrasp) and score the grasp with epsilon.

The paper (section III) computes phi_o in two steps: put the hand at q, close it "with uniform speed until
all fingers have contact or the joint limits are reached" (GraspIt!'s autoGrasp), then score the
contacts with the epsilon quality (:func:`planning.grasp_quality.epsilon_l1`).

Closing, as GraspIt!'s ``Robot::autoGrasp`` does it, on a :class:`planning.world.World`:

* The *closing joints* are the flexion joints of every finger, proximal and middle (the distal joint
  follows the middle one 1:1); abduction and the thumb's base rotation keep their values from q.
* All closing joints that still move advance by the same angle each step (``step_rad``) towards their
  upper limit. After each step the hand's contacts are queried once (one ``performCollisionDetection``
  and one ``getContactPoints``).
* A link that touches anything (the target, the table, an obstacle, another finger), i.e. is closer
  than ``touch_margin_m``, stops every closing joint that moves it: the joint it hangs on and every
  closing joint before it in its finger. A proximal phalanx that touches stops the proximal joint
  and lets the middle one curl on; a touching middle or distal phalanx stops the whole finger.
* A step after which some link penetrates deeper than ``max_penetration_m`` is undone and retried at
  half the angle (down to ``min_step_rad``), so the closed hand touches without sinking in.
* A configuration that is already in collision (``World.is_free(q)`` false) scores 0 without closing.

The contacts with the target object are pybullet's contact points of the closed hand closer than
``touch_margin_m``; their normals are turned to point into the object (the direction the finger pushes).
Points, normals and the object's centre of mass are in the world frame (the centre of mass: the asset's
``center_of_mass_m`` posed by the scene's ``T_world_object``; pybullet's base position is the inertial
frame already, so adding the offset to it would count it twice); the torque radius is the object's
``max_radius_m`` (GraspIt!'s ``maxRadius``).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

import assets
from assets import sah
from assets.errors import InputError
from assets.q_layout import Q_DIM

from ._pybullet import pb
from .grasp_quality import epsilon_l1

__all__ = ["AutoGraspConfig", "GraspResult", "HandCloser", "phi_o"]

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class AutoGraspConfig:
    """Parameters of the closing and of the quality.

    Attributes:
        step_rad: joint advance per step; smaller is slower and more exact (GraspIt! ~ its DOF speed x
            ``AUTO_GRASP_TIME_STEP``).
        min_step_rad: the smallest step the bisection goes down to near a contact.
        touch_margin_m: a link closer than this to something touches it (stops; its contacts count).
        max_penetration_m: a step that sinks a link deeper than this is retried at half the angle.
        num_cone_edges: friction cone edges of each contact (GraspIt!: 8).
        friction: Coulomb coefficient; None takes the object's asset metadata (``friction``).
        merge_radius_m: contact points of one link closer than this are merged into one (mean point
            and normal). pybullet reports one point per convex piece of the object that a link touches
            (up to 4 per link and body), so a link has several only where it touches several pieces (a
            fingertip in the groove between the jam jar's lid and body, a mug's segments).
        max_contacts_per_link: the contact patch of a link is kept as at most this many points: 1 is the
            patch's centroid with its mean normal; 2 or more keep the most distant points (2: a line
            contact exactly, a face contact by its diameter). The default 4 keeps every piece's point
            as a contact, as GraspIt! does, instead of one centroid off the surface with a mean normal.
            Qhull's time grows with the contacts (4 ~3 ms, 7 ~15 ms, 12 ~55 ms here).
    """

    step_rad: float = np.deg2rad(2.0)
    min_step_rad: float = np.deg2rad(0.125)
    touch_margin_m: float = 0.001
    max_penetration_m: float = 0.001
    num_cone_edges: int = 8
    friction: float | None = None
    merge_radius_m: float = 0.005
    max_contacts_per_link: int = 4

    def __post_init__(self):
        if not (0 < self.min_step_rad <= self.step_rad <= np.deg2rad(20.0)):
            raise InputError(
                f"AutoGraspConfig: need 0 < min_step_rad <= step_rad <= 20 deg, found "
                f"{self.min_step_rad}, {self.step_rad} rad"
            )
        if not (self.touch_margin_m >= 0 and self.max_penetration_m > 0):
            raise InputError("AutoGraspConfig: touch_margin_m must be >= 0 m and max_penetration_m > 0 m")
        if self.merge_radius_m < 0 or self.max_contacts_per_link < 1:
            raise InputError("AutoGraspConfig: need merge_radius_m >= 0 m and max_contacts_per_link >= 1")
        if self.friction is not None and not self.friction >= 0:
            raise InputError(f"AutoGraspConfig: friction must be >= 0, found {self.friction}")


@dataclass(frozen=True)
class GraspResult:
    """The outcome of closing the hand at q and scoring it.

    Attributes:
        quality: epsilon (L1), >= 0; 0 for collisions and grasps without force closure.
        closed_q: (19,) [m, rad] the configuration after closing (q itself if it was in collision).
        contact_points_world: (n, 3) [m] contact points on the object's surface.
        contact_normals_world: (n, 3) unit normals pointing into the object.
        contact_links: (n,) names of the hand links in contact.
        in_collision: q was in collision before closing.
        steps: closing steps taken (collision queries, bisections included).
        time_s: wall time of the close-and-score.
        message: a one-line reason (what stopped, why 0).
    """

    quality: float
    closed_q: np.ndarray
    contact_points_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    contact_normals_world: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    contact_links: tuple[str, ...] = ()
    in_collision: bool = False
    steps: int = 0
    time_s: float = 0.0
    message: str = ""

    @property
    def success(self) -> bool:
        """Force closure: quality > 0."""
        return self.quality > 0.0


class HandCloser:
    """Closes the SAH in a world and scores the grasp; holds the link-to-joint maps of one world.

    Args:
        world: a :class:`planning.world.World` with the SAH.
        config: closing and quality parameters.
    """

    def __init__(self, world, config: AutoGraspConfig | None = None):
        self.world = world
        self.config = config or AutoGraspConfig()
        self.client = world.client
        self.hand_id = world.hand_id
        self.object_id = world.object_id
        meta = assets.object_metadata(world.scene.object.name)
        self.friction = float(meta["friction"] if self.config.friction is None else self.config.friction)
        self.torque_radius_m = float(meta["max_radius_m"])
        T_world_object = world.scene.T_world_object
        #: (3,) [m] the object's centre of mass in the world, the torques' reference point
        self.com_world = (
            T_world_object[:3, :3] @ np.asarray(meta["center_of_mass_m"], float) + T_world_object[:3, 3]
        )
        closing = [f"{f}_{j}" for f in sah.FINGERS for j in ("prox", "mid")]
        self.closing = np.array([sah.JOINT_NAMES.index(j) for j in closing])  # indices into the 13 joints
        self.upper = np.asarray(sah.JOINT_LIMITS, dtype=float)[self.closing, 1]
        self._link_names, self._stops = self._link_maps(closing)

    def _link_maps(self, closing: list[str]):
        """Per pybullet link index: its name and the closing joints (positions in self.closing) moving it."""
        n = pb.getNumJoints(self.hand_id, physicsClientId=self.client)
        info = [pb.getJointInfo(self.hand_id, j, physicsClientId=self.client) for j in range(n)]
        joint_name = [i[1].decode() for i in info]
        parent = [i[16] for i in info]
        link_names = {j: info[j][12].decode() for j in range(n)}  # the floating joints' links never touch
        # a distal joint follows its middle joint 1:1: moving it counts as moving the middle joint
        follows = {f"{f}_dist": f"{f}_mid" for f in sah.FINGERS}
        stops = {}
        for j in range(n):
            mask = np.zeros(len(closing), bool)
            k = j
            while k >= 0:
                name = follows.get(joint_name[k], joint_name[k])
                if name in closing:
                    mask[closing.index(name)] = True
                k = parent[k]
            stops[j] = mask
        return link_names, stops

    def close(self, q: np.ndarray) -> GraspResult:
        """Place the hand at ``q`` (19,) [m, rad], close it until contact and score the grasp."""
        t0 = time.perf_counter()
        q = np.array(q, dtype=float).reshape(-1)
        if q.shape != (Q_DIM,) or not np.all(np.isfinite(q)):
            raise InputError(f"phi_o: q must be 19 finite numbers, found shape {q.shape}")
        if not self.world.is_free(q):
            self.world.set_q(q)
            return GraspResult(
                0.0,
                q,
                in_collision=True,
                time_s=time.perf_counter() - t0,
                message="in collision before closing",
            )
        cfg = self.config
        moving = q[6 + self.closing] < self.upper - 1e-12
        steps = 0
        step = cfg.step_rad
        while moving.any():
            q_try = q.copy()
            idx = 6 + self.closing[moving]
            q_try[idx] = np.minimum(q[idx] + step, self.upper[moving])
            self.world.set_q(q_try)
            dist_by_link = self._link_distances()
            steps += 1
            deepest = min(dist_by_link.values(), default=np.inf)
            if deepest < -cfg.max_penetration_m and step > cfg.min_step_rad:
                step = max(step / 2.0, cfg.min_step_rad)
                continue
            q = q_try
            for link, d in dist_by_link.items():
                if d < cfg.touch_margin_m:
                    moving &= ~self._stops[link]
            moving &= q[6 + self.closing] < self.upper - 1e-12
            step = cfg.step_rad
        self.world.set_q(q)
        points, normals, links = self._object_contacts()
        quality = (
            epsilon_l1(
                points, normals, self.friction, self.com_world, self.torque_radius_m, cfg.num_cone_edges
            )
            if len(points)
            else 0.0
        )
        msg = f"{len(points)} contacts on {len(set(links))} links; " + (
            "force closure" if quality > 0 else "no force closure"
        )
        return GraspResult(
            quality, q, points, normals, tuple(links), False, steps, time.perf_counter() - t0, msg
        )

    def close_many(self, qs: np.ndarray) -> list[GraspResult]:
        """:meth:`close` at each row of ``qs`` (n, 19), in order; on several cores:
        :class:`planning.closing_pool.ClosingPool`, which has the same method."""
        return [self.close(q) for q in np.atleast_2d(np.asarray(qs, dtype=float))]

    def _link_distances(self) -> dict[int, float]:
        """The smallest signed distance [m] of each hand link to anything it has contact points with."""
        pb.performCollisionDetection(physicsClientId=self.client)
        out: dict[int, float] = {}
        for c in pb.getContactPoints(bodyA=self.hand_id, physicsClientId=self.client):
            d = c[8]
            for body, link in ((c[1], c[3]), (c[2], c[4])):
                if body == self.hand_id and d < out.get(link, np.inf):
                    out[link] = d
        return out

    def _object_contacts(self):
        """Contacts of the hand with the target: points (n, 3), inward normals (n, 3), link names."""
        pb.performCollisionDetection(physicsClientId=self.client)
        by_link: dict[int, list] = {}
        for c in pb.getContactPoints(bodyA=self.hand_id, bodyB=self.object_id, physicsClientId=self.client):
            if c[8] < self.config.touch_margin_m:
                # position on B (the object); B's normal points from B to A, the finger pushes along -n
                by_link.setdefault(c[3], []).append((c[6], [-x for x in c[7]]))
        pts, nrm, links = [], [], []
        for link, items in sorted(by_link.items()):
            p, n = _reduce_patch(
                np.array([i[0] for i in items]),
                np.array([i[1] for i in items]),
                self.config.merge_radius_m,
                self.config.max_contacts_per_link,
            )
            pts.append(p)
            nrm.append(n)
            links += [self._link_names.get(link, str(link))] * len(p)
        if not pts:
            return np.zeros((0, 3)), np.zeros((0, 3)), []
        return np.concatenate(pts), np.concatenate(nrm), links


def _reduce_patch(points: np.ndarray, normals: np.ndarray, merge_radius_m: float, max_points: int):
    """One link's contact points (k, 3) and normals (k, 3) -> at most ``max_points`` representatives.

    With ``max_points == 1`` the result is the centroid and the renormalised mean normal. Otherwise
    points closer than ``merge_radius_m`` are merged greedily (mean point, renormalised mean normal),
    then the most distant points are kept (farthest-point order starting from the farthest pair). The
    points are taken in lexicographic order of (point, normal), so the result does not depend on the
    order pybullet reports them in, which for an object of many convex pieces (the mugs) changes with
    the world's history.
    """
    order = np.lexsort(np.column_stack([points, normals]).T[::-1])
    points, normals = points[order], normals[order]
    groups: list[list[int]] = []
    for i in range(len(points)):
        for g in groups:
            if np.linalg.norm(points[g[0]] - points[i]) < merge_radius_m:
                g.append(i)
                break
        else:
            groups.append([i])
    if max_points == 1:
        groups = [list(range(len(points)))]
    p = np.array([points[g].mean(axis=0) for g in groups])
    n = np.array([normals[g].sum(axis=0) for g in groups])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    if len(p) <= max_points:
        return p, n
    d = np.linalg.norm(p[:, None] - p[None], axis=-1)
    first = np.unravel_index(np.argmax(d), d.shape)
    keep = list(first[:max_points])
    while len(keep) < max_points:
        keep.append(int(np.argmax(d[keep].min(axis=0))))
    return p[keep], n[keep]


def phi_o(world, q: np.ndarray, config: AutoGraspConfig | None = None) -> GraspResult:
    """Close the hand at ``q`` (19,) in ``world`` and score it; see :class:`HandCloser`."""
    return HandCloser(world, config).close(q)
