"""``ssmpc bench operator-step``: what operator control costs per TE supervisory sample.

The TE state-shared MPC (strategy ``ssmpc``, :mod:`controller.units.te.service`) in
closed loop on the plant runner (noise on, mode 0, plant not timed), one controller
step per sample, the cases taking turns sample by sample so that the machine's load
falls on all alike:

- ``te plain``: the unit's controller alone;
- ``te operated``: under :class:`controller.units.operator.OperatedController` with
  the default settings (mode on, every variable auto);
- ``te operated held``: with XMV 11 in manual and XMEAS 18 off (held handle fixed in
  the QP, the CV's weight 0).

Wall time per step, ms (median, p99, max).
"""

from __future__ import annotations

import time

NAME = "operator-step"
DESCRIPTION = ("TE controller step plain, under operator control (defaults) and with an MV "
               "in manual and a CV off, ms")


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=600,
                        help="timed samples in all (>= 30), split over the three cases")


def run(args) -> list[dict]:
    import numpy as np

    from controller.operator_modes import VariableCommand
    from controller.units.config import build_plant, grade_setpoints
    from controller.units.operator import operate
    from services.bench._common import latency_case
    from services.nodes.plant import TERunner
    from services.output import CLIError
    from services.registry import build_controller, get_unit

    n = int(args.samples)
    if n < 30:
        raise CLIError(f"samples: need at least 30, got {n}")
    cfg = get_unit("te")
    plant = build_plant(cfg)
    grades = grade_setpoints(cfg, plant)
    runs = []
    for held in (False, False, True):
        inner = build_controller(cfg, plant, np.asarray(grades["mode0"]["mv"]), grades)
        op = operate(cfg, plant, inner, grades)
        runs.append((inner, op, TERunner(cfg, noise=True), held))
    times: list[list[float]] = [[], [], []]
    for k in range(20 + n // 3):
        for i, (inner, op, plant_run, held) in enumerate(runs):
            if held and k == 20:
                j = op.mv_names.index("XMV11")
                state = op.state.command("XMV11", VariableCommand(mode="manual"),
                                         plant_run.t / 3600.0, float(plant_run.u[j]))
                op.set_state(state.command("XMEAS18", VariableCommand(mode="off"),
                                           plant_run.t / 3600.0, None))
            u_applied, y = plant_run.u.copy(), plant_run.y()
            t0 = time.perf_counter()
            if i == 0:
                dec = inner.step(k, plant_run.t, y, None)
            else:
                dec = op.step(k, plant_run.t, y, None, u_applied)
            dt = time.perf_counter() - t0
            inner.finish_sample()
            if k >= 21:  # after the build, compilation and (held) the retune
                times[i].append(dt * 1e3)
            plant_run.advance(dec.u, cfg.sample_period_s)
    names = ("te plain", "te operated", "te operated held")
    return [latency_case(name, t, unit="ms") for name, t in zip(names, times)]
