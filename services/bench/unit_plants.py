"""``ssmpc bench unit-plants``: integration cost of the four unit plants.

Cases per plant: ``<plant> step`` is the latency of one :func:`plant_sim.integrate.step`
over the sample period the plant node uses, from a state away from equilibrium
(after an input step); ``<plant> simulate`` is the rate of a step-response
:func:`plant_sim.integrate.simulate` in plant time units per wall second.
"""

from __future__ import annotations

import time

import numpy as np

from services.bench._common import latency_case, rate_case

NAME = "unit-plants"
DESCRIPTION = "unit plant integration: step latency and simulate rate"

# plant: (sample period, simulated duration, input change applied at 10 % of it)
_SETUP = {
    "cstr": (0.1, 40.0, {"u": 0.05}),
    "bioreactor": (0.1, 30.0, {"D": 0.02}),
    "two_phase_reactor": (0.1, 10.0, {"x1": 2.0}),
    "calcium": (0.01, 10.0, {"J": 0.5}),
}


def add_arguments(parser) -> None:
    parser.add_argument("--repeat", type=int, default=5, help="simulate runs per plant")
    parser.add_argument("--steps", type=int, default=300, help="step calls per plant")


def run(args) -> list[dict]:
    from plant_sim import get_plant
    from plant_sim.integrate import simulate, step

    if args.repeat < 1 or args.steps < 1:
        raise ValueError("repeat/steps: must be >= 1")
    cases = []
    for name, (dt, duration, change) in _SETUP.items():
        plant = get_plant(name)
        op = plant.operating_point("OPI")
        u1 = op.u.copy()
        for key, delta in change.items():
            u1[plant.index("input", key)] += delta
        rates = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            simulate(plant, op.x, [(0.0, op.u), (0.1 * duration, u1)], duration, dt)
            rates.append(duration / (time.perf_counter() - t0))
        cases.append(rate_case(f"{name} simulate", rates, f"{plant.time_unit or '-'}/s",
                               sample=dt, duration=duration))
        x = op.x.copy()
        lat = []
        for _ in range(args.steps):
            t0 = time.perf_counter()
            x = step(plant, x, u1, dt)
            lat.append((time.perf_counter() - t0) * 1e6)
        cases.append(latency_case(f"{name} step", np.asarray(lat), "us", sample=dt))
    return cases
