"""Rosenbrock's rotating-coordinates method, a derivative-free local minimiser (Rosenbrock 1960).

H. H. Rosenbrock, "An automatic method for finding the greatest or least value of a function",
The Computer Journal 3(3), 1960. The paper (section IV) uses it for the per-step wrist optimisation of
the retargeting, because the cost (fingertip distances after an inverse kinematics, a 0/1 collision
term, a max over joints) is neither smooth nor cheap to differentiate.

The method, as implemented here:

1. Keep ``n`` orthonormal search directions ``d_i`` (first the coordinate axes) and a step ``e_i`` for
   each. Cycle through the directions and try ``x + e_i d_i``: on success (``f`` not larger) move there
   and multiply the step by 3; on failure multiply it by -0.5 (reverse and halve).
2. A *stage* ends when every direction has seen at least one success followed by a failure. The moves of
   the stage, ``lambda_i`` along ``d_i``, give the vectors ``A_i = sum_{j >= i} lambda_j d_j``; the new
   directions are their Gram-Schmidt orthonormalisation, so ``d_1`` points along the stage's total
   progress. Directions with no move (``lambda_j = 0``) keep their old vector at the end of the list
   (Palmer's 1969 fix for the degenerate case); the orthonormalisation is a QR factorisation.
3. Stop when every ``|e_i|`` is below ``xtol`` (the minimiser is located to that resolution), or when the
   evaluation or stage budget is spent (``success=False``).

The search runs in scaled coordinates ``z = (x - x0) / step0`` so that variables of different units
(metres and radians of a pose) are comparable; ``xtol`` is therefore a fraction of ``step0``.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["RosenbrockResult", "minimize_rosenbrock", "EXPANSION", "CONTRACTION"]

log = logging.getLogger(__name__)

#: Step multiplier after a successful trial (Rosenbrock's alpha).
EXPANSION = 3.0
#: Step multiplier after a failed trial (Rosenbrock's beta): reverse and halve.
CONTRACTION = -0.5


@dataclass(frozen=True, eq=False)
class RosenbrockResult:
    """The outcome of :func:`minimize_rosenbrock`, in the style of ``scipy.optimize.OptimizeResult``.

    Attributes:
        success: True when the steps shrank below ``xtol``; False when a budget ran out.
        message: why the search stopped.
        nfev: number of objective evaluations.
        nit: number of completed stages (rotations of the coordinate system).
        x: (n,) the best point found.
        fun: the objective at ``x``.
    """

    success: bool
    message: str
    nfev: int
    nit: int
    x: np.ndarray
    fun: float


def _rotate(directions: np.ndarray, moves: np.ndarray, tiny: float) -> np.ndarray:
    """New orthonormal directions (n, n) (rows) from the stage's moves ``lambda`` (n,) along the old ones."""
    moved = np.abs(moves) > tiny
    if not np.any(moved):
        return directions
    order = np.concatenate([np.flatnonzero(moved), np.flatnonzero(~moved)])
    d = directions[order]
    lam = np.where(moved, moves, 0.0)[order]
    # A_i = sum_{j >= i} lambda_j d_j for the moved directions, the old d_j for the others.
    A = np.cumsum((lam[:, None] * d)[::-1], axis=0)[::-1]
    k = int(moved.sum())
    A[k:] = d[k:]
    Q, R = np.linalg.qr(A.T)
    signs = np.sign(np.diag(R))
    signs[signs == 0] = 1.0
    return (Q * signs).T


def minimize_rosenbrock(
    fun: Callable[[np.ndarray], float],
    x0: np.ndarray,
    step0: float | np.ndarray = 0.1,
    xtol: float = 1e-3,
    max_nfev: int = 2000,
    max_stages: int = 200,
) -> RosenbrockResult:
    """Minimise ``fun`` from ``x0`` with Rosenbrock's rotating-coordinates method.

    Args:
        fun: objective, (n,) -> float; may be non-smooth or piecewise constant. A non-finite value is a
            failed trial.
        x0: (n,) starting point.
        step0: initial step per coordinate, scalar or (n,), in the units of ``x``; also the scale of
            the search (see the module docstring). Must be positive.
        xtol: stop when every step is below ``xtol`` times its initial length (dimensionless).
        max_nfev: evaluation budget.
        max_stages: stage budget.

    Returns:
        A :class:`RosenbrockResult`; ``x`` is always the best point evaluated.

    Raises:
        ValueError: ``x0`` is not a finite vector, ``step0`` is not positive, or the budgets are invalid.
    """
    x0 = np.asarray(x0, dtype=float)
    if x0.ndim != 1 or x0.size == 0 or not np.all(np.isfinite(x0)):
        raise ValueError(f"x0: expected a finite non-empty vector, found shape {x0.shape}")
    n = x0.size
    scale = np.broadcast_to(np.asarray(step0, dtype=float), (n,)).copy()
    if not np.all(np.isfinite(scale) & (scale > 0)):
        raise ValueError(f"step0: expected positive steps, found {step0!r}")
    if not (xtol > 0 and max_nfev >= 1 and max_stages >= 1):
        raise ValueError("xtol must be > 0 and max_nfev, max_stages >= 1")

    nfev = 0

    def f(z: np.ndarray) -> float:
        nonlocal nfev
        nfev += 1
        value = float(fun(x0 + scale * z))
        return value if np.isfinite(value) else np.inf

    z = np.zeros(n)
    fz = f(z)
    directions = np.eye(n)
    steps = np.ones(n)
    nit = 0
    message = ""
    success = False
    while True:
        moves = np.zeros(n)
        succeeded = np.zeros(n, dtype=bool)
        oscillated = np.zeros(n, dtype=bool)  # a success, then later a failure, along the direction
        stage_done = False
        while not stage_done:
            if np.all(np.abs(steps) < xtol):
                success, message = True, f"steps below xtol={xtol:g} of the initial step"
                break
            for i in range(n):
                if nfev >= max_nfev:
                    break
                trial = z + steps[i] * directions[i]
                ft = f(trial)
                if ft <= fz:
                    z, fz = trial, ft
                    moves[i] += steps[i]
                    steps[i] *= EXPANSION
                    succeeded[i] = True
                else:
                    steps[i] *= CONTRACTION
                    oscillated[i] |= succeeded[i]
            if nfev >= max_nfev:
                message = f"evaluation budget max_nfev={max_nfev} spent"
                break
            stage_done = bool(np.all(oscillated))
        if success or message:
            break
        nit += 1
        new_directions = _rotate(directions, moves, tiny=1e-12)
        if new_directions is not directions:
            # The step lengths keep their magnitudes; their signs restart positive along new axes.
            directions, steps = new_directions, np.abs(steps)
        if nit >= max_stages:
            message = f"stage budget max_stages={max_stages} spent"
            break
    log.debug("rosenbrock: %s (nfev=%d, nit=%d, fun=%.6g)", message, nfev, nit, fz)
    return RosenbrockResult(success=success, message=message, nfev=nfev, nit=nit, x=x0 + scale * z, fun=fz)
