"""The reactor level's set point follows a falling level while the pressure is high and
the E feed is at its range (a guard of the TE cascade at a steady grade).

The plant side's reactor-level loop (seed Table 7.10) moves the D feed, and the E/D ratio
moves the E feed with it (§7.7). Where the E valve is near its range (mode 2: 96 % at
Ricker's optimum) a rise of the D feed cannot be matched by E, so it shifts the reaction
toward G and uses up C. Under IDV(13) at mode 2 (the kinetics' slow drift, seeds 4, 5
and 7 of 1-8) that is how the plant tripped: the MPC answered a pressure of 2901 kPa by
opening the condenser, the reactor level fell to 60 %, its loop raised the D feed from
13 to 30-42 %, C in the reactor feed fell 19 -> 12 mol %, the E left unreacted gathered
(26 -> 39 mol %) and the pressure reached the interlock 2-3 h later. The grade plan
alone, whose pressure did not fall as fast, kept the D feed at 12-16 % and held.
The same sequence with this guard (``ssmpc``, IDV(13) at mode 2, seed 4, 6.75-7.5 h,
eighth-hour means): the pressure reached 2880-2891 kPa, the core opened the condenser
(XMV 11) from 13 to 21 %, the separator cooled from 90 to 80 degC, and the reactor level
fell from 64 to 51 % in 0.6 h while the pressure came down to 2853 kPa and the reactor
temperature rose by 0.7 degC; the D feed rose from 10 to 28 % with the E valve at 100 %,
and the level rose again as the condenser closed.

The guard: at a steady grade (:attr:`LevelSagSettings.after_h` after the last grade
change), while the reactor pressure (XMEAS 7) is at or above
:attr:`LevelSagSettings.pressure_kpa` and the E valve the ratio writes is at or above
:attr:`LevelSagSettings.e_valve_pct`, the level's set point follows the measured level
down (at most :attr:`LevelSagSettings.drop_max_pct` below the plan's), so the loop does
not chase the level with D; otherwise it returns to the plan's at
:attr:`LevelSagSettings.return_per_h`, and while the E valve is still at or above
:attr:`LevelSagSettings.e_valve_pct` it stands at most
:attr:`LevelSagSettings.return_lead_pct` above the measured level on the way: the return
waits for the level rather than outrunning it. It never raises the set point above the
plan's.

The return's wait. Under the drift the pressure often leaves 2870 kPa while the level
is still falling (seed 5: the pressure 2871 -> 2858 kPa at 8-8.5 h, the level 64 -> 59
%); a set point returning at 2 %/h from there stood up to 3.7 % above the level, its
loop raised the D feed to 33.5 % with the E valve at 100 %, and G's hour mean reached
17.3 mol % (mode 2: 11.7). With the set point at most 1 % above the level, 27.0 % and
14.3 mol % (``tests/test_te_level_sag.py``). The kinetics' drift at mode 2
(``docs/campaigns/te_kinetics_drift.json``, seeds 1-40, 48 h; G std mol % / mean $/h /
peak kPa; paired by seed):

=============  ========================  ========================
strategy       the return at 2 %/h       waiting for the level
=============  ========================  ========================
``ssmpc``      0.679 / 213.4 / 2896      0.603 / 211.8 / 2896
``fixed``      0.699 / 213.1 / 2909      0.613 / 211.7 / 2909
=============  ========================  ========================

``ssmpc``: G steadier on 29 of the 40 seeds (by more than 0.005 mol %), less steady on
one (-0.076 mol % on the mean, bootstrap 95 % -0.120 to -0.040); the seeds that were
worst, 4 and 5, 1.36 -> 1.02 and 1.48 -> 0.84. ``fixed``: steadier on 32, on none less
(-0.086). No trip. In
the acceptance matrix (``ssmpc``, 222 runs) only IDV(13) at mode 2 moved (0.592 ->
0.574 mol %, 211.1 -> 204.2 $/h) and IDV(8) at mode 2 by 0.01 $/h; every verdict as
before. Where the E valve has room (modes 0, 1 and 3) the guard does not act, and the
return's wait with it. With the set point's floor 15 % below the plan's instead of 10
(``ssmpc``), the drift at mode 2 gave 0.580 mol % and seeds 4 and 5 0.63 and 0.65, the
matrix only IDV(13) at mode 2 (0.553 mol %, 202.7 $/h); but the level then went down to
48 % for up to 0.6 h (seeds 4, 5, 32; with the floor at 10 % never under 50.8 %): not
taken, the floor keeps its margin.

Measured (``ssmpc``, noise on, seeds 1-8, 48 h, onset 2 h; G std mol % / mean $/h / peak
kPa):

==================  =======================  =======================
case                without                  with the guard
==================  =======================  =======================
IDV(13) at mode 2   trips on seeds 4, 5, 7   0.967 / 232.9 / 2899
IDV(8) at mode 2    0.575 / 201.4 / 2879     0.567 / 199.5 / 2883
IDV(1) at mode 2    0.502 / 192.9 / 2877     0.511 / 187.2 / 2875
IDV(13) at mode 1   0.824 / 140.0 / 2892     the same (E valve 53 %)
==================  =======================  =======================

On seeds 9-16 ``ssmpc`` tripped on seed 15 without the guard and on none with it.
``fixed``, under the same guard, trips on 4 of the 16 seeds with it or without (2, 4, 5
and 9 against 4, 5, 7 and 15). In the acceptance matrix (seeds 1-3) ``fixed`` now trips
IDV(13) at mode 2 on seed 2 (``docs/te_matrix.md``).

At 2880 or 2890 kPa the guard came too late (the same three trips); without the E
valve's condition, at 2870 kPa from a day after a change, the return to mode 0 after
3 -> 0 (the pressure at the MPC's limit for a day, the E valve near 50 %) left its grade
on seed 2 until 26.7 h; acting through the grade change as well, 2 -> 3 took 18.7 h
instead of 11.8. With the condition at 95 % (the valve moves 89-100 % with the ratio's
noisy D measurement) seed 5 still tripped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.units.te.settings_check import check_finite_fields, check_range

__all__ = ["LevelSagSettings", "LevelSag"]


@dataclass(frozen=True)
class LevelSagSettings:
    """Settings of :class:`LevelSag` (see the module docstring).

    Parameters
    ----------
    pressure_kpa : float
        Reactor pressure (XMEAS 7) from which the set point follows the level, kPa.
    e_valve_pct : float
        E valve (XMV 2, %) from which the guard acts.
    drop_max_pct : float
        Most the set point goes below the plan's, % of level (>= 0).
    return_per_h : float
        Rate the set point returns to the plan's at, %/h (> 0).
    after_h : float
        Hours after a grade change from which the guard acts (>= 0).
    return_lead_pct : float
        Most the set point stands above the measured level while it returns with the E
        valve at or above ``e_valve_pct``, % of level (>= 0).
    """

    pressure_kpa: float = 2870.0
    e_valve_pct: float = 80.0
    drop_max_pct: float = 10.0
    return_per_h: float = 2.0
    after_h: float = 24.0
    return_lead_pct: float = 1.0

    def __post_init__(self) -> None:
        label = "level sag "
        check_finite_fields(self, label)
        check_range(self, "pressure_kpa", "(2000, 3000)", "kPa", label)
        check_range(self, "e_valve_pct", "[0, 100]", "%", label)
        check_range(self, "drop_max_pct", "[0, 50]", "%", label)
        check_range(self, "return_per_h", "> 0", label=label)
        check_range(self, "after_h", ">= 0", "h", label)
        check_range(self, "return_lead_pct", "[0, 50]", "%", label)


class LevelSag:
    """The reactor level set point's offset from the plan's (<= 0), sample by sample.

    Parameters
    ----------
    settings : LevelSagSettings, optional
    sample_h : float
        The supervisory sample, h.
    """

    def __init__(self, settings: LevelSagSettings | None = None,
                 sample_h: float = 0.01) -> None:
        self.settings = settings or LevelSagSettings()
        self.sample_h = float(sample_h)
        #: offset of the level's set point from the plan's, % (<= 0)
        self.offset = 0.0

    @property
    def active(self) -> bool:
        return self.offset < 0.0

    def update(self, pressure: float, level: float, setpoint: float, e_valve: float,
               since_h: float) -> float:
        """Advance one sample and return the level's set point (%).

        Parameters
        ----------
        pressure : float
            Reactor pressure, XMEAS 7, kPa.
        level : float
            Reactor level, XMEAS 8, %.
        setpoint : float
            The level's set point without the guard (the plan's), %.
        e_valve : float
            The E valve written this sample, XMV 2, %.
        since_h : float
            Hours since the last grade change.
        """
        s = self.settings
        acts = (math.isfinite(pressure) and math.isfinite(level) and math.isfinite(e_valve)
                and pressure >= s.pressure_kpa and e_valve >= s.e_valve_pct
                and since_h >= s.after_h)
        if acts:
            self.offset = min(self.offset, max(level - setpoint, -s.drop_max_pct))
        else:
            self.offset = self.offset + s.return_per_h * self.sample_h
            if (self.offset < 0.0 and math.isfinite(level) and math.isfinite(e_valve)
                    and e_valve >= s.e_valve_pct):
                # the return waits for the level: not a D feed the E feed cannot follow
                self.offset = min(self.offset,
                                  max(level + s.return_lead_pct - setpoint, -s.drop_max_pct))
            if self.offset > -1e-9:  # back (the steps' sum is not exact in floating point)
                self.offset = 0.0
        return setpoint + self.offset

    def alarms(self) -> list[str]:
        """The guard's alarm while the set point stands below the plan's."""
        if not self.active:
            return []
        return [f"reactor level set point {self.offset:+.1f} % below the plan's: the level "
                "is not chased with D while the pressure is high and the E feed at its range"]

    def checkpoint(self) -> dict[str, Any]:
        return {"offset": self.offset}

    def restore(self, state: dict[str, Any] | None) -> None:
        v = (state if isinstance(state, dict) else {}).get("offset", 0.0)
        self.offset = min(float(v), 0.0) if isinstance(v, int | float) and math.isfinite(v) \
            else 0.0
