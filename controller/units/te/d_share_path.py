"""The D share's path through a TE grade change, paced by what the plant can follow.

The product's G/H split follows the D share ``s = D / (D + E)`` of the D and E feeds
(seed §7.7: the E feed is set in ratio to the measured D feed). The grade plan moves
the share along a first-order path with the plan's valve time constant (3 h,
:data:`controller.units.te.grades.TAU_DEFAULT_H`), and a PI loop on the product
analyzer (XMEAS 40: 0.25 h samples, 0.25 h dead time) corrects it. Through a grade
change that loop integrates the lag between the plan's G reference and the plant's
G: G left the new grade's band again after entering it and took hours to come back
(G first in its band 6.8-10.6 h after the request, at grade after 9-17 h; ssmpc,
seed 1).

The MPC strategies plan the share of a grade change between grades whose D and E
valves leave it free (modes 0, 1 and 3) with their composition core
(:mod:`controller.units.te.composition_core`); through a leg to or from mode 2, whose E
valve sits at 96 % of its range, or one of the back-off modes 4-6, and wherever the
core is off, they move the share along a faster path of their own,
``tau ds/dt = s_grade - s`` (:attr:`DSharePathSettings.tau_h`, slower toward a
higher D share: :attr:`DSharePathSettings.tau_rise_h`), with G feedback until the
grade is steady only within
:data:`controller.units.te.control.RATIO_PATH_WINDOW_MOL` of the new grade's G, and
pace it by the plant:

- the path waits (``s`` stays) while the plan is held near the pressure interlock
  (:class:`controller.units.te.control.TransitionGuards`), in the same share;
- a rise of the D share waits while the D feed (XMEAS 2) is within
  :attr:`DSharePathSettings.d_feed_high` of its full flow and the reactor level
  (XMEAS 8) is more than :attr:`DSharePathSettings.level_low_pct` below its set point:
  the E feed the ratio takes away would then be liquid the level loop's D valve
  cannot make up (into mode 3 with a 0.3 h path and no such wait the level fell from
  65 to 13 % and the reactor temperature tripped the plant, 1 -> 3, seed 1, 2.3 h).

The lead (:attr:`DSharePathSettings.lead`): after a grade change the path first
heads for a share half the change beyond the new grade's, within the ratio's limits,
and turns to the grade's own share once the product's G has covered 30 % of its way
(half of it toward a lower share, below; :attr:`DSharePathSettings.lead_until`,
:attr:`~DSharePathSettings.lead_until_fall`; the analyzer's 0.5 h of delay and the G
loop's window then bring it in without overshoot), at the latest after
:attr:`DSharePathSettings.lead_max_h`. The G response to the share is slow at the
start (linearized cascade, mode 0: 37 % of its change after 1 h, 84 % after 2 h; mode
3: 17 % and 58 %), so a path that only heads for the grade's share spends hours in
its tail. Measured (ssmpc, noise on, seeds 1-3, 36 h, change at 1 h; median hours to
grade, without the lead / with it; the ends of the lead came 0.25-3.5 h after the
change):

====================  ===========  ==========
case                  no lead      lead 0.5
====================  ===========  ==========
0 -> 2                7.6          7.6
0 -> 3                9.9          8.5
2 -> 0                8.4          5.7
2 -> 1                8.3          5.8
2 -> 3                11.9         11.8
3 -> 1                9.1          7.6
the others (6)        7.4-11.4     the same to 0.1 h
sum of 36 runs        358.1 h      334.0 h
====================  ===========  ==========

No trip; the highest pressure 2892 kPa either way. A lead that ends at a fixed time
instead was fragile: 0.5 for 2 h took 2 -> 0 to 3.9 h, 0.4 for 2.5 h to 8.3 h and 0.3
for 4 h to 9.8 h; 0.8 ending at 30 % took
2 -> 0 to 8.1 h, 0.5 ending at 40 % or 50 % made 1 -> 3 or 3 -> 1 slower.

The lead's end into mode 2 (:attr:`DSharePathSettings.lead_until_fall`). Toward mode 2
the lead's aim is the ratio's lower limit (half the change beyond mode 2's share, 0.084,
is cut to 0.03), and the path falls toward it at ``tau_h``. Ended at 30 % of G's way,
as toward a higher share, the lead stopped before the path had passed mode 2's share
(1 -> 2, seed 3: 0.10 at 3.3 h), the path came to it from above and G crept along its
tail (at grade after 9.03 h, 2290 $); ended at half the way, the path had gone past it
(0.054 at 4.5 h), comes back from below, and the grade is made after 7.81 h for
1971 $. Measured (ssmpc, noise on, seeds 1-15, 30 h, change at 1 h; median hours to
grade and mean transition cost, the lead ending at 30 % / at 50 % of the way):

======  =============  ===============  ==================================
leg     hours          transition $     seeds faster (by 0.05 h) / slower
======  =============  ===============  ==================================
0 -> 2  6.92 / 6.77    1383 / 1335      15 / 0
1 -> 2  9.04 / 8.39    2333 / 2204      14 / 0
3 -> 2  10.88 / 10.75  2894 / 2875      11 / 0
======  =============  ===============  ==================================

No trip, the same peaks (2843, 2879 and 2880 kPa at the most); the legs toward a higher
share do not change. Ended at 60 % (``fixed``, seeds 1-15) 1 -> 2 came to 7.94 h but
one seed of 0 -> 2 took 13.0 h.

Before the lead (the acceptance matrix, ``docs/te_matrix.md``: ssmpc, noise on, seeds
1-3, 48 h, median hours to grade; with the plan's path and the G loop through the
change, against this path with
:data:`~controller.units.te.control.RATIO_PATH_WINDOW_MOL`):

==================  ============  ==========
case                plan path     this path
==================  ============  ==========
0 -> 2              10.5          7.6
0 -> 3              13.3          9.9
1 -> 2              15.8          9.1
1 -> 3              13.5          10.5
2 -> 3              15.8          11.9
3 -> 1              14.3          8.1
3 -> 2              18.7          10.8
0 -> 2 with IDV(8)  18.5          7.6
==================  ============  ==========

No trip in the matrix's 222 ssmpc runs. The reactor pressure still peaked above 2895
kPa within 2 h of the request on 0 -> 2 (2910 kPa; 2900 with the plan's path), 1 -> 2
and the legs out of mode 3 (2908-2915 kPa), before the MPC held its pressure limit
itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.units.te.spec import D_FULL_KG_H


@dataclass(frozen=True)
class DSharePathSettings:
    """The D share's own path (MPC strategies).

    Parameters
    ----------
    tau_h : float
        Time constant of the path toward a grade with a lower D share (toward more
        H), h (> 0).
    tau_rise_h : float
        Time constant toward a grade with a higher D share (toward more G, and into
        mode 3), h (> 0). Slower: with 1 h the 1 -> 3 leg tripped on reactor pressure
        on seed 2 (3.3 h) even with the D-feed wait below; with 1.5 h none of the 36
        runs of the 12 transitions on seeds 1-3 tripped.
    d_feed_high : float
        Share of the full D flow (:data:`D_FULL_KG_H`) from which the D valve is
        taken as at its limit, in (0, 1].
    level_low_pct : float
        How far below its set point (% of range, >= 0) the reactor level must fall,
        with the D feed high, for a rise of the D share to wait.
    lead : float
        The lead (>= 0; 0: none): after a grade change the path heads for a share this
        fraction of the change beyond the new grade's, ``s_grade + lead (s_grade -
        s_from)`` within the share's limits, until the product's G (XMEAS 40) has
        covered ``lead_until`` of its way from its value at the change to the new
        grade's G; then for the grade's share.
    lead_until : float
        The share of G's way at which the lead ends, in (0, 1], toward a higher D
        share.
    lead_until_fall : float
        The same toward a lower D share (into mode 2, whose share sits at the E valve's
        limit), in (0, 1]. Later than the rise's: ended at 30 % of the way the path had
        not yet passed mode 2's share, and G crept along its tail for hours (the
        module's "The lead's end into mode 2").
    lead_max_h : float
        The lead ends at the latest this long after the change, h (> 0): with the
        analyzer out (G not finite) or G held back by a limit, the path still
        arrives at the grade's share.
    """

    tau_h: float = 1.0
    tau_rise_h: float = 1.5
    d_feed_high: float = 0.95
    level_low_pct: float = 2.0
    lead: float = 0.5
    lead_until: float = 0.3
    lead_until_fall: float = 0.5
    lead_max_h: float = 6.0

    def __post_init__(self) -> None:
        for name in ("tau_h", "tau_rise_h"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a finite number > 0 h, got {v!r}")
        if not (isinstance(self.d_feed_high, int | float)
                and 0.0 < self.d_feed_high <= 1.0):
            raise ValueError(f"d_feed_high: must be in (0, 1], got {self.d_feed_high!r}")
        if not (isinstance(self.level_low_pct, int | float)
                and math.isfinite(self.level_low_pct) and self.level_low_pct >= 0):
            raise ValueError(f"level_low_pct: must be finite and >= 0 %, got "
                             f"{self.level_low_pct!r}")
        if not (isinstance(self.lead, int | float) and math.isfinite(self.lead)
                and self.lead >= 0):
            raise ValueError(f"lead: must be finite and >= 0, got {self.lead!r}")
        for name in ("lead_until", "lead_until_fall"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and 0.0 < v <= 1.0):
                raise ValueError(f"{name}: must be in (0, 1], got {v!r}")
        if not (isinstance(self.lead_max_h, int | float) and math.isfinite(self.lead_max_h)
                and self.lead_max_h > 0):
            raise ValueError(f"lead_max_h: must be a finite number > 0 h, got "
                             f"{self.lead_max_h!r}")


    def feed_waits(self, d_feed_kg_h: float, level_pct: float, level_sp_pct: float) -> bool:
        """Whether a rise of the D share waits: the D feed (XMEAS 2, kg/h) within
        ``d_feed_high`` of its full flow and the reactor level (XMEAS 8, %) more than
        ``level_low_pct`` below its set point (NaN measurements: no wait)."""
        return (d_feed_kg_h >= self.d_feed_high * D_FULL_KG_H
                and level_pct < level_sp_pct - self.level_low_pct)


class DSharePath:
    """The D share's path, one value per supervisory sample.

    Parameters
    ----------
    settings : DSharePathSettings, optional
    sample_h : float
        The supervisory sample, h.
    limits : (float, float)
        The D share's limits (those of the ratio), which bound the lead's target.
    """

    def __init__(self, settings: DSharePathSettings | None, sample_h: float,
                 limits: tuple[float, float] = (0.0, 1.0)) -> None:
        self.settings = settings or DSharePathSettings()
        self.sample_h = float(sample_h)
        self.limits = (float(limits[0]), float(limits[1]))
        self.alpha_fall = 1.0 - math.exp(-self.sample_h / self.settings.tau_h)
        self.alpha_rise = 1.0 - math.exp(-self.sample_h / self.settings.tau_rise_h)
        #: the path's D share (None before the first sample)
        self.value: float | None = None
        #: whether the last sample's rise waited for the D feed
        self.waiting = False
        #: the grade's share the path heads for (None before the first sample)
        self.s_grade: float | None = None
        #: the lead in force: (its target share, G at the change, h since the change),
        #: or None
        self.lead: tuple[float, float, float] | None = None

    def start(self, s: float, s_grade: float | None = None) -> None:
        """Start the path at the D share ``s`` (the plan's at the first sample), for the
        grade's share ``s_grade`` (None: the first step's)."""
        self.value = float(s)
        self.s_grade = None if s_grade is None else float(s_grade)
        self.lead = None

    def step(self, s_grade: float, hold: float, d_feed_kg_h: float, level_pct: float,
             level_sp_pct: float, g_mol: float = math.nan,
             g_grade_mol: float = math.nan) -> float:
        """Advance one sample toward ``s_grade`` and return the path's D share.

        Parameters
        ----------
        s_grade : float
            The D share of the grade in force on the plan's clock.
        hold : float
            The share of the sample the plan is held, in [0, 1].
        d_feed_kg_h : float
            Measured D feed (XMEAS 2), kg/h.
        level_pct, level_sp_pct : float
            Reactor level (XMEAS 8) and its set point, %.
        g_mol, g_grade_mol : float
            G in product (XMEAS 40) and the grade's G, mol %: they end the lead (none
            when G is not finite at the change).
        """
        if self.value is None:
            self.start(s_grade, s_grade)
            return self.value
        st = self.settings
        if self.s_grade is None:  # a path started without its grade, or restored so
            self.s_grade = s_grade
        elif s_grade != self.s_grade:  # a grade change: the lead from here
            self.lead = None
            if st.lead > 0.0 and math.isfinite(g_mol) and math.isfinite(g_grade_mol) \
                    and g_grade_mol != g_mol:
                lo, hi = self.limits
                target = min(max(s_grade + st.lead * (s_grade - self.value), lo), hi)
                self.lead = (target, g_mol, 0.0)
            self.s_grade = s_grade
        aim = s_grade
        lead = self.lead
        if lead is not None:
            target, g_from, age = lead
            covered = (g_mol - g_from) / (g_grade_mol - g_from) \
                if g_grade_mol != g_from else 1.0
            until = st.lead_until_fall if target < s_grade else st.lead_until
            if age >= st.lead_max_h or covered >= until:  # NaN: goes on
                self.lead = None
            else:
                aim = target
                self.lead = (target, g_from, age + self.sample_h)
        gap = aim - self.value
        step = (self.alpha_rise if gap > 0.0 else self.alpha_fall) * gap
        self.waiting = step > 0.0 and st.feed_waits(d_feed_kg_h, level_pct, level_sp_pct)
        if not self.waiting:  # NaN measurements compare False: no wait on them
            self.value += (1.0 - min(max(hold, 0.0), 1.0)) * step
        return self.value

    def checkpoint(self) -> dict[str, Any]:
        return {"value": self.value, "s_grade": self.s_grade,
                "lead": None if self.lead is None else list(self.lead)}

    def restore(self, state: dict[str, Any] | None) -> None:
        state = state or {}
        value, s_grade, lead = (state.get(k) for k in ("value", "s_grade", "lead"))
        self.value = None if value is None else float(value)
        self.s_grade = None if s_grade is None else float(s_grade)
        self.lead = None if lead is None else tuple(float(v) for v in lead)
        self.waiting = False
