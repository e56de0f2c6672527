"""``ssmpc bench campaign``: campaign throughput, runs per wall second, serial and on Dask.

The work is what a TE campaign run does: ``--runs`` closed-loop runs
(:func:`controller.units.te.control.run_te`) of ``--hours`` process hours,
strategy ``--strategy`` (default the product's ``ssmpc``), mode 0 -> 2 requested
at 0.5 h, measurement noise on, one noise seed per run (the same work on
different data); each run's full record comes back to the caller, as a
campaign's series do. Cases:

- "serial": the runs one after another in this process;
- "workers N": the same runs as one Dask task each on a local cluster of N worker
  processes (:mod:`services.cluster`: one thread each, BLAS single-threaded),
  gathered as they finish;
- "pool N": the reference without Dask, the same runs on a
  :class:`multiprocessing.pool.Pool` of N spawned processes (only each run's CPU
  time comes back): what worker processes can give on this machine at all.

Each case is repeated ``--repeats`` times, the three passes in turn (on a shared
machine they then meet the same load); the median is the rate
(runs/s). Warm-up is not timed: this process and every worker make one short run
of the strategy first (numba kernels from the cache, models built), and the
cluster and the pool are started before. "workers N" and "pool N" carry
``speedup`` (the median over the serial median); all carry the mean 1-minute
load average at the passes' starts, the CPU seconds per run (of the process
that ran it: a worker's includes its event loop meanwhile) and ``cores_used``,
the CPU seconds of the runs over the pass's wall time. On a shared machine other
processes take cores from the workers: "pool N" beside "workers N" tells what
the machine gave from what Dask costs.
"""

from __future__ import annotations

import multiprocessing
import os
import time

import numpy as np

NAME = "campaign"
DESCRIPTION = ("campaign throughput: TE closed-loop runs per wall second, serially and over "
               "N Dask worker processes")


def add_arguments(parser) -> None:
    parser.add_argument("--runs", type=int, default=8, help="runs per repeat (>= 1)")
    parser.add_argument("--hours", type=float, default=3.0, help="process hours per run")
    parser.add_argument("--workers", type=int, default=2, help="worker processes (>= 1)")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats per case (>= 1)")
    parser.add_argument("--strategy", default="ssmpc", help="ssmpc, fixed, pi or plan")


def _te_run(job: tuple[str, float, int]):
    """One run (a task): ``(strategy, hours, seed)`` -> (its TERun, CPU s of its process)."""
    from controller.units.te.control import plant_seed_for, run_te
    from controller.units.te.grades import Leg, TransitionPlan

    strategy, hours, seed = job
    cpu = time.process_time()
    run = run_te(strategy, TransitionPlan("mode0", (Leg(0.5, "mode2"),)), hours, noise=True,
                 seed=seed, plant_seed=plant_seed_for(seed))
    return run, time.process_time() - cpu


def _te_cpu(job: tuple[str, float, int]) -> float:
    """One run in the process pool: only its CPU s come back (the run stays there)."""
    return _te_run(job)[1]


def _warm(strategy: str) -> None:
    from services.cluster import single_threaded_process

    single_threaded_process()
    _te_run((strategy, 0.05, 0))


def run(args) -> list[dict]:
    from controller.units.te.control import STRATEGIES
    from services.bench._common import rate_case
    from services.cluster import gather, open_client
    from services.output import CLIError

    n, hours = int(args.runs), float(args.hours)
    workers, repeats = int(args.workers), int(args.repeats)
    for name, v in (("runs", n), ("workers", workers), ("repeats", repeats)):
        if v < 1:
            raise CLIError(f"{name}: need at least 1, got {v}")
    if not 0.1 <= hours <= 200.0:
        raise CLIError(f"hours: must be in [0.1, 200], got {hours}")
    if args.strategy not in STRATEGIES:
        raise CLIError(f"strategy: unknown {args.strategy!r}; known: {', '.join(STRATEGIES)}")
    jobs = [(args.strategy, hours, seed) for seed in range(1, n + 1)]
    common = {"runs": n, "hours": hours, "strategy": args.strategy, "cores": os.cpu_count()}

    kinds = ("serial", "pool", "workers")
    rates: dict[str, list[float]] = {k: [] for k in kinds}
    cpu: dict[str, list[float]] = {k: [] for k in kinds}
    used: dict[str, list[float]] = {k: [] for k in kinds}

    def timed(kind: str, run_all) -> None:
        t0 = time.perf_counter()
        cpu_s = run_all()
        wall = time.perf_counter() - t0
        rates[kind].append(n / wall)
        cpu[kind].extend(cpu_s)
        used[kind].append(sum(cpu_s) / wall)

    _warm(args.strategy)
    loads = []
    ctx = multiprocessing.get_context("spawn")
    with ctx.Pool(workers, initializer=_warm, initargs=(args.strategy,)) as pool, \
            open_client(None, workers) as (client, _):
        client.run(_warm, args.strategy)
        # and one untimed short task per worker through the task path
        warm_jobs = [(args.strategy, 0.05, 10_000 + i) for i in range(workers)]
        for _ in gather(client, _te_run, warm_jobs, key=lambda j: f"te-warm-{j[2]}"):
            pass
        pool.map(_te_cpu, warm_jobs, chunksize=1)

        def dask_pass() -> list[float]:
            out = []
            for job, result, error in gather(client, _te_run, jobs, key=lambda j: f"te-{j[2]}"):
                if error is not None:
                    raise CLIError(f"run {job}: {type(error).__name__}: {error}", code=1)
                out.append(result[1])
            return out

        # the passes alternate, so that all three meet the same load
        for _ in range(repeats):
            loads.append(os.getloadavg()[0])
            timed("serial", lambda: [_te_run(job)[1] for job in jobs])
            timed("pool", lambda: pool.map(_te_cpu, jobs, chunksize=1))
            timed("workers", dask_pass)
    load = round(float(sum(loads) / len(loads)), 2)

    def case(name: str, kind: str, **extra) -> dict:
        return rate_case(name, rates[kind], "runs/s", load_avg_1min=load, **common,
                         cpu_s_per_run=round(float(np.median(cpu[kind])), 4),
                         cores_used=round(float(np.median(used[kind])), 3), **extra)

    serial = case("serial", "serial")
    cases = [serial]
    for name, kind in ((f"workers {workers}", "workers"), (f"pool {workers}", "pool")):
        c = case(name, kind, workers=workers)
        c["speedup"] = round(c["median"] / serial["median"], 3)
        cases.append(c)
    return cases
