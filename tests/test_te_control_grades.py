"""TE grades, references and run metrics (controller.units.te.grades)."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from controller.units.te.grades import (
    GRADES,
    GradeError,
    Leg,
    TransitionPlan,
    check_reachable,
    first_order_path,
    grade,
    ise,
    level_to_volume,
    limit_margins,
    parse_grade,
    production_change,
    ricker_optimum,
    saturation_time,
    time_to_band,
)

REL_TABLE = 2e-3  # Table 7.3 flows are printed to 4 digits
ODE_TOL = 1e-6


def test_table_7_3_values_as_printed():
    # seed_results.md R7.3 / R7.14: G mol% 53.72 -> 11.66 -> 90.09; level 75 then 65
    assert grade(0).g_mol == 53.72 and grade(2).g_mol == 11.66 and grade(3).g_mol == 90.09
    assert grade("base").reactor_level == 75 and grade("mode2").reactor_level == 65
    assert grade(2).reactor_temperature == 124.2


@pytest.mark.parametrize("name", GRADES)
def test_feed_valves_agree_with_table_7_3(name):
    # facts cross-check: XMV1 % x 5811 kg/h = D feed, XMV2 % x 8354 kg/h = E feed
    g = grade(name)
    assert g.xmv[0] * 5811 / 100 == pytest.approx(g.xmeas[1], rel=REL_TABLE, abs=1.0)
    assert g.xmv[1] * 8354 / 100 == pytest.approx(g.xmeas[2], rel=REL_TABLE, abs=1.0)


def test_unknown_grade_is_a_clear_error():
    with pytest.raises(GradeError, match="grade: unknown grade 'mode9'.*mode0"):
        parse_grade("mode9")
    with pytest.raises(GradeError, match="unknown grade"):
        TransitionPlan("mode0", (Leg(1.0, "7"),))


@pytest.mark.parametrize("mode,valve", [(4, 1), (5, 2), (6, 1)])
def test_ricker_max_production_optima_have_no_margin(mode, valve):
    # Ricker's modes 4-6 optima (ricker1995 csv, states 39-50): a feed valve at 100 %
    g = ricker_optimum(mode)
    assert g.xmv[valve - 1] == 100.0
    assert f"XMV({valve})" in g.unreachable_reason()


def test_reachable_pairs():
    for a in GRADES:
        for b in GRADES:
            check_reachable(a, b)


def test_unknown_target_stays_refused_with_the_field():
    with pytest.raises(GradeError, match="grade: unknown grade 'mode7'"):
        check_reachable("mode0", "mode7")


def test_leg_validation():
    with pytest.raises(GradeError, match="t_h"):
        Leg(-1.0, "mode2")
    with pytest.raises(GradeError, match="legs: times must increase"):
        TransitionPlan("mode0", (Leg(2.0, "mode2"), Leg(1.0, "mode3")))
    with pytest.raises(GradeError, match="tau_xmv_h"):
        TransitionPlan("mode0", tau_xmv_h=math.nan)


def test_first_order_path_matches_ode_solution():
    sw = [(1.0, np.array([10.0, -2.0]), np.array([2.0, 0.5])),
          (4.0, np.array([3.0, 5.0]), np.array([2.0, 0.5]))]
    r0 = np.array([0.0, 1.0])

    def rhs(t, r):
        s, tau = r0, np.ones(2)
        for ts, target, ta in sw:
            if t >= ts:
                s, tau = target, ta
        return (s - r) / tau if t >= 1.0 else np.zeros(2)

    for t_end in (0.5, 2.5, 7.0):
        ref = solve_ivp(rhs, (0.0, t_end), r0, rtol=1e-10, atol=1e-12, max_step=0.01).y[:, -1]
        np.testing.assert_allclose(first_order_path(t_end, 0.0, r0, sw), ref, atol=ODE_TOL)


def test_first_order_path_for_many_times_equals_each_time_alone():
    sw = [(1.0, np.array([10.0, -2.0]), np.array([2.0, 0.0])),
          (4.0, np.array([3.0, 5.0]), 0.5)]
    times = np.array([0.0, 0.5, 1.0, 1.0 + 1e-9, 2.5, 4.0, 7.0, 30.0])
    many = first_order_path(times, 0.0, [0.0, 1.0], sw)
    assert many.shape == (times.size, 2)
    for i, t in enumerate(times):
        np.testing.assert_array_equal(many[i], first_order_path(float(t), 0.0, [0.0, 1.0], sw))
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(9.0, "mode3")))
    ym = plan.xmeas_ref(times)
    assert ym.shape == (times.size, 41)
    for i, t in enumerate(times):
        np.testing.assert_array_equal(ym[i], plan.xmeas_ref(float(t)))
    # the tau = 0 column steps at the switch
    assert many[2, 1] == -2.0 and many[1, 1] == 1.0


def test_plan_references_are_first_order_path_bit_for_bit():
    # the plan evaluates from a table built at its switches; the general path walks
    # every segment from t = 0: both must give the same floats
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(2.5, "mode3"), Leg(9.0, "mode0")),
                          tau_xmeas_h=0.7, tau_xmv_h=1.3, tau_recycle_h=1.3)
    times = np.concatenate([[-1.0, 0.0, 1.0, 2.5, 9.0, 1.0 + 1e-12, 2.5 - 1e-12],
                            np.linspace(0.0, 30.0, 301)])
    g = [grade(n) for n in ("mode0", "mode2", "mode3", "mode0")]
    for attr, tau, got in (("xmeas", 0.7, plan.xmeas_ref), ("xmv", 1.3, plan.xmv_ref)):
        sw = [(t, getattr(gr, attr), tau) for t, gr in zip((1.0, 2.5, 9.0), g[1:])]
        want = first_order_path(times, 0.0, getattr(g[0], attr), sw)
        np.testing.assert_array_equal(got(times), want)
        for t in times[:7]:
            np.testing.assert_array_equal(got(float(t)), first_order_path(t, 0.0,
                                                                           getattr(g[0], attr),
                                                                           sw))
    sw = [(t, np.array([gr.d_fraction]), 1.3) for t, gr in zip((1.0, 2.5, 9.0), g[1:])]
    for t in times:
        assert plan.d_fraction_ref(float(t)) == float(
            first_order_path(t, 0.0, np.array([g[0].d_fraction]), sw)[0])
    # the recycle valve XMV(5) on its own time constant where a leg closes it: the
    # general path with that column's tau per switch
    slow = TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(2.5, "mode3"), Leg(9.0, "mode0")),
                          tau_xmv_h=1.3, tau_recycle_h=7.0)
    sw, prev = [], slow.xmv_ref(1.0)
    for t_sw, gr in zip((1.0, 2.5, 9.0), g[1:]):
        tau = np.full(12, 1.3)
        at = slow.xmv_ref(t_sw - 1e-12) if t_sw > 1.0 else prev
        tau[4] = 7.0 if gr.xmv[4] < at[4] else 1.3
        sw.append((t_sw, gr.xmv, tau))
    np.testing.assert_array_equal(slow.xmv_ref(times), first_order_path(times, 0.0,
                                                                        g[0].xmv, sw))
    step = TransitionPlan("mode0", (Leg(1.0, "mode2"),), tau_xmeas_h=0.0)
    np.testing.assert_array_equal(step.xmeas_ref(np.array([0.5, 1.0, 3.0])),
                                  [g[0].xmeas, g[1].xmeas, g[1].xmeas])


def test_plan_references_closed_form():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"),), tau_xmeas_h=2.0, tau_xmv_h=3.0)
    g0, g2 = grade(0).g_mol, grade(2).g_mol
    for t in (0.0, 0.9, 1.0, 3.0, 10.0):
        expect = g0 if t <= 1 else g2 + (g0 - g2) * math.exp(-(t - 1) / 2.0)
        assert plan.xmeas_ref(t)[39] == pytest.approx(expect, rel=1e-12)
    # XMV(5), XMV(9) close toward Ricker's mode-2 values (1 %), level 75 -> 65 %; the
    # recycle valve XMV(5) on its closing time constant (default 10 h)
    x = plan.xmv_ref(1.0 + 3.0)
    assert x[8] == pytest.approx(1.0 + (47.45 - 1.0) * math.exp(-1), rel=1e-3)
    assert x[4] == pytest.approx(1.0 + (22.21 - 1.0) * math.exp(-0.3), rel=1e-3)
    assert plan.xmeas_ref(100.0)[7] == pytest.approx(65.0)
    assert plan.grade_at(0.5).name == "mode0" and plan.grade_at(1.5).name == "mode2"


def test_metrics_closed_forms():
    t = np.arange(0.0, 10.0, 0.01)
    y = np.exp(-t)
    assert time_to_band(t, y, 0.0, math.exp(-3.0), 0.0) == pytest.approx(3.0, abs=0.011)
    assert time_to_band(t, 1.0 + 0 * t, 0.0, 0.5, 0.0) == math.inf
    rect_tol = 0.01  # left rectangle rule: error ~ dt/2 * y(0)^2
    assert ise(t, y, 0.0) == pytest.approx(0.5 * (1 - math.exp(-20)), abs=rect_tol)
    u = np.where(t < 2.5, 100.0, 40.0)
    assert saturation_time(t, u) == pytest.approx(2.5, abs=0.011)
    p = np.where(t < 5, 100.0, 95.75)
    assert production_change(t, p, 5.0) == pytest.approx(-4.25)


def test_limit_margins_names_the_nearest_limit():
    y = np.zeros((3, 41))
    y[:, 6] = [2700.0, 2950.0, 2800.0]
    y[:, 7], y[:, 11], y[:, 14] = 75.0, 50.0, 50.0
    m = limit_margins(y)
    assert m["reactor pressure"]["margin"] == pytest.approx(50.0)
    # reactor level 75 % = (84.6 + 0.75 * 666.7) ft3 = 16.55 m3 (base case, facts te.md)
    assert level_to_volume(75.0, "reactor") == pytest.approx(16.55, abs=0.01)
    assert m["reactor liquid volume"]["limit"] == 24.0
