"""What the TE plant side and every supervisory strategy share: the supervisory sample
period, the alarm limits below the interlocks, and :class:`TEControlSpec` (which loops
the plant side runs and which valves the supervisory layer writes).

Used by the cascade's controller (:mod:`controller.units.te.control`) and by the
decentralized baseline (:mod:`controller.units.te.decentralized`), which brings its own
loops in its spec.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.units.te.loops import INNER_LOOPS

__all__ = ["ALARM_LIMITS", "D_FULL_KG_H", "E_FULL_KG_H", "SAMPLE_H", "TEControlSpec",
           "alarm_crossings"]

#: Supervisory sample period, h (36 s = 20 Euler steps of 1.8 s).
SAMPLE_H = 0.01
#: D feed (stream 2, XMEAS 2) at 100 % of XMV 1, and E feed (stream 3, XMEAS 3) at 100 %
#: of XMV 2, kg/h (Downs & Vogel's valve ranges).
D_FULL_KG_H = 5811.0
E_FULL_KG_H = 8354.0
#: Alarm limits below the interlocks (XMEAS number -> (low, high), XMEAS units):
#: reactor pressure 2950 kPa (trip 3000), reactor temperature 170 degC (trip 175),
#: levels 10-90 % (the liquid-volume trips correspond to reactor -2 % / 114 %,
#: separator 3 % / 137 %, stripper -27 % / 131 % of the level spans).
ALARM_LIMITS = {7: (-math.inf, 2950.0), 9: (-math.inf, 170.0), 8: (10.0, 90.0),
                12: (10.0, 90.0), 15: (10.0, 90.0)}


@dataclass(frozen=True)
class TEControlSpec:
    """What the plant side needs to apply a TE controller's decisions."""

    strategy: str
    sample_h: float
    sample_steps: int
    loops: tuple = INNER_LOOPS
    loop_xmvs: tuple[int, ...] = tuple(lp.mv for lp in INNER_LOOPS)
    written_xmvs: tuple[int, ...] = (2, 3, 4, 5, 9, 11, 12)


def alarm_crossings(xmeas) -> list[str]:
    """One alarm text per XMEAS beyond its :data:`ALARM_LIMITS` (xmeas: the 41 XMEAS)."""
    alarms = []
    for cv, (lo, hi) in ALARM_LIMITS.items():
        v = xmeas[cv - 1]
        if v > hi or v < lo:
            side, lim = ("above", hi) if v > hi else ("below", lo)
            alarms.append(f"XMEAS{cv} = {v:.1f} {side} its alarm limit {lim:g} "
                          f"(interlock ahead)")
    return alarms
