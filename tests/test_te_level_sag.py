"""The reactor level's set point following a falling level while the pressure is high and
the E feed at its range (controller.units.te.level_sag)."""

from __future__ import annotations

import json
import math

import pytest
from test_te_loop_tuning import steady_level_as_table_7_10

from controller.units.te.control import plant_seed_for, run_te
from controller.units.te.grades import TransitionPlan
from controller.units.te.level_sag import LevelSag, LevelSagSettings
from controller.units.te.loop_tuning import LoopTuningSettings

HIGH, E_AT_RANGE, STEADY = 2880.0, 97.0, 30.0


@pytest.mark.parametrize("kw, field", [({"pressure_kpa": 3000.0}, "pressure_kpa"),
                                       ({"e_valve_pct": 101.0}, "e_valve_pct"),
                                       ({"drop_max_pct": -1.0}, "drop_max_pct"),
                                       ({"return_per_h": 0.0}, "return_per_h"),
                                       ({"after_h": -1.0}, "after_h"),
                                       ({"after_h": math.nan}, "after_h"),
                                       ({"return_lead_pct": -0.5}, "return_lead_pct"),
                                       ({"pressure_kpa": True}, "pressure_kpa")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        LevelSagSettings(**kw)


def test_the_set_point_follows_the_level_down_only_while_the_guard_holds():
    sag = LevelSag(LevelSagSettings(), sample_h=0.01)
    # pressure high, E valve at its range, a steady grade: the set point goes to the level
    assert sag.update(HIGH, 60.0, 65.0, E_AT_RANGE, STEADY) == pytest.approx(60.0)
    assert sag.alarms() and sag.active
    # it follows further down, at most 10 % below the plan's, and never back up meanwhile
    assert sag.update(HIGH, 58.0, 65.0, E_AT_RANGE, STEADY) == pytest.approx(58.0)
    assert sag.update(HIGH, 40.0, 65.0, E_AT_RANGE, STEADY) == pytest.approx(55.0)
    assert sag.update(HIGH, 64.0, 65.0, E_AT_RANGE, STEADY) == pytest.approx(55.0)
    # the pressure back under 2870 kPa: the set point returns at 2 %/h
    for _ in range(100):
        sp = sag.update(2800.0, 64.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == pytest.approx(57.0)
    for _ in range(400):
        sp = sag.update(2800.0, 64.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == 65.0 and not sag.active and sag.alarms() == []


def test_the_return_waits_for_the_level_while_the_e_valve_is_at_its_range():
    sag = LevelSag(LevelSagSettings(), sample_h=0.01)
    sag.update(HIGH, 50.0, 65.0, E_AT_RANGE, STEADY)  # down to the floor, 55 %
    # the pressure back under 2870 kPa, the level still at 53 %: the set point stands 1 %
    # above it rather than returning at 2 %/h (a D feed the E feed cannot follow)
    for _ in range(100):
        sp = sag.update(2850.0, 53.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == pytest.approx(55.0)  # at the floor: the level + 1 % is under it
    for _ in range(100):
        sp = sag.update(2850.0, 58.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == pytest.approx(57.0)  # 2 %/h for 1 h, still under the level + 1 %
    for _ in range(100):
        sp = sag.update(2850.0, 58.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == pytest.approx(59.0)  # the level + 1 %
    # the E valve with room: the ratio follows the D feed, the return is the plan's
    sp = sag.update(2850.0, 58.0, 65.0, 60.0, STEADY)
    assert sp == pytest.approx(59.02)
    # the level recovered: back to the plan's, never above it
    for _ in range(600):
        sp = sag.update(2850.0, 66.0, 65.0, E_AT_RANGE, STEADY)
    assert sp == 65.0 and not sag.active


@pytest.mark.parametrize("pressure, level, e_valve, since", [
    (2860.0, 60.0, E_AT_RANGE, STEADY),   # the pressure under 2870 kPa
    (HIGH, 60.0, 53.0, STEADY),           # the E valve has room (mode 0, 1)
    (HIGH, 60.0, E_AT_RANGE, 12.0),       # within a day of a grade change
    (HIGH, 70.0, E_AT_RANGE, STEADY),     # a level above its set point: never raised
    (math.nan, 60.0, E_AT_RANGE, STEADY),  # no measurement
    (HIGH, math.nan, E_AT_RANGE, STEADY),
])
def test_outside_the_guard_the_set_point_is_the_plans(pressure, level, e_valve, since):
    sag = LevelSag()
    assert sag.update(pressure, level, 65.0, e_valve, since) == 65.0
    assert not sag.active


def test_the_offset_survives_a_restart():
    sag = LevelSag()
    sag.update(HIGH, 61.0, 65.0, E_AT_RANGE, STEADY)
    again = LevelSag()
    again.restore(json.loads(json.dumps(sag.checkpoint())))
    assert again.offset == pytest.approx(-4.0)
    again.restore({"offset": 3.0})  # never above the plan's
    assert again.offset == 0.0
    again.restore(None)
    assert again.offset == 0.0
    for bad in ("not a checkpoint", [-4.0]):  # not a mapping: starts as new
        again.restore(json.loads(json.dumps(sag.checkpoint())))
        again.restore(bad)
        assert again.offset == 0.0


def test_idv13_at_mode_2_on_seed_4_no_longer_trips():
    # the kinetics' drift at mode 2 (noise on, seed 4): the level's loop raised the D feed
    # from 13 to 30-42 % after the MPC's answer to a pressure of 2901 kPa, C ran short, the
    # E left unreacted gathered and the plant tripped on reactor pressure at 9.7 h
    r = run_te("ssmpc", TransitionPlan("mode2"), 12.0, noise=True, seed=4,
               plant_seed=plant_seed_for(4), idv={13: 2.0})
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2950.0
    assert r.setpoints[:, 1].min() < 65.0 - 1.0  # the guard acted


def _g_hour_peak(r) -> float:
    """The highest 1 h mean of G in product (XMEAS 40), mol %."""
    return max(float(r.xmeas[(r.t >= h) & (r.t < h + 1.0), 39].mean())
               for h in range(2, int(r.t[-1])))


def test_under_idv13_at_mode_2_the_return_does_not_chase_the_level_with_d(monkeypatch):
    # the kinetics' drift at mode 2, seed 5: at 8-8.5 h the pressure leaves 2870 kPa
    # while the level still falls; a set point returning at 2 %/h stood up to 3.7 %
    # above it, the level's loop raised the D feed to 33.5 % with the E valve at 100 %
    # and G's hour mean reached 17.3 mol % (mode 2: 11.7); waiting for the level, 27.0 %
    # and 14.3 (seeds 1-40, 48 h: G's standard deviation 0.679 -> 0.603 mol %,
    # docs/te_kinetics_drift.md). With the plant side's steady tuning set (loop_tuning):
    # G's hour peak 15.55 waiting against 17.77 chasing, the D feed 29.4 against 34.2 %.
    # Run on that set, the level's loop at Table 7.10's gain and no feed balance (the
    # case as it was): on the E-limited one the MPC selects at mode 2 by default the
    # level's loop barely moves the D feed (14.42 against 14.74, 18.2 against 18.4 %)
    steady_level_as_table_7_10(monkeypatch)
    kw = dict(noise=True, seed=5, plant_seed=plant_seed_for(5), idv={13: 2.0},
              feed_balance=False, loop_tuning=LoopTuningSettings(e_valve_pct=100.0))
    waits = run_te("ssmpc", TransitionPlan("mode2"), 14.0, **kw)
    chases = run_te("ssmpc", TransitionPlan("mode2"), 14.0,
                    level_sag=LevelSagSettings(return_lead_pct=50.0), **kw)
    assert waits.shutdown is None and chases.shutdown is None
    assert _g_hour_peak(waits) < 16.0 < 17.0 < _g_hour_peak(chases)
    assert waits.xmv[:, 0].max() < chases.xmv[:, 0].max() - 4.0
