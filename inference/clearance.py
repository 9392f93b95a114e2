"""The clearance of the hand in a scene, smooth and with analytic Jacobians: the constraint of the variation
model's clearance factors (:func:`inference.factors.clearance_factors`).

A clearance function maps ``(T_world_object, T_world_wrist, joints)`` to ``m`` margins [m], each the
distance of something on the hand to something it must keep away from, minus the required clearance:
negative when the constraint is violated. :class:`HandClearance` is the one built from a hand's sphere
cover (:mod:`assets.sphere_cover`) and signed distance fields (:mod:`assets.distance_fields`), as GPMP2's
``ObstacleSDFFactor`` does. Its rows:

* one per sphere ``i`` (centre ``c_i``, radius ``r_i``): ``min(d_env(c_i) - clearance, d_obj(c_i) -
  object_clearance) - r_i``, with ``d_env`` the minimum over the table's and the obstacles' fields (world
  frame) and ``d_obj`` the grasped object's field, held in the object frame (so that the margin depends on
  O and the factor keeps O's Jacobian);
* one per self pair ``(i, j)`` (:meth:`assets.sphere_cover.SphereCover.self_pairs`): ``|c_i - c_j| - r_i -
  r_j - self_clearance``, in the wrist frame.

Jacobians are with respect to GTSAM's right perturbations ``T Exp([omega, v])`` of O and W and the 13
joints; only the rows with a margin below ``active_margin_m`` get theirs (the smooth hinge is zero beyond
its cutoff, so the other rows need none).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Protocol

import numpy as np

from assets.errors import InputError
from assets.sphere_cover import SphereCover

__all__ = ["ClearanceFn", "HandClearance"]


class ClearanceFn(Protocol):
    """``m`` clearance margins [m] of a hand configuration; negative where a constraint is violated."""

    dim: int
    active_margin_m: float  # margins below this are exact and have Jacobians

    def __call__(
        self,
        T_world_object: np.ndarray,
        T_world_wrist: np.ndarray,
        joints: np.ndarray,
        jacobians: bool = False,
    ):
        """Margins (m,), or with ``jacobians`` ``(margins, H_O (m, 6), H_W (m, 6), H_J (m, 13))``; the
        rows of margins >= ``active_margin_m`` may be lower bounds with zero Jacobians."""


class HandClearance:
    """The clearance margins of a sphere-covered hand to a scene and to itself (module docstring).

    Args:
        cover: the hand's spheres.
        environment: the table's and obstacles' fields, world frame (``distance(points (n, 3)) -> (d, g)``).
        object_field: the grasped object's field in the object frame, or None.
        clearance_m, object_clearance_m, self_clearance_m: the required clearances [m].
        self_pairs: (p, 2) sphere index pairs; default ``cover.self_pairs(rest_joints)``.
        rest_joints: (13,) the joints at which touching pairs are found (for the default ``self_pairs``).
        active_margin_m: margins below this are exact and have Jacobians; the others may be lower bounds
            (>= it) without (the smooth hinge of :func:`inference.factors.clearance_error` needs its cutoff).
    """

    def __init__(
        self,
        cover: SphereCover,
        environment: Sequence,
        object_field=None,
        clearance_m: float = 0.010,
        object_clearance_m: float = 0.003,
        self_clearance_m: float = 0.002,
        self_pairs: np.ndarray | None = None,
        rest_joints: np.ndarray | None = None,
        active_margin_m: float = 0.0,
    ):
        for name, value in (("clearance_m", clearance_m), ("object_clearance_m", object_clearance_m),
                            ("self_clearance_m", self_clearance_m),
                            ("active_margin_m", active_margin_m)):  # fmt: skip
            if not (np.isfinite(value) and value >= 0):
                raise InputError(f"{name}: expected a finite number >= 0, found {value!r}")
        self.cover = cover
        self.environment = tuple(environment)
        self.object_field = object_field
        self.clearance_m = float(clearance_m)
        self.object_clearance_m = float(object_clearance_m)
        self.self_clearance_m = float(self_clearance_m)
        self.active_margin_m = float(active_margin_m)
        pairs = cover.self_pairs(rest_joints) if self_pairs is None else np.asarray(self_pairs, dtype=int)
        if (
            pairs.ndim != 2
            or pairs.shape[1] != 2
            or (pairs.size and (pairs.min() < 0 or pairs.max() >= len(cover)))
        ):
            raise InputError(f"self_pairs: expected (p, 2) sphere indices below {len(cover)}")
        self.self_pairs = pairs
        link_pairs = cover.bound_of[pairs] if len(pairs) else np.zeros((0, 2), dtype=int)
        self._link_pairs, self._pair_link_pair = np.unique(link_pairs, axis=0, return_inverse=True)
        self._pair_link_pair = self._pair_link_pair.reshape(-1)
        self._link_pairs = self._link_pairs.reshape(-1, 2)
        self.n_spheres = len(cover)
        self.dim = self.n_spheres + len(pairs)

    def reaching(self, active_margin_m: float) -> HandClearance:
        """A copy whose margins are exact, with Jacobians, below ``active_margin_m`` [m] (>= 0)."""
        if not (np.isfinite(active_margin_m) and active_margin_m >= 0):
            raise InputError(f"active_margin_m: expected a finite number >= 0, found {active_margin_m!r}")
        out = copy.copy(self)
        out.active_margin_m = float(active_margin_m)
        return out

    def with_object(self, object_field) -> HandClearance:
        """A copy whose grasped object is ``object_field`` (in the object frame), everything else equal."""
        out = copy.copy(self)
        out.object_field = object_field
        return out

    def environment_only(self) -> HandClearance:
        """A copy with the table's and the obstacles' rows alone (no grasped object, no self pairs)."""
        return HandClearance(
            self.cover,
            self.environment,
            None,
            clearance_m=self.clearance_m,
            self_pairs=np.zeros((0, 2), dtype=int),
            active_margin_m=self.active_margin_m,
        )

    def object_only(self, active_margin_m: float) -> HandClearance | None:
        """A copy with the grasped object's sphere rows alone, exact below ``active_margin_m`` [m]; None
        without an object field."""
        if self.object_field is None:
            return None
        return HandClearance(
            self.cover,
            (),
            self.object_field,
            object_clearance_m=self.object_clearance_m,
            self_pairs=np.zeros((0, 2), dtype=int),
            active_margin_m=active_margin_m,
        )

    def penetration(self, T_world_object, T_world_wrist, joints) -> np.ndarray:
        """(...,) the smallest distance [m] of a sphere to the scene or of two spheres to each other, without
        clearances: negative where the hand penetrates; exact below ``active_margin_m``."""
        bare = copy.copy(self)
        bare.clearance_m = bare.object_clearance_m = bare.self_clearance_m = 0.0
        return bare(T_world_object, T_world_wrist, joints).min(axis=-1)

    def row_links(self) -> np.ndarray:
        """(dim,) per row, the link of its sphere (the cover's groups) or, for a self row, ``n_links +`` the
        index of its pair of links."""
        links = self.cover.group_of
        pairs = self._pair_link_pair if len(self.self_pairs) else np.zeros(0, dtype=int)
        return np.concatenate([links, links.max() + 1 + pairs])

    def parts(self, with_object: bool = True) -> list[HandClearance]:
        """One clearance per constraint source, each row of which is one smooth function: one per environment
        field and one for the object (their sphere rows; no self rows), and one of the self pairs (its rows
        ``n_spheres..``; sphere rows +inf). The margins of ``self`` are the rows' minimum over the parts."""
        kw = dict(
            clearance_m=self.clearance_m,
            object_clearance_m=self.object_clearance_m,
            self_clearance_m=self.self_clearance_m,
            active_margin_m=self.active_margin_m,
        )
        none = np.zeros((0, 2), dtype=int)
        out = [HandClearance(self.cover, (f,), None, self_pairs=none, **kw) for f in self.environment]
        if self.object_field is not None and with_object:
            out.append(HandClearance(self.cover, (), self.object_field, self_pairs=none, **kw))
        if len(self.self_pairs):
            out.append(HandClearance(self.cover, (), None, self_pairs=self.self_pairs, **kw))
        return out

    def _checks(self):
        """Per field: (field, clearance [m], in the object frame, Lipschitz bound)."""
        out = [(f, self.clearance_m, False, getattr(f, "lipschitz", 1.0)) for f in self.environment]
        if self.object_field is not None:
            out.append((self.object_field, self.object_clearance_m, True, self.object_field.lipschitz))
        return out

    def __call__(self, T_world_object, T_world_wrist, joints, jacobians: bool = False):
        """The margins (..., dim) of wrists (..., 4, 4) and joints (..., 13) (a common batch shape) and,
        with ``jacobians``, ``H_O, H_W`` (..., dim, 6) and ``H_J`` (..., dim, 13), zero where margin >=
        ``active_margin_m``.

        A broad phase bounds groups of a link's spheres by one sphere: where a field's distance at the
        bound's centre, less its clearance and Lipschitz bound times the bound's radius, is >=
        ``active_margin_m``, no sphere of the group comes below that and the group's rows get that lower
        bound instead of their margin (likewise for pairs of groups in the self rows). Margins below
        ``active_margin_m`` are always exact.
        """
        cover, r, g_of, ns = self.cover, self.cover.radii_m, self.cover.bound_of, self.n_spheres
        act_m = self.active_margin_m
        T_world_object = np.asarray(T_world_object, dtype=float)
        joints = np.asarray(joints, dtype=float)
        T_world_wrist = np.asarray(T_world_wrist, dtype=float)
        batch = np.broadcast_shapes(T_world_wrist.shape[:-2], joints.shape[:-1])
        W = np.broadcast_to(T_world_wrist, batch + (4, 4)).reshape(-1, 4, 4)
        J = np.broadcast_to(joints, batch + joints.shape[-1:]).reshape(-1, joints.shape[-1])
        B = len(J)
        R_W, t_W = W[:, :3, :3], W[:, :3, 3]
        R_O, t_O = T_world_object[:3, :3], T_world_object[:3, 3]
        state = cover.state(J)
        bound_wrist = cover.bounds(state)  # (B, G, 3)
        bound_world = np.einsum("bij,bgj->bgi", R_W, bound_wrist) + t_W[:, None]
        # broad phase: per field, the links that may violate its clearance, and the others' lower bound
        checks = []
        for field, clearance, in_object, lipschitz in self._checks():
            pts = (bound_world - t_O) @ R_O if in_object else bound_world
            d = field.distance(pts.reshape(-1, 3))[0].reshape(B, -1)
            low = d - clearance - lipschitz * cover.bound_radii_m
            checks.append((field, clearance, in_object, (low < act_m)[:, g_of], low[:, g_of]))
        qa, qb = self._link_pairs.T
        link_gap = (
            np.linalg.norm(bound_wrist[:, qa] - bound_wrist[:, qb], axis=-1)
            - cover.bound_radii_m[qa]
            - cover.bound_radii_m[qb]
            - self.self_clearance_m
        )[:, self._pair_link_pair]  # (B, p)
        pair_near = link_gap < act_m
        # narrow phase, on the entries (batch, sphere) some check needs
        need = np.zeros((B, ns), dtype=bool)
        for *_, near, _ in checks:
            need |= near
        bp, pp = np.nonzero(pair_near)
        i, j = self.self_pairs[pp, 0], self.self_pairs[pp, 1]
        need[bp, i] = need[bp, j] = True
        bn, sn = np.nonzero(need)
        entry = np.full((B, ns), -1)
        entry[bn, sn] = np.arange(len(bn))
        c_wrist = cover.centers_at(state, bn, sn)  # (K, 3)
        c_world = np.einsum("kij,kj->ki", R_W[bn], c_wrist) + t_W[bn]
        margin = np.min([low for *_, low in checks], axis=0) if checks else np.full((B, ns), np.inf)
        m_e = np.full(len(bn), np.inf)
        grad = np.zeros((len(bn), 3))  # the gradient of the margin w.r.t. the centre, world frame
        by_object = np.zeros(len(bn), dtype=bool)
        for field, clearance, in_object, near, low in checks:
            sel = near[bn, sn]
            m = low[bn, sn]
            pts = c_world[sel]
            if in_object:
                pts = (pts - t_O) @ R_O
            d, dg = field.distance(pts)
            m[sel] = d - clearance - r[sn[sel]]
            closer = m < m_e
            m_e = np.where(closer, m, m_e)
            upd = closer & sel
            grad[upd] = (dg @ R_O.T if in_object else dg)[closer[sel]]
            by_object[closer] = in_object
        margin[bn, sn] = m_e
        self_margin = link_gap.copy()
        ei, ej = entry[bp, i], entry[bp, j]
        diff = c_wrist[ei] - c_wrist[ej]
        dist = np.linalg.norm(diff, axis=-1)
        self_margin[bp, pp] = dist - r[i] - r[j] - self.self_clearance_m
        margins = np.concatenate([margin, self_margin], axis=-1)
        if not jacobians:
            return margins.reshape(batch + (self.dim,))
        H_O = np.zeros((B, self.dim, 6))
        H_W = np.zeros((B, self.dim, 6))
        H_J = np.zeros((B, self.dim, J.shape[-1]))
        act = np.flatnonzero(m_e < act_m)  # active sphere rows, as entries
        ba, sa = bn[act], sn[act]
        hit = self_margin[bp, pp] < act_m
        bs, ps, ei, ej = bp[hit], pp[hit], ei[hit], ej[hit]
        # the Jacobians of the centres that active rows need, once each
        rows = np.unique(np.concatenate([act, ei, ej]))
        Jc = np.zeros((len(bn), 3, J.shape[-1]))
        Jc[rows] = cover.jacobians_at(state, bn[rows], sn[rows], c_wrist[rows])
        g_wrist = np.einsum("ki,kij->kj", grad[act], R_W[ba])  # w.r.t. the centre in the wrist frame
        # c_world(W Exp(xi)) = R_W (c_wrist + omega x c_wrist + v) + t_W: g . (omega x c) = omega . (c x g)
        H_W[ba, sa, :3] = np.cross(c_wrist[act], g_wrist)
        H_W[ba, sa, 3:] = g_wrist
        H_J[ba, sa] = np.einsum("ki,kij->kj", g_wrist, Jc[act])
        o = act[by_object[act]]
        if len(o):  # c_object(O Exp(d)) = Exp(-d) c_object: d c_object = -omega x c - v
            g_obj = grad[o] @ R_O
            c_object = (c_world[o] - t_O) @ R_O
            H_O[bn[o], sn[o], :3] = np.cross(g_obj, c_object)
            H_O[bn[o], sn[o], 3:] = -g_obj
        u = diff[hit] / np.maximum(dist[hit], 1e-12)[:, None]
        H_J[bs, ns + ps] = np.einsum("ki,kij->kj", u, Jc[ei] - Jc[ej])
        shape = batch + (self.dim,)
        return margins.reshape(shape), *(H.reshape(shape + H.shape[-1:]) for H in (H_O, H_W, H_J))
