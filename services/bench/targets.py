"""``ssmpc bench targets``: the steady-state target optimizer's solve time.

Cases at the TE core's size (5 MVs, 5 CVs with high and low limits), random gains
of unit scale: ``feasible`` (every limit holds: one QP) and ``relaxed`` (limits that
cannot all hold, relaxed by rank: one QP per rank and the economic QP).
"""

from __future__ import annotations

import time

import numpy as np

from services.bench._common import latency_case

NAME = "targets"
DESCRIPTION = "steady-state target optimizer: solve time at TE core size"


def add_arguments(parser) -> None:
    parser.add_argument("--n", type=int, default=2000, help="solves per case")


def _problem(rng, relaxed: bool):
    from controller.targets import TargetProblem

    ny = nu = 5
    G = rng.normal(size=(ny, nu))
    lo, hi = (np.full(ny, 50.0), np.full(ny, 60.0)) if relaxed else (np.full(ny, -15.0),
                                                                      np.full(ny, 15.0))
    return TargetProblem(gain=G, u0=np.full(nu, 50.0), y0=np.zeros(ny), u_min=np.zeros(nu),
                         u_max=np.full(nu, 100.0), q_u=np.ones(nu), y_min=lo, y_max=hi,
                         y_rank=np.array([1, 1, 2, 2, 3]), cost_u=rng.normal(size=nu))


def run(args) -> list[dict]:
    from controller.targets import solve_targets

    if args.n < 1:
        raise ValueError("n: must be >= 1")
    rng = np.random.default_rng(0)
    cases = []
    for name, relaxed in (("feasible", False), ("relaxed", True)):
        p = _problem(rng, relaxed)
        res = solve_targets(p)
        times = []
        for _ in range(args.n):
            t0 = time.perf_counter()
            solve_targets(p)
            times.append((time.perf_counter() - t0) * 1e6)
        cases.append(latency_case(name, times, "us", unit_size="5x5", status=res.status,
                                  qps=res.qps))
    return cases
