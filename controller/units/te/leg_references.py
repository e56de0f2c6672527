"""The MPC's own references of the reactor level and temperature through a TE leg.

The grade plan moves every measured-output reference from one grade to the next on
one first-order time constant (seed §7.7, "a first-order reference trajectory";
:class:`controller.units.te.grades.TransitionPlan`, 3 h by default). It is the pace
the PI structure and the plan's feedforward alone can follow. The MPC can follow a
faster one for two of them, the reactor level (XMEAS 8) and the reactor temperature
(XMEAS 9), where that does not take from the leg's product or add to the pressure:

- on a leg that keeps the product (G in product and the product flow of the two
  grades within the bands that judge a grade, 1 mol % and 5 %: modes 0 and 1), the
  level and the temperature *are* the grade change, and both move on
  ``tau_fraction`` of the plan's time constant;
- on a leg that changes the product, the level moves faster only where it falls (the
  liquid drawn down goes to product) and the temperature only where it rises (more
  of the gas reacts, the pressure falls). A level rising fast holds back the liquid
  the product flow needs, a temperature falling fast leaves gas unreacted while the
  purge is already at its range (legs into mode 0 from modes 2 and 3).

Measured (strategy ``fixed``, noise on, seeds 1-6, 36 h, medians; Intel Xeon, 2 vCPU):
this pace (without the level's dip, below) against the plan's for every reference.

=====  ===========  ===============  ======================  ==========================
leg    moves        plan's pace      this rule               both on 1 h (seeds 1-3)
=====  ===========  ===============  ======================  ==========================
0->1   both         7.38 h, 889 $    2.75 h, 392 $           2.73 h, 391 $
1->0   both         7.56 h, 1680 $   2.71 h, 541 $           2.75 h, 542 $
0->2   both         7.33 h, 2197 $   6.78 h, 1402 $          6.85 h, 1417 $
0->3   both         6.69 h, 354 $    6.71 h, 340 $           6.63 h, 339 $
1->2   temperature  9.17 h, 2559 $   9.09 h, 2471 $
3->1   temperature  7.97 h, 1567 $   7.99 h, 1536 $
3->2   temperature  11.16 h, 3010 $  11.01 h, 2933 $
2->0   neither      5.75 h, 918 $    as the plan             7.98 h, 1260 $
3->0   neither      10.13 h, 2714 $  as the plan             11.99 h, 3354 $
=====  ===========  ===============  ======================  ==========================

1 -> 3, 2 -> 1 and 2 -> 3 move neither (the temperature falls, the level stays). No
trip in the 72 runs. Level alone on 1 h (seeds 1-3): 0 -> 1 5.28 h, 2 -> 0 8.07 h, 3 ->
0 10.9 h; temperature alone: 0 -> 1 7.49 h, 3 -> 0 11.36 h. The PI structure with both
references on 1 h on every leg: 0 -> 1 24.4 h, and 1 -> 3, 3 -> 0, 3 -> 1, 3 -> 2
tripped on every seed: the faster pace is the MPC's, not the plan's. Measured and not
taken: the product flow's reference (XMEAS 17) on 1 h too on the legs to and from mode 3
(3 -> 0 10.1 -> 19.4 h, 3 -> 2 11.0 -> 13.4, 1 -> 3 8.9 -> 12.7; 0 -> 3 6.7 -> 6.5);
G's (XMEAS 40) on the legs with mode 2 (no change: the D-share path makes them on the
grade's G, not on the path's).

And on a leg that changes G in product the level's target dips ``level_dip_pct`` (5 %
of range) below the new grade's for ``level_dip_h`` (4 h) after the leg, then returns
to it on the plan's time constant: the reactor holds less liquid while its
composition changes, so the old product leaves it sooner, and the liquid drawn down
goes to product; refilled on 3 h once most of the change is made, the product flow
stays within its band. Measured against the pace rule alone (strategy ``fixed``,
seeds 1-6, 36 h, medians, hours to grade and transition cost): every one of the ten
legs cheaper (0 -> 2 1402 -> 1301 $, 1 -> 2 2471 -> 2269, 3 -> 0 2714 -> 2454, 3 -> 1
1536 -> 1446, 2 -> 3 671 -> 634, 3 -> 2 2933 -> 2831, 2 -> 1 815 -> 785, 2 -> 0 918 ->
895, 1 -> 3 562 -> 545, 0 -> 3 340 -> 339); seven faster (3 -> 0 10.13 -> 9.37 h, 2 -> 3
11.16 -> 10.73, 2 -> 0 5.75 -> 5.56, 3 -> 1 7.99 -> 7.81, 1 -> 2 9.09 -> 8.94, 3 -> 2
11.01 -> 10.87, 2 -> 1 5.60 -> 5.51), three slower (1 -> 3 8.93 -> 9.09, 0 -> 3 6.71 ->
6.81, 0 -> 2 6.78 -> 6.79); no trip in the 60 runs. A dip of 7 % for 6 h, 5 % for 6 or
9 h: 3 -> 0 faster still (8.9-9.7 h), 1 -> 3 slower (9.06-9.45 h); 10 % for 8 h: 1 -> 2
7.6 h but 3 -> 0 12.5 h and 3 -> 1 11.4 h (seeds 1-3; refilled while the product flow
still rises to mode 0's). A leg that changes only the production gets no dip: with it
1 -> 4 took 6.85, 26.3 and 10.77 h against 6.3 on each seed, and 6 -> 3 1.6-2.1 h against
0.7 (seeds 1-3, 48 h; the maximum-production campaigns). The level is not among the
signals that judge a leg that changes the product; it is back at its grade about 9 h
after the leg.

Measured and not taken as well: the pace at 0.15 of the plan's instead of a third
(seeds 1-6): 0 -> 1 2.75 -> 2.6 h, 1 -> 0 2.71 -> 2.6 h, but 1 -> 0's peak 2850 -> 2878
kPa (the plan hold starts at 2880) and its cost 541 -> 577 $.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from controller.units.te.settings_check import check_finite_fields, check_range

__all__ = ["LEVEL_COLUMN", "TEMPERATURE_COLUMN", "LegReferenceSettings"]

#: 0-based XMEAS column of the reactor level (XMEAS 8) and temperature (XMEAS 9).
LEVEL_COLUMN = 7
TEMPERATURE_COLUMN = 8


@dataclass(frozen=True)
class LegReferenceSettings:
    """When and how much faster the MPC's level and temperature references move.

    Parameters
    ----------
    tau_fraction : float
        The faster references' time constant as a fraction of the plan's (0 < f <= 1;
        1/3: the plan's 3 h -> 1 h; an operator's longer duration stays longer).
    g_band_mol : float
        Two grades keep the product when their G in product (XMEAS 40) differ by at
        most this, mol % ...
    flow_band_rel : float
        ... and their product flows (XMEAS 17) by at most this fraction of the new one.
    level_dip_pct : float
        On a leg that changes G in product (by more than ``g_band_mol``), how far below
        the new grade's level the level's target goes, % of range (0: no dip).
    level_dip_h : float
        Hours after the leg at which the level's target returns to the grade's (on the
        plan's time constant), unless the next leg comes first.
    """

    tau_fraction: float = 1.0 / 3.0
    g_band_mol: float = 1.0
    flow_band_rel: float = 0.05
    level_dip_pct: float = 5.0
    level_dip_h: float = 4.0

    def __post_init__(self) -> None:
        check_finite_fields(self)
        check_range(self, "tau_fraction", "(0, 1]")
        check_range(self, ("g_band_mol", "flow_band_rel", "level_dip_pct", "level_dip_h"),
                    ">= 0")

    def keeps_product(self, before, after) -> bool:
        """Whether a leg from grade ``before`` to ``after`` keeps the product (objects
        with ``xmeas`` (41,), as :class:`controller.units.te.grades.Grade`)."""
        fa, fb = float(after.xmeas[16]), float(before.xmeas[16])
        return (not self.changes_g(before, after)
                and abs(fa - fb) <= self.flow_band_rel * abs(fa))

    def path(self, times, grades, tau_h: float):
        """The plan's measured-output path with these references.

        Parameters
        ----------
        times : sequence of float
            The legs' start times, h, increasing.
        grades : sequence of Grade
            The start grade, then each leg's grade (``len(times) + 1``).
        tau_h : float
            The plan's time constant of the measured outputs, h.

        Returns
        -------
        times : list of float
            Its switch times, h (the legs', and the level's return where it dips).
        values : list of ndarray (41,)
            The start's outputs, then the targets from each switch on.
        segment : callable
            ``segment(j, start)``: column -> time constant (h) of the j-th switch's
            segment, which starts at ``start`` (41,).
        legs : list of int
            The leg (0-based) each switch belongs to: the other tables of the plan
            switch at the same times, toward that leg's grade.

        A leg that changes G in product with ``level_dip_pct`` > 0 gets two switches for
        the reactor level: at the leg, toward the new grade's level less the dip; and
        ``level_dip_h`` later (before the next leg), back to the grade's level on the
        plan's time constant. The other columns go on as they were (a first-order path
        restarted on its own target and time constant is the same path).
        """
        x_times, values, legs_of = [], [grades[0].xmeas], []
        for i, t in enumerate(times):
            before, after = grades[i], grades[i + 1]
            dip = float(self.level_dip_pct) if self.changes_g(before, after) else 0.0
            x_times.append(float(t))
            if dip > 0.0:
                v = np.array(after.xmeas, dtype=float)
                v[LEVEL_COLUMN] -= dip
                values.append(v)
                legs_of.append((i, "dip"))
                back = float(t) + self.level_dip_h
                if i + 1 == len(times) or back < times[i + 1]:
                    x_times.append(back)
                    values.append(np.asarray(after.xmeas, dtype=float))
                    legs_of.append((i, "back"))
            else:
                values.append(np.asarray(after.xmeas, dtype=float))
                legs_of.append((i, "leg"))
        leg_taus: dict[int, dict[int, float]] = {}

        def segment(j: int, start) -> dict[int, float]:
            i, kind = legs_of[j]
            if kind == "back":  # the level back on the plan's pace, the rest as they were
                return {**leg_taus.get(i, {}), LEVEL_COLUMN: float(tau_h)}
            out = self.column_taus(grades[i], grades[i + 1], start, tau_h,
                                   target=values[j + 1])
            leg_taus[i] = out
            return out

        return x_times, values, segment, [i for i, _ in legs_of]

    def changes_g(self, before, after) -> bool:
        """Whether a leg changes G in product (XMEAS 40) by more than ``g_band_mol``."""
        return abs(float(after.xmeas[39]) - float(before.xmeas[39])) > self.g_band_mol

    def column_taus(self, before, after, start, tau_h: float,
                    target=None) -> dict[int, float]:
        """The faster time constants of one leg, column (0-based XMEAS) -> h.

        Parameters
        ----------
        before, after : Grade
            The grades the leg leaves and heads for.
        start : array_like, shape (41,)
            The references where the leg starts (the path may be between grades).
        tau_h : float
            The plan's time constant, h.
        target : array_like, shape (41,), optional
            Where the references head (default ``after.xmeas``; the level less its dip).
        """
        target = after.xmeas if target is None else target
        fast = self.tau_fraction * float(tau_h)
        same = self.keeps_product(before, after)
        out = {}
        if same or target[LEVEL_COLUMN] < start[LEVEL_COLUMN]:
            out[LEVEL_COLUMN] = fast
        if same or target[TEMPERATURE_COLUMN] > start[TEMPERATURE_COLUMN]:
            out[TEMPERATURE_COLUMN] = fast
        return out
