"""Close-and-score many configurations of one scene on several cores.

:class:`ClosingPool` splits a batch of configurations (n, 19) into contiguous chunks, one per process:
this process closes the first chunk with its own :class:`~planning.autograsp.HandCloser` while worker
processes (forks of this one, each building its own pybullet :class:`~planning.world.World` of the same
scene; ``spawn`` where ``fork`` does not exist) close the others. A closing depends only on the
configuration and the scene (pybullet keeps no state between queries that changes a result:
``tests/test_closing_pool.py``), so the results are those of :meth:`HandCloser.close` one row at a time,
in order, whatever the number of processes.

The workers start when the pool is made and build their worlds in the background, so a caller that
makes the pool before other work (the refined final grasp: before the fingertip search) does not wait
for them. Inside a daemonic process (a Dask worker) no child may be started, and the pool closes
everything in this process; likewise with ``processes=1``. A worker that dies is not retried: its chunk
is closed here and the pool goes on without workers. Workers ignore Ctrl-C: the caller is interrupted,
and leaving the pool stops them. BLAS should run on one thread (the CLI sees to it): otherwise its
spinning threads take the workers' cores.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal
from collections.abc import Callable
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

import numpy as np

from assets.errors import InputError
from assets.q_layout import Q_DIM

from .autograsp import AutoGraspConfig, GraspResult, HandCloser
from .scene import Scene
from .world import World

__all__ = ["ClosingPool", "MAX_DEFAULT_PROCESSES", "RowsFn", "close_rows", "default_processes"]

log = logging.getLogger(__name__)

MAX_DEFAULT_PROCESSES = 8
"""The default number of processes is the machine's cores, at most this many (each worker holds a world,
and a batch of 32 draws gains little from more)."""

RowsFn = Callable[[HandCloser, np.ndarray], list]
"""``fn(closer, rows (m, 19)) -> list`` of m results, one per row, that depend on the row and the scene only
(the closer's world is this process's or a worker's). A module-level function: workers get it by name."""

_WORKER: HandCloser | None = None  # a worker process's closer (its world lives as long as the process)


def _init_worker(scene: Scene, config: AutoGraspConfig | None) -> None:
    global _WORKER
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is this process's parent's to handle
    _WORKER = HandCloser(World(scene, hand="sah"), config)


def _ready() -> bool:
    return _WORKER is not None


def _run_chunk(fn: RowsFn, qs: np.ndarray) -> list:
    return fn(_WORKER, qs)


def close_rows(closer: HandCloser, qs: np.ndarray) -> list[GraspResult]:
    """:meth:`HandCloser.close_many` as :meth:`ClosingPool.close_many`'s :data:`RowsFn`."""
    return closer.close_many(qs)


def default_processes() -> int:
    """The machine's cores, at most :data:`MAX_DEFAULT_PROCESSES`: a pool's size when none is given."""
    return min(os.cpu_count() or 1, MAX_DEFAULT_PROCESSES)


def _context():
    """``fork``: a worker starts in milliseconds and never re-runs the caller's script (``spawn`` imports
    ``__main__`` again, which runs an unguarded script's body in the worker). The worker touches neither
    this process's pybullet client nor GTSAM, only its own world."""
    methods = multiprocessing.get_all_start_methods()
    return multiprocessing.get_context("fork" if "fork" in methods else "spawn")


class ClosingPool:
    """:meth:`HandCloser.close` (or any :data:`RowsFn`) over a batch on ``processes`` processes (module
    docstring).

    Args:
        scene: the scene every process closes the hand in.
        config: the closing and quality settings (default :class:`AutoGraspConfig`).
        processes: processes in all, this one included (default: the machine's cores, at most
            :data:`MAX_DEFAULT_PROCESSES`); 1 closes in this process only.
        world: this process's world of ``scene`` (default: one of its own, closed with the pool).

    Raises:
        InputError: ``processes`` < 1.

    Use it as a context manager, or call :meth:`close`, to stop the workers.
    """

    def __init__(
        self,
        scene: Scene,
        config: AutoGraspConfig | None = None,
        processes: int | None = None,
        world: World | None = None,
    ):
        processes = default_processes() if processes is None else int(processes)
        if processes < 1:
            raise InputError(f"ClosingPool: processes must be >= 1, found {processes}")
        if multiprocessing.current_process().daemon:
            processes = 1  # a daemonic process may not have children
        self._own_world = world is None
        self._world = World(scene, hand="sah") if world is None else world
        self._closer = HandCloser(self._world, config)
        self._pool: ProcessPoolExecutor | None = None
        if processes > 1:
            self._pool = ProcessPoolExecutor(
                processes - 1,
                mp_context=_context(),
                initializer=_init_worker,
                initargs=(scene, config),
            )
            for _ in range(processes - 1):
                self._pool.submit(_ready)  # start the workers now: they build their worlds meanwhile
        self.processes = processes

    def close_many(self, qs: np.ndarray) -> list[GraspResult]:
        """The closed and scored grasps at each row of ``qs`` (n, 19) [m, rad], in order.

        Raises:
            InputError: ``qs`` not (n, 19), or a row that :meth:`HandCloser.close` refuses.
        """
        return self.map_rows(close_rows, qs)

    def map_rows(self, fn: RowsFn, qs: np.ndarray) -> list:
        """``fn`` over contiguous chunks of ``qs`` (n, 19), one per process; the n results in order.

        Raises:
            InputError: ``qs`` not (n, 19), and whatever ``fn`` raises.
        """
        qs = np.asarray(qs, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != Q_DIM:
            raise InputError(f"expected (n, {Q_DIM}) configurations, found shape {qs.shape}")
        chunks = np.array_split(qs, self.processes) if self._pool is not None else [qs]
        remote = [self._submit(fn, chunk) for chunk in chunks[1:]]
        out = list(fn(self._closer, chunks[0]))
        for chunk, job in zip(chunks[1:], remote, strict=True):
            out += self._result(job, fn, chunk)
        return out

    def _submit(self, fn: RowsFn, chunk: np.ndarray) -> Future | None:
        try:
            return self._pool.submit(_run_chunk, fn, chunk)
        except (BrokenProcessPool, RuntimeError):  # already broken or shut down
            return None

    def _result(self, job: Future | None, fn: RowsFn, chunk: np.ndarray) -> list:
        if job is not None:
            try:
                return job.result()
            except BrokenProcessPool:
                log.warning("a pool worker died; its configurations are done in this process")
        return fn(self._closer, chunk)

    def close(self) -> None:
        """Stop the workers and close the pool's own world (not one the caller passed)."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        if self._own_world:
            self._world.close()

    def __enter__(self) -> ClosingPool:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
