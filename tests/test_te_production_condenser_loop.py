"""The MPC strategies' production loop on the condenser (off by default; when on, opened
by the condenser's cooling-water balance): at a steady grade, while the balance reports a
condenser-side disturbance, a product flow (XMEAS 17) that falls below its recent mean
opens the condenser's input target (XMV 11); without the report it does not, nor does a
standing offset; the trim washes out over hours, it holds through a grade change and
when the operator holds it, it survives a restart; on the plant it takes up a
condenser-side disturbance that otherwise reaches G through the reactor level's D feed,
and holds the kinetics-drift case it tripped before the balance opened it."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import (
    CONDENSER_TRIM_WASHOUT_H,
    PRODUCTION_CONDENSER_LOOP,
    PRODUCTION_CONDENSER_MEAN_H,
    SEPARATOR_LOOP_STEADY_AFTER_H,
    make_te_controller,
    plant_seed_for,
    run_te,
)
from controller.units.te.grades import Leg, TransitionPlan, grade
from controller.units.te.loop_tuning import LoopTuningSettings
from controller.units.te.velocity_trim import VelocityTrim

#: Product flow this far under its reference in the controller tests, m3/h.
SHORT_M3_H = 0.5
#: The condenser's cooling-water outlet (XMEAS 22) swings this far each sample in the
#: controller tests (a condenser-side disturbance the balance reports), degC.
SWING_DEGC = 2.0


def _swing(x: np.ndarray, k: int, swing: float) -> np.ndarray:
    """``x`` with the condenser's cooling-water outlet ``swing`` degC up or down."""
    y = x.copy()
    y[21] += swing if k % 2 else -swing
    return y


def _condenser_trims(plan: TransitionPlan, t0: float, short: float, n: int = 10,
                     held: set[int] | None = None, separator: bool = False,
                     settle: int = 20, swing: float = SWING_DEGC):
    """The production loop's trim of the condenser's target, each of ``n`` samples
    from ``t0``: the product flow at the grade's for ``settle`` samples before, then
    ``short`` m3/h under it, the condenser's cooling-water outlet swinging by ``swing``
    throughout, every other measurement at the grade (the separator loop off unless
    ``separator``)."""
    ctl, _ = make_te_controller("fixed", plan, separator_loop=separator,
                                production_condenser_loop=True,
                                condenser_disturbance_loop=False)
    if held:
        ctl.hold_outer_loops(held)
    x = np.array(plan.grade_at(t0).xmeas, dtype=float)
    dt = ctl.sample_h
    for k in range(settle):
        ctl.step(k, t0 + (k - settle) * dt, _swing(x, k, swing), None)
        ctl.finish_sample()
    x[16] -= short
    trims = []
    for k in range(n):
        ctl.step(settle + k, t0 + k * dt, _swing(x, settle + k, swing), None)
        ctl.finish_sample()
        trims.append(ctl.pc_trim)
    return ctl, trims


def test_the_loop_is_off_by_default():
    # the condenser-side disturbance loop (the separator on the condenser) does better
    # on the same report (tests/test_te_condenser_disturbance_loop.py)
    ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode2"))
    assert ctl.production_condenser_loop is None
    on, _ = make_te_controller("ssmpc", TransitionPlan("mode2"),
                               production_condenser_loop=True)
    assert on.production_condenser_loop is PRODUCTION_CONDENSER_LOOP


def test_the_loop_holds_the_kinetics_drift_case_it_tripped_when_always_open():
    # IDV(13) at mode 1, seed 28: with the loop always open, ssmpc tripped at 27.9 h
    # (reactor pressure, the MPC opening the condenser into the separator's collapse);
    # the balance does not open it for the kinetics' drift
    r = run_te("ssmpc", TransitionPlan("mode1"), 30.0, noise=True, seed=28,
               plant_seed=plant_seed_for(28), idv={13: 2.0},
               production_condenser_loop=True)
    assert r.shutdown is None
    assert float(np.max(r.xmeas[:, 6])) < 2900.0


def test_without_a_condenser_side_disturbance_the_loop_does_not_act():
    ctl, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, SHORT_M3_H, swing=0.0)
    assert not ctl.condenser_balance.active
    assert max(abs(t) for t in trims) < 1e-12


def test_the_loop_is_the_decentralized_pairing():
    assert (PRODUCTION_CONDENSER_LOOP.cv, PRODUCTION_CONDENSER_LOOP.output) == (17, 4)
    assert PRODUCTION_CONDENSER_LOOP.gain > 0  # short product (e > 0) opens the condenser
    assert math.isfinite(CONDENSER_TRIM_WASHOUT_H) and CONDENSER_TRIM_WASHOUT_H > 0
    assert math.isfinite(PRODUCTION_CONDENSER_MEAN_H) and PRODUCTION_CONDENSER_MEAN_H > 0


def test_a_short_product_flow_opens_the_condenser_at_a_steady_grade():
    ctl, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, SHORT_M3_H)
    assert ctl.condenser_balance.active
    assert trims[-1] > 0.05
    assert all(b > a for a, b in zip(trims[1:], trims[2:], strict=False))  # integral
    _, more = _condenser_trims(TransitionPlan("mode2"), 2.0, -SHORT_M3_H)
    assert more[-1] == pytest.approx(-trims[-1], rel=1e-6)  # it closes it as well


def test_a_standing_offset_from_the_plan_is_left_to_the_a_c_feed():
    # the product flow 0.5 m3/h under the plan's from the start: the loop's reference is
    # the flow's own mean, so it does not move the condenser (the A+C feed's loop
    # answers the offset)
    ctl, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, 0.0, settle=0, n=40)
    assert ctl.condenser_balance.active
    assert max(abs(t) for t in trims) < 1e-12
    plan = TransitionPlan("mode2")
    ctl, _ = make_te_controller("fixed", plan, production_condenser_loop=True,
                                condenser_disturbance_loop=False)
    x = np.array(grade("mode2").xmeas, dtype=float)
    x[16] -= SHORT_M3_H
    for k in range(40):
        ctl.step(k, 2.0 + k * ctl.sample_h, _swing(x, k, SWING_DEGC), None)
        ctl.finish_sample()
    assert ctl.condenser_balance.active
    assert abs(ctl.pc_trim) < 1e-12
    assert ctl.p_trim > 0.0  # the A+C feed's loop raises its target


def test_the_trim_washes_out_when_the_error_is_gone():
    # an integral trim left without error: after one washout time a third of it is
    # left (e^-1), after three a twentieth, whatever the sample
    for dt in (0.01, 0.05):
        trim = VelocityTrim(-20.0, 20.0, washout_h=2.0)
        trim.value = 4.0
        for _ in range(round(2.0 / dt)):
            trim.step(0.0, 3.0, 0.72, dt, held=False)
        assert trim.value == pytest.approx(4.0 / math.e, rel=0.03)
        for _ in range(round(4.0 / dt)):
            trim.step(0.0, 3.0, 0.72, dt, held=False)
        assert trim.value == pytest.approx(4.0 * math.exp(-3.0), rel=0.05)
    held = VelocityTrim(-20.0, 20.0, washout_h=2.0)
    held.value = 4.0
    for _ in range(200):
        held.step(1.0, 3.0, 0.72, 0.01, held=True)  # the error is not followed
    assert held.value == pytest.approx(4.0 / math.e, rel=0.03)  # the washout goes on
    plain = VelocityTrim(-20.0, 20.0)
    plain.value = 4.0
    for held_ in (False, True):
        plain.step(0.0, 3.0, 0.72, 0.01, held=held_)
    assert plain.value == 4.0  # no washout by default, a held plain trim stands


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan")])
def test_a_washout_that_is_not_positive_is_refused(bad):
    with pytest.raises(ValueError, match="washout_h"):
        VelocityTrim(-1.0, 1.0, washout_h=bad)


def test_the_loop_holds_through_a_grade_change_and_acts_after():
    change = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    _, through = _condenser_trims(change, 2.0, SHORT_M3_H)
    assert max(abs(t) for t in through) < 1e-12
    _, after = _condenser_trims(change, 1.0 + SEPARATOR_LOOP_STEADY_AFTER_H + 0.5,
                                SHORT_M3_H)
    assert after[-1] > 0.05


@pytest.mark.parametrize("cv", [17, 11])
def test_the_operator_holds_it_on_the_product_flow_or_the_separator(cv):
    _, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, SHORT_M3_H, held={cv})
    assert max(abs(t) for t in trims) < 1e-12


def test_the_condenser_target_carries_both_trims():
    # the separator loop's trim (a separator at its reference: none) and this one add
    ctl, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, SHORT_M3_H, separator=True)
    assert ctl.sep_trim == pytest.approx(0.0, abs=1e-9)
    assert trims[-1] > 0.05


def test_a_restored_controller_goes_on_with_the_trim_and_mean_it_reached():
    plan = TransitionPlan("mode2")
    ctl, _ = _condenser_trims(plan, 2.0, SHORT_M3_H)
    state = ctl.checkpoint()
    assert state["pc_trim"] > 0.05 and math.isfinite(state["pc_mean"])
    again, _ = make_te_controller("fixed", plan, separator_loop=False,
                                  production_condenser_loop=True,
                                  condenser_disturbance_loop=False)
    again.restore(state)
    again.take_over()
    assert again.pc_trim == ctl.pc_trim
    assert again.condenser_balance.state() == ctl.condenser_balance.state()
    assert again.condenser_balance.active
    x = np.array(grade("mode2").xmeas, dtype=float)
    x[16] -= SHORT_M3_H
    a = ctl.step(30, 2.1, x, None)
    b = again.step(30, 2.1, x, None)
    # the uninterrupted controller's next trim, but for the proportional step the
    # take-over leaves out (the error's change over one sample as the mean follows the
    # flow: 3 %/(m3/h) x 0.5 m3/h x 0.01 h / 4 h, under 0.01 % of the trim's 1.6 %)
    assert again.pc_trim == pytest.approx(ctl.pc_trim, abs=0.01)
    assert b.u[10] == pytest.approx(a.u[10], abs=0.02)
    # a checkpoint from before the loop, or a damaged mean: the trim starts at 0 and
    # the mean at the next measurement, with no error
    for damaged in ({k: v for k, v in state.items()
                     if k not in ("pc_trim", "e_pc_prev", "pc_mean")},
                    {**state, "pc_mean": float("nan")}, {**state, "pc_mean": "x"}):
        before, _ = make_te_controller("fixed", plan, separator_loop=False,
                                       production_condenser_loop=True,
                                       condenser_disturbance_loop=False)
        before.restore(damaged)
        before.step(30, 2.1, x, None)
        assert math.isfinite(before.checkpoint()["pc_mean"])


def test_a_condenser_side_disturbance_is_taken_up_before_it_reaches_g():
    # IDV(12) (the condenser's cooling water inlet temperature) at mode 2, where the E
    # valve runs near its range: without the loop the product flow wanders, the reactor
    # level's D feed follows, the E valve the ratio ties to it clips and G wanders
    # (seed 1, 8 h: G 0.71 mol %, the decentralized structure's 0.49 over 48 h). Run on
    # the plant side's `steady` set: on the E-limited one the MPC selects at mode 2 the
    # slow level loop leaves the D feed still and G is steady either way (0.505 on,
    # 0.508 off)
    runs = {}
    for on in (True, False):
        r = run_te("ssmpc", TransitionPlan("mode2"), 8.0, noise=True, seed=1,
                   plant_seed=plant_seed_for(1), idv={12: 1.0},
                   production_condenser_loop=on, condenser_disturbance_loop=False,
                   loop_tuning=LoopTuningSettings(e_valve_pct=100.0))
        assert r.shutdown is None
        m = r.t >= 1.0
        runs[on] = (float(np.std(r.xmeas[m, 39])), float(np.std(r.xmeas[m, 16])),
                    float(np.std(r.xmv[m, 10])))
    (g_on, prod_on, cond_on), (g_off, prod_off, cond_off) = runs[True], runs[False]
    assert cond_on > 1.0 > cond_off  # the condenser moves with it, hardly without
    assert prod_on < 0.75 * prod_off
    assert g_on < 0.6 < 0.68 < g_off
