"""File-format helpers shared by every package: atomic writes and input validation.

Every file pbdgrasp writes goes through :func:`atomic_write` (a temporary file in the same directory,
then ``os.replace``), so a failed or killed run never leaves a partial file. Every loader validates with
the ``require_*`` helpers, which raise :class:`assets.errors.InputError` naming the field.
"""

from __future__ import annotations

import io
import os
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = [
    "atomic_write",
    "atomic_savez",
    "load_npz",
    "require_shape",
    "require_finite",
    "require_spd",
    "require_psd",
    "require_rotation",
]


def atomic_write(path: str | os.PathLike, write: Callable[[io.BufferedWriter], None]) -> Path:
    """Write a file atomically: ``write(f)`` fills a temporary file that is then renamed onto ``path``.

    Args:
        path: destination; its directory is created if missing.
        write: called with a binary file object opened for writing.

    Returns:
        The destination path.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    umask = os.umask(0)
    os.umask(umask)
    try:
        os.fchmod(fd, 0o666 & ~umask)  # mkstemp creates 0600; give the file an ordinary open()'s mode
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def atomic_savez(path: str | os.PathLike, **arrays) -> Path:
    """``numpy.savez_compressed`` to ``path`` atomically (the name is kept exactly, no ``.npz`` added)."""
    return atomic_write(path, lambda f: np.savez_compressed(f, **arrays))


def load_npz(path: str | os.PathLike, required: tuple[str, ...] = ()) -> dict[str, np.ndarray]:
    """Load an ``.npz`` file fully into memory, with pickles refused.

    Raises:
        InputError: the file is missing, not an npz archive, truncated, or lacks a required key.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError("no such file", path)
    try:
        with np.load(path, allow_pickle=False) as data:
            out = {k: data[k] for k in data.files}
    except Exception as exc:  # numpy raises many types for corrupt archives
        raise InputError(f"not a readable .npz archive ({type(exc).__name__}: {exc})", path) from None
    missing = [k for k in required if k not in out]
    if missing:
        raise InputError(f"missing keys {missing}; found {sorted(out)}", path)
    return out


def require_shape(name: str, array, shape: tuple, path=None, dtype=float) -> np.ndarray:
    """Return ``array`` as an ndarray of ``dtype`` with the given shape (``None`` matches any length).

    Raises:
        InputError: wrong type or shape.
    """
    try:
        arr = np.asarray(array, dtype=dtype)
    except (TypeError, ValueError):
        raise InputError(
            f"{name}: expected numbers of shape {_fmt(shape)}, found {type(array).__name__}", path
        ) from None
    ok = arr.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, arr.shape, strict=True))
    if not ok:
        raise InputError(f"{name}: expected shape {_fmt(shape)}, found {arr.shape}", path)
    return arr


def require_finite(name: str, array, path=None) -> np.ndarray:
    """Raise :class:`InputError` if ``array`` has a NaN or an infinity."""
    arr = np.asarray(array, dtype=float)
    if not np.all(np.isfinite(arr)):
        bad = np.argwhere(~np.isfinite(arr))[0]
        raise InputError(f"{name}: non-finite value at index {tuple(int(i) for i in bad)}", path)
    return arr


def require_spd(name: str, cov, path=None, rtol: float = 1e-9) -> np.ndarray:
    """Check that every matrix in ``cov`` (..., n, n) is symmetric positive definite.

    Raises:
        InputError: not finite, not symmetric (relative ``rtol``), or not positive definite.
    """
    cov = require_finite(name, cov, path)
    scale = max(float(np.max(np.abs(cov))), 1e-300) if cov.size else 1.0
    if not np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=0.0, atol=rtol * scale):
        raise InputError(f"{name}: covariance is not symmetric", path)
    try:
        np.linalg.cholesky(cov)
    except np.linalg.LinAlgError:
        raise InputError(f"{name}: covariance is not positive definite", path) from None
    return cov


def require_psd(name: str, cov, path=None, rtol: float = 1e-9) -> np.ndarray:
    """Check that every matrix in ``cov`` (..., n, n) is symmetric positive semi-definite.

    Degenerate covariances are allowed (the retargeting error Sigma_r(t) is rank-deficient by design);
    eigenvalues may be negative only by ``rtol`` times the largest magnitude.
    """
    cov = require_finite(name, cov, path)
    scale = max(float(np.max(np.abs(cov))), 1e-300) if cov.size else 1.0
    if not np.allclose(cov, np.swapaxes(cov, -1, -2), rtol=0.0, atol=rtol * scale):
        raise InputError(f"{name}: covariance is not symmetric", path)
    if cov.size and np.linalg.eigvalsh(cov).min() < -1e-7 * scale:
        raise InputError(f"{name}: covariance is not positive semi-definite", path)
    return cov


def require_rotation(name: str, R, path=None, atol: float = 1e-6) -> np.ndarray:
    """Check that every matrix in ``R`` (..., 3, 3) is a rotation (orthonormal, determinant +1)."""
    R = require_finite(name, R, path)
    with np.errstate(over="ignore", invalid="ignore"):  # entries near 1e308 overflow: still refused
        err = np.abs(np.swapaxes(R, -1, -2) @ R - np.eye(3)).max() if R.size else 0.0
        err = err if np.isfinite(err) else np.inf
    if err > atol or np.any(np.linalg.det(R) < 0):
        raise InputError(f"{name}: not a rotation matrix (|R^T R - I| = {err:.2e}, tolerance {atol:g})", path)
    return R


def _fmt(shape: tuple) -> str:
    return (
        "(" + ", ".join("N" if s is None else str(s) for s in shape) + ("," if len(shape) == 1 else "") + ")"
    )
