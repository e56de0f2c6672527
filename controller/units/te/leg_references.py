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
the rule against the plan's pace for every reference.

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
"""

from __future__ import annotations

import math
from dataclasses import dataclass

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
    """

    tau_fraction: float = 1.0 / 3.0
    g_band_mol: float = 1.0
    flow_band_rel: float = 0.05

    def __post_init__(self) -> None:
        f = self.tau_fraction
        if not (isinstance(f, int | float) and not isinstance(f, bool) and math.isfinite(f)
                and 0.0 < f <= 1.0):
            raise ValueError(f"tau_fraction: must be in (0, 1], got {f!r}")
        for name in ("g_band_mol", "flow_band_rel"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and not isinstance(v, bool)
                    and math.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name}: must be a finite number >= 0, got {v!r}")

    def keeps_product(self, before, after) -> bool:
        """Whether a leg from grade ``before`` to ``after`` keeps the product (objects
        with ``xmeas`` (41,), as :class:`controller.units.te.grades.Grade`)."""
        fa, fb = float(after.xmeas[16]), float(before.xmeas[16])
        return (abs(float(after.xmeas[39]) - float(before.xmeas[39])) <= self.g_band_mol
                and abs(fa - fb) <= self.flow_band_rel * abs(fa))

    def column_taus(self, before, after, start, tau_h: float) -> dict[int, float]:
        """The faster time constants of one leg, column (0-based XMEAS) -> h.

        Parameters
        ----------
        before, after : Grade
            The grades the leg leaves and heads for.
        start : array_like, shape (41,)
            The references where the leg starts (the path may be between grades).
        tau_h : float
            The plan's time constant, h.
        """
        fast = self.tau_fraction * float(tau_h)
        same = self.keeps_product(before, after)
        out = {}
        if same or after.xmeas[LEVEL_COLUMN] < start[LEVEL_COLUMN]:
            out[LEVEL_COLUMN] = fast
        if same or after.xmeas[TEMPERATURE_COLUMN] > start[TEMPERATURE_COLUMN]:
            out[TEMPERATURE_COLUMN] = fast
        return out
