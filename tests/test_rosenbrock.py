"""Rosenbrock's method on functions whose minimum is known."""

from __future__ import annotations

import numpy as np
import pytest

from retarget.rosenbrock import RosenbrockResult, minimize_rosenbrock

#: Distance to the known minimiser that counts as "reached" on the banana valley.
BANANA_XTOL = 1e-4
#: Distance to the minimiser of a well-conditioned quadratic.
QUADRATIC_XTOL = 1e-5
#: Direct search can stall in the narrow descent cone of a kink (8.6e-5 measured); 1e-3 is required.
NONSMOOTH_XTOL = 1e-3


def banana(x: np.ndarray) -> float:
    return 100.0 * (x[1] - x[0] ** 2) ** 2 + (1.0 - x[0]) ** 2


def test_reaches_the_banana_minimum_from_the_classic_start():
    res = minimize_rosenbrock(banana, [-1.2, 1.0], step0=0.1, xtol=1e-7, max_nfev=5000)
    assert isinstance(res, RosenbrockResult)
    assert res.success, res.message
    err = np.max(np.abs(res.x - 1.0))
    assert err < BANANA_XTOL, f"max |x - (1, 1)| = {err:.2e}"
    assert res.fun == pytest.approx(banana(res.x))
    assert res.nit >= 2  # the valley needs rotated coordinates


def test_quadratic_with_known_minimum_and_mixed_scales():
    rng = np.random.default_rng(0)
    M = rng.normal(size=(5, 5))
    A = M @ M.T + 5 * np.eye(5)
    x_star = rng.normal(size=5) * np.array([1e-3, 1e-3, 1.0, 1.0, 10.0])
    scale = np.array([1e-3, 1e-3, 1.0, 1.0, 10.0])

    def quad(x):
        z = (x - x_star) / scale
        return float(z @ A @ z)

    res = minimize_rosenbrock(quad, np.zeros(5), step0=0.5 * scale, xtol=1e-8, max_nfev=20000)
    assert res.success, res.message
    err = np.max(np.abs((res.x - x_star) / scale))
    assert err < QUADRATIC_XTOL, f"max scaled error {err:.2e}"


def test_non_smooth_and_infinite_values_are_handled():
    # |x| + |y| with a forbidden half-plane returning inf: the minimum (0.2, 0) is on its border.
    def f(x):
        return np.inf if x[0] < 0.2 else abs(x[0]) + abs(x[1])

    res = minimize_rosenbrock(f, [1.0, 1.0], step0=0.3, xtol=1e-7, max_nfev=5000)
    err = np.max(np.abs(res.x - [0.2, 0.0]))
    assert err < NONSMOOTH_XTOL, f"max error {err:.2e}"
    assert res.fun < 0.2 + 2 * NONSMOOTH_XTOL


def test_budget_exhaustion_reports_failure_with_the_best_point():
    res = minimize_rosenbrock(banana, [-1.2, 1.0], step0=0.1, xtol=1e-12, max_nfev=30)
    assert not res.success
    assert "max_nfev" in res.message
    assert res.nfev <= 30
    assert res.fun <= banana(np.array([-1.2, 1.0]))
    assert res.fun == pytest.approx(banana(res.x))


def test_starting_at_the_minimum_stays_there():
    res = minimize_rosenbrock(lambda x: float(np.sum(x**2)), np.zeros(3), step0=1.0, xtol=1e-6)
    assert res.success
    assert np.max(np.abs(res.x)) == 0.0


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"x0": [np.nan, 0.0]}, "x0"),
        ({"x0": np.zeros((2, 2))}, "x0"),
        ({"step0": 0.0}, "step0"),
        ({"step0": [1.0, -1.0]}, "step0"),
        ({"xtol": 0.0}, "xtol"),
    ],
)
def test_invalid_arguments_raise(kwargs, match):
    args = {"x0": [0.0, 0.0], "step0": 0.1, "xtol": 1e-3} | kwargs
    with pytest.raises(ValueError, match=match):
        minimize_rosenbrock(banana, **args)
