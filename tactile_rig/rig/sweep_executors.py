"""Where a sweep's episodes run: a local process or thread pool, or Dask distributed (the optional
extra ``distributed``: a scheduler at an address, or a local cluster started and closed with the
executor, its logs kept to errors)."""

from __future__ import annotations

import concurrent.futures as cf
import logging
from typing import Any, Callable

__all__ = ["DaskExecutor", "dask_executor", "make_executor"]


class DaskExecutor(cf.Executor):
    """A Dask ``Client``'s executor that also closes the client (and a cluster it started) on
    ``shutdown``; the cluster's logs are kept to errors so a sweep's output stays one table."""

    def __init__(self, client: Any, cluster: Any = None, *, restore_log_level: int | None = None) -> None:
        self.client = client
        self.cluster = cluster
        self._ex = client.get_executor()
        self._log_level = restore_log_level

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> cf.Future:
        return self._ex.submit(fn, *args, **kwargs)

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        self._ex.shutdown(wait=wait)
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()
        if self._log_level is not None:
            logging.getLogger("distributed").setLevel(self._log_level)
            self._log_level = None


def dask_executor(address: str | None = None, *, workers: int = 2, processes: bool = True,
                  threads_per_worker: int = 1) -> DaskExecutor:
    """An executor on the Dask scheduler at ``address``, or on a local cluster of ``workers``
    (processes, or threads in this process with ``processes=False``) with no dashboard."""
    try:
        from distributed import Client, LocalCluster
    except ModuleNotFoundError:
        raise ValueError("--executor dask needs Dask distributed: pip install 'tactile-rig[distributed]'") from None
    # Dask logs its cluster's life at INFO; a sweep's output is its table: keep only errors (here and,
    # through silence_logs, in the workers), restored when the executor shuts down.
    quiet = logging.getLogger("distributed")
    level = quiet.level
    quiet.setLevel(logging.ERROR)
    if address:
        return DaskExecutor(Client(address), restore_log_level=level)
    cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, processes=processes,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return DaskExecutor(Client(cluster), cluster, restore_log_level=level)


def make_executor(kind: str = "process", *, workers: int | None = None, address: str | None = None) -> cf.Executor:
    """``process`` (default), ``thread``, or ``dask`` (needs the 'distributed' extra; a local cluster
    of ``workers`` processes unless ``address`` names a scheduler)."""
    if kind == "process":
        return cf.ProcessPoolExecutor(max_workers=workers)
    if kind == "thread":
        return cf.ThreadPoolExecutor(max_workers=workers)
    if kind == "dask":
        return dask_executor(address, workers=workers or 2)
    raise ValueError(f"executor {kind!r} must be 'process', 'thread' or 'dask'")
