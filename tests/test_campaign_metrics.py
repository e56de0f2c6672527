"""Campaign metrics against small series whose answers are worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from controller.units.te.grades import trailing_mean
from services.campaign import metrics

# seed Table 7.3 (R7.3), mode 2: G in product (row 40) 11.66 mol %, product flow
# (row 17) 22.73 m3/h; the flow band is 5 % of it
MODE2_G, MODE2_FLOW = 11.66, 22.73


def test_time_to_grade_counts_from_the_leg_to_the_last_exit_of_the_band():
    t = [0.0, 1.0, 2.0, 3.0, 4.0, 5.0]
    g = [50.0, 50.0, 52.0, 54.5, 55.2, 54.9]  # inside |g - 55| <= 1 from t = 3 on
    flow = [20.0] * 6
    ttg = metrics.time_to_grade_h(t, np.c_[g, flow], [55.0, 20.0], [1.0, 1.0], t_leg=1.0)
    assert ttg == pytest.approx(2.0)  # 3 h - 1 h
    # the flow leaves its band at t = 4: inside for good only from t = 5
    flow[4] = 21.5
    ttg = metrics.time_to_grade_h(t, np.c_[g, flow], [55.0, 20.0], [1.0, 1.0], t_leg=1.0)
    assert ttg == pytest.approx(4.0)


def test_time_to_grade_is_none_when_the_last_sample_is_outside():
    t = [0.0, 1.0, 2.0]
    g = [55.0, 55.0, 57.0]
    assert metrics.time_to_grade_h(t, np.c_[g], [55.0], [1.0], t_leg=0.0) is None


def test_time_to_grade_only_looks_at_samples_from_the_leg_on():
    # outside before the leg, inside from the first sample after it (at 1.0, leg at 0.5)
    t = [0.0, 1.0, 2.0]
    g = [0.0, 55.0, 55.5]
    assert metrics.time_to_grade_h(t, np.c_[g], [55.0], [1.0], t_leg=0.5) == pytest.approx(0.5)


def test_a_nan_sample_is_outside_the_band():
    t = [0.0, 1.0, 2.0, 3.0]
    g = [55.0, np.nan, 55.0, 55.0]
    assert metrics.time_to_grade_h(t, np.c_[g], [55.0], [1.0], t_leg=0.0) == pytest.approx(2.0)


def test_integrate_rate_is_the_rectangle_sum_over_the_window():
    t = [0.0, 0.5, 1.0, 1.5]
    cost = [100.0, 200.0, 300.0, 400.0]
    # samples at 0.5 and 1.0 are in [0.5, 1.5): (200 + 300) $/h x 0.5 h
    assert metrics.integrate_rate(t, cost, 0.5, 0.5, 1.5) == pytest.approx(250.0)


def test_final_mean_is_the_mean_of_the_last_hour():
    t = np.arange(8) * 0.25          # 2 h at 15 min
    v = [1, 1, 1, 1, 2, 4, 6, 8]
    assert metrics.final_mean(t, v, 0.25) == pytest.approx(5.0)   # (2 + 4 + 6 + 8) / 4
    # a run shorter than the window: the whole run
    assert metrics.final_mean(t[:2], v[:2], 0.25) == pytest.approx(1.0)


def test_trailing_mean_by_hand():
    v = np.array([[1.0, 10.0], [3.0, 10.0], [5.0, 40.0], [7.0, 10.0]])
    np.testing.assert_allclose(trailing_mean(v, 2), [[1, 10], [2, 10], [4, 25], [6, 25]])
    np.testing.assert_allclose(trailing_mean(v[:, 0], 3), [1, 2, 3, 5])


def test_active_model_share_by_name():
    share = metrics.active_model_share([0, 0, 1, 2, 1, 1, 0, 0], ("mode0", "mode2", "reinit"))
    assert share == pytest.approx({"mode0": 4 / 8, "mode2": 3 / 8, "reinit": 1 / 8})
    assert metrics.active_model_share([-1, -1], ()) == {}


def _te_series():
    """Six samples 0.5 h apart, the leg to mode 2 at 1.0 h, in the grade from 1.5 h."""
    t = np.arange(6) * 0.5
    x = np.zeros((6, 41))
    x[:, 6] = [2700, 2750, 2900, 2800, 2790, 2780]            # reactor pressure, kPa
    x[:, 39] = [53.7, 40.0, 20.0, MODE2_G + 0.9, MODE2_G - 0.5, MODE2_G]
    x[:, 16] = [22.9, 22.9, 22.0, 22.0, 23.5, MODE2_FLOW]      # band 22.73 +- 1.1365
    cost = np.array([100.0, 110.0, 120.0, 130.0, 140.0, 150.0])
    active = np.array([1, 1, 0, 0, 0, 2])
    return t, x, cost, active


def test_te_metrics_of_a_transition_by_hand():
    t, x, cost, active = _te_series()
    m = metrics.te_metrics(t, x, cost, active, ("reinit", "mode0", "mode2"), 0.5,
                           (1.0, "mode2"), None)
    assert m["tripped"] is False and m["trip"] is None
    # the grade signals as 1 h trailing means (two samples): G at 1.5 h is
    # (20 + 12.56) / 2 = 16.3, outside; at 2.0 h (12.56 + 11.16) / 2 = 11.86 and at
    # 2.5 h 11.41, inside; the flow means 22.0, 22.75, 23.12, inside: in from 2.0 h
    assert m["time_to_grade_h"] == pytest.approx(1.0)
    assert m["peak_pressure_kpa"] == pytest.approx(2900.0)
    assert m["mean_cost_usd_h"] == pytest.approx(125.0)
    assert m["final_cost_usd_h"] == pytest.approx(145.0)   # last hour: 140 and 150
    assert m["transition_cost_usd"] == pytest.approx(125.0)  # (120 + 130) $/h x 0.5 h
    assert m["active_model_share"] == pytest.approx({"reinit": 3 / 6, "mode0": 2 / 6,
                                                     "mode2": 1 / 6})
    assert list(m) == ["tripped", "trip", "time_to_grade_h", "peak_pressure_kpa",
                       "mean_cost_usd_h", "final_cost_usd_h", "transition_cost_usd",
                       "active_model_share", "product_variability", "limit_bound_share",
                       "binding_limit", "limit_shares"]


def test_te_metrics_of_a_tripped_run_integrate_the_cost_to_the_end():
    t, x, cost, active = _te_series()
    trip = metrics.trip_record(2.6, "reactor pressure high")
    m = metrics.te_metrics(t, x, cost, active, ("reinit", "mode0", "mode2"), 0.5,
                           (1.0, "mode2"), trip)
    assert m["tripped"] is True
    assert m["trip"] == {"at_h": 2.6, "reason": "reactor pressure high"}
    assert m["time_to_grade_h"] is None
    # samples at 1.0, 1.5, 2.0, 2.5 h: (120 + 130 + 140 + 150) x 0.5
    assert m["transition_cost_usd"] == pytest.approx(270.0)


def test_te_metrics_without_legs_have_no_grade_time_nor_transition_cost():
    t, x, cost, active = _te_series()
    m = metrics.te_metrics(t, x, cost, -np.ones(6, int), (), 0.5, None, None)
    assert m["time_to_grade_h"] is None and m["transition_cost_usd"] is None
    assert m["active_model_share"] == {}
    assert m["mean_cost_usd_h"] == pytest.approx(125.0)


def test_product_variability_is_the_spread_from_the_disturbance_on():
    t = np.arange(6) * 0.5
    x = np.zeros((6, 41))
    # G steady at 50 mol % before the onset at 1.0 h, then 49 / 51 alternating:
    # a standard deviation of 1 mol %; the flow 20 before, 18 / 22 after: 2 on a
    # mean of 20, 10 %
    x[:, 39] = [50.0, 50.0, 49.0, 51.0, 49.0, 51.0]
    x[:, 16] = [20.0, 20.0, 18.0, 22.0, 18.0, 22.0]
    v = metrics.product_variability(t, x, from_h=1.0)
    assert v["g_std_mol"] == pytest.approx(1.0)
    assert v["production_std_pct"] == pytest.approx(10.0)
    # the samples before the onset are steady, so the whole run spreads less
    whole = metrics.product_variability(t, x)
    assert whole["g_std_mol"] < v["g_std_mol"]
    assert metrics.product_variability(t, x, from_h=2.5) is None   # one sample left


def test_te_metrics_score_the_variability_from_the_onset_given():
    t, x, cost, active = _te_series()
    m = metrics.te_metrics(t, x, cost, active, ("reinit", "mode0", "mode2"), 0.5,
                           None, None, disturbance_on_h=1.5)
    # from 1.5 h G is MODE2_G + 0.9, - 0.5, + 0: the deviations' mean square less
    # their mean squared, (0.81 + 0.25) / 3 - (0.4 / 3)^2 = 0.3356, std 0.579 mol %
    assert m["product_variability"]["g_std_mol"] == pytest.approx(0.5793, abs=1e-4)
    # the whole run (from 53.7 mol % down) spreads far more
    whole = metrics.te_metrics(t, x, cost, active, ("reinit", "mode0", "mode2"), 0.5,
                               None, None)
    assert whole["product_variability"]["g_std_mol"] > 5.0


def test_limit_binding_is_the_share_of_the_window_any_limit_binds_and_names_the_longest():
    t = np.arange(10) * 1.0
    # window [2, 8): six samples; A binds at 2, 3, 4; B at 4 and 7; before the window
    # A binds too (not counted)
    a = np.zeros(10, bool)
    a[[0, 1, 2, 3, 4]] = True
    b = np.zeros(10, bool)
    b[[4, 7]] = True
    share, name, shares = metrics.limit_binding(t, {"A": a, "B": b}, 2.0, 8.0)
    assert share == pytest.approx(4 / 6)          # samples 2, 3, 4, 7
    assert name == "A"
    assert shares == pytest.approx({"A": 3 / 6, "B": 2 / 6})


def test_limit_binding_without_binding_and_with_an_empty_window():
    t = np.arange(4) * 1.0
    none = np.zeros(4, bool)
    assert metrics.limit_binding(t, {"A": none}, 0.0, 4.0) == (0.0, None, {})
    assert metrics.limit_binding(t, {"A": ~none}, 2.0, 2.0) == (None, None, {})


def _flat_series(n: int):
    x = np.zeros((n, 41))
    x[:, 6] = 2800.0
    u = np.full((n, 12), 50.0)
    return x, u


def test_te_limits_bind_at_a_valve_end_and_near_the_pressure_limit():
    x, u = _flat_series(6)
    u[1, 0] = 99.5          # D feed 0.5 % from full: binds
    u[2, 0] = 98.0          # 2 % from full: does not
    u[3, 5] = 0.4           # purge nearly shut: binds
    u[4, 4] = 0.0           # the recycle valve is the plan's, not a controlled valve
    u[4, 11] = 100.0        # nor is the agitator
    x[5, 6] = 2885.0        # within 15 kPa of 2895: binds
    x[2, 6] = 2870.0        # 25 kPa under: does not
    b = metrics.te_limits_at_bound(x, u)
    hits = {k: np.flatnonzero(v).tolist() for k, v in b.items() if v.any()}
    assert hits == {"XMV1": [1], "XMV6": [3], "reactor pressure": [5]}


def test_te_metrics_report_the_binding_over_the_transition_window_only():
    dt = 0.5
    t = np.arange(12) * dt                 # 0 ... 5.5 h, leg at 1 h
    x, u = _flat_series(12)
    x[:, 39], x[:, 16] = 53.72, 22.95      # mode 0's G and flow: never at mode 2
    x[4:8, 39], x[4:8, 16] = MODE2_G, MODE2_FLOW
    x[8:, 39], x[8:, 16] = MODE2_G, MODE2_FLOW
    u[3:6, 1] = 100.0                      # the E feed wide open from 1.5 to 2.5 h
    u[10:, 1] = 100.0                      # and after the grade is reached (not counted)
    cost = np.full(12, 100.0)
    row = metrics.te_metrics(t, x, cost, np.full(12, -1), (), dt, (1.0, "mode2"), None, xmv=u)
    # the one-hour trailing mean (2 samples) is at grade from the sample at 2.5 h:
    # window [1.0, 2.5): samples at 1.0, 1.5, 2.0; the E feed binds at 1.5 and 2.0
    assert row["time_to_grade_h"] == pytest.approx(1.5)
    assert row["limit_bound_share"] == pytest.approx(2 / 3)
    assert row["binding_limit"] == "XMV2"
    assert row["limit_shares"] == pytest.approx({"XMV2": 2 / 3})
    # a run with no leg has no transition window
    row = metrics.te_metrics(t, x, cost, np.full(12, -1), (), dt, None, None, xmv=u)
    assert row["limit_bound_share"] is None and row["binding_limit"] is None


# seed Table 7.3 (R7.3), modes 0 and 1: the same product (G 53.72 / 53.83 mol %, flow
# 22.95 / 22.89 m3/h) at another operating point (reactor level 75 / 65 %, rows 8;
# reactor temperature 120.4 / 122.9 degC, rows 9)
MODE1_G, MODE1_FLOW, MODE1_LEVEL, MODE1_TR = 53.83, 22.89, 65.0, 122.9


def test_modes_zero_and_one_make_the_same_product_and_mode_two_another():
    assert metrics.te_same_product("mode0", "mode1")
    assert metrics.te_same_product("mode1", "mode0")
    assert not metrics.te_same_product("mode0", "mode2")
    assert not metrics.te_same_product("mode1", "mode3")


def _same_product_series():
    """Nine samples 0.5 h apart, the leg 0 -> 1 at 1.0 h: G and flow at mode 1's from
    the start, the reactor level in mode 1's band from 3.0 h, the temperature from 2.5 h."""
    t = np.arange(9) * 0.5
    x = np.zeros((9, 41))
    x[:, 6] = 2750.0
    x[:, 39] = MODE1_G
    x[:, 16] = MODE1_FLOW
    x[:, 7] = [75, 75, 75, 72, 69, 67, 65, 65, 65]
    x[:, 8] = [120.4, 120.4, 121.0, 121.6, 122.4, 122.9, 122.9, 122.9, 122.9]
    return t, x, np.full(9, 100.0), np.full(9, -1)


def test_a_leg_that_keeps_the_product_is_at_grade_when_the_operating_point_is():
    t, x, cost, active = _same_product_series()
    m = metrics.te_metrics(t, x, cost, active, (), 0.5, (1.0, "mode1"), None,
                           previous_grade="mode0")
    # 1 h trailing means (two samples): level (67 + 65) / 2 = 66.0 at 3.0 h, inside
    # 65 +- 1, (69 + 67) / 2 = 68 at 2.5 h outside; temperature (122.4 + 122.9) / 2 =
    # 122.65 at 2.5 h inside 122.9 +- 0.5, (121.6 + 122.4) / 2 = 122.0 at 2.0 h outside
    assert m["time_to_grade_h"] == pytest.approx(2.0)   # 3.0 h - 1.0 h
    # samples at 1.0, 1.5, 2.0, 2.5 h: 4 x 100 $/h x 0.5 h
    assert m["transition_cost_usd"] == pytest.approx(200.0)
    # without the grade before (or from a grade of another product) only the product
    # signals count, and they were in the band from the leg on
    m = metrics.te_metrics(t, x, cost, active, (), 0.5, (1.0, "mode1"), None)
    assert m["time_to_grade_h"] == pytest.approx(0.0)


def test_a_leg_that_changes_the_product_is_judged_on_the_product_alone():
    t, x, cost, active = _te_series()
    x[:, 7] = 50.0  # reactor level far from every grade's: not a grade signal here
    m = metrics.te_metrics(t, x, cost, active, ("reinit", "mode0", "mode2"), 0.5,
                           (1.0, "mode2"), None, previous_grade="mode0")
    assert m["time_to_grade_h"] == pytest.approx(1.0)  # as without the grade before
