"""The TE production index: where a lost A feed makes the grade unreachable, every feed
is lowered together by one index held back by the reactor pressure (after the
production-rate index Fp and its pressure override in Ricker's 1996 decentralized
control of the Tennessee Eastman process), and the operator is told.

Method
    The index ``F`` (1 = the feeds as the cascade sets them) starts when the feed
    overrides find the A feed lost (:mod:`controller.units.te.overrides`). The feeds
    then in force are its references: the A+C valve ``u4_0``, the E valve ``u2_0``, the
    D feed ``d_0`` (XMEAS 2 filtered, % of XMV 1's range) and the share
    ``a = 0.485 u4_0 1500 / (0.485 u4_0 1500 + u3 100)`` of the A fed (lb-mol/h) that
    came with the A+C feed. Every sample while the A feed is lost

    - ``dF/dt = gain (p_target - p) / 100 kPa`` on the reactor pressure ``p``
      (XMEAS 7), within ``-fall_per_h .. rise_per_h`` and ``[f_min, 1]``;
    - the A+C valve is at most ``F u4_0`` (the MPC's input target of it too, and the
      production trim held, so the core does not work against the index);
    - the E valve is at most ``F a (1 + t_E) u2_0``: the E feed in proportion to the A
      left, trimmed by ``t_E`` in ``[-e_trim_max, 0]``, a PI on the E in the reactor
      feed (XMEAS 27) against the plan's (E that finds no A gathers in the recycle);
    - the reactor level's set point is lowered (at most ``level_drop_max``) while the
      D feed is above ``F a d_0``: the level loop sets the D feed, and a lower E feed
      would otherwise be replaced by D, with no A to react either.

    Once the A feed is back, ``F`` and ``t_E`` rise at ``rise_per_h`` and the level's
    set point at ``level_return_per_h`` back to the plan's; then the index is inactive.
    While inactive it changes nothing: the moves are those without it. While active it
    raises one alarm (its key, numbers masked, does not change).

    Why all feeds: with A only from the A+C feed (48.5 % A, 51 % C), a lower A+C feed
    alone (the high-pressure override's cut) leaves the E and, through the level loop,
    the D feed without the A to react with; E gathered in the recycle gas and the
    reactor pressure reached the interlock (ssmpc, IDV(6) at mode 2: 13.9 h). The same
    index without the E trim and the level's set point tripped at 14.5 h (the level
    loop brought the D feed from 12 % to 93 %), with the level's set point but without
    the E trim at 31.1 h (A in the feed 35 -> 10 mol %).

Measured (ssmpc, noise on, plant seeds 1-3, 48 h, IDV(6) from 2 h; production =
XMEAS 17 over the last half hour, the grade's in brackets):

=======  ==============  =================  ==========  ===========================
mode     trip            reactor pressure   level       production, m3/h
=======  ==============  =================  ==========  ===========================
2        none (before:   at most 2861-2867  45 %        20.1-20.2 (22.7)
         13.9-14.0 h)    kPa
0        none            at most 2838-2845  55-57 %     21.4-21.6 (23.0)
3        none            at most 2846-2850  65 %        16.7-16.9 (18.0)
=======  ==============  =================  ==========  ===========================

The baselines at mode 2 (same runs): fixed no trip (before 13.8-13.9 h), peak
2861-2867 kPa, production 20.1-20.2; plan no trip (before 13.5-13.6 h), 2858-2866 kPa,
20.1-20.2; pi no trip on seeds 1 and 2 (2860-2875 kPa, 20.3), a trip on seed 3 at
39.4 h (before 15.3-15.6 h).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.lag import lag_step
from controller.units.te.settings_check import check_finite_fields, check_range
from controller.units.te.spec import D_FULL_KG_H

__all__ = ["ProductionIndexSettings", "ProductionIndex"]

#: A feed (stream 1) and A+C feed (stream 4) at 100 % of XMV 3 and XMV 4, lb-mol/h.
A_FULL_LBMOL_H = 100.0
AC_FULL_LBMOL_H = 1500.0
#: A's mole fraction in the A+C feed (stream 4, base case).
A_IN_AC = 0.485


@dataclass(frozen=True)
class ProductionIndexSettings:
    """Settings of :class:`ProductionIndex` (see the module docstring).

    Parameters
    ----------
    pressure_target_kpa : float
        Reactor pressure (XMEAS 7) the index holds the plant at or below, kPa.
    gain : float
        Index change per hour per 100 kPa of pressure margin, 1/h.
    fall_per_h, rise_per_h : float
        Fastest fall and rise of the index, 1/h (the rise also returns the E trim).
    f_min : float
        Lowest index (the feeds' lowest share of their references).
    level_gain : float
        Reactor level set point change per % of D feed above its share per hour,
        %/(% h).
    level_drop_max : float
        Most the reactor level set point is lowered, % (the level alarm is at 10 %).
    level_return_per_h : float
        Rate the level's set point returns at once the A feed is back, %/h.
    filter_h : float
        Time constant of the D feed's filter, h.
    e_gain, e_ti_h : float
        The E trim's PI: share of the E valve per mol % of E above the plan's in the
        reactor feed (XMEAS 27), and its integral time, h.
    e_trim_max : float
        Largest cut of the E valve by the trim, share of it.
    """

    pressure_target_kpa: float = 2850.0
    gain: float = 0.5
    fall_per_h: float = 0.2
    rise_per_h: float = 0.05
    f_min: float = 0.3
    level_gain: float = 2.0
    level_drop_max: float = 20.0
    filter_h: float = 0.1
    e_gain: float = 0.01
    e_ti_h: float = 1.0
    e_trim_max: float = 0.5
    level_return_per_h: float = 5.0

    def __post_init__(self) -> None:
        check_finite_fields(self)
        check_range(self, "pressure_target_kpa", "(2000, 3000)", "kPa",
                    note="interlock 3000")
        check_range(self, ("gain", "fall_per_h", "rise_per_h", "filter_h", "level_gain",
                           "e_gain", "e_ti_h", "level_return_per_h"), "> 0")
        check_range(self, "f_min", "(0, 1)")
        check_range(self, "e_trim_max", "[0, 1)")
        check_range(self, "level_drop_max", "[0, 60]", "%")


class ProductionIndex:
    """The production index's state over the samples (:class:`ProductionIndexSettings`).

    Parameters
    ----------
    settings : ProductionIndexSettings, optional
    sample_h : float
        Supervisory sample, h.
    """

    def __init__(self, settings: ProductionIndexSettings | None = None,
                 sample_h: float = 0.01) -> None:
        self.settings = settings or ProductionIndexSettings()
        self.sample_h = float(sample_h)
        #: the index, 1 = the feeds as the cascade sets them
        self.f = 1.0
        #: whether it acts (False: the cascade runs as without it)
        self.active = False
        #: the references: A+C valve %, E valve %, D feed % of XMV 1's range
        self.u4_0 = math.nan
        self.u2_0 = math.nan
        self.d_0 = math.nan
        #: filtered D feed, % of XMV 1's range (NaN: none yet)
        self.d_f = math.nan
        #: reactor level set point offset, % (<= 0)
        self.level_offset = 0.0
        #: the E valve's trim on the A in the reactor feed, share of ``F u2_0`` (<= 0)
        self.e_trim = 0.0
        self._e_prev: float | None = None
        #: the share of the A fed that the A+C feed delivered when the A feed was lost
        self.a_share = 1.0

    def _filter_d(self, xmeas) -> None:
        d = float(xmeas[1])
        if not math.isfinite(d):
            return
        d = d / D_FULL_KG_H * 100.0
        if not math.isfinite(self.d_f):
            self.d_f = d
        else:
            self.d_f = lag_step(self.d_f, d, self.sample_h, self.settings.filter_h)

    def update(self, xmeas, a_lost: bool, u2: float, u4: float,
               u3_lost: float = 0.0, e_ref: float = math.nan) -> None:
        """Advance one sample.

        Parameters
        ----------
        xmeas : array (41,)
            This sample's XMEAS.
        a_lost : bool
            The feed overrides' state (:class:`controller.units.te.overrides.FeedOverrides`).
        u2, u4 : float
            The E and A+C valves the cascade asks for now, %; the references when the
            index starts.
        u3_lost : float
            The A valve applied when the A feed was lost, %.
        e_ref : float
            The plan's E in the reactor feed (XMEAS 27 reference), mol %.
        """
        s = self.settings
        self._filter_d(xmeas)
        if not self.active:
            if not a_lost:
                return
            self.active = True
            self.f = 1.0
            self.u4_0, self.u2_0, self.d_0 = float(u4), float(u2), self.d_f
            a_ac = A_IN_AC * self.u4_0 / 100.0 * AC_FULL_LBMOL_H
            a_1 = max(float(u3_lost), 0.0) / 100.0 * A_FULL_LBMOL_H
            self.a_share = a_ac / (a_ac + a_1) if a_ac + a_1 > 0 else 1.0
            self.level_offset = 0.0
            self.e_trim, self._e_prev = 0.0, None
        p = float(xmeas[6])
        dt = self.sample_h
        if not a_lost:  # the A feed is back: production, level and E return
            self.f = min(self.f + s.rise_per_h * dt, 1.0)
            self.level_offset = min(self.level_offset + s.level_return_per_h * dt, 0.0)
            self.e_trim = min(self.e_trim + s.rise_per_h * dt, 0.0)
            self._e_prev = None
            if self.f >= 1.0 and self.level_offset >= 0.0 and self.e_trim >= 0.0:
                self.active = False
            return
        if math.isfinite(p):
            rate = s.gain * (s.pressure_target_kpa - p) / 100.0
            rate = min(max(rate, -s.fall_per_h), s.rise_per_h)
            self.f = min(max(self.f + rate * dt, s.f_min), 1.0)
        if math.isfinite(self.d_f) and math.isfinite(self.d_0):
            excess = self.d_f - self.f * self.a_share * self.d_0
            self.level_offset -= s.level_gain * excess * dt
            self.level_offset = min(max(self.level_offset, -s.level_drop_max), 0.0)
        y_e = float(xmeas[26])
        if math.isfinite(y_e) and math.isfinite(e_ref):
            e = e_ref - y_e  # E gathering in the reactor feed: less E for the A there is
            if self._e_prev is None:
                self._e_prev = e
            self.e_trim += s.e_gain * ((e - self._e_prev) + dt / s.e_ti_h * e)
            self.e_trim = min(max(self.e_trim, -s.e_trim_max), 0.0)
            self._e_prev = e

    def ac_valve(self, u4: float) -> float:
        """The A+C valve (%) within the index."""
        if not self.active or not math.isfinite(self.u4_0):
            return u4
        return min(u4, self.f * self.u4_0)

    def e_valve(self, u2: float) -> float:
        """The E valve (%) within the index."""
        if not self.active or not math.isfinite(self.u2_0):
            return u2
        return min(u2, self.f * self.a_share * (1.0 + self.e_trim) * self.u2_0)

    def level_setpoint(self, level: float) -> float:
        """The reactor level set point (%) with the index's offset."""
        return level + self.level_offset if self.active else level

    def alarms(self) -> list[str]:
        """The index's alarm text while it acts (numbers change, the key does not)."""
        if not self.active:
            return []
        return [f"production lowered to {100 * self.f:.0f} % of its feeds (A feed lost; "
                f"reactor level set point {self.level_offset:+.1f} %)"]

    def checkpoint(self) -> dict[str, Any]:
        def num(v):  # JSON without NaN
            return None if not math.isfinite(v) else v

        return {"f": self.f, "active": self.active, "u4_0": num(self.u4_0),
                "u2_0": num(self.u2_0), "d_0": num(self.d_0), "d_f": num(self.d_f),
                "a_share": self.a_share, "level_offset": self.level_offset,
                "e_trim": self.e_trim, "e_prev": self._e_prev}

    def restore(self, state: dict[str, Any] | None) -> None:
        state = state or {}
        self.f = float(state.get("f", 1.0))
        self.active = bool(state.get("active", False))
        for name in ("u4_0", "u2_0", "d_0", "d_f"):
            v = state.get(name)
            setattr(self, name, math.nan if v is None else float(v))
        self.a_share = float(state.get("a_share", 1.0))
        self.level_offset = float(state.get("level_offset", 0.0))
        self.e_trim = float(state.get("e_trim", 0.0))
        self._e_prev = state.get("e_prev")
