"""Floating pressure: P_r* follows a rising reactor pressure while C is in excess in the
recycle gas (controller.units.te.floating_pressure)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import make_te_controller, plant_seed_for, run_te
from controller.units.te.floating_pressure import (
    FloatingPressureSettings,
    floating_pressure_floor,
)
from controller.units.te.grades import TransitionPlan, grade
from controller.units.te.reactant_trim import ReactantTrimSettings

C_PLAN, STEADY = 14.6, 30.0


@pytest.mark.parametrize("kw, field", [({"margin_kpa": -1.0}, "margin_kpa"),
                                       ({"margin_kpa": 150.0}, "margin_kpa"),
                                       ({"ceiling_kpa": 3000.0}, "ceiling_kpa"),
                                       ({"ceiling_kpa": math.inf}, "ceiling_kpa"),
                                       ({"release_per_kpa": 0.0}, "release_per_kpa"),
                                       ({"c_excess_mol": math.nan}, "c_excess_mol"),
                                       ({"after_h": -1.0}, "after_h"),
                                       ({"after_h": True}, "after_h")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        FloatingPressureSettings(**kw)


def test_the_floor_stands_the_margin_under_the_pressure_up_to_the_ceiling():
    s = FloatingPressureSettings()  # 5 kPa, 2850 kPa, C 1 mol % over the plan's, a day
    assert floating_pressure_floor(s, 2830.0, C_PLAN + 2.0, C_PLAN, STEADY, False) == 2825.0
    assert floating_pressure_floor(s, 2854.0, C_PLAN + 2.0, C_PLAN, STEADY, False) == 2849.0
    assert floating_pressure_floor(s, 2855.0, C_PLAN + 2.0, C_PLAN, STEADY, False) == 2850.0
    # exactly 1 mol % over the plan's is enough
    assert floating_pressure_floor(s, 2830.0, C_PLAN + 1.0, C_PLAN, STEADY, False) == 2825.0
    other = FloatingPressureSettings(margin_kpa=0.0, ceiling_kpa=2870.0, c_excess_mol=0.0)
    assert floating_pressure_floor(other, 2860.0, C_PLAN, C_PLAN, STEADY, False) == 2860.0


def test_past_the_ceiling_the_floor_gives_way_to_the_purge():
    # 2 kPa of floor per kPa of pressure: the grade's 2800 kPa again at 2880 kPa, so near
    # the MPC's soft limit (2875 kPa) the purge loop meets the whole excess
    s = FloatingPressureSettings()
    floors = [floating_pressure_floor(s, p, C_PLAN + 5.0, C_PLAN, STEADY, False)
              for p in (2855.0, 2860.0, 2870.0, 2880.0, 2900.0)]
    assert floors == pytest.approx([2850.0, 2840.0, 2820.0, 2800.0, 2760.0])


@pytest.mark.parametrize("c, since, held_down, pressure", [
    (C_PLAN + 0.9, STEADY, False, 2830.0),   # C not enough in excess
    (C_PLAN - 5.0, STEADY, False, 2830.0),   # C short: what the kinetics' drift does
    (C_PLAN + 3.0, 23.9, False, 2830.0),     # within a day of a grade change
    (C_PLAN + 3.0, STEADY, True, 2830.0),    # the A feed lost / production lowered
    (math.nan, STEADY, False, 2830.0),       # no C analysis
    (C_PLAN + 3.0, STEADY, False, math.nan),  # no pressure
])
def test_outside_its_conditions_the_guard_does_not_act(c, since, held_down, pressure):
    s = FloatingPressureSettings()
    assert floating_pressure_floor(s, pressure, c, C_PLAN, since, held_down) is None
    assert floating_pressure_floor(s, 2830.0, C_PLAN + 3.0, math.nan, STEADY, False) is None


def test_a_high_limit_on_the_pressure_lowers_the_ceiling():
    s = FloatingPressureSettings()
    args = (C_PLAN + 2.0, C_PLAN, STEADY, False)
    assert floating_pressure_floor(s, 2820.0, *args, limit_kpa=2815.0) == 2815.0
    assert floating_pressure_floor(s, 2860.0, *args, limit_kpa=2895.0) == 2840.0
    assert floating_pressure_floor(s, 2860.0, *args, limit_kpa=math.nan) == 2840.0
    # past a lowered ceiling the floor gives way from it
    assert floating_pressure_floor(s, 2830.0, *args, limit_kpa=2815.0) == 2795.0


def _sample(pressure: float, c_purge: float) -> np.ndarray:
    x = grade("mode2").xmeas.copy()
    x[6], x[30] = pressure, c_purge
    return x


def test_the_controller_raises_the_plans_pressure_set_point_and_reports_it():
    # the grade plan alone writes the plan's P_r* (2800 kPa at mode 2)
    ctl, _ = make_te_controller("plan", TransitionPlan("mode2"))
    plan_c = float(grade("mode2").xmeas[30])
    dec = ctl.step(0, 1.0, _sample(2830.0, plan_c))
    assert dec.extra["setpoints"][4] == pytest.approx(2800.0)
    assert dec.extra["pressure_floats"] is False
    dec = ctl.step(1, 1.01, _sample(2830.0, plan_c + 2.0))
    assert dec.extra["setpoints"][4] == pytest.approx(2825.0)
    assert dec.extra["pressure_floats"] is True
    # a pressure under the plan's set point: nothing to follow
    dec = ctl.step(2, 1.02, _sample(2790.0, plan_c + 2.0))
    assert dec.extra["setpoints"][4] == pytest.approx(2800.0)
    assert dec.extra["pressure_floats"] is False


def _float_alarms(dec) -> list[str]:
    return [a for a in dec.alarms if "set point floats" in a]


def test_the_float_raises_an_alarm_that_stands_through_short_pauses():
    # the operator sees the guard act (the alarm reaches the service's status, its event
    # log and telemetry); it stands ALARM_HOLD_H after the last raise, so a guard
    # acting sample on, sample off does not raise and clear the alarm every minute
    ctl, _ = make_te_controller("plan", TransitionPlan("mode2"))
    plan_c = float(grade("mode2").xmeas[30])
    dec = ctl.step(0, 1.0, _sample(2830.0, plan_c))
    assert _float_alarms(dec) == []
    dec = ctl.step(1, 1.01, _sample(2830.0, plan_c + 2.0))
    (text,) = _float_alarms(dec)
    assert "2825 kPa" in text and "2800" in text and f"{plan_c + 2.0:.1f} mol %" in text
    # the guard pauses (the pressure back under the plan's P_r*): the alarm stands a while
    t, k, seen = 1.01, 1, []
    while t < 1.01 + 0.75:
        k, t = k + 1, t + 0.01
        dec = ctl.step(k, t, _sample(2790.0, plan_c + 2.0))
        assert dec.extra["pressure_floats"] is False
        seen.append((t - 1.01, bool(_float_alarms(dec))))
    standing = [dt for dt, on in seen if on]
    cleared = [dt for dt, on in seen if not on]
    assert standing and cleared and 0.45 < max(standing) < min(cleared) <= 0.5 + 1e-6
    assert all(not on for dt, on in seen if dt >= min(cleared))  # and stays cleared


def test_the_floats_alarm_survives_a_restart():
    plan_c = float(grade("mode2").xmeas[30])
    ctl, _ = make_te_controller("plan", TransitionPlan("mode2"))
    ctl.step(0, 1.0, _sample(2830.0, plan_c + 2.0))
    state = ctl.checkpoint()
    again, _ = make_te_controller("plan", TransitionPlan("mode2"))
    again.restore(state)
    assert _float_alarms(again.step(1, 1.01, _sample(2790.0, plan_c + 2.0)))
    # a checkpoint from before the alarm, or a damaged one: no alarm, no error
    for bad in (None, {"left_h": math.nan, "text": "x"}, {"left_h": 0.3, "text": 7},
                {"left_h": True, "text": "x"}, "garbage"):
        other, _ = make_te_controller("plan", TransitionPlan("mode2"))
        other.restore({**state, "float_alarm": bad} if bad is not None else
                      {k: v for k, v in state.items() if k != "float_alarm"})
        assert _float_alarms(other.step(1, 1.01, _sample(2790.0, plan_c + 2.0))) == []


def test_an_operators_high_limit_on_the_pressure_caps_the_float():
    # the operator's XMEAS 7 limit reaches the MPC strategies through the steady-state
    # targets (controller/units/te/operator.py); the float must not carry P_r* past it
    plan_c = float(grade("mode2").xmeas[30])
    free, _ = make_te_controller("ssmpc", TransitionPlan("mode2"))
    capped, _ = make_te_controller("ssmpc", TransitionPlan("mode2"))
    capped.targets.set_operator_limits(None, [2820.0, np.inf, np.inf, np.inf, np.inf])
    sp = {}
    for name, ctl in (("free", free), ("capped", capped)):
        for k in range(3):
            dec = ctl.step(k, 1.0 + 0.01 * k, _sample(2840.0, plan_c + 2.0))
            ctl.finish_sample()
        sp[name] = float(dec.extra["setpoints"][4])
    assert sp["free"] == pytest.approx(2835.0)
    assert sp["capped"] <= 2820.0 + 1e-9


def test_idv8_at_mode_2_keeps_the_purge_closer_to_its_grade():
    # seed 1: the A loop cuts the A feed, C gathers and the pressure rises to 2830-2847
    # kPa 6-10 h in; held at 2800 kPa the purge opened to 0.61 kscmh (the grade's 0.36).
    # The reactant trim's cut, which lowers the A+C feed on that C, is off: with it the
    # purge's late mean is 0.44 against 0.49 kscmh held at 2800 kPa (measured). So is the
    # steady grade's pressure lead (controller/units/te/pressure_gain.py): it
    # holds the pressure nearer P_r* by itself, and the late purge is 0.46 against 0.50
    # kscmh held at 2800 kPa (measured). So is the reactor-feed balance: it acts on the
    # same A+C feed (with it the late purge stays under 0.48 kscmh held at 2800 kPa)
    runs = {}
    for name, fp in (("on", None), ("off", FloatingPressureSettings(c_excess_mol=1e3))):
        runs[name] = run_te("ssmpc", TransitionPlan("mode2"), 13.0, noise=True, seed=1,
                            plant_seed=plant_seed_for(1), idv={8: 2.0}, floating_pressure=fp,
                            reactants=ReactantTrimSettings(excess_max=0.0),
                            pressure_gain=False, feed_balance=False)
    on, off = runs["on"], runs["off"]
    assert on.shutdown is None and off.shutdown is None
    late = on.t >= 7.0
    assert off.xmeas[late, 9].max() > 0.55
    assert on.xmeas[late, 9].mean() < off.xmeas[late, 9].mean() - 0.05
    assert on.cost[late].mean() < off.cost[late].mean() - 15.0
    assert 2840.0 < on.setpoints[:, 4].max() <= 2850.0 + 1e-9  # it acted, to its ceiling
    # the run's alarm log has the float's alarm when it is raised, not every sample it
    # stands: the guard held P_r* above the plan's for many samples
    floats = [a for a in on.alarms if "set point floats" in a]
    assert 1 <= len(floats) <= 3 < 50 < int(np.sum(on.setpoints[:, 4] > 2800.5))
    assert not any("set point floats" in a for a in off.alarms)
    assert on.xmeas[:, 6].max() < 2895.0


def test_idv13_at_mode_2_on_seed_5_is_left_to_the_purge():
    # the kinetics' drift gathers E, not C: the guard stays out and the purge opens at
    # once (the guard without its condition on C tripped this run at 11.8 h)
    r = run_te("ssmpc", TransitionPlan("mode2"), 13.0, noise=True, seed=5,
               plant_seed=plant_seed_for(5), idv={13: 2.0})
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2920.0
