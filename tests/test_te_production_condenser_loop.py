"""The MPC strategies' production loop on the condenser: at a steady grade a product
flow (XMEAS 17) under its reference opens the condenser's input target (XMV 11), the
trim washes out over hours, it holds through a grade change and when the operator
holds it, it survives a restart; on the plant it takes up a condenser-side
disturbance that otherwise reaches G through the reactor level's D feed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import (
    CONDENSER_TRIM_WASHOUT_H,
    PRODUCTION_CONDENSER_LOOP,
    SEPARATOR_LOOP_STEADY_AFTER_H,
    make_te_controller,
    plant_seed_for,
    run_te,
)
from controller.units.te.grades import Leg, TransitionPlan, grade
from controller.units.te.velocity_trim import VelocityTrim

#: Product flow this far under its reference in the controller tests, m3/h.
SHORT_M3_H = 0.5


def _condenser_trims(plan: TransitionPlan, t0: float, short: float, n: int = 10,
                     held: set[int] | None = None, separator: bool = False):
    """The production loop's trim of the condenser's target, each of ``n`` samples from
    ``t0``, with the product flow ``short`` m3/h under the grade's and every other
    measurement at the grade (the separator loop off unless ``separator``)."""
    ctl, _ = make_te_controller("fixed", plan, separator_loop=separator)
    if held:
        ctl.hold_outer_loops(held)
    x = np.array(plan.grade_at(t0).xmeas, dtype=float)
    x[16] -= short
    trims = []
    for k in range(n):
        ctl.step(k, t0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
        trims.append(ctl.pc_trim)
    return ctl, trims


def test_the_loop_is_the_decentralized_pairing():
    assert (PRODUCTION_CONDENSER_LOOP.cv, PRODUCTION_CONDENSER_LOOP.output) == (17, 4)
    assert PRODUCTION_CONDENSER_LOOP.gain > 0  # short product (e > 0) opens the condenser
    assert math.isfinite(CONDENSER_TRIM_WASHOUT_H) and CONDENSER_TRIM_WASHOUT_H > 0


def test_a_short_product_flow_opens_the_condenser_at_a_steady_grade():
    _, trims = _condenser_trims(TransitionPlan("mode2"), 2.0, SHORT_M3_H)
    assert trims[-1] > 0.05
    assert all(b > a for a, b in zip(trims[1:], trims[2:], strict=False))  # integral
    _, more = _condenser_trims(TransitionPlan("mode2"), 2.0, -SHORT_M3_H)
    assert more[-1] == pytest.approx(-trims[-1], rel=1e-6)  # it closes it as well


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
    held.step(0.0, 3.0, 0.72, 0.01, held=True)
    assert held.value == 4.0  # a held trim stands
    plain = VelocityTrim(-20.0, 20.0)
    plain.value = 4.0
    plain.step(0.0, 3.0, 0.72, 0.01, held=False)
    assert plain.value == 4.0  # no washout by default


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


def test_a_restored_controller_goes_on_with_the_trim_it_reached():
    plan = TransitionPlan("mode2")
    x = np.array(grade("mode2").xmeas, dtype=float)
    x[16] -= SHORT_M3_H
    ctl, _ = make_te_controller("fixed", plan)
    for k in range(10):
        ctl.step(k, 2.0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
    state = ctl.checkpoint()
    assert state["pc_trim"] > 0.05
    again, _ = make_te_controller("fixed", plan)
    again.restore(state)
    again.take_over()
    assert again.pc_trim == ctl.pc_trim
    a = ctl.step(10, 2.1, x, None)
    b = again.step(10, 2.1, x, None)
    assert b.u[10] == pytest.approx(a.u[10], abs=0.02)
    old = {k: v for k, v in state.items() if k not in ("pc_trim", "e_pc_prev")}
    before, _ = make_te_controller("fixed", plan)
    before.restore(old)  # a checkpoint from before the loop: its trim starts at 0
    assert before.pc_trim == 0.0


def test_a_condenser_side_disturbance_is_taken_up_before_it_reaches_g():
    # IDV(12) (the condenser's cooling water inlet temperature) at mode 2, where the E
    # valve runs near its range: without the loop the product flow wanders, the reactor
    # level's D feed follows, the E valve the ratio ties to it clips and G wanders
    # (seed 1, 8 h: G 0.71 mol %, the decentralized structure's 0.49 over 48 h)
    runs = {}
    for on in (True, False):
        r = run_te("ssmpc", TransitionPlan("mode2"), 8.0, noise=True, seed=1,
                   plant_seed=plant_seed_for(1), idv={12: 1.0},
                   production_condenser_loop=on)
        assert r.shutdown is None
        m = r.t >= 1.0
        runs[on] = (float(np.std(r.xmeas[m, 39])), float(np.std(r.xmeas[m, 16])),
                    float(np.std(r.xmv[m, 10])))
    (g_on, prod_on, cond_on), (g_off, prod_off, cond_off) = runs[True], runs[False]
    assert cond_on > 1.0 > cond_off  # the condenser moves with it, hardly without
    assert prod_on < 0.75 * prod_off
    assert g_on < 0.6 < 0.68 < g_off
