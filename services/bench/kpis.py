"""``ssmpc bench kpis``: what the KPIs cost the TE controller node.

The TE unit's KPIs (:class:`controller.units.kpis.UnitKPIs`: 41 CVs and 12 MVs at their
limits, the Downs & Vogel cost from the measurements, 8 models' prediction errors, since
start and over 1 h and 24 h windows) fed with the measurements of the TE plant runner
(noise on, mode 0, valves held; the plant not timed):

- ``te count``: one sample counted (what the node does after each move), µs;
- ``te report``: the KPI document of a query, µs;
- ``te checkpoint``: the KPI part of the checkpoint encoded as JSON, µs (its size in
  ``bytes``).
"""

from __future__ import annotations

import json
import time

NAME = "kpis"
DESCRIPTION = "TE KPIs: one sample counted, a report, the checkpoint part encoded, us"


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=2000,
                        help="samples counted (>= 100); reports and checkpoints: 1 in 10")


def run(args) -> list[dict]:
    import numpy as np

    from controller.units.baselines import HoldController
    from controller.units.config import build_plant, grade_setpoints, unit_info
    from controller.units.kpis import UnitKPIs
    from controller.units.operator import operate
    from controller.units.variables import unit_variables
    from services.bench._common import latency_case
    from services.nodes.plant import TERunner
    from services.output import CLIError
    from services.registry import get_unit

    n = int(args.samples)
    if n < 100:
        raise CLIError(f"samples: need at least 100, got {n}")
    cfg = get_unit("te")
    plant = build_plant(cfg)
    grades = grade_setpoints(cfg, plant)
    info = unit_info(cfg, plant)
    u0 = np.asarray(grades["mode0"]["mv"], float)
    state = operate(cfg, plant, HoldController(u0), grades).state
    kpis = UnitKPIs(cfg, info.cv_names, info.mv_names, unit_variables(cfg, plant))
    runner = TERunner(cfg, noise=True)
    models = tuple(f"model{j}" for j in range(8))
    rng = np.random.default_rng(0)
    count, report, checkpoint = [], [], []
    size = 0
    for k in range(n):
        runner.advance(runner.u, cfg.sample_period_s)
        y, u = runner.y(), runner.u.copy()
        rms = rng.uniform(0.0, 2.0, len(models))
        t0 = time.perf_counter()
        kpis.count(runner.t, "on", False, y, u, state, rms, models)
        count.append((time.perf_counter() - t0) * 1e6)
        if k % 10 == 9:
            t0 = time.perf_counter()
            kpis.report()
            report.append((time.perf_counter() - t0) * 1e6)
            t0 = time.perf_counter()
            size = len(json.dumps(kpis.checkpoint()))
            checkpoint.append((time.perf_counter() - t0) * 1e6)
    return [latency_case("te count", count[20:]), latency_case("te report", report),
            latency_case("te checkpoint", checkpoint, bytes=size)]
