"""File-format helpers shared by every package: the output policy, atomic writes and input validation.

The output policy, for every file pbdgrasp writes:

* before any work, :func:`check_output_file` (or :func:`check_output_dir`) resolves the path and refuses a
  directory, a missing parent directory, a place that cannot be written, a special file (a device, a
  FIFO, a socket) and a name whose extension does not match the format;
* :func:`atomic_write` fills a temporary file in the same directory and renames it onto the target, so a
  failed or killed run never leaves a partial file; it replaces only regular files (keeping their mode)
  and writes through a symbolic link to the file it points to.

Every loader validates with the ``require_*`` helpers, which raise :class:`assets.errors.InputError`
naming the field.
"""

from __future__ import annotations

import io
import math
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = [
    "check_output_file",
    "check_output_dir",
    "atomic_write",
    "atomic_savez",
    "load_npz",
    "require_shape",
    "require_finite",
    "require_spd",
    "require_psd",
    "require_rotation",
]


def _writable_dir(directory: Path, shown: str) -> None:
    """Raise :class:`InputError` unless a file can be created in ``directory`` (probed, so that it holds
    for root and for read-only file systems alike)."""
    try:
        fd, probe = tempfile.mkstemp(prefix=".pbdgrasp-probe.", dir=directory)
    except OSError as exc:
        raise InputError(f"cannot write in directory {directory} ({exc.strerror or exc})", shown) from None
    os.close(fd)
    os.unlink(probe)


def check_output_file(path: str | os.PathLike, suffixes: tuple[str, ...]) -> Path:
    """Resolve and check a file to be written, before the work that produces it.

    Args:
        path: the output as given (a symbolic link is followed to the file it points to).
        suffixes: the accepted endings of the name, e.g. ``(".png",)``; compared without case.

    Returns:
        The absolute path to write (the link's target for a link).

    Raises:
        InputError: an empty name, a name without one of ``suffixes``, a directory, a special file (device,
            FIFO, socket), a read-only file, a missing parent directory or one that cannot be written.
    """
    shown = str(path)
    if not shown:
        raise InputError("expected an output file name, found an empty string")
    given = Path(path)
    if not given.name.lower().endswith(tuple(s.lower() for s in suffixes)):
        raise InputError(f"expected a file name ending in {' or '.join(suffixes)}", shown)
    target = Path(os.path.realpath(given))
    if target.exists():
        mode = target.stat().st_mode
        if stat.S_ISDIR(mode):
            raise InputError("is a directory; expected a file name", shown)
        if not stat.S_ISREG(mode):
            raise InputError("is a special file (a device, FIFO or socket); refusing to replace it", shown)
        if not os.access(target, os.W_OK):
            raise InputError("is a read-only file; refusing to replace it", shown)
    parent = target.parent
    if not parent.is_dir():
        raise InputError(f"directory {parent} does not exist", shown)
    _writable_dir(parent, shown)
    return target


def check_output_dir(path: str | os.PathLike) -> Path:
    """Resolve and check a directory to be written into (created later if missing).

    Returns:
        The absolute directory.

    Raises:
        InputError: an empty name, a path that exists and is not a directory, or one whose nearest
            existing ancestor is not a writable directory.
    """
    shown = str(path)
    if not shown:
        raise InputError("expected a directory name, found an empty string")
    target = Path(os.path.realpath(path))
    if target.exists() and not target.is_dir():
        raise InputError("exists and is not a directory", shown)
    existing = target
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{existing} is not a directory", shown)
    _writable_dir(existing, shown)
    return target


def atomic_write(path: str | os.PathLike, write: Callable[[io.BufferedWriter], None]) -> Path:
    """Write a file atomically: ``write(f)`` fills a temporary file that is then renamed onto ``path``.

    A symbolic link is written through (its target is replaced, the link stays); an existing regular
    file keeps its permission bits; anything else that exists at the target is refused.

    Args:
        path: destination; its directory is created if missing.
        write: called with a binary file object opened for writing.

    Returns:
        The destination path as given.

    Raises:
        InputError: the target exists and is a directory or a special file (device, FIFO, socket).
    """
    path = Path(path)
    target = Path(os.path.realpath(path))
    umask = os.umask(0)
    os.umask(umask)
    mode = 0o666 & ~umask  # mkstemp creates 0600; give a new file an ordinary open()'s mode
    if target.exists():
        st = target.stat()
        if not stat.S_ISREG(st.st_mode):
            raise InputError("is not a regular file; refusing to replace it", path)
        mode = stat.S_IMODE(st.st_mode)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        os.fchmod(fd, mode)
        with os.fdopen(fd, "wb") as f:
            write(f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, target)
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


def is_number(value) -> bool:
    """True for a number as a JSON or YAML parser returns it (a Python int or float), never a bool.

    ``True`` and ``False`` are ints in Python; a configuration field that reads ``true`` is a mistake,
    not 1. Finiteness is the caller's check (some fields take infinity).
    """
    return isinstance(value, int | float) and not isinstance(value, bool)


def is_finite_number(value) -> bool:
    """:func:`is_number` and finite."""
    return is_number(value) and math.isfinite(value)


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
