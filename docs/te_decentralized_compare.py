"""Decentralized (temain_mod.f) vs ssmpc vs pi on the TE cases of the strategy's docstring.

Runs, noise on, the plant's original generator seed: the base case (24 h), the 0 -> 2
grade change (leg at 1 h, 48 h) and IDV(1), (6), (7) switched on at 2 h at modes 0
and 2 (48 h), and prints a Markdown table: trip time (h) or "none", mean cost ($/h),
time to grade (the trailing 1 h mean of XMEAS 40 within 1 mol% of mode 2's G, from
the request; on the raw analyzer in brackets) and peak reactor pressure (kPa).

    PYTHONPATH=. python docs/te_decentralized_compare.py [strategy ...]
"""

from __future__ import annotations

import sys

import numpy as np

from controller.units.te.control import run_te
from controller.units.te.grades import Leg, TransitionPlan, grade, time_to_band

CASES = {"base 24 h": ("mode0", (), None, 24.0),
         "0 -> 2": ("mode0", (Leg(1.0, "mode2"),), None, 48.0),
         **{f"IDV({k}) mode {m}": (f"mode{m}", (), k, 48.0) for k in (1, 6, 7) for m in (0, 2)}}


def trailing_mean(y: np.ndarray, n: int = 100) -> np.ndarray:
    c = np.cumsum(np.r_[0.0, y])
    i = np.arange(y.size)
    lo = np.maximum(i + 1 - n, 0)
    return (c[i + 1] - c[lo]) / (i + 1 - lo)


def measure(strategy: str, case: str) -> str:
    start, legs, idv, hours = CASES[case]
    run = run_te(strategy, TransitionPlan(start, legs), hours, noise=True,
                 idv=None if idv is None else {idv: 2.0})
    trip = "none" if run.shutdown is None else f"{run.shutdown.time_h:.2f} h"
    out = f"trip {trip}, cost {np.mean(run.cost):.1f}, P max {run.xmeas[:, 6].max():.0f}"
    if legs:
        g, g2 = run.xmeas[:, 39], grade(2).g_mol
        ttg = time_to_band(run.t, trailing_mean(g), g2, 1.0, 1.0)
        raw = time_to_band(run.t, g, g2, 1.0, 1.0)
        out += f", to grade {ttg:.1f} h ({raw:.1f} h)"
    return out


def main(strategies) -> None:
    print("| case | " + " | ".join(strategies) + " |")
    print("|---" * (len(strategies) + 1) + "|")
    for case in CASES:
        print(f"| {case} | " + " | ".join(measure(s, case) for s in strategies) + " |",
              flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or ["decentralized", "ssmpc", "pi"])
