"""Feed overrides of the TE cascade: a short A+C feed is made up by its valve, a lost
A feed is reported and the A-in-feed trim held (after the flow loops of Ricker's 1996
decentralized control, which set each feed's flow rather than its valve).

Method
    Every sample the flow each feed delivers is compared with the flow its valve asks
    for: the delivered share ``r = XMEAS / (XMV x full range)`` of the A feed (XMEAS 1,
    1.017 kscmh at 100 %) and of the A+C feed (XMEAS 4, 15.25 kscmh at 100 %), with
    the valve applied at the previous sample (the valves follow in 5-9 s, the sample is
    36 s), filtered first order over ``filter_h``.

    - A+C feed short (``r_AC < short_ratio``, released above ``short_release``; e.g.
      IDV(7), a C header at 80 % of its pressure): the A+C valve is opened by
      ``1 / r_AC`` (at most 100 %), as a flow loop would, so the cascade gets the flow
      its handle asks for. Measurement noise (0.05 kscmh on 7-9 kscmh) moves the
      filtered share by well under 1 %, so a healthy feed never engages it and the
      moves without a short feed are those without this module.
    - A feed lost (``r_A < lost_ratio``, back above ``restored_ratio``; IDV(6)): an
      alarm, and the A-in-feed loop holds its trim (on a valve that delivers nothing
      it would wind up to its limit and flood the reactor with A when the feed
      returns). Production is lowered by :mod:`controller.units.te.production_index`,
      not here. The balance says why: with A
      only from the A+C feed (48.5 % A, 51 % C; reactions 1 and 2 take them one for
      one), the purge has to carry C in excess of A at 2.5 % of the A+C feed (0.21
      kscmh at mode 2), which a full purge (0.77 kscmh) does only at y_C - y_A near
      0.3, too little A left to react. But in this structure the reactor level holds
      its liquid with the D feed and the E feed follows D by the ratio, so a lower
      A+C feed leaves D and E to gather, and a lower E feed is replaced by D. Measured
      (ssmpc, noise on, seed 1, IDV(6) at mode 2 from 2 h; trip on reactor pressure,
      13.8 h with no cut): the plan's A+C feed and the production reference lowered
      by 20 % with the E feed 9.4-10.1 h (E in the reactor feed 25 -> 40 mol%); by
      50 % over 10 h, the E feed left to the ratio and P_r* at 2500 kPa (purge open)
      9.5 h (E 25 -> 44 mol%); the E feed trimmed on the A error 8.9-15.3 h (the D
      feed rose from 734 to 5700 kg/h through the level loop, A 35 -> 12 mol%); a cut
      that grows only with the pressure above P_r* 13.7 h. Ricker's production index,
      which sets every feed's flow together and holds the reactor level otherwise,
      is what lowering production needs.
    - Everything else: the moves are those without this module (no alarm, valves
      untouched) as long as both feeds deliver what their valves ask.

Measured (noise on, plant seeds 1-3, 48 h, disturbance from 2 h):

========================  ===================================================
ssmpc, IDV(7), modes      no trip, reactor pressure at most 2814 kPa (before:
0, 2, 3                   mode 3 tripped at 5.9-6.0 h)
ssmpc, IDV(6), modes      as before (mode 2 trips at 13.8-13.95 h); with the
0, 2, 3                   production index no trip (see that module)
fixed, pi, plan, IDV(7),  no trip, peak 2802-2815 kPa (before, seed 1: fixed
mode 3                    6.0 h, plan 22.6 h)
fixed, pi, plan, IDV(6),  trip as before: fixed 13.8-13.9 h, pi 15.3-15.6 h,
mode 2                    plan 13.5-13.6 h; with the production index no trip
                          but pi on seed 3 (39.4 h)
========================  ===================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.lag import lag_step
from controller.units.te.settings_check import (
    check_finite_fields,
    check_range,
    is_finite_number,
)

__all__ = ["FeedOverrideSettings", "FeedOverrides", "A_FULL_KSCMH", "AC_FULL_KSCMH"]

#: A feed (stream 1) at 100 % of XMV 3, kscmh (XMEAS 1 at the base case / XMV 3).
A_FULL_KSCMH = 1.017
#: A and C feed (stream 4) at 100 % of XMV 4, kscmh.
AC_FULL_KSCMH = 15.25


@dataclass(frozen=True)
class FeedOverrideSettings:
    """Settings of :class:`FeedOverrides` (see the module docstring).

    Parameters
    ----------
    filter_h : float
        Time constant of the delivered-share filter, h.
    min_valve : float
        A delivered share is formed only for a valve at least this open, %.
    lost_ratio, restored_ratio : float
        The A feed is lost below the first delivered share, back above the second.
    short_ratio, short_release : float
        The A+C valve makes up a short feed below the first share, stops above the
        second.
    """

    filter_h: float = 0.05
    min_valve: float = 5.0
    lost_ratio: float = 0.25
    restored_ratio: float = 0.6
    short_ratio: float = 0.9
    short_release: float = 0.95

    def __post_init__(self) -> None:
        check_finite_fields(self)
        check_range(self, "filter_h", "> 0", "h")
        check_range(self, "min_valve", "(0, 100)", "%")
        if not 0.0 < self.lost_ratio < self.restored_ratio <= 1.0:
            raise ValueError(f"lost_ratio/restored_ratio: need 0 < lost < restored <= 1, "
                             f"got {self.lost_ratio}, {self.restored_ratio}")
        if not 0.0 < self.short_ratio < self.short_release <= 1.0:
            raise ValueError(f"short_ratio/short_release: need 0 < short < release <= 1, "
                             f"got {self.short_ratio}, {self.short_release}")


class FeedOverrides:
    """The feed overrides' state over the samples (:class:`FeedOverrideSettings`).

    Parameters
    ----------
    settings : FeedOverrideSettings, optional
    sample_h : float
        Supervisory sample, h.
    """

    def __init__(self, settings: FeedOverrideSettings | None = None,
                 sample_h: float = 0.01) -> None:
        self.settings = settings or FeedOverrideSettings()
        self.sample_h = float(sample_h)
        self.a_lost = False
        self.ac_short = False
        #: filtered delivered shares of the A and the A+C feed (None: none formed yet)
        self.r_a: float | None = None
        self.r_ac: float | None = None
        #: the previous sample's A and A+C valves, %
        self._last: tuple[float, float] | None = None

    @property
    def last_a_valve(self) -> float:
        """The A valve (%) applied at the previous sample (0 before any)."""
        return 0.0 if self._last is None else self._last[0]

    @property
    def active(self) -> bool:
        """Whether any override acts (False: the cascade runs as without them)."""
        return self.a_lost or self.ac_short

    def _share(self, old: float | None, flow: float, valve: float, full: float):
        s = self.settings
        if not (math.isfinite(flow) and math.isfinite(valve)) or valve < s.min_valve:
            return old
        r = flow / (valve / 100.0 * full)
        if old is None:
            return r
        return lag_step(old, r, self.sample_h, s.filter_h)

    def observe(self, xmeas) -> None:
        """Update the delivered shares and the feed states from this sample's XMEAS
        (41,) against the valves applied at the previous sample."""
        if self._last is None:
            return
        s = self.settings
        u3, u4 = self._last
        self.r_a = self._share(self.r_a, float(xmeas[0]), u3, A_FULL_KSCMH)
        self.r_ac = self._share(self.r_ac, float(xmeas[3]), u4, AC_FULL_KSCMH)
        if self.r_a is not None:
            if not self.a_lost and self.r_a < s.lost_ratio:
                self.a_lost = True
            elif self.a_lost and self.r_a > s.restored_ratio:
                self.a_lost = False
        if self.r_ac is not None:
            if not self.ac_short and self.r_ac < s.short_ratio:
                self.ac_short = True
            elif self.ac_short and self.r_ac > s.short_release:
                self.ac_short = False

    def ac_valve(self, u4: float) -> float:
        """The A+C valve (%) that delivers the flow ``u4`` asks of a healthy feed."""
        if not (self.ac_short and self.r_ac is not None and self.r_ac > 0.0
                and math.isfinite(u4)):
            return u4
        return min(max(u4 / self.r_ac, 0.0), 100.0)

    def applied(self, u3: float, u4: float) -> None:
        """The A and A+C valves (%) sent this sample (NaN: not written, no share)."""
        self._last = (min(max(float(u3), 0.0), 100.0), min(max(float(u4), 0.0), 100.0))

    def alarms(self) -> list[str]:
        """Alarm texts of the overrides in force (numbers change, the keys do not)."""
        out = []
        if self.a_lost and self.r_a is not None:
            out.append(f"A feed lost: it delivers {100 * self.r_a:.0f} % of its valve's "
                       f"flow; the A-in-feed trim held")
        if self.ac_short and self.r_ac is not None:
            out.append(f"A+C feed delivers {100 * self.r_ac:.0f} % of its valve's flow: "
                       f"the valve makes it up")
        return out

    def checkpoint(self) -> dict[str, Any]:
        return {"a_lost": self.a_lost,
                "ac_short": self.ac_short, "r_a": self.r_a, "r_ac": self.r_ac,
                "last": None if self._last is None else list(self._last)}

    def restore(self, state: dict[str, Any] | None) -> None:
        """Take the feeds' states back. A damaged entry starts that part afresh, as at
        start-up: a flag that is not ``true`` is off, a share that is not a finite
        positive number is formed again from the next sample, and valves that are not
        two finite numbers wait for the next sample's."""
        state = state if isinstance(state, dict) else {}
        self.a_lost = state.get("a_lost") is True
        self.ac_short = state.get("ac_short") is True
        self.r_a = _share_back(state.get("r_a"))
        self.r_ac = _share_back(state.get("r_ac"))
        last = state.get("last")
        ok = isinstance(last, list | tuple) and len(last) == 2 and all(
            is_finite_number(v) for v in last)
        self._last = (float(last[0]), float(last[1])) if ok else None
        if self.r_a is None:  # a lost feed is judged on its share
            self.a_lost = False
        if self.r_ac is None:
            self.ac_short = False


def _share_back(v) -> float | None:
    return float(v) if is_finite_number(v) and v > 0.0 else None
