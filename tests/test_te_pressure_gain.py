"""The reactor-pressure loop's gain raised at a steady grade through its set point: the
lead's arithmetic by hand, its ramp in and out, what it does with a bad pressure and
across a restart, and on the closed loop that the pressure moves less with the core's
P_r* still its target."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from controller.units.te.control import make_te_controller, plant_seed_for, run_te
from controller.units.te.grades import TransitionPlan
from controller.units.te.pressure_gain import SteadyPressureGain, SteadyPressureGainSettings


@pytest.mark.parametrize("kw, field", [({"factor": 0.5}, "factor"),
                                       ({"factor": 11.0}, "factor"),
                                       ({"factor": float("nan")}, "factor"),
                                       ({"washout_h": 0.0}, "washout_h"),
                                       ({"after_h": -1.0}, "after_h"),
                                       ({"ramp_h": 0.0}, "ramp_h"),
                                       ({"ramp_h": True}, "ramp_h")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        SteadyPressureGainSettings(**kw)


def _run(lead, n, setpoint, pressure, since):
    for _ in range(n):
        out = lead.update(setpoint, pressure, since)
    return out


#: a washout so slow that the lead acts on the whole change of the error from the
#: first sample's (the ramp's arithmetic apart from the washout's)
NO_WASHOUT = dict(washout_h=1e9)


def test_the_lead_ramps_in_at_a_steady_grade_and_out_through_a_change():
    lead = SteadyPressureGain(SteadyPressureGainSettings(factor=3.0, after_h=24.0,
                                                         ramp_h=1.0, **NO_WASHOUT),
                              sample_h=0.01)
    assert _run(lead, 1, 2800.0, 2800.0, math.inf) == 2800.0  # the washout's start
    # half the ramp: the loop at 2 times its gain; 10 kPa under the set point -> +10
    assert _run(lead, 49, 2800.0, 2790.0, math.inf) == pytest.approx(2810.0)
    assert lead.gain_multiple == pytest.approx(2.0)
    # the whole ramp: 3 times; 10 kPa over -> the set point 20 kPa under P_r*
    assert _run(lead, 60, 2800.0, 2810.0, math.inf) == pytest.approx(2780.0)
    # a grade change 2 h ago (before after_h): out within the hour, at the same rate
    assert _run(lead, 25, 2800.0, 2810.0, 2.0) == pytest.approx(2785.0)
    assert _run(lead, 100, 2800.0, 2810.0, 2.0) == 2800.0
    assert lead.share == 0.0


def test_the_washout_leaves_a_standing_error_to_the_plant_sides_gain():
    # washout 1 h, 36 s samples: a = 0.01 / 1.01 of the way a sample; a step of the
    # error of 10 kPa leaves 10 (1 - a)^n = 10 / 1.01^n of it to the lead after n
    # samples
    lead = SteadyPressureGain(SteadyPressureGainSettings(factor=3.0, washout_h=1.0),
                              sample_h=0.01)
    assert _run(lead, 30, 2800.0, 2800.0, math.inf) == 2800.0  # the ramp in, no error
    assert lead.update(2800.0, 2790.0, math.inf) == pytest.approx(2800.0 + 2 * 10 / 1.01)
    assert _run(lead, 99, 2800.0, 2790.0, math.inf) == pytest.approx(
        2800.0 + 2 * 10 * 0.369711, rel=1e-6)            # 1 / 1.01^100 = 0.369711
    assert _run(lead, 900, 2800.0, 2790.0, math.inf) == pytest.approx(2800.0, abs=1e-3)


def test_a_move_of_the_cores_set_point_is_led_as_the_errors_move():
    # the lead is on the loop's error, as the plant side's PI loop is: P_r* lowered by
    # 1 kPa a sample, the pressure still, is written 2 kPa lower a sample beyond it
    # while the washout (very slow here) lets the move through
    lead = SteadyPressureGain(SteadyPressureGainSettings(**NO_WASHOUT), sample_h=0.01)
    _run(lead, 100, 2800.0, 2800.0, math.inf)
    for k in range(1, 20):
        assert lead.update(2800.0 - k, 2800.0, math.inf) == pytest.approx(2800.0 - 3 * k)


def test_a_step_of_a_guards_rule_is_not_led():
    # the purge's floor ending puts P_r* back a margin above the pressure: with the
    # step marked the washout takes the new error as it is, and only later changes
    # are led
    lead = SteadyPressureGain(SteadyPressureGainSettings(**NO_WASHOUT), sample_h=0.01)
    _run(lead, 100, 2790.0, 2790.0, math.inf)         # at the floor: P_r* = P
    assert lead.update(2800.0, 2790.0, math.inf, stepped=True) == 2800.0
    assert lead.update(2805.0, 2790.0, math.inf) == pytest.approx(2815.0)  # + 2 * 5
    unmarked = SteadyPressureGain(SteadyPressureGainSettings(**NO_WASHOUT), sample_h=0.01)
    _run(unmarked, 100, 2790.0, 2790.0, math.inf)
    assert unmarked.update(2800.0, 2790.0, math.inf) == pytest.approx(2820.0)


def test_before_after_h_the_set_point_is_the_cores():
    lead = SteadyPressureGain(SteadyPressureGainSettings(after_h=24.0, ramp_h=0.25,
                                                         **NO_WASHOUT), sample_h=0.01)
    assert _run(lead, 500, 2800.0, 2800.0, 23.99) == 2800.0
    assert _run(lead, 500, 2800.0, 2750.0, 23.99) == 2800.0
    # the first sample at 24 h: a 25th of the ramp, 2 * 0.04 * 50 kPa
    assert _run(lead, 1, 2800.0, 2750.0, 24.0) == pytest.approx(2804.0)


def test_a_bad_pressure_writes_the_cores_set_point_and_the_ramp_goes_on():
    lead = SteadyPressureGain(SteadyPressureGainSettings(**NO_WASHOUT), sample_h=0.01)
    assert _run(lead, 100, 2800.0, float("nan"), math.inf) == 2800.0
    assert lead.share == 1.0
    assert lead.update(2800.0, 2800.0, math.inf) == 2800.0  # the washout starts here
    assert lead.update(2800.0, 2790.0, math.inf) == pytest.approx(2820.0)


def test_the_share_survives_a_restart_and_a_damaged_one_ramps_in_again():
    lead = SteadyPressureGain(sample_h=0.01)
    _run(lead, 40, 2800.0, 2795.0, math.inf)
    again = SteadyPressureGain(sample_h=0.01)
    again.restore(json.loads(json.dumps(lead.checkpoint())))
    assert again.update(2800.0, 2790.0, math.inf) == lead.update(2800.0, 2790.0, math.inf)
    for bad in ({"share": "x", "error_lag": "y"}, {"share": float("nan")}, None, {},
                "not a checkpoint", [0.5]):
        damaged = SteadyPressureGain(sample_h=0.01)
        damaged.restore(bad)
        assert damaged.share == 0.0 and damaged.error_lag is None
    over = SteadyPressureGain(sample_h=0.01)
    over.restore({"share": 7.0})
    assert over.share == 1.0


def test_a_take_over_continues_from_the_set_point_the_plant_holds():
    lead = SteadyPressureGain(SteadyPressureGainSettings(**NO_WASHOUT, ramp_h=0.25),
                              sample_h=0.01)
    _run(lead, 1, 2800.0, 2800.0, math.inf)
    held = _run(lead, 50, 2800.0, 2795.0, math.inf)  # the whole ramp: 2800 + 2 * 5
    assert held == pytest.approx(2810.0)
    assert lead.applied(held) == pytest.approx(2800.0)  # the core's own P_r*
    # the operator's warm: the plant keeps 2810 while the controller writes nothing;
    # back, the core is told 2800, and the first set point written is the one held
    # (the lead's 10 kPa as a bias that runs out over the ramp, 0.4 kPa a sample)
    assert lead.take_over(held) == pytest.approx(2800.0)
    assert lead.update(2800.0, 2795.0, math.inf) == pytest.approx(2810.0 - 0.4)
    # an operator holding P_r*: no lead, no bias, the core told the operator's value
    lead.operator_held = True
    assert lead.take_over(2790.0) == 2790.0
    assert lead.update(2790.0, 2780.0, math.inf) == 2790.0


def test_on_by_default_for_the_mpc_strategies_only():
    for strategy, on in (("ssmpc", True), ("fixed", True), ("pi", False), ("plan", False)):
        ctl, _ = make_te_controller(strategy, realtime=False)
        assert (ctl.pressure_gain is not None) is on, strategy
        if on:
            assert ctl.pressure_gain.settings == SteadyPressureGainSettings()
        ctl, _ = make_te_controller(strategy, realtime=False, pressure_gain=False)
        assert ctl.pressure_gain is None, strategy
        ctl, _ = make_te_controller(strategy, realtime=False,
                                    pressure_gain=SteadyPressureGainSettings(factor=2.0))
        assert (ctl.pressure_gain is not None) is on, strategy
    with pytest.raises(ValueError, match="pressure_gain"):
        make_te_controller("ssmpc", realtime=False, pressure_gain=3.0)


def test_the_controller_hands_the_core_its_own_set_point_on_a_take_over():
    # at a steady grade with the pressure moving the set point written carries the lead;
    # the plant holding that set point, the core is told its own P_r*, not the lead's
    from controller.units.te.grades import grade

    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode2"), realtime=False,
                                pressure_gain=True)
    x = np.array(grade("mode2").xmeas, dtype=float)
    for k in range(40):
        x[6] = 2800.0 - 0.5 * k  # the pressure falling 0.5 kPa a sample
        dec = ctl.step(k, 0.01 * k, x, None)
        ctl.finish_sample()
    written, own = float(dec.extra["setpoints"][4]), float(dec.extra["core_u"][2])
    assert written > own + 1.0  # the lead on a falling pressure: the purge closes more
    u = np.array(dec.extra["core_u"], dtype=float)
    u[2] = written
    assert ctl.take_over(u)[2] == pytest.approx(own)
    ctl.applied(u)  # the same set point as applied: the core's own again
    assert ctl.core.u_last[2] == pytest.approx(own)


def _half_hour_means(t, x):
    k = np.floor((t - t[0]) / 0.5).astype(int)
    return np.array([x[k == i].mean() for i in range(k.max())])


def test_under_idv20_at_mode_0_the_pressure_moves_less():
    # IDV(20): the reactor effluent's flow coefficient, a 2 h sawtooth that moves the
    # pressure. Measured (seeds 1-3, 24 h, hours 4-24): the half-hour means' step
    # 19.1 / 26.5 / 24.8 kPa without the lead, 15.8 / 21.3 / 19.7 with it (the purge
    # valve's standard deviation 4.9-5.9 % without, 10.2-13.2 % with).
    moves = {}
    for on in (False, True):
        r = run_te("ssmpc", TransitionPlan("mode0"), 24, noise=True, idv={20: 2.0}, seed=1,
                   plant_seed=plant_seed_for(1), pressure_gain=on)
        assert r.shutdown is None
        m = r.t >= 4.0
        p = _half_hour_means(r.t[m], r.xmeas[m, 6])
        moves[on] = float(np.std(np.diff(p)) / np.sqrt(2.0))
    assert moves[True] < 0.85 * moves[False]
