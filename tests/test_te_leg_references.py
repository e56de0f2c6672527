"""The MPC's own level and temperature references through a TE leg.

Checked against the closed form of a first-order path written out here (not the
plan's own evaluator), against the grades' tabulated values, and in closed loop: the
leg that keeps the product (mode 0 -> mode 1) reaches its grade faster with them.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import make_te_controller, run_te
from controller.units.te.grades import GradeError, Leg, TransitionPlan, grade
from controller.units.te.leg_references import (
    LEVEL_COLUMN,
    TEMPERATURE_COLUMN,
    LegReferenceSettings,
)
from controller.units.te.service import HeldPlan
from services.campaign.metrics import te_metrics

LR = LegReferenceSettings()


def _first_order(r0, target, tau, dt):
    return target + (r0 - target) * math.exp(-dt / tau)


@pytest.mark.parametrize("kw", [dict(tau_fraction=0.0), dict(tau_fraction=1.5),
                                dict(tau_fraction=float("nan")), dict(tau_fraction=True),
                                dict(g_band_mol=-1.0), dict(flow_band_rel=float("inf")),
                                dict(g_band_mol="1"), dict(level_dip_pct=-5.0),
                                dict(level_dip_h=float("nan"))])
def test_settings_refuse_bad_values_naming_the_field(kw):
    with pytest.raises(ValueError, match=next(iter(kw))):
        LegReferenceSettings(**kw)


def test_a_plan_refuses_leg_references_of_another_type():
    with pytest.raises(GradeError, match="leg_references"):
        TransitionPlan("mode0", (Leg(1.0, "mode1"),), leg_references={"tau_fraction": 0.5})


@pytest.mark.parametrize("a, b, level, temperature", [
    ("mode0", "mode1", True, True),     # same product: both are the grade change
    ("mode1", "mode0", True, True),     # the level rises, the temperature falls: both
    ("mode0", "mode2", True, True),     # the level falls, the temperature rises
    ("mode2", "mode0", False, False),   # the level rises, the temperature falls
    ("mode3", "mode0", False, False),
    ("mode3", "mode2", False, True),    # the level stays, the temperature rises
    ("mode2", "mode3", False, False),   # the temperature falls
])
def test_which_references_move_faster_on_a_leg(a, b, level, temperature):
    ga, gb = grade(a), grade(b)
    taus = LR.column_taus(ga, gb, ga.xmeas, 3.0)
    assert (LEVEL_COLUMN in taus) is level
    assert (TEMPERATURE_COLUMN in taus) is temperature
    assert all(v == pytest.approx(1.0) for v in taus.values())
    assert set(taus) <= {LEVEL_COLUMN, TEMPERATURE_COLUMN}


def test_the_plan_moves_level_and_temperature_on_a_third_of_its_time_constant():
    slow = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    fast = slow.with_leg_references(LR)
    g0, g1 = grade("mode0"), grade("mode1")
    for t in (1.0, 1.5, 2.0, 4.0, 9.0):
        rf, rs = fast.xmeas_ref(t), slow.xmeas_ref(t)
        for col in (LEVEL_COLUMN, TEMPERATURE_COLUMN):
            assert rf[col] == pytest.approx(_first_order(g0.xmeas[col], g1.xmeas[col],
                                                         1.0, t - 1.0), abs=1e-9)
            assert rs[col] == pytest.approx(_first_order(g0.xmeas[col], g1.xmeas[col],
                                                         3.0, t - 1.0), abs=1e-9)
        others = np.ones(41, bool)
        others[[LEVEL_COLUMN, TEMPERATURE_COLUMN]] = False
        np.testing.assert_array_equal(rf[others], rs[others])  # nothing else moves
    np.testing.assert_array_equal(fast.xmv_ref(3.0), slow.xmv_ref(3.0))


def test_an_operators_duration_stays_in_proportion():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode1"),), tau_xmeas_h=6.0,
                          leg_references=LR)
    g0, g1 = grade("mode0"), grade("mode1")
    assert plan.xmeas_ref(3.0)[LEVEL_COLUMN] == pytest.approx(
        _first_order(g0.reactor_level, g1.reactor_level, 2.0, 2.0), abs=1e-9)


def test_a_second_leg_starts_where_the_faster_path_is():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode1"), Leg(2.0, "mode0")),
                          leg_references=LR)
    g0, g1 = grade("mode0"), grade("mode1")
    at_2 = _first_order(g0.reactor_level, g1.reactor_level, 1.0, 1.0)
    assert plan.xmeas_ref(2.5)[LEVEL_COLUMN] == pytest.approx(
        _first_order(at_2, g0.reactor_level, 1.0, 0.5), abs=1e-9)


def test_a_leg_that_changes_the_product_dips_the_level_and_refills_it():
    g1, g2 = grade("mode1"), grade("mode2")
    assert g1.reactor_level == g2.reactor_level  # the dip is the only level move here
    plan = TransitionPlan("mode1", (Leg(1.0, "mode2"),), leg_references=LR)
    low = g2.reactor_level - LR.level_dip_pct
    back = 1.0 + LR.level_dip_h
    at_back = _first_order(g1.reactor_level, low, 1.0, LR.level_dip_h)
    for t in (1.5, 3.0, back - 1e-9):  # down on the fast pace (a falling level)
        assert plan.xmeas_ref(t)[LEVEL_COLUMN] == pytest.approx(
            _first_order(g1.reactor_level, low, 1.0, t - 1.0), abs=1e-9)
    for t in (back + 0.5, back + 3.0, 30.0):  # back to the grade's on the plan's 3 h
        assert plan.xmeas_ref(t)[LEVEL_COLUMN] == pytest.approx(
            _first_order(at_back, g2.reactor_level, 3.0, t - back), abs=1e-9)
    # every other reference as without the dip: a first-order path restarted on its own
    # target and time constant is the same path
    no_dip = TransitionPlan("mode1", (Leg(1.0, "mode2"),),
                            leg_references=LegReferenceSettings(level_dip_pct=0.0))
    times = np.array([0.5, 1.0, 2.0, back, back + 0.01, 9.0, 20.0])
    others = np.ones(41, bool)
    others[LEVEL_COLUMN] = False
    np.testing.assert_allclose(plan.xmeas_ref(times)[:, others],
                               no_dip.xmeas_ref(times)[:, others], rtol=0, atol=1e-9)
    np.testing.assert_allclose(plan.xmv_ref(times), no_dip.xmv_ref(times), rtol=0, atol=1e-9)
    for t in times:
        assert plan.d_fraction_ref(t) == pytest.approx(no_dip.d_fraction_ref(t), abs=1e-12)


def test_a_leg_that_changes_only_the_production_keeps_the_level_on_its_grade():
    g1, g4 = grade("mode1"), grade("mode4")
    assert abs(g1.g_mol - g4.g_mol) <= LR.g_band_mol  # the same G, more production
    plan = TransitionPlan("mode1", (Leg(1.0, "mode4"),), leg_references=LR)
    no_dip = TransitionPlan("mode1", (Leg(1.0, "mode4"),),
                            leg_references=LegReferenceSettings(level_dip_pct=0.0))
    times = np.array([1.5, 3.0, 5.0, 8.0, 20.0])
    np.testing.assert_array_equal(plan.xmeas_ref(times), no_dip.xmeas_ref(times))


def test_a_next_leg_before_the_refill_takes_the_level_from_where_it_is():
    g2, g3 = grade("mode2"), grade("mode3")
    plan = TransitionPlan("mode1", (Leg(1.0, "mode2"), Leg(3.0, "mode3")),
                          leg_references=LR)
    at_3 = _first_order(grade("mode1").reactor_level, g2.reactor_level - LR.level_dip_pct,
                        1.0, 2.0)
    low3 = g3.reactor_level - LR.level_dip_pct
    # no refill toward mode 2 at 5 h: the leg to mode 3 dips from where the level is
    # (still above mode 3's dip, so it falls on the fast pace)
    assert at_3 > low3
    assert plan.xmeas_ref(5.0)[LEVEL_COLUMN] == pytest.approx(
        _first_order(at_3, low3, 1.0, 2.0), abs=1e-9)
    assert plan.xmeas_ref(3.0 + LR.level_dip_h + 6.0)[LEVEL_COLUMN] > low3


def test_only_the_mpc_strategies_take_them_and_keep_them_on_a_new_plan():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    for strategy in ("fixed", "ssmpc"):
        ctl, _ = make_te_controller(strategy, plan)
        assert ctl.plan.leg_references == LR
        ctl.retarget(TransitionPlan("mode1", (Leg(5.0, "mode0"),)))
        assert ctl.plan.leg_references == LR
        held = HeldPlan(TransitionPlan("mode0", (Leg(1.0, "mode1"),)), 2.0)
        ctl.retarget(held)  # an abort holds where the controller's own path was
        assert ctl.plan.xmeas_ref(9.0)[LEVEL_COLUMN] == pytest.approx(
            plan.with_leg_references(LR).xmeas_ref(2.0)[LEVEL_COLUMN])
    ctl, _ = make_te_controller("fixed", plan, leg_references=False)
    assert ctl.plan is plan
    for strategy in ("pi", "plan"):
        assert make_te_controller(strategy, plan)[0].plan is plan
    with pytest.raises(ValueError, match="leg_references"):
        make_te_controller("fixed", plan, leg_references="fast")


def _hours_to_grade(leg_references):
    plan = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    r = run_te("fixed", plan, 14.0, noise=True, seed=1, leg_references=leg_references)
    assert r.shutdown is None
    m = te_metrics(r.t, r.xmeas, r.cost, r.active, r.model_names, 0.01, (1.0, "mode1"),
                   None, xmv=r.xmv, previous_grade="mode0")
    return m["time_to_grade_h"]


def test_a_leg_that_keeps_the_product_reaches_its_grade_faster():
    fast, slow = _hours_to_grade(True), _hours_to_grade(False)
    # the level band (1 %) of a 10 % change on 3 h takes 6.9 h; on 1 h, 2.3 h
    assert slow > 6.0
    assert fast < 0.6 * slow
