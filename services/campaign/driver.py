"""The campaign driver: one Dask task per run, gathered as they finish.

Cluster
    :mod:`services.cluster`: a local cluster of worker processes (one per core,
    one thread each, BLAS single-threaded) or a running scheduler
    (``--scheduler tcp://HOST:8786``).
Workers
    The first run of each strategy in a worker process warms it (numba kernels
    from the on-disk cache, models built) outside the run's timed part
    (:func:`services.campaign.runs.ensure_warm`).
Results
    Runs are gathered as they finish; each finished run is written to the results
    directory at once, so an interrupted campaign keeps every run that finished. A
    task that raises (or whose worker dies) becomes a row with its ``error``; the
    campaign goes on.

Measured (``ssmpc bench campaign``, 8 runs of 3 h of the ``ssmpc`` strategy x 5
repeats, passes in turn, this 2-core VM shared with other work at a load average
of 4.2)

    ================  ========  ==============  ==========
    case              runs/s    CPU s per run   cores used
    ================  ========  ==============  ==========
    serial            3.07      0.31            0.92
    workers 2 (Dask)  3.30      0.34            1.08
    pool 2 (no Dask)  2.49      0.32            0.98
    ================  ========  ==============  ==========

The rate is bounded by the cores the machine gives (about one here), not by
Dask: a plain process pool does no better. A worker's first run of a strategy
also pays its warm-up: 5-20 s for the MPC strategies (models built), under 1 s
for ``pi`` and ``plan``.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from collections.abc import Iterator

from services.campaign.identity import RunSpec, plan_runs
from services.campaign.progress import Progress
from services.campaign.runs import RunOutcome, base_row, execute, failed_metrics
from services.campaign.spec import CampaignSpec
from services.campaign.store import ResultStore
from services.cluster import gather, open_client

__all__ = ["run_campaign", "campaign_document", "gather_runs"]

#: results.json is rewritten at most this often while runs finish, s.
DOCUMENT_EVERY_S = 10.0


def gather_runs(client, runs: list[RunSpec]) -> Iterator[tuple[RunSpec, RunOutcome]]:
    """One task per run; yields ``(run, outcome)`` as each finishes (a task that raised
    or lost its worker: an error outcome)."""
    for run, outcome, error in gather(client, execute, runs, key=_task_key):
        yield run, (outcome if error is None else _error_outcome(run, error))


def _task_key(run: RunSpec) -> str:
    return f"ssmpc-run-{run.run_id}"


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
        copies = Counter(run.run_id for run in planned)
        with open_client(scheduler, workers) as (client, n_workers):
            last_doc = time.monotonic()
            try:
                for run, outcome in gather_runs(client, pending):
                    executed += 1
                    if store is not None and outcome.row.get("error") is None:
                        store.save_run(run.run_id, outcome.row, outcome.series,
                                       run.identity_document())
                    rows[run.run_id] = outcome.row
                    for _ in range(copies[run.run_id]):
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

