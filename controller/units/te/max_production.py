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
    (:data:`_STEADY`), so the references agree with what the cascade settles at.

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
4     XMV(1)    +0.86     36.04 34.19 100.0  94.88   243.9  220.2     6.77 6.48
5     XMV(2)    -0.32     23.55 22.47 100.0  94.99   194.6  176.9     8.26 7.87
6     XMV(1)    +0.50     20.20 19.19 100.0  94.88    49.2   32.7     2.44 2.43
====  ========  ========  ==========  =============  ===============  =========

Each pair: Ricker's optimum, then our grade. Ricker's state is not a steady state of
this model (it drifts, :mod:`plant_sim.tennessee_eastman.modes`), so his cost here
is the model's at his state. The steady state is steady to 0.04-0.3 % of valve
range over the last 10 of the 36 h, except mode 4's A feed XMV(3), still moving
1.4 % (its slow A-in-feed trim).
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
    "mode5": BackOff("mode5", "mode2", 2, -0.32),
    "mode6": BackOff("mode6", "mode3", 1, 0.50),
}

#: The cascade's steady state at each back-off grade (ssmpc, noise off, 36 h from the
#: neighbour, mean of the last hour; ``python docs/te_modes.py``): per grade one row
#: of XMEAS 1-41 then one row of XMV 1-12.
_STEADY = """\
mode4,xmeas,0.446647,5513.36,6840.79,13.9553,29.2169,52.4573,2803.01,65.0064,127.45,0.40137,75.7373,49.9968,2702.46,38.1856,49.977,3363.37,34.1925,52.7079,6.69883,261.294,97.5095,74.7439,35.0073,9.77,22.3279,7.78474,17.4023,3.84392,38.2707,17.3029,15.975,0.735642,16.1511,5.61183,4.03788,1.91497,0.0166422,1.19194,0.401412,53.424,43.4948
mode4,xmv,94.8766,81.89,43.9357,91.5179,1,43.943,57.8954,70.6114,1,56.8511,32.2993,100
mode5,xmeas,0.303529,725.282,7935.51,8.45266,31.8539,46.0519,2799.95,65,124.072,0.354373,90.6853,50.0001,2705.47,25.9256,50.0002,3326.49,22.468,65.8732,4.83399,275.851,108.572,92.1492,34.8336,8.27398,19.5107,1.19182,25.2353,5.55298,36.6015,11.8302,14.8089,0.126751,22.1207,7.28852,1.34054,5.88276,0.001683,0.881664,0.281291,11.6631,85.6855
mode5,xmv,12.481,94.9946,29.8578,55.432,1,43.545,35.2516,42.3369,1,25.0068,12.5204,100
mode6,xmeas,0.224837,5513.78,748.229,8.27872,19.9306,33.0905,2799.51,65.005,122.443,0.0407181,81.7187,50.0022,2762.8,18.5044,49.9955,3004.07,19.1923,61.4074,5.46656,282.876,101.098,45.3351,29.6786,24.9357,21.2657,12.8247,3.54105,1.08538,28.1032,41.2497,14.2644,1.86321,3.4738,1.54406,9.02086,0.480752,0.02502,0.146506,0.0631174,90.087,8.21242
mode6,xmv,94.8838,8.95693,22.1177,54.291,74.4961,4.40377,30.8891,42.063,1,38.3284,99,100
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
