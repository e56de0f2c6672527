"""The TE transition guards (E-feed limit, plan hold, the recycle valve's closing time
constant) and the reduced no-trip matrix: cases of the acceptance matrix that tripped
before them, each run only as long as it took to trip then."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from controller.units.te.control import (
    GUARDS_MPC,
    TEMPCOptions,
    TransitionGuards,
    make_te_controller,
    plant_seed_for,
    run_te,
)
from controller.units.te.grades import Leg, TransitionPlan, grade
from controller.units.te.level_sag import LevelSagSettings
from controller.units.te.reactant_trim import ReactantTrimSettings

INTERLOCK_KPA = 3000.0


@pytest.mark.parametrize("kw, field", [({"e_feed_margin": -1.0}, "e_feed_margin"),
                                       ({"e_feed_margin_held": 101.0}, "e_feed_margin_held"),
                                       ({"e_feed_margin": float("nan")}, "e_feed_margin"),
                                       ({"hold_full_kpa": 3100.0}, "hold_full_kpa"),
                                       ({"purge_track_kpa": -1.0}, "purge_track_kpa"),
                                       ({"purge_track_lift_kpa": float("nan")},
                                        "purge_track_lift_kpa"),
                                       ({"purge_track_settle_kpa": -5.0},
                                        "purge_track_settle_kpa"),
                                       ({"purge_track_settle_from_h": 24.0},
                                        "purge_track_settle_from_h"),
                                       ({"purge_track_settle_to_h": float("inf")},
                                        "purge_track_settle_to_h"),
                                       ({"a_loop_hold_h": -1.0}, "a_loop_hold_h"),
                                       ({"purge_floor_fraction": 1.0},
                                        "purge_floor_fraction"),
                                       ({"purge_floor_fraction": float("nan")},
                                        "purge_floor_fraction"),
                                       ({"purge_floor_after_h": -1.0},
                                        "purge_floor_after_h"),
                                       ({"a_loop_hold_h": float("inf")}, "a_loop_hold_h"),
                                       ({"a_loop_hold_falling_h": -1.0},
                                        "a_loop_hold_falling_h"),
                                       ({"hold_start_kpa": 2950.0, "hold_full_kpa": 2900.0},
                                        "hold_start_kpa/hold_full_kpa"),
                                       ({"a_rise_hold_kpa": 3000.0}, "a_rise_hold_kpa"),
                                       ({"a_rise_hold_kpa": float("nan")}, "a_rise_hold_kpa"),
                                       ({"a_rise_hold_c_short_mol": -0.5},
                                        "a_rise_hold_c_short_mol"),
                                       ({"a_rise_hold_c_short_mol": True},
                                        "a_rise_hold_c_short_mol"),
                                       ({"a_loop_cut_c_fraction": 0.0},
                                        "a_loop_cut_c_fraction"),
                                       ({"pressure_hold_c_fraction": 1.5},
                                        "pressure_hold_c_fraction"),
                                       ({"pressure_hold_c_fraction": float("nan")},
                                        "pressure_hold_c_fraction"),
                                       ({"pressure_hold_h": -1.0}, "pressure_hold_h"),
                                       ({"a_loop_raise_c_excess_mol": 0.0},
                                        "a_loop_raise_c_excess_mol"),
                                       ({"e_cap_c_fraction": 1.5}, "e_cap_c_fraction"),
                                       ({"e_cap_c_fraction": float("nan")},
                                        "e_cap_c_fraction"),
                                       ({"plan_hold_a_lost": 1}, "plan_hold_a_lost"),
                                       ({"pressure_hold_a_lost": "yes"},
                                        "pressure_hold_a_lost")])
def test_bad_guards_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        TransitionGuards(**kw)


def test_hold_fraction_is_zero_below_the_start_one_at_the_full_hold_and_for_no_reading():
    g = TransitionGuards(hold_start_kpa=2880.0, hold_full_kpa=2930.0)
    assert g.hold_fraction(2700.0) == 0.0 and g.hold_fraction(2880.0) == 0.0
    assert 0.0 < g.hold_fraction(2900.0) < g.hold_fraction(2920.0) < 1.0
    assert g.hold_fraction(2930.0) == 1.0 and g.hold_fraction(2990.0) == 1.0
    assert g.hold_fraction(float("nan")) == 0.0


def _xmeas(mode: int, pressure: float) -> np.ndarray:
    x = np.array(grade(mode).xmeas, dtype=float)
    x[6] = pressure
    return x


def _tr_setpoint(ctl, k, t, x) -> float:
    dec = ctl.step(k, t, x, None)
    ctl.finish_sample()
    return float(dec.extra["setpoints"][0]), dec


def test_the_plan_waits_while_the_pressure_is_at_the_full_hold_and_goes_on_after():
    plan = TransitionPlan("mode0", (Leg(0.0, "mode2"),))   # T_r 120.4 -> 124.2 degC
    held, _ = make_te_controller("plan", plan)
    free, _ = make_te_controller("plan", plan)
    dt = held.sample_h
    n = 100                                               # one hour
    high, low = _xmeas(0, 2950.0), _xmeas(0, 2705.0)
    for k in range(n // 2):                               # half an hour under way
        _tr_setpoint(held, k, k * dt, low)
    first, _ = _tr_setpoint(held, n // 2, n // 2 * dt, high)
    for k in range(n // 2 + 1, n // 2 + n):
        tr, dec = _tr_setpoint(held, k, k * dt, high)
    assert any("grade plan held" in a for a in dec.alarms)
    assert tr == first                                    # the plan did not move
    assert held.plan_lag_h == pytest.approx(1.0)
    # released: it goes on from where it stopped, one hour behind the free plan
    for k in range(n // 2 + n):
        free_tr, _ = _tr_setpoint(free, k, k * dt, low)
    for k in range(n // 2 + n, n // 2 + 2 * n):
        tr, dec = _tr_setpoint(held, k, k * dt, low)
    assert not any("grade plan held" in a for a in dec.alarms)
    assert tr == pytest.approx(free_tr, abs=1e-9) and tr > first + 0.5
    # the lag is kept by a checkpoint and dropped by a new plan
    state = json.loads(json.dumps(held.checkpoint()))
    again, _ = make_te_controller("plan", plan)
    again.restore(state)
    assert again.plan_lag_h == pytest.approx(1.0)
    again.retarget(TransitionPlan("mode2"))
    assert again.plan_lag_h == 0.0


def _a_trim(plan, start: int, t0: float, n: int = 10, a_error: float = -3.0,
            c_purge: float | None = None, **guards) -> float:
    """The A loop's trim after ``n`` samples from ``t0`` with A in the reactor feed
    (XMEAS 23) ``a_error`` mol % off the start grade's and, if given, C in the purge
    (XMEAS 31) at ``c_purge`` mol %."""
    ctl, _ = make_te_controller("fixed", plan, guards=TransitionGuards(**guards))
    x = _xmeas(start, 2705.0)
    x[22] += a_error
    if c_purge is not None:
        x[30] = c_purge
    for k in range(n):
        ctl.step(k, t0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
    return ctl.a_trim


def test_the_a_feed_loop_holds_its_trim_through_a_grade_change_only():
    # A in the reactor feed (XMEAS 23) 3 mol % under the plan's: the loop raises the A
    # feed's target, unless a grade change started less than a_loop_hold_h ago

    def trim(plan, hold_h):
        return _a_trim(plan, 0, 1.0, a_loop_hold_h=hold_h)

    change = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    assert trim(change, 0.0) > 0.0                         # the default: the loop acts
    assert trim(change, 4.0) == 0.0                        # within 4 h of the change
    assert trim(change, 0.05) > 0.0                        # past a short hold it acts
    assert trim(TransitionPlan("mode0"), 4.0) > 0.0        # a steady grade: it acts


@pytest.mark.parametrize("start, to, falls", [(1, 3, True), (2, 3, True), (0, 3, True),
                                              (2, 0, True), (3, 0, False), (0, 2, False),
                                              (3, 2, False)])
def test_a_leg_that_lowers_the_a_in_feed_holds_the_a_loop(start, to, falls):
    # XMEAS 23 by grade: mode 0 32.19, mode 1 32.21, mode 2 34.82, mode 3 29.46 mol %
    plan = TransitionPlan(f"mode{start}", (Leg(1.0, f"mode{to}"),))
    assert (_a_trim(plan, start, 1.0) == 0.0) is falls      # the default: 8 h
    assert _a_trim(plan, start, 9.5) != 0.0                  # past the hold it acts
    assert _a_trim(plan, start, 1.0, a_loop_hold_falling_h=0.0) != 0.0
    assert _a_trim(TransitionPlan(f"mode{start}"), start, 1.0) > 0.0  # no leg: it acts


def _a_trim_in_leg(a_error: float, c_purge: float, start: int = 1, to: int = 3,
                   **guards) -> float:
    """The A loop's trim 1 h into ``start`` -> ``to`` (a falling-A leg: its hold), after 10
    samples with A in the reactor feed ``a_error`` mol % off the start grade's and C in
    the purge ``c_purge`` mol %."""
    plan = TransitionPlan(f"mode{start}", (Leg(1.0, f"mode{to}"),))
    return _a_trim(plan, start, 2.0, a_error=a_error, c_purge=c_purge, **guards)


def test_with_c_short_the_held_a_loop_may_cut_the_a_feed_but_not_raise_it():
    # the plan's C in the purge is 12-13 mol % here; 3 mol % is short of half of it
    assert _a_trim_in_leg(3.0, 3.0) < 0.0                   # A in excess, C short: cut
    assert _a_trim_in_leg(3.0, 12.0) == 0.0                 # C as planned: held
    assert _a_trim_in_leg(-3.0, 3.0) == 0.0                 # A short: never raised here
    assert _a_trim_in_leg(3.0, 3.0, a_loop_cut_c_fraction=None) == 0.0  # the guard off
    assert _a_trim_in_leg(3.0, float("nan")) == 0.0         # no analyzer: held


def test_with_c_gathering_the_held_a_loop_may_raise_the_a_feed_but_not_cut_it():
    # 2 -> 0: the plan's C in the purge is about 17.5 mol % an hour in; 30 is 12.5 above
    assert _a_trim_in_leg(-3.0, 30.0, 2, 0) > 0.0            # A short, C gathering: raise
    assert _a_trim_in_leg(-3.0, 18.0, 2, 0) == 0.0           # C near the plan's: held
    assert _a_trim_in_leg(3.0, 30.0, 2, 0) == 0.0            # A in excess: never cut here
    assert _a_trim_in_leg(-3.0, 30.0, 2, 0, a_loop_raise_c_excess_mol=None) == 0.0


def test_idv1_through_a_leg_that_lowers_the_a_does_not_trip():
    # IDV(1) (stream 4's A/C ratio down) from 0.5 h, 2 -> 0 at 1 h: with the A loop held
    # through the leg A fell to 13 mol % in the reactor feed, C gathered and the plant
    # tripped at 7.5 h (seed 7). Seed 1 tripped at 7.2 h with the steady-grade A loop at
    # 4 %/mol % before the leg; at 8 %/mol % it peaks at 2907 kPa. The loop may raise A
    # while C gathers (seeds 1-8: peaks 2879-2882 kPa, A at least 25 mol %)
    plan = TransitionPlan("mode2", (Leg(1.0, "mode0"),))
    kw = dict(noise=True, seed=7, plant_seed=plant_seed_for(7), idv={1: 0.5})
    off = TransitionGuards(**{**GUARDS_MPC.__dict__, "a_loop_raise_c_excess_mol": None})
    assert run_te("ssmpc", plan, 8.0, guards=off, **kw).shutdown is not None
    r = run_te("ssmpc", plan, 8.0, **kw)
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 22].min() > 20.0  # A in the reactor feed kept


def _pr_setpoints(c_purge: float, t0: float = 2.0, **guards) -> tuple[list[float], list]:
    """P_r* applied over 20 samples from ``t0`` on 1 -> 3 (requested at 1 h) while the
    reactor pressure rises 2500 -> 2785 kPa, 15 kPa a sample, with C in the purge
    ``c_purge`` mol %; and the last sample's alarms."""
    ctl, _ = make_te_controller("plan", TransitionPlan("mode1", (Leg(1.0, "mode3"),)),
                                guards=TransitionGuards(**guards))
    out, dec = [], None
    for k in range(20):
        x = _xmeas(1, 2500.0 + 15.0 * k)
        x[30] = c_purge
        dec = ctl.step(k, t0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
        out.append(float(dec.extra["setpoints"][4]))
    return out, list(dec.alarms)


def test_with_c_short_in_a_grade_change_the_pressure_set_point_does_not_follow_a_rise():
    held, alarms = _pr_setpoints(3.0, pressure_hold_c_fraction=0.5)
    assert held == [held[0]] * 20 and held[0] == pytest.approx(2510.0)  # the first sample's
    assert any("reactor pressure set point held at 2510 kPa: C in the purge 3.0 mol %" in a
               for a in alarms)
    # C as planned, the guard off, or past pressure_hold_h: P_r* follows the pressure up
    for c, t0, kw in ((12.0, 2.0, {"pressure_hold_c_fraction": 0.5}), (3.0, 2.0, {}),
                      (3.0, 14.0, {"pressure_hold_c_fraction": 0.5})):
        free, alarms = _pr_setpoints(c, t0, **kw)
        assert free[-1] > free[0] + 250.0
        assert not any("set point held" in a for a in alarms)


def test_the_held_pressure_set_point_survives_a_restart():
    ctl, _ = make_te_controller("plan", TransitionPlan("mode1", (Leg(1.0, "mode3"),)),
                                guards=TransitionGuards(pressure_hold_c_fraction=0.5))
    x = _xmeas(1, 2500.0)
    x[30] = 3.0
    ctl.step(0, 2.0, x, None)
    ctl.finish_sample()
    state = json.loads(json.dumps(ctl.checkpoint()))
    again, _ = make_te_controller("plan", TransitionPlan("mode1", (Leg(1.0, "mode3"),)),
                                  guards=TransitionGuards(pressure_hold_c_fraction=0.5))
    again.restore(state)
    x[6] = 2700.0
    dec = again.step(1, 2.0 + again.sample_h, x, None)
    assert dec.extra["setpoints"][4] == pytest.approx(2510.0)
    state["pr_applied"] = "broken"  # a damaged value: no hold until the next sample
    again.restore(state)
    assert again.step(1, 2.0 + again.sample_h, x, None).extra["setpoints"][4] > 2600.0


def test_idv8_through_a_leg_into_mode_3_does_not_trip():
    # IDV(8) from 0.5 h, 1 -> 3 at 1 h (seed 2): C ran out in the purge, the pressure
    # rebounded from its dip with P_r* following it, the MPC's limit cut the A+C feed and
    # the plant tripped at 3.3 h. With the pressure set point held while C is short, the
    # A loop cutting through its hold and the reactant trim raising the A+C feed through
    # the change it runs on (of 75 runs over five legs, seeds 1-15: 21 trips -> 2)
    plan = TransitionPlan("mode1", (Leg(1.0, "mode3"),))
    kw = dict(noise=True, seed=2, plant_seed=plant_seed_for(2), idv={8: 0.5})
    before = run_te("ssmpc", plan, 6.0, guards=TransitionGuards(
        **{**GUARDS_MPC.__dict__, "pressure_hold_c_fraction": None,
           "a_loop_cut_c_fraction": None}),
        reactants=ReactantTrimSettings(raise_settle_h=24.0), **kw)
    assert before.shutdown is not None  # the case as it was
    r = run_te("ssmpc", plan, 6.0, **kw)
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2895.0
    assert any("reactor pressure set point held" in a for a in r.alarms)


def test_at_a_steady_grade_the_a_loop_corrects_faster_than_through_a_change():
    # the same A shortfall: a steady grade (no leg, or 12 h past one) against 1 h
    # after a change that does not hold the loop (0 -> 1: XMEAS 23 rises)
    change = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    through = _a_trim(change, 0, 2.0)
    assert through > 0.0
    assert _a_trim(TransitionPlan("mode0"), 0, 2.0) > 1.5 * through
    assert _a_trim(change, 0, 13.5) > 1.5 * through


def _a_trim_at(pressure: float, c_short: float, **guards) -> tuple[float, list[str]]:
    """The A loop's trim and the last sample's alarms after 10 samples at mode 2 with A
    in the reactor feed 3 mol % under the grade's, the reactor pressure ``pressure`` and
    C in the purge ``c_short`` mol % under the grade's."""
    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode2"),
                                guards=TransitionGuards(**guards))
    x = _xmeas(2, pressure)
    x[22] -= 3.0
    x[30] -= c_short
    for k in range(10):
        dec = ctl.step(k, 1.0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
    return ctl.a_trim, list(dec.alarms)


def test_a_high_pressure_with_c_short_holds_the_a_loops_rise():
    # A falls in the reactor feed with C (the kinetics' drift leaves E unreacted): the
    # A loop may not add A while the pressure is near the MPC's limit
    free, alarms = _a_trim_at(2800.0, 2.0)
    assert free > 0.0 and not any("trim held" in a for a in alarms)
    held, alarms = _a_trim_at(2870.0, 2.0)
    assert held == 0.0
    assert any("A feed's trim held from rising: reactor pressure 2870 kPa" in a
               for a in alarms)
    # C at the plan's: the A is short, not diluted, and the loop acts (IDV(1))
    assert _a_trim_at(2870.0, 0.0)[0] > 0.0
    assert _a_trim_at(2870.0, 2.0, a_rise_hold_kpa=None)[0] > 0.0  # the guard off


def test_the_a_loop_may_still_lower_its_trim_under_the_hold():
    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode2"))
    x = _xmeas(2, 2870.0)
    x[30] -= 2.0
    x[22] += 3.0  # A in excess: the loop lowers the A feed
    for k in range(10):
        ctl.step(k, 1.0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
    assert ctl.a_trim < 0.0


def test_a_kinetics_drift_at_mode_2_does_not_trip_on_the_a_loops_added_a():
    # IDV(13) at mode 2, seed 17: the A loop raised the A feed from 30 to 80 % over 3 h
    # while C in the purge fell 14.6 -> 2.2 mol %, and the plant tripped on reactor
    # pressure at 9.3 h; with the rise held it runs on (48 h on seeds 1-80: no trip).
    # The case as it was has the steady grade's pressure lead off
    # (controller/units/te/pressure_gain.py), the adaptive model's gain of then, 10
    # 1/h (TEMPCOptions.nls_gain), and the level's set point returning at its rate
    # without waiting for the level (controller/units/te/level_sag.py), and no tuning set
    # of the plant side's selected (controller/units/te/loop_tuning.py): with any of
    # them as now the free rise does not trip either (with the lead: peak 2903.5 kPa);
    # the product runs on
    runs = {}
    kw_run = dict(noise=True, seed=17, plant_seed=plant_seed_for(17), idv={13: 2.0})
    for name, kw in (("held", {}), ("free", {"a_rise_hold_kpa": None})):
        guards = TransitionGuards(**{**GUARDS_MPC.__dict__, **kw})
        runs[name] = run_te("ssmpc", TransitionPlan("mode2"), 10.0, guards=guards,
                            pressure_gain=False, mpc=TEMPCOptions(nls_gain=10.0),
                            level_sag=LevelSagSettings(return_lead_pct=50.0),
                            loop_tuning=False, **kw_run)
    assert runs["free"].shutdown is not None  # the case as it was
    product = run_te("ssmpc", TransitionPlan("mode2"), 10.0, **kw_run)
    assert product.shutdown is None, product.shutdown
    held = runs["held"]
    assert held.shutdown is None, held.shutdown
    assert held.xmeas[:, 6].max() < 2950.0
    assert held.xmv[:, 2].max() < runs["free"].xmv[:, 2].max() - 10.0  # less A added
    assert any("trim held from rising" in a for a in held.alarms)


def test_no_hold_without_a_leg_under_way():
    # a high pressure at a steady grade, or before the leg's time, holds nothing
    for plan in (TransitionPlan("mode0"), TransitionPlan("mode0", (Leg(5.0, "mode2"),))):
        ctl, _ = make_te_controller("plan", plan)
        for k in range(20):
            _, dec = _tr_setpoint(ctl, k, k * ctl.sample_h, _xmeas(0, 2960.0))
        assert ctl.plan_lag_h == 0.0
        assert not any("grade plan held" in a for a in dec.alarms)


def test_the_e_feed_stays_within_its_margin_above_the_plan_when_the_d_feed_runs_high():
    # mode 3 at its D share: a D feed measured twice the grade's would take the E feed
    # (the ratio) to about twice the plan's 8.4 % valve
    x = _xmeas(3, 2800.0)
    x[1] *= 2.0
    e_plan = float(grade(3).xmv[1])
    u = {}
    for margin in (0.0, 5.0, 100.0):
        ctl, _ = make_te_controller("plan", TransitionPlan("mode3"),
                                    guards=TransitionGuards(e_feed_margin=margin))
        u[margin] = float(ctl.step(0, 0.0, x, None).u[1])
    assert u[0.0] == pytest.approx(e_plan)
    assert u[5.0] == pytest.approx(e_plan + 5.0)
    assert u[100.0] > 1.8 * e_plan
    # at a pressure that holds the plan the default margin is the held one, 0 %
    held, _ = make_te_controller("plan", TransitionPlan("mode3"))
    x[6] = 2960.0
    assert float(held.step(0, 0.0, x, None).u[1]) == pytest.approx(e_plan)


@pytest.mark.parametrize("strategy", ["plan", "ssmpc"])
def test_the_pressure_set_point_tracks_a_pressure_below_it(strategy):
    # mode 2's P_r* is 2800 kPa: with the pressure at 2700 the purge loop gets 2710, at
    # 2795 the plan's own set point; the MPC goes on from the set point applied
    for p, want in ((2700.0, 2710.0), (2795.0, 2800.0), (2400.0, 2500.0)):
        ctl, _ = make_te_controller(strategy, TransitionPlan("mode2"))
        dec = ctl.step(0, 0.0, _xmeas(2, p), None)
        assert dec.extra["setpoints"][4] == pytest.approx(want, abs=0.5)
        if strategy == "ssmpc":
            assert ctl.core.u_last[2] == pytest.approx(dec.extra["setpoints"][4])
    off, _ = make_te_controller("plan", TransitionPlan("mode2"),
                                guards=TransitionGuards(purge_track_kpa=1000.0))
    assert off.step(0, 0.0, _xmeas(2, 2700.0), None).extra["setpoints"][4] == 2800.0


def test_the_tracking_margin_widens_while_the_grade_settles():
    # MPC strategies: 20 kPa from 8 h to 24 h after a grade change, 10 kPa otherwise;
    # the baselines keep 10 kPa throughout
    x = _xmeas(2, 2700.0)

    def cap(strategy, since):
        ctl, _ = make_te_controller(strategy, TransitionPlan("mode2"))
        ctl._since = since
        ask = np.full(5, np.nan) if ctl.core is None else np.array(ctl.core.u_last, float)
        ask[2] = 2800.0
        return float(ctl._track_pressure_setpoint(ask, x, x[9], x[30])[2])

    for strategy in ("ssmpc", "fixed"):
        assert [cap(strategy, h) for h in (0.0, 7.99, 8.0, 23.99, 24.0, math.inf)] == \
            [2710.0, 2710.0, 2720.0, 2720.0, 2710.0, 2710.0]
    assert cap("plan", 12.0) == 2710.0


def test_after_a_leg_the_purge_closes_sooner_and_the_plant_costs_less():
    # 1 -> 0, noise on, seed 1: the grade is made within 3 h with the purge at 80-90 %;
    # at 10 kPa of lead the pressure loop closes it at 3 %/h, at 20 kPa from 8 h twice
    # as fast (measured: 15-18 h about 48 against 63 %, 163 against 192 $/h from 9 h)
    from controller.units.te.control import GUARDS_MPC

    def run(guards):
        r = run_te("ssmpc", TransitionPlan("mode1", (Leg(1.0, "mode0"),)), 18.0, noise=True,
                   seed=1, plant_seed=plant_seed_for(1), guards=guards)
        assert r.shutdown is None, r.shutdown
        late = (r.t >= 15.0) & (r.t < 18.0)
        return (float(np.mean(r.xmv[late, 5])), float(np.mean(r.cost[r.t >= 9.0])),
                float(np.max(r.xmeas[:, 6])))

    purge, cost, peak = run(GUARDS_MPC)
    tight_purge, tight_cost, _ = run(dataclasses.replace(GUARDS_MPC,
                                                         purge_track_settle_kpa=None))
    assert purge < tight_purge - 8.0 and cost < tight_cost - 10.0
    assert peak < 2895.0


def test_the_recycle_valve_closes_more_slowly_than_it_opens():
    # leaving mode 3 XMV(5) closes from 77.6 %; entering mode 3 it opens toward it
    t = 1.0 + 3.0
    out = TransitionPlan("mode3", (Leg(1.0, "mode0"),))
    into = TransitionPlan("mode0", (Leg(1.0, "mode3"),))

    def moved(plan, j):
        a, b = plan._grades[0].xmv[j], plan._grades[-1].xmv[j]
        return (plan.xmv_ref(t)[j] - a) / (b - a)

    assert moved(out, 4) < 0.5 * moved(out, 2)             # XMV(5) against the A feed
    assert moved(into, 4) == pytest.approx(moved(into, 2))  # opening: the valves' pace


def _e_valves(c_purge: float, t0: float = 2.0, **guards) -> tuple[list[float], list]:
    """The E valve written over 10 samples from ``t0`` on 2 -> 3 (requested at 1 h) with
    the D feed at 5000 kg/h (the level's loop raising it) and C in the purge ``c_purge``
    mol %; the last alarms."""
    ctl, _ = make_te_controller("plan", TransitionPlan("mode2", (Leg(1.0, "mode3"),)),
                                guards=TransitionGuards(**guards))
    out, dec = [], None
    for k in range(10):
        x = _xmeas(2, 2600.0)
        x[1], x[30] = 5000.0, c_purge
        dec = ctl.step(k, t0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
        out.append(float(dec.u[1]))
    return out, list(dec.alarms)


def test_with_c_short_in_a_grade_change_the_e_valve_goes_no_higher_than_the_new_grades():
    cap = float(grade("mode3").xmv[1]) + TransitionGuards().e_feed_margin  # 8 % + 10 %
    capped, alarms = _e_valves(2.0, e_cap_c_fraction=0.3)
    assert max(capped) == pytest.approx(cap)
    assert any(f"E feed held at {cap:.0f} %" in a for a in alarms)
    # C as planned (13 mol % on this leg), or past pressure_hold_h: as with the guard off
    free, _ = _e_valves(2.0)
    assert min(free) > cap + 20.0
    for c, t0 in ((13.0, 2.0), (2.0, 14.0)):
        on, alarms = _e_valves(c, t0, e_cap_c_fraction=0.3)
        assert on == _e_valves(c, t0)[0]
        assert not any("E feed held" in a for a in alarms)


def test_idv8_through_a_leg_into_mode_3_with_the_d_feed_rising_does_not_trip():
    # IDV(8) from 0.5 h, 2 -> 3 at 1 h (seed 8): the plan lowered the E valve over hours
    # while the level's loop raised the D feed to 96 %; with C out of the purge E stayed
    # at 58-60 % and gathered, the purge at 100 % from 2.2 h, and the plant tripped at
    # 2.7 h. E held to mode 3's and its margin while C is short: no trip (of 75 runs over
    # five legs, seeds 1-15: 2 trips -> 0)
    plan = TransitionPlan("mode2", (Leg(1.0, "mode3"),))
    kw = dict(noise=True, seed=8, plant_seed=plant_seed_for(8), idv={8: 0.5})
    off = dataclasses.replace(GUARDS_MPC, e_cap_c_fraction=None)
    assert run_te("ssmpc", plan, 3.5, guards=off, **kw).shutdown is not None
    r = run_te("ssmpc", plan, 6.0, **kw)
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2895.0
    assert any("E feed held" in a for a in r.alarms)


def test_idv8_before_a_leg_into_mode_3_the_cut_waits_for_its_settling_hour():
    # IDV(8) from 0.5 h, 1 -> 3 at 1 h (seed 1): the run passes near the interlocks (C
    # out of the purge, the reactor level at 11-19 % at 4.5 h). With the settled excess
    # taken from the first sample a cut of under 0.1 % started at 0.3 h on the
    # analyzer's noise, and the plant tripped at 4.8 h; with the first hour's mean as
    # the reference the cut waits for that hour
    plan = TransitionPlan("mode1", (Leg(1.0, "mode3"),))
    kw = dict(noise=True, seed=1, plant_seed=plant_seed_for(1), idv={8: 0.5})
    one_sample = run_te("ssmpc", plan, 6.0, reactants=ReactantTrimSettings(settle_window_h=0.0),
                        **kw)
    assert any("A+C feed target lowered" in a for a in one_sample.alarms)
    assert one_sample.shutdown is not None
    r = run_te("ssmpc", plan, 6.0, **kw)
    assert r.shutdown is None, r.shutdown


#: IDV(6) (A feed lost) from 0.5 h through a leg at 1 h, seed 1: the guards that the case
#: needs off, and how long it runs (past the trip without them)
A_LOST_LEGS = [(3, 2, {"plan_hold_a_lost": False, "pressure_hold_a_lost": False}, 12.5),
               (1, 3, {"pressure_hold_a_lost": False}, 12.5)]


@pytest.mark.parametrize("start, to, off, hours", A_LOST_LEGS,
                         ids=[f"{a}-{b}" for a, b, _, _ in A_LOST_LEGS])
def test_a_grade_change_waits_while_the_a_feed_is_lost(start, to, off, hours):
    # 3 -> 2: the leg went on beneath the production index, the plan closed the condenser
    # with the purge at 100 % and the pressure reached the interlock (12.2 h). 1 -> 3 with
    # the plan held but P_r* following the pressure up from its dip: C without A gathered
    # with the purge shut (11.9 h). Both guards: the plan waits at the old grade, the purge
    # takes what does not react. The case as it was has the steady grade's pressure lead
    # off (controller/units/te/pressure_gain.py): in force until the change at 1 h, it
    # carries 1 -> 3 through without the guard too (measured); the guards hold it with the
    # lead off
    plan = TransitionPlan(f"mode{start}", (Leg(1.0, f"mode{to}"),))
    kw = dict(noise=True, seed=1, plant_seed=plant_seed_for(1), idv={6: 0.5})
    without = run_te("ssmpc", plan, hours, guards=dataclasses.replace(GUARDS_MPC, **off),
                     pressure_gain=False, **kw)
    assert without.shutdown is not None  # the case as it was
    guarded = run_te("ssmpc", plan, hours, pressure_gain=False, **kw)
    assert guarded.shutdown is None, guarded.shutdown
    r = run_te("ssmpc", plan, hours, **kw)
    assert r.shutdown is None, r.shutdown
    assert any("A feed lost: grade plan held" in a for a in r.alarms)
    assert any("set point held" in a and "the A feed lost" in a for a in r.alarms)


def test_a_leg_requested_while_the_a_feed_is_lost_starts_once_it_is_back():
    # IDV(6) from 0.5 h to 4 h, 2 -> 1 requested at 1 h (seed 1)
    plan = TransitionPlan("mode2", (Leg(1.0, "mode1"),))
    r = run_te("ssmpc", plan, 14.0, noise=True, seed=1, plant_seed=plant_seed_for(1),
               idv={6: 0.5}, idv_off={6: 4.0})
    assert r.shutdown is None, r.shutdown
    g = r.xmeas[:, 39]
    g1, g2 = grade("mode1").g_mol, grade("mode2").g_mol  # 53.8 and 11.7 mol %
    # waited at mode 2 (mode 1's G is 42 mol % away): the A feed's loss moves G by
    # itself, measured at most 4.03 mol % from mode 2's at 1.5-4 h (seeds 2-4: 2.98, 1.89,
    # 4.66; on the plant side's `steady` set alone 2.44, 3.63, 1.95, 11.58)
    assert np.all(np.abs(g[(r.t > 1.5) & (r.t < 4.0)] - g2) < 6.0)
    assert abs(float(np.mean(g[r.t > 13.0])) - g1) < 1.5  # then went to mode 1


def test_a_leg_held_at_its_start_counts_its_hours_from_when_it_goes_on():
    # the guards' windows after a change (the A loop's hold, the P_r* hold) start when
    # the leg does, not when it was due; the wait survives a restart
    plan = TransitionPlan("mode2", (Leg(1.0, "mode1"),))
    ctl, _ = make_te_controller("plan", plan, guards=TransitionGuards(plan_hold_a_lost=True))
    x = np.array(grade("mode2").xmeas, dtype=float)
    lost = x.copy()
    lost[0] = 0.0  # XMEAS 1: no A delivered at the A valve's opening
    k = 0
    for k in range(250):  # 0.5 h to 3.0 h
        ctl.step(k, 0.5 + k * ctl.sample_h, lost, None)
        ctl.finish_sample()
    assert ctl.plan_lag_h == pytest.approx(2.0)
    assert ctl.since_change_h == np.inf  # still waiting
    state = json.loads(json.dumps(ctl.checkpoint()))
    again, _ = make_te_controller("plan", plan, guards=TransitionGuards(plan_hold_a_lost=True))
    again.restore(state)
    for j in range(1, 51):  # the A feed back: 3.0 h to 3.5 h
        again.step(k + j, 0.5 + (k + j) * again.sample_h, x, None)
        again.finish_sample()
    assert 0.3 < again.since_change_h < 0.5  # the leg went on when A was back
    assert again.plan_lag_h == pytest.approx(2.0, abs=0.1)


# -- the reduced no-trip matrix --------------------------------------------------------------
#: (strategy, start mode, leg mode, IDV, hours): before the guards these tripped on
#: reactor pressure (noise on, seed 1) at 3.8 h (ssmpc 3 -> 0), 2.9 h (3 -> 1), 2.6 h
#: (3 -> 2), 3.1 h (1 -> 3), 6.5 h (IDV(7) from 2 h at mode 2) and 4.1 h (plan 3 -> 0),
#: before the feed overrides IDV(7) from 2 h at mode 3 at 6.0 h, and before the
#: production index IDV(6) from 2 h at mode 2 at 13.9 h, before the reactant trim
#: IDV(8) from 2 h at mode 3 at 6.5 h; each runs a little past that.
NO_TRIP = [("ssmpc", 3, 0, 0, 5.0), ("ssmpc", 3, 1, 0, 4.0), ("ssmpc", 3, 2, 0, 4.0),
           ("ssmpc", 1, 3, 0, 4.0), ("ssmpc", 2, 2, 7, 7.0), ("plan", 3, 0, 0, 5.0),
           ("ssmpc", 3, 3, 7, 7.0), ("ssmpc", 2, 2, 6, 14.5), ("ssmpc", 3, 3, 8, 7.0)]


@pytest.mark.parametrize("strategy, start, to, idv, hours", NO_TRIP,
                         ids=[f"{s}-{a}-{b}-idv{i}" for s, a, b, i, _ in NO_TRIP])
def test_no_trip(strategy, start, to, idv, hours):
    plan = TransitionPlan(f"mode{start}", (Leg(1.0, f"mode{to}"),) if to != start else ())
    r = run_te(strategy, plan, hours, noise=True, seed=1, plant_seed=plant_seed_for(1),
               idv={idv: 2.0} if idv else None)
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < INTERLOCK_KPA - 50.0


@pytest.mark.parametrize("seed", [2, 3])
def test_one_to_three_requested_after_a_steady_day_holds(seed):
    # 1 -> 3 requested at 13 h, after 12 h at mode 1 (noise on): tripped at 15.3 h on
    # seeds 2 and 3 while the A loop raised the A feed to 51 % through the leg; requested
    # at 1 h it held. With the A loop held through a leg that lowers the A in the reactor
    # feed (TransitionGuards.a_loop_hold_falling_h) seed 3 still tripped, at 16.0 h (C
    # run out in the purge, the pressure rebounding): the guards on C short hold it
    # (peaks 2836-2845 kPa on seeds 1-3)
    plan = TransitionPlan("mode1", (Leg(13.0, "mode3"),))
    r = run_te("ssmpc", plan, 17.0, noise=True, seed=seed, plant_seed=plant_seed_for(seed))
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2895.0


def test_the_economic_pressure_survives_a_disturbance_that_swings_the_pressure():
    # IDV(20) at mode 0 (noise on, seed 2): with the set-point tracking at 10 kPa all
    # along P_r* fell with every dip of the pressure and the plant ran at 2650-2730 kPa,
    # dearer than the decentralized structure (its own run here); with the wider margin
    # while the economics lift P_r* it holds near their 2800 kPa (measured: 150.0 $/h at
    # 2806 kPa, against 166.5 $/h at 2730 kPa with the tight tracking and 170.7 $/h for
    # the decentralized structure. On seed 1, with the A loop's steady-grade tuning at
    # 8 %/mol %, the tight tracking's dips are smaller: 158.1 $/h at 2777 kPa against 149.2.
    # With the plant side's steady tuning set (loop_tuning), hours 24-48: 151.6 $/h at
    # 2767 kPa against 160.3 at 2742; without it 151.8 at 2767 against 162.7 at 2735)
    import dataclasses

    from controller.units.te.control import GUARDS_MPC

    def run(strategy, **kw):
        r = run_te(strategy, TransitionPlan("mode0"), 48.0, noise=True, seed=2,
                   plant_seed=plant_seed_for(2), idv={20: 2.0}, **kw)
        assert r.shutdown is None, r.shutdown
        late = r.t >= 24.0
        return float(np.mean(r.cost)), float(np.mean(r.xmeas[late, 6]))

    cost, pressure = run("ssmpc")
    tight_cost, tight_pressure = run(
        "ssmpc", guards=dataclasses.replace(GUARDS_MPC, purge_track_lift_kpa=None))
    decentralized_cost, _ = run("decentralized")
    assert cost < decentralized_cost and cost < tight_cost - 5.0
    assert pressure > 2760.0 > tight_pressure


def test_the_wide_margin_lasts_half_an_hour_of_cutting_and_survives_a_restart():
    import json

    def cuts(ctl, n, pressure=2700.0):
        x = _xmeas(0, pressure)
        ask = np.array(ctl.core.u_last, dtype=float)
        ask[2] = 2800.0  # the core asks for the economic P_r*
        return [float(ctl._track_pressure_setpoint(ask.copy(), x, x[9], x[30])[2])
                for _ in range(n)]

    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode0"))
    assert cuts(ctl, 1) == [2710.0]  # no lift yet: the tight margin
    ctl.targets.econ_lift = 50.0  # the economics hold P_r*'s target above the plan
    first = cuts(ctl, 30)
    assert first == [2740.0] * 30
    again, _ = make_te_controller("ssmpc", TransitionPlan("mode0"))
    again.restore(json.loads(json.dumps(ctl.checkpoint())))
    again.targets.econ_lift = 50.0
    rest, rest_again = cuts(ctl, 40), cuts(again, 40)
    assert rest == rest_again  # the restored controller's clock goes on
    # 0.5 h (50 samples of 0.01 h) of cutting at 40 kPa, then 10 kPa
    assert rest[:19] == [2740.0] * 19 and rest[-18:] == [2710.0] * 18
    # a sample that does not cut starts the clock again
    assert cuts(ctl, 1, pressure=2795.0) == [2800.0]
    assert cuts(ctl, 1) == [2740.0]


def test_without_the_economic_lift_the_tracking_stays_tight():
    # IDV(13) at mode 2 (noise on, seed 1): the kinetics' drift cycles the pressure over
    # 20 h (2526-2872 kPa); with 40 kPa of margin there too the purge closed from 45 to
    # 0.5 % while the pressure stood low, the gas gathered, and the plant tripped at 19.2 h
    r = run_te("ssmpc", TransitionPlan("mode2"), 21.0, noise=True, seed=1,
               plant_seed=plant_seed_for(1), idv={13: 2.0})
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[:, 6].max() < 2895.0


def test_a_purge_below_its_floor_stops_the_tracking_margin():
    # mode 2's P_r* is 2800 kPa and its purge 0.361 kscmh: at 2700 kPa the loop gets
    # 2710 kPa, but with the purge at a tenth of the grade's (below the floor's quarter)
    # the set point stays at the pressure, so the loop's integral stops closing the purge
    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode2"))
    x = _xmeas(2, 2700.0)
    ask = np.array(ctl.core.u_last, dtype=float)
    ask[2] = 2800.0
    ref = grade("mode2").xmeas[9]
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2710.0)
    x[9] = 0.1 * ref
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2700.0)
    x[9] = 0.3 * ref
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2710.0)
    # within a day of a grade change (into mode 3 the plant closes the purge) no floor
    # (and from 8 h the settling margin of 20 kPa)
    x[9] = 0.1 * ref
    ctl._since = 5.0
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2710.0)
    ctl._since = 23.0
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2720.0)
    ctl._since = 24.0
    assert ctl._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2700.0)
    off, _ = make_te_controller("ssmpc", TransitionPlan("mode2"),
                                guards=TransitionGuards(purge_floor_fraction=None))
    x[9] = 0.1 * ref
    assert off._track_pressure_setpoint(ask.copy(), x, ref, x[30])[2] == pytest.approx(2710.0)


def test_a_slow_kinetics_drift_at_mode_1_does_not_close_the_purge_and_trip():
    # IDV(13) at mode 1 (noise on, seed 2): the pressure stood 40-170 kPa under P_r* from
    # 14 to 32 h, the tracking's 10 kPa margin integrated the purge from 48 % to 0.2 %,
    # and the plant tripped on reactor pressure at 35.3 h; with the purge's floor it runs
    # on (48 h: peak 2882 kPa)
    r = run_te("ssmpc", TransitionPlan("mode1"), 37.0, noise=True, seed=2,
               plant_seed=plant_seed_for(2), idv={13: 2.0})
    assert r.shutdown is None, r.shutdown
    assert r.xmeas[r.t > 14.0, 9].min() > 0.25 * grade("mode1").xmeas[9] * 0.5
    assert r.xmeas[:, 6].max() < 2950.0


def test_change_at_gives_the_grades_of_the_last_leg_started():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(5.0, "mode3")))
    names = lambda t: tuple(g.name for g in plan.change_at(t))  # noqa: E731
    assert names(0.5) == ("mode0", "mode0")
    assert names(1.0) == ("mode0", "mode2") == names(4.9)
    assert names(5.0) == ("mode2", "mode3") == names(40.0)
