"""The Table I run's workers and progress: a Dask client (embedded cluster or a scheduler) and a tqdm bar
with per-row success counts."""

from __future__ import annotations

import contextlib
import logging

from .results_db import TrialRecord

__all__ = ["TrialProgress", "dask_client", "quiet_dask"]


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


@contextlib.contextmanager
def dask_client(config):
    """A Dask client for ``config`` (a :class:`~pbdgrasp.table1.Table1Config`): connected to
    ``config.scheduler``, or to an embedded ``LocalCluster`` of ``config.workers`` single-threaded worker
    processes."""
    from distributed import Client, LocalCluster

    quiet_dask()
    if config.scheduler:
        with Client(config.scheduler) as client:
            yield client
        return
    with (
        LocalCluster(
            n_workers=config.workers,
            threads_per_worker=1,
            processes=True,
            dashboard_address=None,
            silence_logs=logging.WARNING,
        ) as cluster,
        Client(cluster) as client,
    ):
        yield client
