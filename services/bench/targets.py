"""``ssmpc bench targets``: the steady-state target optimizer's solve time.

Cases at the TE core's size (5 MVs, 5 CVs with high and low limits), random gains
of unit scale: ``feasible`` (every limit holds: one QP) and ``relaxed`` (limits that
cannot all hold, relaxed by rank: one QP per rank and the economic QP).

``median``/``p99``/``max``: one sample's solve as the units run it,
:meth:`controller.target_solver.TargetSolver.solve` on the fields (their checks
included). Beside it, in alternating blocks of the same run (so under the same load):
``solve_targets_median``/``solve_targets_p99``, the one-shot
:func:`controller.targets.solve_targets` on a problem built beforehand (what this
bench timed before the solver existed), and ``problem_median``/``problem_p99``,
building and checking that :class:`~controller.targets.TargetProblem`.
"""

from __future__ import annotations

import time

import numpy as np

from services.bench._common import latency_case

NAME = "targets"
DESCRIPTION = "steady-state target optimizer: solve time at TE core size"


def add_arguments(parser) -> None:
    parser.add_argument("--n", type=int, default=2000, help="solves per case")


def _fields(rng, relaxed: bool) -> dict:
    ny = nu = 5
    G = rng.normal(size=(ny, nu))
    lo, hi = (np.full(ny, 50.0), np.full(ny, 60.0)) if relaxed else (np.full(ny, -15.0),
                                                                      np.full(ny, 15.0))
    return dict(gain=G, u0=np.full(nu, 50.0), y0=np.zeros(ny), u_min=np.zeros(nu),
                u_max=np.full(nu, 100.0), q_u=np.ones(nu), y_min=lo, y_max=hi,
                y_rank=np.array([1, 1, 2, 2, 3]), cost_u=rng.normal(size=nu))


def _problem(rng, relaxed: bool):
    from controller.targets import TargetProblem

    return TargetProblem(**_fields(rng, relaxed))


def run(args) -> list[dict]:
    from controller.target_solver import TargetSolver
    from controller.targets import TargetProblem, solve_targets

    if args.n < 1:
        raise ValueError("n: must be >= 1")
    rng = np.random.default_rng(0)
    cases = []
    clock = time.perf_counter
    for name, relaxed in (("feasible", False), ("relaxed", True)):
        fields = _fields(rng, relaxed)
        p = TargetProblem(**fields)
        solver = TargetSolver(p.ny, p.nu)
        res = solver.solve(**fields)
        solve_targets(p)
        fast, ref, build = [], [], []
        blocks = 10  # alternating blocks of each, so that the machine's load falls alike
        for k in range(blocks):
            n = args.n // blocks + (k < args.n % blocks)
            for _ in range(n):
                t0 = clock()
                solver.solve(**fields)
                fast.append((clock() - t0) * 1e6)
            for _ in range(n):
                t0 = clock()
                solve_targets(p)
                ref.append((clock() - t0) * 1e6)
            for _ in range(n):
                t0 = clock()
                TargetProblem(**fields)
                build.append((clock() - t0) * 1e6)
        cases.append(latency_case(
            name, fast, "us", unit_size="5x5", status=res.status, qps=res.qps,
            solve_targets_median=float(np.median(ref)),
            solve_targets_p99=float(np.percentile(ref, 99)),
            problem_median=float(np.median(build)), problem_p99=float(np.percentile(build, 99))))
    return cases
