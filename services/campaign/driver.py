"""The campaign driver: one Dask task per run, gathered as they finish.

Cluster
    Without a scheduler address a :class:`dask.distributed.LocalCluster` of worker
    *processes* (one per core by default, one thread each: the closed loop is
    Python and numba under the interpreter lock, threads would share one core);
    with ``scheduler="tcp://HOST:8786"`` an existing cluster (``dask scheduler`` and
    ``dask worker --nthreads 1`` processes that can import this package).
Workers
    A worker plugin (:class:`SingleThreadedWorker`) limits BLAS/OpenMP to one
    thread in every worker as it joins (threadpoolctl; the local cluster also
    starts its workers with ``OMP/OPENBLAS/MKL_NUM_THREADS=1``). The first run of
    each strategy in a worker process warms it (numba kernels from the on-disk
    cache, models built) outside the run's timed part
    (:func:`services.campaign.runs.ensure_warm`).
Results
    Futures are gathered with :func:`dask.distributed.as_completed`; each finished
    run is written to the results directory at once, so an interrupted campaign
    keeps every run that finished. A task that raises (or whose worker dies)
    becomes a row with its ``error``; the campaign goes on.
"""

from __future__ import annotations

import contextlib
import logging
import os
import time
import uuid
from collections.abc import Iterator

from distributed import WorkerPlugin

from services.campaign.identity import RunSpec, plan_runs
from services.campaign.progress import Progress
from services.campaign.runs import (
    RunOutcome,
    base_row,
    execute,
    failed_metrics,
    single_threaded_process,
)
from services.campaign.spec import CampaignSpec
from services.campaign.store import ResultStore

__all__ = ["SingleThreadedWorker", "run_campaign", "campaign_document", "open_client"]

#: Thread pools limited in the local cluster's worker processes (set before they start).
_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
               "NUMBA_NUM_THREADS")
#: results.json is rewritten at most this often while runs finish, s.
DOCUMENT_EVERY_S = 10.0


class SingleThreadedWorker(WorkerPlugin):
    """Limits the worker process's BLAS/OpenMP pools to one thread as it joins."""

    name = "ssmpc-single-threaded"

    def setup(self, worker) -> None:
        single_threaded_process()


@contextlib.contextmanager
def open_client(scheduler: str | None = None, workers: int | None = None,
                connect_timeout_s: float = 10.0) -> Iterator[tuple[object, int]]:
    """A Dask client: on a local cluster of ``workers`` processes, or on ``scheduler``.

    Yields ``(client, number of workers)``.
    """
    from distributed import Client, LocalCluster

    if scheduler is None:
        n = int(workers or os.cpu_count() or 1)
        for var in _THREAD_ENV:
            os.environ.setdefault(var, "1")
        cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                               dashboard_address=None, silence_logs=logging.ERROR)
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
            client.wait_for_workers(int(workers), timeout=60)
        client.register_plugin(SingleThreadedWorker())
        yield client, len(client.scheduler_info()["workers"])
    finally:
        client.close()


def campaign_document(spec: CampaignSpec, rows: list[dict], workers: int, wall_s: float,
                      executed: int, skipped: int) -> dict:
    """The campaign result (DESIGN.md shape), with the runs in plan order."""
    return {"campaign": spec.name, "unit": spec.unit, "workers": int(workers),
            "wall_s": round(float(wall_s), 3), "runs": rows,
            "summary": {"runs": len(rows), "tripped": sum(bool(r.get("tripped")) for r in rows),
                        "errors": sum(bool(r.get("error")) for r in rows),
                        "executed": int(executed), "skipped": int(skipped)}}


def _error_outcome(run: RunSpec, exc: BaseException) -> RunOutcome:
    row = base_row(run)
    row.update(failed_metrics())
    row.update(wall_s=None, error=f"{type(exc).__name__}: {exc}")
    return RunOutcome(row, {})


def run_campaign(spec: CampaignSpec, out: str | os.PathLike | None = None, *,
                 scheduler: str | None = None, workers: int | None = None,
                 progress: Progress | None = None, report: bool = True) -> dict:
    """Run every run of ``spec`` not yet finished in ``out``; returns the campaign document.

    Parameters
    ----------
    spec : CampaignSpec
    out : path, optional
        Results directory (created); finished runs found there are not run again.
    scheduler : str, optional
        Address of a running Dask scheduler; default a local cluster.
    workers : int, optional
        Local cluster: worker processes (default: the cores). With a scheduler: wait
        for this many workers before submitting.
    progress : Progress, optional
        Default: a progress line on stderr.
    report : bool
        Write the report (figure, HTML, CSV) into ``out`` at the end.
    """
    t0 = time.perf_counter()
    planned = plan_runs(spec)
    store = ResultStore(out) if out is not None else None
    if store is not None:
        store.create()
    rows: dict[str, dict] = {}
    unique: dict[str, RunSpec] = {}
    for run in planned:
        unique.setdefault(run.run_id, run)
    for rid in unique:
        row = store.load_row(rid) if store is not None else None
        if row is not None:
            rows[rid] = row
    pending = [run for rid, run in unique.items() if rid not in rows]
    skipped_runs = sum(1 for run in planned if run.run_id in rows)
    prog = progress or Progress(spec.name, len(planned), skipped_runs)
    for row in rows.values():
        prog.note_skipped_row(row)
    prog.start()
    n_workers = 0
    executed = 0

    def document() -> dict:
        ordered = []
        for run in planned:
            if run.run_id in rows:
                row = dict(rows[run.run_id])
                row["case"] = run.case.name  # a renamed case keeps its runs
                ordered.append(row)
        return campaign_document(spec, ordered, n_workers, time.perf_counter() - t0,
                                 executed, skipped_runs)

    if pending:
        from distributed import as_completed

        token = uuid.uuid4().hex[:8]
        with open_client(scheduler, workers) as (client, n_workers):
            futures, by_key = [], {}
            for run in pending:
                fut = client.submit(execute, run, key=f"ssmpc-run-{run.run_id}-{token}",
                                    pure=False)
                futures.append(fut)
                by_key[fut.key] = run
            last_doc = time.monotonic()
            try:
                finished = as_completed(futures)
                futures = []  # as_completed holds them until each is yielded
                for fut in finished:
                    run = by_key[fut.key]
                    try:
                        outcome = fut.result()
                    except Exception as exc:  # the worker died, or the task could not run
                        outcome = _error_outcome(run, exc)
                    executed += 1
                    if store is not None and outcome.row.get("error") is None:
                        store.save_run(run.run_id, outcome.row, outcome.series,
                                       run.identity_document())
                    rows[run.run_id] = outcome.row
                    fut.release()  # the run's series are written; free the worker's copy
                    for _ in range(sum(1 for p in planned if p.run_id == run.run_id)):
                        prog.update(outcome.row)
                    if store is not None and time.monotonic() - last_doc >= DOCUMENT_EVERY_S:
                        store.save_document(document())
                        last_doc = time.monotonic()
            finally:
                if store is not None:  # an interrupted campaign keeps what finished
                    store.save_document(document())
    prog.finish()
    doc = document()
    if store is not None:
        store.save_document(doc)
        if report:
            from services.campaign.report import write_report

            write_report(doc, store.root)
    return doc

