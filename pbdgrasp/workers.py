"""Dask workers: a client (embedded cluster or a scheduler) for the Table I run and its tqdm bar with per-row
success counts, and an ordered map of tasks over a local cluster or this process (the ceiling's)."""

from __future__ import annotations

import contextlib
import logging
import re
import signal

from assets.errors import InputError

from .results_db import TrialRecord

__all__ = [
    "TrialProgress",
    "dask_client",
    "check_scheduler",
    "quiet_dask",
    "task_client",
    "map_tasks",
    "CONNECT_TIMEOUT_S",
]

CONNECT_TIMEOUT_S = 10.0
"""How long to wait for a Dask scheduler to answer, and then for it to have a worker [s]."""

_ADDRESS = re.compile(r"^(tcp|tls|ws|wss|ucx)://[^\s/:]+:\d{1,5}$")


class TrialProgress:
    """A tqdm bar over all trials with per-row success counts in the postfix.

    Args:
        config: the run's :class:`~pbdgrasp.table1.Table1Config` (rows, planners, progress).
        total: trials of the run. initial: those already finished. records: the finished trials.
    """

    def __init__(self, config, total: int, initial: int, records: list[TrialRecord]):
        from tqdm import tqdm

        self.counts = {r: {p: [0, 0] for p in config.planners} for r in config.rows}
        for rec in records:
            self._count(rec)
        disable = None if config.progress is None else not config.progress
        self.bar = tqdm(total=total, initial=initial, unit="trial", disable=disable, dynamic_ncols=True)
        self._postfix()

    def _count(self, rec: TrialRecord) -> None:
        c = self.counts.get(rec.row, {}).get(rec.planner)
        if c is not None:
            c[0] += int(rec.success)
            c[1] += 1

    def _postfix(self) -> None:
        text = " ".join(
            f"{row}:" + "/".join(f"{s}" for s, _ in per.values()) for row, per in self.counts.items()
        )
        self.bar.set_postfix_str(f"solved per row ({'/'.join(next(iter(self.counts.values())))}) {text}")

    def update(self, rec: TrialRecord) -> None:
        self._count(rec)
        self.bar.update(1)
        self._postfix()

    def close(self) -> None:
        self.bar.close()


def quiet_dask() -> None:
    """Dask's, tornado's and bokeh's loggers at WARNING."""
    for name in ("distributed", "dask", "tornado", "bokeh"):
        logging.getLogger(name).setLevel(logging.WARNING)


def _connect(address: str):
    """A client of the scheduler at ``address`` that has at least one worker.

    Raises:
        InputError: a malformed address, no answer within :data:`CONNECT_TIMEOUT_S`, or no worker within
            as long again.
    """
    from distributed import Client

    if not _ADDRESS.match(address):
        raise InputError(f"--scheduler: expected an address like tcp://HOST:PORT, found {address!r}")
    quiet_dask()
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as exc:
        raise InputError(
            f"--scheduler: no Dask scheduler answered at {address} within {CONNECT_TIMEOUT_S:g} s "
            f"({type(exc).__name__})"
        ) from None
    try:
        client.wait_for_workers(1, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError):
        client.close()
        raise InputError(
            f"--scheduler: the Dask scheduler at {address} has no worker after {CONNECT_TIMEOUT_S:g} s; "
            "start one with: dask worker " + address
        ) from None
    return client


def check_scheduler(address: str) -> None:
    """Raise :class:`InputError` unless the scheduler at ``address`` answers and has a worker (see
    :func:`dask_client`); called before long work."""
    _connect(address).close()


@contextlib.contextmanager
def _sigint_ignored():
    """Child processes started inside inherit an ignored SIGINT: Ctrl-C interrupts only this process,
    which then shuts its workers down, instead of every worker printing its own traceback."""
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: nothing to do
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


@contextlib.contextmanager
def dask_client(workers: int, scheduler: str | None = None):
    """A Dask client connected to ``scheduler``, or to an embedded ``LocalCluster`` of ``workers``
    single-threaded worker processes (which ignore Ctrl-C; the coordinating process stops them).

    Raises:
        InputError: the scheduler cannot be reached or has no worker (:data:`CONNECT_TIMEOUT_S`).
    """
    from distributed import Client, LocalCluster

    quiet_dask()
    if scheduler:
        with _connect(scheduler) as client:
            yield client
        return
    with _sigint_ignored():
        cluster = LocalCluster(
            n_workers=workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.WARNING,
        )
    with cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def task_client(workers: int):
    """For :func:`map_tasks`: a client of an embedded cluster of ``workers`` processes
    (:func:`dask_client`), or None for one worker (the tasks then run in this process)."""
    if workers == 1:
        yield None
        return
    with dask_client(workers) as client:
        yield client


def map_tasks(client, fn, tasks: list[tuple], done=None) -> list:
    """``[fn(*task) for task in tasks]``, in this process (``client`` None) or on the client's workers, in
    the order of ``tasks`` whatever the order they finish in; ``done(task, result)``, if given, is called
    as each arrives (a progress bar)."""
    results = [None] * len(tasks)
    if client is None:
        for k, task in enumerate(tasks):
            results[k] = fn(*task)
            if done:
                done(task, results[k])
        return results
    from distributed import as_completed

    futures = {client.submit(fn, *task, pure=False): k for k, task in enumerate(tasks)}
    for future in as_completed(futures):
        k = futures[future]
        results[k] = future.result()
        if done:
            done(tasks[k], results[k])
    return results
