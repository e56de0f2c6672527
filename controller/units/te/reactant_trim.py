"""The TE reactant trim: at a steady grade, A+C short in the reactor feed while the
reactor level's D feed is at its limit raises the A+C feed's target (after the
A+C-in-feed loop on the C feed of Ricker's 1996 decentralized control of the
Tennessee Eastman process).

Method
    Every sample the deficit ``e = (y_A* + y_C*) - (y_A + y_C)`` of A and C in the
    reactor feed (XMEAS 23 + 25 against the plan's references, mol %) integrates into
    a trim ``c`` of the MPC's input target for the A+C feed (XMV 4, %):

    - it starts only at a steady grade (``settle_h`` after the last grade change, or
      none) with the D feed (XMEAS 2) above ``d_limit`` % of its range and
      ``e > deadband``: the reactor level's loop then has no D left to give, so the
      liquid it is short of must come from more reaction of the D already there;
    - while ``c > 0``: ``dc/dt = gain (e - deadband)`` for ``e > deadband``,
      ``gain e`` (back toward 0) for ``e < 0``, within ``[0, trim_max]``.

    Under IDV(8) (stream 4's A share up by as much as 0.03, its C share down by as
    much) the A-in-feed loop shut the A feed (19 -> 6 %) on the A surplus while C fell
    (17.8 -> 9.3 mol %): D found too little C to react (13 -> 21 mol %), the D valve
    stood at 96-100 %, the reactor level fell and the high-pressure override cut the
    A+C feed, which left even less C (trip at mode 3, 6.5 h). With ``c = 0`` (every
    other run) the moves are those without this module.

Measured (ssmpc, noise on, 48 h, IDV(8) from 2 h at mode 3; before: trip at 6.47 h on
plant seed 1):

========  ======  ===================  ==============
seed      trip    reactor pressure     largest trim
========  ======  ===================  ==============
1         none    at most 2902 kPa     11.5 %
2         none    at most 2901 kPa     0 (not needed)
3         none    at most 2913 kPa     7.1 %
========  ======  ===================  ==============
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

__all__ = ["ReactantTrimSettings", "ReactantTrim"]

#: D feed (stream 2) at 100 % of XMV 1, kg/h.
D_FULL_KG_H = 5811.0


@dataclass(frozen=True)
class ReactantTrimSettings:
    """Settings of :class:`ReactantTrim` (see the module docstring).

    Parameters
    ----------
    d_limit : float
        D feed (XMEAS 2, % of XMV 1's range) above which the level loop is taken to be
        at its limit.
    deadband : float
        A+C deficit in the reactor feed the trim ignores, mol %.
    gain : float
        Trim rate per mol % of deficit beyond the deadband, %/(mol % h).
    trim_max : float
        Largest trim of the A+C feed's target, %.
    settle_h : float
        Hours after a grade change before the trim may start (a moving plan's
        references are not a deficit).
    """

    d_limit: float = 93.0
    deadband: float = 1.0
    gain: float = 5.0
    trim_max: float = 30.0
    settle_h: float = 24.0

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise ValueError(f"{f.name}: must be a finite number, got {v!r}")
        if not 0.0 < self.d_limit < 100.0:
            raise ValueError(f"d_limit: must be in (0, 100) %, got {self.d_limit!r}")
        for name in ("deadband", "settle_h"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name}: must be >= 0, got {getattr(self, name)!r}")
        for name in ("gain", "trim_max"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name}: must be > 0, got {getattr(self, name)!r}")
        if self.trim_max > 100.0:
            raise ValueError(f"trim_max: must be <= 100 %, got {self.trim_max!r}")


class ReactantTrim:
    """The reactant trim's state over the samples (:class:`ReactantTrimSettings`).

    Parameters
    ----------
    settings : ReactantTrimSettings, optional
    sample_h : float
        Supervisory sample, h.
    """

    def __init__(self, settings: ReactantTrimSettings | None = None,
                 sample_h: float = 0.01) -> None:
        self.settings = settings or ReactantTrimSettings()
        self.sample_h = float(sample_h)
        #: the trim of the A+C feed's target, % (0: inactive)
        self.trim = 0.0
        #: the last deficit of A+C in the reactor feed, mol %
        self.deficit = math.nan

    @property
    def active(self) -> bool:
        return self.trim > 0.0

    def step(self, xmeas, ym, hours_since_change: float) -> float:
        """Advance one sample: ``xmeas`` (41,) this sample's XMEAS, ``ym`` (41,) the
        plan's XMEAS references, ``hours_since_change`` h since the last grade change
        (inf: none). Returns the trim, %."""
        s = self.settings
        e = float(ym[22] + ym[24] - xmeas[22] - xmeas[24])
        d = float(xmeas[1]) / D_FULL_KG_H * 100.0
        if not (math.isfinite(e) and math.isfinite(d)):
            return self.trim
        self.deficit = e
        if e > s.deadband and (self.trim > 0.0 or (d > s.d_limit
                                                   and hours_since_change >= s.settle_h)):
            self.trim += s.gain * self.sample_h * (e - s.deadband)
        elif e < 0.0:
            self.trim += s.gain * self.sample_h * e
        self.trim = min(max(self.trim, 0.0), s.trim_max)
        return self.trim

    def alarms(self) -> list[str]:
        """The trim's alarm text while it acts (numbers change, the key does not)."""
        if not self.active:
            return []
        return [f"A+C in the reactor feed {self.deficit:.1f} mol % short with the D feed "
                f"at its limit: A+C feed target raised by {self.trim:.1f} %"]

    def checkpoint(self) -> dict[str, Any]:
        return {"trim": self.trim}

    def restore(self, state: dict[str, Any] | None) -> None:
        self.trim = float((state or {}).get("trim", 0.0))
