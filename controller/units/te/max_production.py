"""Reachable grades for Ricker's maximum-production TE modes 4, 5 and 6 (seed Table 7.1).

Ricker's (1995) modes 4-6 are the maximum-production optima at the G/H ratios of
modes 1-3 (50/50, 10/90, 90/10; seed Table 7.1, R7.1). Such an optimum is pushed
onto a valve limit: the D feed XMV(1) at 100 % in modes 4 and 6, the E feed XMV(2)
in mode 5. A controller needs room to move there, so the product runs each at a
documented *back-off* from the optimum.

Back-off rule
    The grade lies on the line from Ricker's minimum-cost optimum of the same G/H
    ratio (mode ``k - 3``, a reachable grade) to his maximum-production optimum
    (mode ``k``): every set point and valve feedforward is
    ``neighbour + fraction x (optimum - neighbour)`` (seed Table 7.3 for the
    XMEAS, Ricker's states 39-50 for the valves). ``fraction`` is the largest
    multiple of 0.01 (in [-1, 1]) at which the *limiting valve* (the one the
    optimum puts at 100 %) keeps :data:`BACKOFF_MARGIN` from its range end at the
    closed-loop steady state of the cascade (strategy ``ssmpc``, noise off, 36 h
    from the neighbour, mean of the last hour), with every other controlled valve
    within :data:`controller.units.te.grades.CONTROL_MARGIN` as for modes 0-3.
    The grade's set points and feedforwards are then that measured steady state
    (:data:`_STEADY`), so the references agree with what the cascade settles at;
    and a run toward that table itself must settle there again (production within
    1 %, G within 0.5 mol %, the feeds within 1 % of range), its limiting valve 0.2 %
    further inside the margin, or the fraction steps back by 0.01: at 36 h the
    cascade still drifts, and a table right at the margin landed past it as the grade
    (mode 6 at +0.50: 95.2 %).

    Mode 2 (the neighbour of mode 5) already runs its E feed at 96.2 %, so mode 5's
    back-off lies *below* mode 2's production (a negative fraction): at a 5 %
    margin the 10/90 grade gains nothing over mode 2.

Why 5 %: with measurement noise on, the ratio-controlled E feed at mode 2 moves
with a standard deviation of 4.5 % and reaches 100 % (ssmpc, seed 1, 12 h), and the
level-controlled D feed with 2.0 %; 5 % is about one such standard deviation. So in
noise the limiting valve still touches 100 %: the D feed in 0.7-1.8 % of the samples
at modes 4 and 6, the E feed in 26-27 % at mode 5 (mode 2 itself: 37.5 %; 48 h
campaigns, ``docs/te_modes.md``).

Measured (``python docs/te_modes.py``; cost Downs & Vogel from the simulator,
Ricker's optimum evaluated with this model at his state, our grade at the cascade's
noise-free steady state):

====  ========  ========  ==========  =============  ===============  =========
mode  limiting  fraction  production  limiting       cost $/h         cost $/m3
      valve               m3/h        valve %        (Ricker / ours)  of product
====  ========  ========  ==========  =============  ===============  =========
4     XMV(1)    +0.86     36.04 34.19 100.0  94.84   243.9  224.8     6.77 6.57
5     XMV(2)    -0.37     23.55 22.43 100.0  94.80   194.6  176.2     8.26 7.86
6     XMV(1)    +0.47     20.20 19.10 100.0  94.47    49.2   34.5     2.44 1.81
====  ========  ========  ==========  =============  ===============  =========

Each pair: Ricker's optimum, then our grade. Ricker's state is not a steady state of
this model (it drifts, :mod:`plant_sim.tennessee_eastman.modes`), so his cost here
is the model's at his state. Over the last 10 of the 36 h the valves still move by
up to 4.2 % (mode 4), 0.1 % (mode 5) and 1.9 % (mode 6; the purge closing).
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = ["BACKOFF_MARGIN", "BackOff", "BACKOFFS", "interpolated", "steady_state"]

#: Smallest distance (% of range) the limiting valve keeps from its range end at a
#: back-off grade's steady state.
BACKOFF_MARGIN = 5.0


@dataclass(frozen=True)
class BackOff:
    """Where a maximum-production grade runs.

    Parameters
    ----------
    grade : str
        ``mode4``, ``mode5`` or ``mode6``.
    neighbour : str
        Ricker's minimum-cost optimum of the same G/H ratio (``mode1`` ... ``mode3``).
    limiting_valve : int
        XMV number the optimum puts at 100 %.
    fraction : float
        Position on the line neighbour -> optimum, in [-1, 1].
    """

    grade: str
    neighbour: str
    limiting_valve: int
    fraction: float

    def __post_init__(self) -> None:
        if self.grade not in ("mode4", "mode5", "mode6"):
            raise ValueError(f"grade: a maximum-production mode4..mode6, got {self.grade!r}")
        if self.neighbour != f"mode{int(self.grade[4:]) - 3}":
            raise ValueError(f"neighbour: {self.grade} shares its G/H ratio with "
                             f"mode{int(self.grade[4:]) - 3}, got {self.neighbour!r}")
        if not 1 <= self.limiting_valve <= 12:
            raise ValueError(f"limiting_valve: XMV number 1..12, got {self.limiting_valve!r}")
        if not (math.isfinite(self.fraction) and -1.0 <= self.fraction <= 1.0):
            raise ValueError(f"fraction: must be in [-1, 1], got {self.fraction!r}")


BACKOFFS = {
    "mode4": BackOff("mode4", "mode1", 1, 0.86),
    "mode5": BackOff("mode5", "mode2", 2, -0.37),
    "mode6": BackOff("mode6", "mode3", 1, 0.47),
}

#: The cascade's steady state at each back-off grade (ssmpc, noise off, 36 h from the
#: neighbour, mean of the last hour; ``python docs/te_modes.py``): per grade one row
#: of XMEAS 1-41 then one row of XMV 1-12.
_STEADY = """\
mode4,xmeas,0.452308,5511,6848.46,13.9642,29.1531,52.399,2799.25,64.9969,127.464,0.418774,75.7704,50,2698.81,38.1144,50.0056,3358.99,34.1925,52.7962,6.68633,260.803,97.5028,74.7186,34.9113,9.62777,22.6455,7.78698,17.3651,3.78729,38.0828,17.0626,16.5165,0.731291,16.0956,5.53538,4.05173,1.924,0.0164207,1.17865,0.393165,53.4044,43.5342
mode4,xmv,94.8361,81.9819,44.4942,91.5764,1,45.9453,57.8018,70.5907,1,56.8958,32.2576,100
mode5,xmeas,0.302349,723.905,7919.19,8.43712,31.8815,46.0489,2800.06,65,124.052,0.353325,90.757,50,2705.61,25.8629,49.9997,3326.47,22.4265,65.9544,4.82249,276.051,108.575,92.2487,34.8355,8.28815,19.5286,1.18976,25.19,5.54753,36.5965,11.8399,14.8451,0.126589,22.0715,7.2775,1.34408,5.89883,0.00167402,0.875782,0.279609,11.6638,85.6922
mode5,xmv,12.4573,94.7993,29.7418,55.3301,1,43.4136,35.1635,42.2534,1,24.9673,12.4577,100
mode6,xmeas,0.222828,5489.57,744.286,8.24402,19.9253,33.0381,2800.63,65.0086,122.408,0.0468772,81.9055,50.0012,2764.01,18.4792,49.9883,3004.68,19.1027,61.4548,5.45985,282.469,101.183,45.3253,29.7098,26.1076,19.7947,12.8699,3.68347,1.14715,28.1781,43.1308,11.869,1.98583,3.68052,1.63082,9.04467,0.480354,0.0266684,0.1551,0.0666787,90.1028,8.18239
mode6,xmv,94.4672,8.90972,21.9191,54.0636,74.6835,5.06923,30.8102,41.8618,1,38.0634,99,100
"""


def interpolated(b: BackOff, neighbour, optimum) -> tuple[np.ndarray, np.ndarray]:
    """The back-off line at ``b.fraction``: (XMEAS 1-41 (41,), XMV 1-12 (12,) %).

    From Ricker's optima (:func:`controller.units.te.grades.ricker_optimum`) of
    ``b.neighbour`` (``neighbour``) and ``b.grade`` (``optimum``), each with ``xmeas``
    (41,) and ``xmv`` (12,)."""
    q, r = neighbour, optimum
    f = float(b.fraction)
    return q.xmeas + f * (r.xmeas - q.xmeas), q.xmv + f * (r.xmv - q.xmv)


@lru_cache(maxsize=1)
def _steady_table() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    rows = [r for r in csv.reader(io.StringIO(_STEADY)) if r]
    out = {}
    for r in rows:
        name, kind, vals = r[0], r[1], np.array([float(v) for v in r[2:]])
        out.setdefault(name, {})[kind] = vals
    table = {}
    for name in BACKOFFS:
        got = out.get(name, {})
        if got.get("xmeas", np.zeros(0)).shape != (41,) or got.get("xmv",
                                                                   np.zeros(0)).shape != (12,):
            raise RuntimeError(f"_STEADY: {name} needs 41 XMEAS and 12 XMV values")
        table[name] = (got["xmeas"], got["xmv"])
    return table


def steady_state(name: str) -> tuple[np.ndarray, np.ndarray]:
    """A back-off grade's set points and feedforwards: (XMEAS (41,), XMV (12,) %)."""
    xm, xv = _steady_table()[name]
    return xm.copy(), xv.copy()
