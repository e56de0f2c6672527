"""Floating pressure: the reactor pressure set point follows a rising pressure while the
excess in the recycle gas is C (a guard of the TE cascade at a steady grade).

The plant side's pressure loop opens the purge (XMV 6) to hold the reactor pressure at
P_r*. The purge is the plant's costliest stream (its reactants and product leave with
it; about 70 % of the operating cost at mode 2), and a pressure held tightly turns each
pressure swing into a purge swing. Under IDV(8) at mode 2 (seed 1) the A-in-feed loop cut
the A feed, C gathered in the recycle gas (C in the purge 14.6 -> 17-18 mol %, the plan's
14.6), the pressure rose to 2830-2847 kPa, and the loop opened the purge from 0.30 to 0.60
kscmh over 3 h (264 $/h); the set point's tracking then let the pressure fall to
2700 kPa with the purge still open, for about ten hours. The decentralized
structure, whose purge follows B in the purge slowly, lets its pressure ride instead.

The guard: at a steady grade (:attr:`FloatingPressureSettings.after_h` after the last
grade change), while C in the purge (XMEAS 31) is at least
:attr:`FloatingPressureSettings.c_excess_mol` above the plan's, P_r* stands at most
:attr:`FloatingPressureSettings.margin_kpa` below the measured pressure, up to
:attr:`FloatingPressureSettings.ceiling_kpa`: the purge loop then sees at most the
margin, and the excess C is left to the feeds (the A+C feed's reactant trim,
:mod:`controller.units.te.reactant_trim`, and the A-in-feed loop) rather than purged.
Past the ceiling the floor gives way (:attr:`FloatingPressureSettings.release_per_kpa`),
so that by the MPC's soft pressure limit the loop meets the whole excess again. It never
lowers P_r*. It does not act while the A feed is lost or the production index lowers
production (the C then in excess is what the lost A leaves unreacted, and the pressure
must be held down).

Why the condition on C: a pressure rise with the kinetics' drift (IDV(13)) gathers E,
not C (C in the purge falls 14.6 -> 6-13 mol %); there the purge must open at once.
Without the condition the guard floated through those rises and IDV(13) at mode 2
tripped on seeds 3, 5 and 7 of 1-16 (45.7, 11.8 and 20.0 h); with it, on none. The
margin of 1 mol % over the plan's C was needed by a first form of the guard without the
release (below), which at the plan's C tripped on seed 3 or 5 of 1-11; with the release,
at the plan's C none of 1-16 trips (IDV(8) at mode 2 187.9 $/h, G 0.543 mol %), and the
margin is kept. In that first form, without the A-feed condition, IDV(6) tripped at
modes 0, 1 and 2 (the lost A leaves C in excess).
Without the release, P_r* held at the ceiling while C ran away (0 -> 2 with IDV(8),
seed 3: C in the purge 14.6 -> 26 mol % 27-29 h into the run, the high-pressure
override cut the A+C feed to 16 %) took the product off its grade at 29 h (to grade at
30.1 h instead of 6.9 in the acceptance matrix), and with IDV(8) from the start it
tripped.

Measured (``ssmpc``, noise on, seeds 1-3, 48 h, onset 2 h; G std mol % / mean $/h /
peak kPa; the decentralized structure's cost in the last column):

==================  =======================  =======================  =============
case                without                  with the guard           decentralized
==================  =======================  =======================  =============
IDV(1) at mode 2    0.509 / 189.1 / 2874     0.519 / 180.7 / 2877     176.1
IDV(8) at mode 2    0.580 / 204.1 / 2870     0.525 / 189.0 / 2872     185.3
IDV(18) at mode 2   1.040 / 183.5 / 2838     1.030 / 182.8 / 2842     181.4
IDV(20) at mode 2   0.676 / 182.4 / 2839     0.664 / 178.9 / 2855     181.3
IDV(1) at mode 0    0.562 / 159.8 / 2851     0.528 / 153.1 / 2877     166.0
IDV(8) at mode 0    0.575 / 161.9 / 2878     0.570 / 154.5 / 2878     174.6
IDV(20) at mode 0   0.562 / 150.7 / 2861     0.558 / 149.2 / 2871     170.6
IDV(1) at mode 1    0.558 / 123.0 / 2877     0.541 / 117.0 / 2880     -
IDV(8) at mode 1    0.715 / 135.2 / 2878     0.659 / 121.1 / 2877     -
IDV(20) at mode 1   0.681 / 118.5 / 2857     0.661 / 115.6 / 2877     -
==================  =======================  =======================  =============

IDV(13) at mode 2 holds on seeds 1-16 (peak 2899 kPa, as without the guard). At mode 3
the guard does not act (C in the purge stays within 1 mol % of the plan's): IDV 1-20
there are as without it. Without the release (the P_r* held at the ceiling) the costs
were 1-4 $/h lower: IDV(8) at mode 2 187.3, at mode 0 150.8 $/h.

Measured, not taken: acting only while B in the purge (the inert) is at most 0-0.4 mol %
above the plan's. It gives up the mode-0 gains (IDV(8) 161.2-161.7 $/h against 154.5,
IDV(20) 150.5-150.7 against 149.2), where the economics raise the pressure and keep more
B on purpose, and half of IDV(8)'s at mode 2 (192.4-195.7 against 189.0). What it
answered: after 0 -> 2 without noise the guard lets B gather while it holds the purge
back (30-34 h), and the purge then opens further (hour 40: 196 against 174 $/h); over
hours 24-72 the run's mean cost is 173.1 against 173.6 $/h without the guard, and both
settle at 180 $/h from 60 h on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.units.te.settings_check import check_finite_fields, check_range

__all__ = ["FloatingPressureSettings", "floating_pressure_floor"]


@dataclass(frozen=True)
class FloatingPressureSettings:
    """Settings of the floating pressure (see the module docstring).

    Parameters
    ----------
    margin_kpa : float
        Most P_r* stands below the measured reactor pressure while the guard acts, kPa
        (>= 0).
    ceiling_kpa : float
        Highest P_r* the guard sets, kPa.
    release_per_kpa : float
        Above the ceiling (and its margin) the floor falls by this many kPa per kPa of
        pressure (> 0): with 2, from 2850 kPa at 2855 kPa to the grades' 2800 kPa at
        2880 kPa, just past the MPC's soft pressure limit (2875 kPa).
    c_excess_mol : float
        C in the purge (XMEAS 31) above the plan's from which the guard acts, mol %.
    after_h : float
        Hours after a grade change from which the guard acts (>= 0).
    """

    margin_kpa: float = 5.0
    ceiling_kpa: float = 2850.0
    release_per_kpa: float = 2.0
    c_excess_mol: float = 1.0
    after_h: float = 24.0

    def __post_init__(self) -> None:
        label = "floating pressure "
        check_finite_fields(self, label)
        check_range(self, "margin_kpa", "[0, 100]", "kPa", label)
        check_range(self, "ceiling_kpa", "(2000, 3000)", "kPa", label)
        check_range(self, "release_per_kpa", "> 0", label=label)
        check_range(self, "after_h", ">= 0", "h", label)


def floating_pressure_floor(settings: FloatingPressureSettings, pressure_kpa: float,
                            c_purge_mol: float, c_purge_plan_mol: float, since_h: float,
                            held_down: bool, limit_kpa: float = math.inf) -> float | None:
    """Lowest P_r* this sample (kPa), or None where the guard does not act.

    Parameters
    ----------
    settings : FloatingPressureSettings
    pressure_kpa : float
        Reactor pressure, XMEAS 7, kPa.
    c_purge_mol, c_purge_plan_mol : float
        C in the purge, XMEAS 31, and the plan's reference of it, mol %.
    since_h : float
        Hours since the last grade change.
    held_down : bool
        True while the pressure must be held down whatever the composition (the A feed
        lost, the production index lowering production).
    limit_kpa : float
        A high limit on the reactor pressure in force (an operator's, through the
        steady-state targets), kPa: the ceiling goes no higher.
    """
    s = settings
    if held_down or since_h < s.after_h:
        return None
    if not all(math.isfinite(v) for v in (pressure_kpa, c_purge_mol, c_purge_plan_mol)):
        return None
    if c_purge_mol < c_purge_plan_mol + s.c_excess_mol:
        return None
    ceiling = min(s.ceiling_kpa, limit_kpa) if not math.isnan(limit_kpa) else s.ceiling_kpa
    if pressure_kpa <= ceiling + s.margin_kpa:
        return pressure_kpa - s.margin_kpa
    # past the ceiling the floor gives way, and the loop meets the pressure in full
    return ceiling - s.release_per_kpa * (pressure_kpa - ceiling - s.margin_kpa)
