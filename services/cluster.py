"""Dask clusters for offline work: worker processes, one thread each, single-threaded BLAS.

Used by the campaigns and their benchmark. Without a scheduler address
:func:`open_client` starts a :class:`distributed.LocalCluster` of worker
*processes* (one per core by default, one thread each: a closed loop is Python
and numba under the interpreter lock, threads of one process would share one
core); with ``scheduler="tcp://HOST:8786"`` it joins a running cluster
(``dask scheduler`` and ``dask worker --nthreads 1`` processes that can import
this package). Every worker gets the :class:`SingleThreadedWorker` plugin as it
joins: its BLAS/OpenMP pools limited to one thread (threadpoolctl), so N workers
on N cores do not spin N x BLAS threads; local workers also start with
``OMP/OPENBLAS/MKL/NUMBA_NUM_THREADS=1``. :func:`gather` submits one task per
item and yields the results as they finish (:func:`distributed.as_completed`).
"""

from __future__ import annotations

import contextlib
import logging
import os
import uuid
from collections.abc import Callable, Iterable, Iterator

from distributed import WorkerPlugin

__all__ = ["SingleThreadedWorker", "open_client", "gather", "single_threaded_process",
           "THREAD_ENV"]

#: Thread pools limited in the local cluster's worker processes (set before they start).
THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")

_LIMITED = False


def single_threaded_process() -> None:
    """BLAS and OpenMP pools of this process limited to one thread (threadpoolctl), once."""
    global _LIMITED
    if _LIMITED:
        return
    import scipy.linalg  # noqa: F401  (load the BLAS scipy uses before limiting it)
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1)
    _LIMITED = True


class SingleThreadedWorker(WorkerPlugin):
    """Limits the worker process's BLAS/OpenMP pools to one thread as it joins."""

    name = "ssmpc-single-threaded"

    def setup(self, worker) -> None:
        single_threaded_process()


@contextlib.contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None,
                connect_timeout_s: float = 10.0) -> Iterator[tuple[object, int]]:
    """A Dask client on a local cluster of ``workers`` processes, or on ``scheduler``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler; default a local cluster.
    workers : int, optional
        Local cluster: worker processes (default the cores). With a scheduler: wait
        (at most 60 s) for this many workers.
    connect_timeout_s : float
        Time to reach the scheduler, s.

    Yields
    ------
    (distributed.Client, int)
        The client and the number of workers.

    Raises
    ------
    ConnectionError
        The scheduler cannot be reached (message names ``scheduler``).
    """
    import dask
    from distributed import Client, LocalCluster

    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        # the thread-pool variables go to the worker processes before they start (the
        # nanny's pre-spawn environment). distributed applies them to this process's
        # environment to spawn the workers and leaves them there; they are put back
        # once the workers run, or every later child of the caller would inherit them
        # (seen: a node test's BLAS started single-threaded after a campaign test).
        saved = {var: os.environ.get(var) for var in (*THREAD_ENV, "MALLOC_TRIM_THRESHOLD_")}
        # No dashboard: the workers' statistical profiler (a stack sample every 10 ms,
        # taken under the interpreter lock) would have no one to show its samples to.
        # The scheduler's small HTTP server (health, metrics) still starts: on a free
        # loopback port (the default 8787 may be another cluster's)
        pre_spawn = dict(dask.config.get("distributed.nanny.pre-spawn-environ", {}) or {})
        pre_spawn.update({var: "1" for var in THREAD_ENV})
        # distributed's default MALLOC_TRIM_THRESHOLD_=65536 makes glibc hand freed
        # memory back to the system at once; a closed loop allocates and frees small
        # arrays every sample, and with it a TE run took 15-20 % more CPU (0.345 vs
        # 0.286 s per 3 h run, measured). The workers keep glibc's default.
        pre_spawn.pop("MALLOC_TRIM_THRESHOLD_", None)
        with dask.config.set({"distributed.worker.profile.enabled": False,
                              "distributed.nanny.pre-spawn-environ": pre_spawn}):
            cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                                   host="127.0.0.1", dashboard_address="127.0.0.1:0",
                                   silence_logs=logging.ERROR)
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
        client = Client(cluster)
        try:
            client.register_plugin(SingleThreadedWorker())
            yield client, n
        finally:
            client.close()
            cluster.close()
        return
    try:
        client = Client(scheduler, timeout=connect_timeout_s)
    except (OSError, TimeoutError) as exc:
        raise ConnectionError(f"scheduler: cannot connect to {scheduler!r}: {exc}") from exc
    try:
        if workers:
            try:
                client.wait_for_workers(int(workers), timeout=60)
            except TimeoutError as exc:
                raise ConnectionError(f"scheduler: fewer than {workers} workers joined "
                                      f"{scheduler!r} within 60 s") from exc
        client.register_plugin(SingleThreadedWorker())
        yield client, len(client.scheduler_info()["workers"])
    finally:
        client.close()


def gather(client, fn: Callable, items: Iterable, key: Callable[[object], str] = str
           ) -> Iterator[tuple[object, object, BaseException | None]]:
    """Run ``fn(item)`` as one task per item; yield ``(item, result, error)`` as each ends.

    ``error`` is the exception when the task raised or its worker was lost (then
    ``result`` is None). Each result is released on the cluster once yielded, so
    a long campaign keeps no finished results on the workers. ``key(item)`` names
    the task (made unique per call).
    """
    from distributed import as_completed

    token = uuid.uuid4().hex[:8]
    futures, by_key = [], {}
    for item in items:
        fut = client.submit(fn, item, key=f"{key(item)}-{token}", pure=False)
        futures.append(fut)
        by_key[fut.key] = item
    # the results come with the futures (fetched on the client's event loop as each
    # task ends; a result() call per future costs a round trip to that loop)
    finished = as_completed(futures, with_results=True, raise_errors=False)
    futures = []  # as_completed holds them until each is yielded
    for fut, result in finished:
        item = by_key.pop(fut.key)
        if fut.status == "error":  # the task raised, or its worker died: (type, exc, tb)
            result, error = None, result[1]
        elif isinstance(result, BaseException):  # cancelled
            result, error = None, result
        else:
            error = None
        fut.release()
        yield item, result, error
