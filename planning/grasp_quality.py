"""GraspIt!'s epsilon quality (L1 grasp wrench space, unit-ball task wrench space), as a pure function.

The paper scores a closed grasp with GraspIt!'s "Epsilon quality measure (L1 norm, unit ball TWS)":
every contact contributes the edges of its linearised Coulomb friction cone with unit normal force; the
grasp wrench space (GWS) is the convex hull of all those edge wrenches; epsilon is the radius of the
largest origin-centred ball inside it, i.e. the smallest distance from the origin to a facet
hyperplane. Torques are divided by the object's largest radius about its centre of mass, as GraspIt!
does (``wrenchFromFrictionEdge`` in ``src/contact/contact.cpp``), so forces and torques share a unit.

Qhull ('QJ', joggled input) builds the hull; joggling perturbs the points by ~1e-11 relative, so the
facet offsets are recomputed from the *unperturbed* wrenches: ``h(n_f) = max_i n_f . w_i`` for each
facet normal ``n_f``. Every ``h(n)`` is >= the true epsilon (the support function bounds the inscribed
ball from above) and equals it at the true closest facet normal, so the minimum is epsilon up to the
normal's joggle error. Measured on 4 contacts x 8 edges (``pbdgrasp bench``): 'QJ' is faster than
scipy's default options ('Qbb Qc Qz Qx', which merge coplanar facets) and never raises the precision
errors (QH6154, QH6013) that coplanar cone edges provoke.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from assets.errors import InputError

__all__ = [
    "EPSILON_ZERO",
    "QHULL_OPTIONS",
    "tangent_basis",
    "friction_cone_edges",
    "contact_wrenches",
    "epsilon_from_wrenches",
    "epsilon_l1",
]

_log = logging.getLogger(__name__)

EPSILON_ZERO = 1e-9
"""Qualities below this are reported as 0 (the origin on, or numerically on, a facet)."""

QHULL_OPTIONS = "QJ"
"""Qhull options: joggle the input so that coplanar cone edges never raise precision errors."""

_RANK_TOL = 1e-9  # relative singular value under which the wrenches are taken not to span 6-D


def tangent_basis(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The fixed tangent basis of each contact: e = least aligned axis, t1 = n x e / |n x e|, t2 = n x t1.

    Args:
        normals: (n, 3) unit contact normals.

    Returns:
        ``(t1, t2)``, each (n, 3); ``(t1, t2, n)`` is a right-handed orthonormal frame.
    """
    normals = np.asarray(normals, dtype=float)
    axis = np.argmin(np.abs(normals), axis=1)  # argmin returns the first index on ties
    e = np.eye(3)[axis]
    t1 = np.cross(normals, e)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    return t1, t2


def friction_cone_edges(normals: np.ndarray, friction: float, num_cone_edges: int = 8) -> np.ndarray:
    """Edges ``f = n + mu (cos a_k t1 + sin a_k t2)``, ``a_k = 2 pi k / K``, of each contact's cone.

    Args:
        normals: (n, 3) unit normals pointing into the object.
        friction: Coulomb coefficient mu >= 0.
        num_cone_edges: K, edges per cone.

    Returns:
        (n, K, 3) edge forces with unit normal component.
    """
    normals = np.asarray(normals, dtype=float)
    t1, t2 = tangent_basis(normals)
    a = 2.0 * np.pi * np.arange(num_cone_edges) / num_cone_edges
    return normals[:, None, :] + friction * (
        np.cos(a)[None, :, None] * t1[:, None, :] + np.sin(a)[None, :, None] * t2[:, None, :]
    )


def contact_wrenches(
    contact_points: np.ndarray,
    contact_normals: np.ndarray,
    friction: float,
    center: np.ndarray,
    torque_radius: float,
    num_cone_edges: int = 8,
) -> np.ndarray:
    """All edge wrenches ``[f; (p - center) x f / torque_radius]`` of a grasp: (n * K, 6).

    Args: as :func:`epsilon_l1`.
    """
    p = np.asarray(contact_points, dtype=float)
    f = friction_cone_edges(contact_normals, friction, num_cone_edges)  # (n, K, 3)
    r = (p - np.asarray(center, dtype=float))[:, None, :]
    torque = np.cross(np.broadcast_to(r, f.shape), f) / torque_radius
    return np.concatenate([f, torque], axis=-1).reshape(-1, 6)


def epsilon_from_wrenches(wrenches: np.ndarray, qhull_options: str = QHULL_OPTIONS) -> float:
    """The smallest distance from the origin to the boundary of ``conv(wrenches)``; 0 without closure.

    Args:
        wrenches: (m, 6) points of the grasp wrench space.
        qhull_options: passed to Qhull (see :data:`QHULL_OPTIONS`).

    Returns:
        epsilon >= 0; exactly 0.0 when the wrenches do not span 6-D, Qhull fails, the origin is not
        strictly inside the hull, or the distance is below :data:`EPSILON_ZERO`.
    """
    w = np.asarray(wrenches, dtype=float)
    if w.shape[0] < 7:
        return 0.0
    # Force closure needs the origin strictly inside, hence a 6-D *linear* span of the wrenches.
    sv = np.linalg.svd(w, compute_uv=False)
    if sv[-1] <= _RANK_TOL * max(sv[0], 1e-300):
        return 0.0
    try:
        hull = ConvexHull(w, qhull_options=qhull_options)
    except (QhullError, ValueError) as exc:
        _log.debug("Qhull failed (%s): epsilon = 0", str(exc).splitlines()[0] if str(exc) else exc)
        return 0.0
    normals = hull.equations[:, :6]
    normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
    # Offsets from the unperturbed points (Qhull's offsets belong to the joggled ones).
    support = (normals @ w.T).max(axis=1)
    eps = float(support.min())
    if not np.isfinite(eps) or eps < EPSILON_ZERO:
        return 0.0
    return eps


def epsilon_l1(
    contact_points: np.ndarray,
    contact_normals: np.ndarray,
    friction: float,
    center: np.ndarray,
    torque_radius: float,
    num_cone_edges: int = 8,
) -> float:
    """GraspIt!'s epsilon quality (L1 GWS, unit-ball TWS) of a set of frictional point contacts.

    Args:
        contact_points: (n, 3) [m] contact positions, in any one frame.
        contact_normals: (n, 3) unit normals in the same frame, pointing into the object (the direction
            in which the finger pushes); they are renormalised.
        friction: Coulomb coefficient mu >= 0.
        center: (3,) [m] the object's centre of mass, same frame.
        torque_radius: [m] the object's largest distance from its centre of mass; torques are divided
            by it.
        num_cone_edges: edges of each linearised friction cone (GraspIt!'s point contact uses 8).

    Returns:
        epsilon in [0, 1] (unitless); 0.0 for no contact, no force closure or degenerate contacts.

    Raises:
        InputError: wrong shapes, non-finite values, a zero normal, negative friction, a
            non-positive torque radius or fewer than 3 cone edges.
    """
    try:
        p = np.asarray(contact_points, dtype=float).reshape(-1, 3)
        n = np.asarray(contact_normals, dtype=float).reshape(-1, 3)
        c = np.asarray(center, dtype=float).reshape(3)
    except ValueError as exc:
        raise InputError(f"epsilon_l1: contacts must be (n, 3) and center (3,): {exc}") from None
    if p.shape != n.shape:
        raise InputError(f"epsilon_l1: {p.shape[0]} contact points but {n.shape[0]} normals")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(n)) and np.all(np.isfinite(c))):
        raise InputError("epsilon_l1: non-finite contact point, normal or center")
    if not (np.isfinite(friction) and friction >= 0):
        raise InputError(f"epsilon_l1: friction must be a finite number >= 0, found {friction}")
    if not (np.isfinite(torque_radius) and torque_radius > 0):
        raise InputError(f"epsilon_l1: torque_radius must be > 0 m, found {torque_radius}")
    if int(num_cone_edges) != num_cone_edges or num_cone_edges < 3:
        raise InputError(f"epsilon_l1: num_cone_edges must be an integer >= 3, found {num_cone_edges}")
    if p.shape[0] == 0:
        return 0.0
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    if np.any(norm < 1e-12):
        raise InputError("epsilon_l1: a contact normal has zero length")
    w = contact_wrenches(p, n / norm, friction, c, torque_radius, int(num_cone_edges))
    return epsilon_from_wrenches(w)
