"""The scene's clearance in the marginals, by expectation propagation (our addition; docs/method.md).

The clearance factors (:func:`inference.factors.clearance_factors`) move the *means* out of the scene, but a
hinge says nothing where a margin is positive, so the marginals keep the width of the demonstration's
variation towards an obstacle or the object that the mean only just clears, and their draws collide. Here
every clearance row ``u_i = margin_i(W_t, J_t)`` whose marginal puts more than
``params.clearance_site_min_probability`` below zero gets a Gaussian *site* over ``u_i`` such that the
marginal of ``u_i`` has the mean and variance of its cavity (the marginal without the site) truncated to
``u_i >= 0``: the moment matching of expectation propagation for linear inequalities (Cunningham, Hennig
and Lacoste-Julien, "Gaussian probabilities and expectation propagation", 2011), with each margin
linearized at the current solution (:meth:`inference.clearance.HandClearance.__call__`'s Jacobians).

A site is a linear Gaussian factor on ``(W_t, J_t)``, ``gtsam.LinearContainerFactor`` around the point where
its Jacobian was taken, so that the graph's optimizer moves the mean with it and ``gtsam.Marginals`` takes it
into the covariance. Sites live in margin units [m], which do not depend on the linearization point; updates
are damped in the natural parameters, like the joint limits' (:mod:`inference.joint_limits`).
"""

from __future__ import annotations

import gtsam
import numpy as np
from scipy.special import ndtr

from assets.se3 import se3_inverse, se3_log

from .clearance import ClearanceFn
from .graph import key_j, key_w, means_of
from .joint_limits import truncated_normal_moments
from .params import VariationParams

__all__ = ["ClearanceSites"]

_MAX_PRECISION = 1.0 / (0.1e-3) ** 2  # [1/m^2] a site holds a margin to 0.1 mm at most


class ClearanceSites:
    """The clearance ``margin >= 0`` of every row of every step by expectation propagation (module doc).

    The rows are those of the clearance's parts (:meth:`inference.clearance.HandClearance.parts`: one per
    field and the self pairs), so that each site's margin is one smooth function; a minimum over fields
    switches its gradient where two fields are equally near (a fingertip between the table and a lying
    can), and the sites on it then cycle.

    Args:
        clearance: the scene's margins; rows are evaluated exactly up to ``params.clearance_site_reach_mm``.
        n: the number of steps.
        T_world_object: (4, 4) the object pose at which the steps' margins are taken (O is held fixed).
        params: ``clearance_site_*``.

    Falsy when ``params.clearance_sites`` is off or without a clearance.
    """

    def __init__(self, clearance: ClearanceFn | None, n: int, T_world_object, params: VariationParams):
        self.n = n
        self.enabled = clearance is not None and params.clearance_sites
        parts = []
        if self.enabled:
            with_object = params.clearance_site_object
            parts = clearance.parts(with_object) if hasattr(clearance, "parts") else [clearance]
            reach = params.clearance_site_reach_mm * 1e-3
            parts = [p.reaching(reach) if hasattr(p, "reaching") else p for p in parts]
        T = np.asarray(T_world_object, dtype=float)
        self.parts = [_PartSites(p, n, T, params) for p in parts]
        self.damping = params.clearance_site_damping
        self.updates = 0
        self._last: tuple | None = None  # (W, J, stds) of the last update, where the sites are linearized

    DAMPING_HALF_LIFE = 10  # [updates] the damping halves after this many updates, a third after twice

    def __bool__(self) -> bool:
        return self.enabled

    def steps(self) -> np.ndarray:
        """(T,) bool: the steps with a site."""
        out = np.zeros(self.n, dtype=bool)
        for part in self.parts:
            out |= np.any(part.tau > 0, axis=1)
        return out

    def add_to(self, graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
        """``graph`` plus, per step with sites, one linear factor ``N(margin_i; nu_i / tau_i, 1 / tau_i)``
        over its site rows, linearized where the sites were last updated."""
        for t in np.flatnonzero(self.steps()):
            rows = [part.rows(int(t)) for part in self.parts]
            A = np.concatenate([r[0] for r in rows])
            b = np.concatenate([r[1] for r in rows])
            W, J = self._last[0][t], self._last[1][t]
            factor = gtsam.JacobianFactor(
                key_w(int(t)),
                np.asfortranarray(A[:, :6]),
                key_j(int(t)),
                np.asfortranarray(A[:, 6:]),
                b,
                gtsam.noiseModel.Unit.Create(len(b)),
            )
            at = gtsam.Values()
            at.insert(key_w(int(t)), gtsam.Pose3(W))
            at.insert(key_j(int(t)), J)
            graph.add(gtsam.LinearContainerFactor(factor, at))
        return graph

    def update(self, values: gtsam.Values, covs: np.ndarray) -> float:
        """One damped EP update of every site at ``values`` with the steps' marginal covariances ``covs``
        (T, 19, 19) ``[omega, v, joints]``; returns how far the steps' marginals moved since the last update:
        the largest change of a coordinate's mean or std, in that coordinate's std (infinite at the first,
        0 when no row needs a site). The damping decays with the updates (``DAMPING_HALF_LIFE``): the
        margins are relinearized at each one, and a constant damping leaves the means jittering by some
        0.2 std."""
        W, J = means_of(values, self.n)
        damping = self.damping / (1.0 + self.updates / self.DAMPING_HALF_LIFE)
        self.updates += 1
        any_site = [part.update(W, J, covs, damping) for part in self.parts]
        std = np.sqrt(np.diagonal(covs, axis1=1, axis2=2))
        now = (W, J, std)
        last, self._last = self._last, now
        if not any(any_site):
            return 0.0
        if last is None:
            return np.inf
        xi = se3_log(se3_inverse(last[0]) @ W)  # (T, 6) [omega, v]
        moved = np.concatenate([np.abs(xi), np.abs(J - last[1]), np.abs(std - last[2])], axis=1)
        return float((moved / np.concatenate([last[2], last[2]], axis=1)).max())


class _PartSites:
    """The sites of one part of the clearance (:class:`ClearanceSites`)."""

    def __init__(self, clearance: ClearanceFn, n: int, T_world_object: np.ndarray, params: VariationParams):
        self.clearance = clearance
        self.T_world_object = T_world_object
        self.group = _row_groups(clearance)  # (dim,) each row's group
        self.softmin_m = params.clearance_site_softmin_mm * 1e-3
        g = int(self.group.max()) + 1 if len(self.group) else 0
        self.tau = np.zeros((n, g))  # site precisions [1/m^2]
        self.nu = np.zeros((n, g))  # site precision x mean [1/m]
        self.at: tuple = ()  # (margins (T, G), H (T, G, 19)) of the groups at the last update
        self.min_probability = params.clearance_site_min_probability

    def rows(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Step ``t``'s site rows as ``(A (k, 19), b (k,))``: ``|A dx - b|^2`` is the sites' error at
        ``dx`` from the point of the last update."""
        rows = np.flatnonzero(self.tau[t] > 0)
        s = np.sqrt(self.tau[t, rows])
        margins, H = self.at[0][t], self.at[1][t]
        return s[:, None] * H[rows], self.nu[t, rows] / s - s * margins[rows]  # b: sqrt(tau) (mean - margin)

    def update(self, W: np.ndarray, J: np.ndarray, covs: np.ndarray, damping: float) -> bool:
        """One update of this part's sites at wrists ``W`` and joints ``J`` (:meth:`ClearanceSites.update`)
        with ``damping``; False when no row needs a site."""
        m, _, H_W, H_J = self.clearance(self.T_world_object, W, J, jacobians=True)
        m, H = _softmin(m, np.concatenate([H_W, H_J], axis=-1), self.group, self.tau.shape[1], self.softmin_m,
                        self.clearance.active_margin_m)  # fmt: skip
        self.at = (m, H)
        v = np.einsum("tij,tjk,tik->ti", H, covs, H)
        exact = (m < self.clearance.active_margin_m) & (v > 0)
        self.tau[~exact] = 0.0  # a row that left the reach (or has no Jacobian) loses its site
        self.nu[~exact] = 0.0
        with np.errstate(divide="ignore", invalid="ignore"):
            tau_c = np.where(exact, 1.0 / v, 0.0) - self.tau
            nu_c = np.where(exact, m / v, 0.0) - self.nu
            ok = exact & (tau_c > 0)
            m_c = np.where(ok, nu_c / np.where(ok, tau_c, 1.0), 0.0)
            s_c = np.where(ok, 1.0 / np.sqrt(np.where(ok, tau_c, 1.0)), 1.0)
        alpha = -m_c / s_c
        todo = ok & ((ndtr(alpha) > self.min_probability) | (self.tau > 0))
        if not todo.any():
            return False
        mean_z, var_z = truncated_normal_moments(alpha[todo], np.full(int(todo.sum()), np.inf))
        mean_t, var_t = m_c[todo] + s_c[todo] * mean_z, s_c[todo] ** 2 * var_z
        with np.errstate(divide="ignore"):
            tau_new = np.clip(1.0 / var_t - tau_c[todo], 0.0, _MAX_PRECISION)
        nu_new = (tau_new + tau_c[todo]) * mean_t - tau_c[todo] * m_c[todo]
        self.tau[todo] = (1 - damping) * self.tau[todo] + damping * tau_new
        self.nu[todo] = (1 - damping) * self.nu[todo] + damping * nu_new
        self.nu[self.tau <= 0] = 0.0
        return True


def _row_groups(clearance: ClearanceFn) -> np.ndarray:
    """(dim,) a group per row: :meth:`inference.clearance.HandClearance.row_links` (the spheres of one link
    overlap, and a site on each would count the same truncation several times); any other clearance's rows
    one each."""
    row_links = getattr(clearance, "row_links", None)
    return np.arange(clearance.dim) if row_links is None else row_links()


def _softmin(m, H, group, n_groups: int, s: float, reach: float):
    """Per step and group the soft minimum ``-s log sum exp(-m_i / s)`` of the exact rows (margins below
    ``reach``) and its Jacobian ``sum w_i H_i`` (w the soft-min weights); groups without an exact row get
    ``reach`` and a zero Jacobian. ``m`` (T, dim), ``H`` (T, dim, 19) -> (T, G), (T, G, 19)."""
    T = m.shape[0]
    exact = m < reach
    m_min = np.full((T, n_groups), np.inf)
    np.minimum.at(m_min, (slice(None), group), np.where(exact, m, np.inf))
    has = np.isfinite(m_min)
    m_min = np.where(has, m_min, 0.0)
    e = np.where(exact, np.exp(-(np.where(exact, m, 0.0) - m_min[:, group]) / s), 0.0)
    z = np.zeros((T, n_groups))
    np.add.at(z, (slice(None), group), e)
    m_g = np.where(has, m_min - s * np.log(np.where(has, z, 1.0)), reach)
    w = e / np.where(has, z, 1.0)[:, group]
    H_g = np.zeros((T, n_groups, H.shape[-1]))
    np.add.at(H_g, (slice(None), group), w[..., None] * H)
    return m_g, H_g
