"""The sampling distribution P(Y) of the planner (paper section VII), vectorized.

The scheme, for each sample: strategy ``s ~ P(S)`` (``beta`` for the uniform strategy, ``(1 - beta) / n``
for each of the ``n`` learned models); object ``o ~ P(O_s) = N(mu_o, Sigma_o)`` drawn as
``mu_o Exp(xi_o)``; step ``k ~ U(0..T_s - 1)``; configuration ``y ~ P(X_sk | o)``: wrist
``o @ T_object_wrist_mean[k] @ Exp(xi_w)`` and joints ``joints_mean[k] + dj`` clipped to the joint limits,
with ``[xi_w, dj] ~ N(0, cov[k])`` (``[omega, v, joints]``, GTSAM's Pose3 body tangent). The uniform
strategy (the paper's T_0 = 1) draws the wrist position uniformly in the given bounds, its rotation
uniformly on SO(3) (normalized 4-D Gaussian quaternions) and the joints uniformly in their limits.

Samples are configurations ``q = [p (3, m), rotation vector (3, rad), joints (13, rad)]`` in the WORLD frame,
returned with their strategy (``-1`` uniform, else the model's index), their step ``k`` (0-based; 0 for
uniform) and ``is_last = (k == T_s - 1)``; for the uniform strategy T_0 = 1, so ``is_last`` is True there too,
as in the paper, where the goal test runs on every sample with ``k = T_s``.

Speed: counts per (strategy, step) are drawn at once (a multinomial), the Gaussians per group by one matrix
product each, and the rigid-body algebra is done on unit quaternions component-wise (no Python loop over
samples, no per-sample 4x4 products); the output is shuffled so that its order is i.i.d.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from assets.errors import InputError
from assets.q_layout import JOINTS, POS, Q_DIM, ROT, TAN_POSE
from assets.se3 import (
    pose_rows_compose,
    quat_rows_from_matrix,
    quat_rows_mul,
    quat_rows_rotate,
    retract,
    rotvec_rows_from_quat,
)

from .model import VariationModel

__all__ = ["MixtureSampler", "MixtureSample", "sample", "sample_marginal", "sample_object"]


class MixtureSample(NamedTuple):
    """``n`` draws from P(Y): ``q`` (n, 19) world frame, ``strategy`` (n,) int (-1 uniform), ``k`` (n,) int
    (0-based step), ``is_last`` (n,) bool (``k == T_s - 1``)."""

    q: np.ndarray
    strategy: np.ndarray
    k: np.ndarray
    is_last: np.ndarray


def _default_limits() -> np.ndarray:
    from assets import sah

    return np.asarray(sah.JOINT_LIMITS, dtype=float)


class MixtureSampler:
    """P(Y): the uniform strategy with probability ``beta`` and the learned models sharing the rest equally.

    Args:
        models: the learned variation models (strategies); may be empty only if ``beta == 1``.
        wrist_bounds_lo, wrist_bounds_hi: (3,) [m] world box of the uniform strategy's wrist positions.
        beta: probability of the uniform strategy, in [0, 1] (the paper: (0, 1]; > 0 keeps the planner
            probabilistically complete).
        joint_limits: (13, 2) [rad] lower and upper limits; ``assets.sah.JOINT_LIMITS`` if None.

    Raises:
        InputError: bad shapes, empty bounds, beta outside [0, 1], no models with beta < 1.
    """

    def __init__(
        self,
        models: Sequence[VariationModel],
        wrist_bounds_lo,
        wrist_bounds_hi,
        beta: float,
        joint_limits=None,
    ):
        self.models = list(models)
        lo = np.asarray(wrist_bounds_lo, dtype=float)
        hi = np.asarray(wrist_bounds_hi, dtype=float)
        if lo.shape != (3,) or hi.shape != (3,) or not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise InputError(
                f"wrist bounds: expected two finite (3,) vectors, found {lo.shape} and {hi.shape}"
            )
        if np.any(hi < lo):
            raise InputError(f"wrist bounds: lower {lo.tolist()} exceeds upper {hi.tolist()}")
        beta = float(beta)
        if not 0.0 <= beta <= 1.0:
            raise InputError(f"beta: expected a probability in [0, 1], found {beta}")
        if beta < 1.0 and not self.models:
            raise InputError("beta < 1 needs at least one learned model")
        limits = _default_limits() if joint_limits is None else np.asarray(joint_limits, dtype=float)
        if limits.shape != (13, 2) or np.any(limits[:, 1] < limits[:, 0]):
            raise InputError(
                f"joint_limits: expected (13, 2) [lower, upper] rows, found shape {limits.shape}"
            )
        self.lo, self.hi, self.beta, self.joint_limits = lo, hi, beta, limits
        # flat per-(model, step) tables
        steps = [m.num_steps for m in self.models]
        self._offset = np.concatenate([[0], np.cumsum(steps)]).astype(int)
        if self.models:
            T = np.concatenate([m.T_object_wrist_mean for m in self.models])
            self._quat_k = quat_rows_from_matrix(T[:, :3, :3])  # (4, sum T_s)
            self._p_k = np.ascontiguousarray(T[:, :3, 3].T)  # (3, sum T_s)
            self._joints_k = np.ascontiguousarray(np.concatenate([m.joints_mean for m in self.models]).T)
            self._chol_k32 = np.linalg.cholesky(np.concatenate([m.cov for m in self.models])).astype(
                np.float32
            )
            To = np.stack([m.T_world_object_mean for m in self.models])
            self._quat_o = quat_rows_from_matrix(To[:, :3, :3])
            self._p_o = np.ascontiguousarray(To[:, :3, 3].T)
            self._chol_o32 = np.linalg.cholesky(np.stack([m.cov_object for m in self.models])).astype(
                np.float32
            )
            self._model_of = np.repeat(np.arange(len(self.models)), steps)
            self._k_of = np.concatenate([np.arange(t) for t in steps])
            self._last_of = np.concatenate([np.arange(t) == t - 1 for t in steps])
        n_models = len(self.models)
        self._probs = (
            np.concatenate([[beta]] + [np.full(t, (1.0 - beta) / n_models / t) for t in steps])
            if n_models
            else np.array([1.0])
        )

    def sample(self, n: int, rng: np.random.Generator) -> MixtureSample:
        """Draw ``n`` configurations from P(Y); see :class:`MixtureSample`."""
        n = int(n)
        if n < 0:
            raise InputError(f"n: expected a count >= 0, found {n}")
        counts = rng.multinomial(n, self._probs / self._probs.sum())
        n_uniform = int(counts[0])
        qT = np.empty((Q_DIM, n))  # components in rows: every operation below runs on contiguous (n,) rows
        strategy = np.full(n, -1, dtype=int)
        k = np.zeros(n, dtype=int)
        is_last = np.ones(n, dtype=bool)
        qT[:, :n_uniform] = self._uniform(n_uniform, rng)
        m = n - n_uniform
        if m:
            group = np.repeat(np.arange(len(counts) - 1), counts[1:])  # flat (model, step) index, sorted
            model = self._model_of[group]
            # float32 normals are twice as fast and far more precise than any use of these samples needs
            z = rng.standard_normal((m, Q_DIM), dtype=np.float32)
            starts = np.concatenate([[0], np.cumsum(counts[1:])])
            for g in np.flatnonzero(counts[1:]):  # contiguous row blocks: one BLAS call per (model, step)
                sl = slice(starts[g], starts[g + 1])
                z[sl] = z[sl] @ self._chol_k32[g].T
            xi = np.ascontiguousarray(z.T, dtype=float)
            zo = rng.standard_normal((m, 6), dtype=np.float32)
            bounds = np.searchsorted(model, np.arange(len(self.models) + 1))
            for s in range(len(self.models)):
                sl = slice(bounds[s], bounds[s + 1])
                zo[sl] = zo[sl] @ self._chol_o32[s].T
            xo = np.ascontiguousarray(zo.T, dtype=float)
            # o = mu_o Exp(xo); y = o T_k Exp(xi_w)
            quat_o, p_o = pose_rows_compose(self._quat_o[:, model], self._p_o[:, model], xo)
            quat_ok = quat_rows_mul(quat_o, self._quat_k[:, group])
            p_ok = p_o + quat_rows_rotate(quat_o, self._p_k[:, group])
            quat_y, p_y = pose_rows_compose(quat_ok, p_ok, xi[TAN_POSE])
            qT[POS, n_uniform:] = p_y
            qT[ROT, n_uniform:] = rotvec_rows_from_quat(quat_y)
            joints = self._joints_k[:, group]
            joints += xi[JOINTS]
            np.clip(joints, self.joint_limits[:, :1], self.joint_limits[:, 1:], out=joints)
            qT[JOINTS, n_uniform:] = joints
            strategy[n_uniform:] = model
            k[n_uniform:] = self._k_of[group]
            is_last[n_uniform:] = self._last_of[group]
        perm = rng.permutation(n)
        return MixtureSample(np.take(qT, perm, axis=1).T, strategy[perm], k[perm], is_last[perm])

    def _uniform(self, n: int, rng: np.random.Generator) -> np.ndarray:
        qT = np.empty((Q_DIM, n))
        qT[POS] = rng.uniform(self.lo[:, None], self.hi[:, None], size=(3, n))
        wxyz = rng.standard_normal((4, n))  # drawn and normalized w first, as the stored trials were
        wxyz /= np.sqrt(np.einsum("ij,ij->j", wxyz, wxyz))
        quat = wxyz[[1, 2, 3, 0]]
        qT[ROT] = rotvec_rows_from_quat(quat)
        qT[JOINTS] = rng.uniform(self.joint_limits[:, :1], self.joint_limits[:, 1:], size=(13, n))
        return qT


# -- draws from one model (clear matrix code; the mixture above is the fast path) --------------------------
def sample_object(model: VariationModel, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` object poses (n, 4, 4) from P(O) = N(mu_o, Sigma_o): ``mu_o Exp(xi)``, ``xi ~ N(0, Sigma_o)``."""
    xi = rng.multivariate_normal(np.zeros(6), model.cov_object, size=int(n), method="cholesky")
    return retract(model.T_world_object_mean, xi)


def sample_marginal(
    model: VariationModel, k: int, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """``n`` draws from P(X_k | O = mu_o) in the object frame, without clipping.

    Returns:
        ``T_object_wrist`` (n, 4, 4) = ``T_object_wrist_mean[k] Exp(xi_w)`` and ``joints`` (n, 13).
    """
    k = _check_step(model, k)
    x = rng.multivariate_normal(np.zeros(Q_DIM), model.cov[k], size=int(n), method="cholesky")
    return retract(model.T_object_wrist_mean[k], x[:, TAN_POSE]), model.joints_mean[k] + x[:, JOINTS]


def sample(model: VariationModel, k: int, n: int, rng: np.random.Generator, joint_limits=None) -> np.ndarray:
    """``n`` configurations q (n, 19) in the WORLD frame: ``o ~ P(O)``, then ``y ~ P(X_k | o)``.

    Args:
        joint_limits: (13, 2) to clip the joints to; no clipping if None.
    """
    T_world_object = sample_object(model, n, rng)
    T_object_wrist, joints = sample_marginal(model, k, n, rng)
    T = T_world_object @ T_object_wrist
    if joint_limits is not None:
        limits = np.asarray(joint_limits, dtype=float)
        joints = np.clip(joints, limits[:, 0], limits[:, 1])
    rotvec = Rotation.from_matrix(T[:, :3, :3]).as_rotvec()
    return np.concatenate([T[:, :3, 3], rotvec, joints], axis=1)


def _check_step(model: VariationModel, k: int) -> int:
    if not 0 <= int(k) < model.num_steps:
        raise InputError(f"k: expected a step in 0..{model.num_steps - 1}, found {k}")
    return int(k)
