"""The TE reactant trim: A+C short in the reactor feed while the reactor level's D feed
is at its limit raises the A+C feed's target (through a grade change too), and at a
steady grade A+C in excess lowers it (after the A+C-in-feed loop on the C feed of
Ricker's 1996 decentralized control of the Tennessee Eastman process).

Method
    Every sample the deficit ``e = (y_A* + y_C*) - (y_A + y_C)`` of A and C in the
    reactor feed (XMEAS 23 + 25 against the plan's references, mol %) integrates into
    a trim ``c`` of the MPC's input target for the A+C feed (XMV 4, %):

    - it starts with the D feed (XMEAS 2) above ``d_limit`` % of its range and
      ``e > deadband``, ``raise_settle_h`` after the last grade change or later (0: at
      any time, through a change too): the reactor level's loop then has no D left to
      give, so the liquid it is short of must come from more reaction of the D already
      there;
    - while ``c > 0``: ``dc/dt = gain (e - deadband)`` for ``e > deadband``,
      ``gain e`` (back toward 0) for ``e < 0``, within ``[0, trim_max]``;
    - a cut (``c < 0``) acts on the excess beyond the one the grade settled with:
      when the grade becomes steady (``settle_h`` after a change, or the start of a
      run without one) ``e_s = min(ē, 0)`` is kept, ``ē`` the mean of ``e`` over the
      first ``settle_window_h`` (no cut within it), and with ``x = e - e_s``,
      ``dc/dt = gain (x + excess_deadband)`` while ``x < -excess_deadband``,
      ``gain x`` (back toward 0) for ``x > 0``, within ``[-excess_max, 0]``. It
      neither starts nor grows while the A feed is lost
      (:mod:`controller.units.te.overrides`) or the production index acts: the A in
      the feed is short then and the A+C excess is the C the A+C feed still brings.
      Why against the settled excess and not the plan's reference: after the legs
      into and out of mode 3 A+C settles 6-19 mol % above the plan's reference for a
      day and more with G and the production at grade (seed 1, 24-48 h after the
      change); cut against the reference, the plant left the grade at 25 h and 0 ->
      3, 1 -> 3, 2 -> 3 and 3 -> 0 came to grade after 35-38 h instead of 13-16 h
      (the matrix, seeds 1-3). A grade change ends a cut (the new grade's A+C target
      is the plan's): with the cut standing through 2 -> 3 requested at 1 h, IDV(8)
      from 0.5 h (seed 8), A+C ran short and the plant tripped at 4.8 h. The
      reference ``e_s`` is the mean of the first steady hour: taken from the first
      sample, a cut of under 0.1 % started at 0.3 h on IDV(8) from 0.5 h with 1 -> 3
      and 2 -> 3 requested at 1 h (seed 1), and both legs tripped at 4.8 h. Both pass
      near the interlocks either way (C out of the purge, the reactor level at 11-19 %
      at 4.5 h); without that cut they held. IDV(8) through 1 -> 3, 2 -> 3, 0 -> 3,
      2 -> 1 and 2 -> 0 on seeds 1-15: no trip with the hour's mean.

    Under IDV(8) (stream 4's A share up by as much as 0.03, its C share down by as
    much) the A-in-feed loop shut the A feed (19 -> 6 %) on the A surplus while C fell
    (17.8 -> 9.3 mol %): D found too little C to react (13 -> 21 mol %), the D valve
    stood at 96-100 %, the reactor level fell and the high-pressure override cut the
    A+C feed, which left even less C (trip at mode 3, 6.5 h). With ``c = 0`` (every
    other run) the moves are those without this module.

    Under IDV(1) (stream 4's A/C ratio steps down) the A-in-feed loop raised the A
    feed (24 -> 74 % over 4 h) while the A+C feed stayed where the production loop
    held it: C in the reactor feed rose from 26 to 34.5 mol %, the excess gathered in
    the recycle gas and the purge stood at 95-100 % from 4 to 8 h (mode 0, 340 $/h).
    The decentralized structure cut the A+C feed 62 -> 56 % and kept C at 26 mol %.
    The cut does that.

Measured when the cut was made, with its first deadband and limit (1.5 mol %, 15 %; ssmpc,
noise on, seeds 1-3, 48 h, onset 2 h; run-mean $/h and G standard deviation mol %,
without -> with the cut; the decentralized structure's, which
trips at mode 3, in brackets):

=========  ===========================  ===========================  ==================
case       mode 0                       mode 2                       mode 3
=========  ===========================  ===========================  ==================
IDV(1)     212.0 -> 184.0 (166.0)       211.6 -> 192.5 (176.1)       106.3 -> 45.4
           G 0.538 -> 0.578 (0.508)     G 0.542 -> 0.507 (0.516)
IDV(5)     141.2 -> 142.6 (170.6)       182.2 -> 181.9 (181.2)       134.0 -> 46.6
IDV(8)     180.4 -> 180.1 (174.6)       210.0 -> 203.2 (185.2)       75.7 -> 49.2
           G 0.618 -> 0.606 (0.529)     G 0.653 -> 0.581 (0.518)
IDV(18)    179.3 -> 177.5               184.6 -> 185.0 (181.4)       217.2 -> 112.1
IDV(20)    196.9 -> 175.1 (170.6)       186.0 -> 183.8 (181.3)       127.6 -> 52.1
           G 0.560 -> 0.592 (0.510)     G 0.692 -> 0.711 (0.523)
=========  ===========================  ===========================  ==================

The other cases move by less than 0.5 $/h; the 40 cases at modes 0 and 2 average 181.5
-> 179.5 $/h; no trip in IDV 1-20 at modes 0, 2, 3, and the 12 transitions (seed 1) and
0 -> 2, 2 -> 0 with IDV(8) (seeds 1-3) come to grade at the same hours as without the
cut. The production's standard deviation rises where the cut acts (IDV(1) at mode 3
2.2 -> 4.2 %, IDV(8) 3.7 -> 5.4 %). Tried: the cut's deadband at 1 mol % against the
plan's reference: IDV(1) at mode 0 172.7, at mode 2 186.4 $/h, but the transitions
above; at 3 mol % against the settled excess: IDV(1) 193.6 and 205.8 $/h. Held while
the A feed is lost: without that hold IDV(6) cost 258 instead of 308 $/h at mode 0 but
G wandered (standard deviation 6.3 against 0.57 mol %).

The raise (ssmpc, noise on, 48 h, IDV(8) from 2 h at mode 3; before: trip at 6.47 h on
plant seed 1):

========  ======  ===================  ==============
seed      trip    reactor pressure     largest trim
========  ======  ===================  ==============
1         none    at most 2902 kPa     11.5 %
2         none    at most 2901 kPa     0 (not needed)
3         none    at most 2913 kPa     7.1 %
========  ======  ===================  ==============

The cut's deadband and limit: 0.1 mol % and 6 % (before 1.5 mol % and 15 %). At mode
2 the plan's pressure is Ricker's 2800 kPa already, the economic targets have nothing
to lift, and under IDV(1) and IDV(8) the C that the A+C feed brings beyond the A loop's
need gathered in the recycle and left through the purge within the old deadband (IDV(1)
at mode 2, seeds 1-3: C in the purge 16.0 mol % against 14.5 for the decentralized
structure, which sets the A+C feed from the reactor level). The acceptance matrix
(``docs/te_matrix.md``; seeds 1-3, 48 h; ``ssmpc`` before -> after, the decentralized
structure's in brackets):

=================  ==========================  ================================
case               $/h                         G standard deviation, mol %
=================  ==========================  ================================
IDV(1) at mode 2   179.76 -> 177.26 (176.09)   0.508 -> 0.503 (0.516)
IDV(8) at mode 2   188.24 -> 186.52 (185.25)   0.522 -> 0.520 (0.518)
IDV(1) at mode 0   155.36 -> 154.93 (166.04)   0.509 -> 0.505 (0.508)
IDV(20) at mode 0  149.53 -> 152.41 (170.64)   0.555 -> 0.567 (0.510)
=================  ==========================  ================================

The 36 cases at modes 0 and 2 in which the decentralized structure does not trip: the
cost 0.30 $/h lower on the mean, G's deviation as before (+0.0002 mol %); no trip.
Mode 3 held from the start (hours 24-36 and 36-48, seeds 1-3): 12 h windows at -0.4 to
+2.1 % of Ricker's optimum (-2.7 to +3.6 % before). IDV(13) at mode 2 over seeds 1-80:
no trip, peak 2903 kPa (as before); IDV 1, 6, 8, 12, 13, 18, 20 at modes 0 and 2 and
IDV 1, 6, 8, 20 at mode 3 over seeds 4-13: no trip. Measured and not taken (seeds 1-3):
a deadband of 0.2 mol % with the 15 % limit cut G under IDV(1) at mode 0 (0.519 mol %,
against the decentralized structure's 0.508: the cut there grows past 6 %; at mode 2 it
stays under 5 %); with that deadband a limit of 8 % 0.516, 3 % 0.501 but 165.0 $/h;
the cut's gain at 1, 2, 10 or 20 %/(mol % h) instead of 5 with the 0.2 mol % deadband:
IDV(1) at mode 0 0.532, 0.519, 0.564, 0.546 mol %.

Through a grade change
    Into a grade richer in G (mode 3) the D share rises while the E of the grade
    before still reacts, the reactor level falls as the pressure dips, the level loop
    drives the D valve to its range and A and C run short: C in the purge went to 0
    on 1 -> 3 without a disturbance, and with IDV(8) the plant tripped (see
    :data:`controller.units.te.control.GUARDS_MPC`). The raise then acts from the
    change on (``raise_settle_h = 0``); before, it waited the cut's 24 h. With the
    guards on C short in the purge, IDV(8) from 0.5 h through five legs at 1 h (1 -> 3,
    2 -> 3, 0 -> 3, 2 -> 1, 2 -> 0; seeds 1-15, 24 h) tripped ``ssmpc`` in 2 of 75
    runs, against 21 before; with the raise alone 10 of the 25 runs on seeds 1-5
    tripped (14 before). On the acceptance matrix's legs, alone, it took 1 -> 3
    from 10.5 to 13.1 h; with the guards 10.8 h (``docs/te_matrix.md``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.units.te.settings_check import check_finite_fields, check_range, is_finite_number
from controller.units.te.spec import D_FULL_KG_H

__all__ = ["ReactantTrimSettings", "ReactantTrim"]


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
        Hours after a grade change before a cut may start, and from which the excess
        the grade settled with is kept (a moving plan's references are not an excess).
    raise_settle_h : float
        Hours after a grade change before a raise may start (0: through the change
        too). Into a grade richer in G the D feed reaches its range while the E left
        from the grade before still reacts, and A+C runs short: with 24 h (the cut's
        wait) IDV(8) through a leg into mode 3 tripped the plant (see the module
        docstring, "Through a grade change").
    excess_max : float
        Largest cut of the A+C feed's target for A+C in excess in the reactor feed, %
        (0: the trim only raises it).
    excess_deadband : float
        Excess beyond the one the grade settled with that the cut ignores, mol %.
    settle_window_h : float
        Hours over which the excess the grade settled with is averaged once it is
        steady; no cut starts within them (0: the first steady sample alone). The
        analyzer's noise on A and C in the reactor feed (0.25 mol % each, Downs &
        Vogel) is larger than the deadband: taken from one sample, the reference let a
        cut start within minutes of a controller's start (the trip it caused: the
        module docstring, "Method").
    """

    d_limit: float = 93.0
    deadband: float = 1.0
    gain: float = 5.0
    trim_max: float = 30.0
    settle_h: float = 24.0
    raise_settle_h: float = 0.0
    excess_max: float = 6.0
    excess_deadband: float = 0.1
    settle_window_h: float = 1.0

    def __post_init__(self) -> None:
        check_finite_fields(self)
        check_range(self, "d_limit", "(0, 100)", "%")
        check_range(self, ("deadband", "settle_h", "raise_settle_h", "excess_max",
                           "excess_deadband", "settle_window_h"), ">= 0")
        check_range(self, ("gain", "trim_max"), "> 0")
        check_range(self, ("trim_max", "excess_max"), "<= 100", "%")


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
        #: the deficit the grade settled with (set when the grade becomes steady), mol %
        self.settled = math.nan
        # the deficits summed, and their samples, over the settling window
        self._window_sum = 0.0
        self._window_n = 0

    @property
    def active(self) -> bool:
        return self.trim != 0.0

    def step(self, xmeas, ym, hours_since_change: float, hold_cut: bool = False) -> float:
        """Advance one sample: ``xmeas`` (41,) this sample's XMEAS, ``ym`` (41,) the
        plan's XMEAS references, ``hours_since_change`` h since the last grade change
        (inf: none); ``hold_cut``: a cut neither starts nor grows (the A feed lost).
        Returns the trim, %."""
        s = self.settings
        e = float(ym[22] + ym[24] - xmeas[22] - xmeas[24])
        d = float(xmeas[1]) / D_FULL_KG_H * 100.0
        if not (math.isfinite(e) and math.isfinite(d)):
            return self.trim
        self.deficit = e
        steady = hours_since_change >= s.settle_h
        if not steady:
            self.settled = math.nan
            self._window_sum, self._window_n = 0.0, 0
            # a grade change ends a cut: the new grade's A+C target is the plan's
            self.trim = max(self.trim, 0.0)
        elif not math.isfinite(self.settled):
            self._window_sum += e
            self._window_n += 1
            if self._window_n * self.sample_h >= s.settle_window_h - 1e-9:
                self.settled = min(self._window_sum / self._window_n, 0.0)
        # the excess beyond what the grade settled with
        x = e - self.settled if math.isfinite(self.settled) else 0.0
        rate = s.gain * self.sample_h
        if self.trim >= 0.0:
            if e > s.deadband and (self.trim > 0.0 or (
                    d > s.d_limit and hours_since_change >= s.raise_settle_h)):
                self.trim += rate * (e - s.deadband)
            elif e < 0.0 and self.trim > 0.0:
                self.trim = max(self.trim + rate * e, 0.0)
            elif x < -s.excess_deadband and s.excess_max > 0.0 and not hold_cut:
                self.trim += rate * (x + s.excess_deadband)  # a cut starts
        elif x < -s.excess_deadband:  # a cut acts
            if not hold_cut:
                self.trim += rate * (x + s.excess_deadband)
        elif x > 0.0:
            self.trim = min(self.trim + rate * x, 0.0)
        self.trim = min(max(self.trim, -s.excess_max), s.trim_max)
        return self.trim

    def alarms(self) -> list[str]:
        """The trim's alarm text while it acts (numbers change, the key does not)."""
        if not self.active:
            return []
        if self.trim < 0.0:
            return [f"A+C in the reactor feed {-self.deficit:.1f} mol % in excess: A+C feed "
                    f"target lowered by {-self.trim:.1f} %"]
        return [f"A+C in the reactor feed {self.deficit:.1f} mol % short with the D feed "
                f"at its limit: A+C feed target raised by {self.trim:.1f} %"]

    def checkpoint(self) -> dict[str, Any]:
        return {"trim": self.trim,
                "settled": self.settled if math.isfinite(self.settled) else None,
                "window_sum": self._window_sum, "window_n": self._window_n}

    def restore(self, state: dict[str, Any] | None) -> None:
        """Go on from :meth:`checkpoint`'s ``state`` (None: start again). The four
        fields are taken together: one of them damaged (not a finite number, the trim
        beyond its limits, a negative or fractional count) starts the trim again with
        no trim and the settling window empty, as a controller's start does, rather
        than a cut or raise read half from the store."""
        s = self.settings
        st = state if isinstance(state, dict) else {}
        trim = st.get("trim", 0.0)
        settled = st.get("settled")
        window_sum = st.get("window_sum", 0.0)
        window_n = st.get("window_n", 0)
        whole = (is_finite_number(trim) and -s.excess_max <= trim <= s.trim_max
                 and (settled is None or is_finite_number(settled))
                 and is_finite_number(window_sum)
                 and is_finite_number(window_n) and window_n >= 0
                 and float(window_n).is_integer())
        if not whole:
            trim, settled, window_sum, window_n = 0.0, None, 0.0, 0
        self.trim = float(trim)
        self.settled = math.nan if settled is None else float(settled)
        self._window_sum = float(window_sum)
        self._window_n = int(window_n)
