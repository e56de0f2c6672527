"""The KPI accumulator (controller.kpis) against hand-made sample sequences: modes and
fallbacks -> service factor, at-limit flags -> constraint activity, costs -> cost against
the base case, prediction errors -> their means; trailing windows; checkpoint and
restore; and the vector at-limit flags against the status' own rule."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from controller.kpis import KPIAccumulator, KPISettings
from controller.units.variables import at_limit, at_limit_flags

TS = 60.0  # one sample a minute: 60 samples an hour
VARS = [("P", "cv"), ("L", "cv"), ("V", "mv")]
NONE = [False, False, False]


def _acc(**kw):
    kw.setdefault("base_cost_usd_h", 100.0)
    return KPIAccumulator(KPISettings(TS, **kw), VARS)


def _window(rep, name):
    return next(w for w in rep["windows"] if w["window"] == name)


def _activity(w, name):
    return next(a for a in w["constraint_activity"] if a["name"] == name)


def test_service_factor_counts_only_on_and_not_in_fallback():
    acc = _acc()
    k = 0
    # 6 samples ON, 2 of them in fallback; 3 WARM; 1 OFF; then 2 ON again
    for mode, fb in [("on", False)] * 4 + [("on", True)] * 2 + [("warm", False)] * 3 + [
            ("off", False)] + [("on", False)] * 2:
        k += 1
        acc.update(k * TS, mode, fb, NONE, NONE)
    w = _window(acc.report(), "since start")
    assert w["hours"] == pytest.approx(12 / 60)
    assert w["service_factor"] == pytest.approx(6 / 12)
    assert w["time_share"] == pytest.approx({"on": 6 / 12, "fallback": 2 / 12,
                                             "warm": 3 / 12, "off": 1 / 12, "down": 0.0})


def test_a_warm_period_lowers_the_service_factor_and_it_recovers_in_the_window():
    acc = _acc(windows_h=(1.0,), buckets=12)  # 5-minute buckets
    t = 0.0
    for _ in range(60):  # 1 h ON
        t += TS
        acc.update(t, "on", False, NONE, NONE)
    assert _window(acc.report(), "1 h")["service_factor"] == 1.0
    for _ in range(30):  # 30 min WARM
        t += TS
        acc.update(t, "warm", False, NONE, NONE)
    rep = acc.report()
    assert _window(rep, "since start")["service_factor"] == pytest.approx(60 / 90)
    assert _window(rep, "1 h")["service_factor"] == pytest.approx(30 / 60)
    for _ in range(60):  # 1 h ON again: the WARM half hour has left the trailing hour
        t += TS
        acc.update(t, "on", False, NONE, NONE)
    rep = acc.report()
    one = _window(rep, "1 h")
    assert one["service_factor"] == 1.0
    assert 55 / 60 <= one["hours"] <= 1.0  # the last 11 full buckets and the current one
    assert _window(rep, "since start")["service_factor"] == pytest.approx(120 / 150)


def test_a_long_gap_is_down_time_and_a_plant_restart_is_not():
    acc = _acc(windows_h=(1.0,), buckets=12)
    for k in range(1, 11):
        acc.update(k * TS, "on", False, NONE, NONE)
    # no sample for 20 minutes (a controller restart): one period ON, the rest down
    acc.update(10 * TS + 20 * 60.0, "on", False, NONE, NONE)
    w = _window(acc.report(), "since start")
    assert w["time_share"]["down"] * w["hours"] == pytest.approx(19 / 60)
    assert w["service_factor"] * w["hours"] == pytest.approx(11 / 60)
    # two samples dropped under load (a gap of 3 periods): still ON
    acc.update(10 * TS + 20 * 60.0 + 3 * TS, "on", False, NONE, NONE)
    w = _window(acc.report(), "since start")
    assert w["service_factor"] * w["hours"] == pytest.approx(14 / 60)
    # a restarted plant counts its time from 0 again: one period, no gap
    acc.update(TS, "on", False, NONE, NONE)
    w2 = _window(acc.report(), "since start")
    assert w2["hours"] == pytest.approx(w["hours"] + 1 / 60)
    # a gap longer than the window leaves it all down
    acc.update(TS + 5 * 3600.0, "off", False, NONE, NONE)
    one = _window(acc.report(), "1 h")
    assert 55 / 60 <= one["hours"] <= 1.0
    assert one["time_share"]["off"] * one["hours"] == pytest.approx(1 / 60)
    assert one["time_share"]["down"] + one["time_share"]["off"] == pytest.approx(1.0)


def test_constraint_activity_is_the_share_of_samples_on_at_a_limit():
    acc = _acc()
    seq = ([True, False, False], [False, False, False]), \
          ([False, False, True], [True, False, False]), \
          ([False, False, False], [True, False, False]), \
          ([False, False, False], [False, False, False])
    for k, (lo, hi) in enumerate(seq, start=1):
        acc.update(k * TS, "on", False, lo, hi)
    # WARM samples and a sample without flags do not count, at a limit or not
    acc.update(5 * TS, "warm", False, [True] * 3, [False] * 3)
    acc.update(6 * TS, "on", True)
    w = _window(acc.report(), "since start")
    assert w["samples_on"] == 4
    p, lvl, v = (_activity(w, n) for n in ("P", "L", "V"))
    assert (p["at_lo"], p["at_hi"], p["active"]) == (0.25, 0.5, 0.75)
    assert (lvl["at_lo"], lvl["at_hi"], lvl["active"]) == (0.0, 0.0, 0.0)
    assert (v["at_lo"], v["at_hi"], v["kind"]) == (0.25, 0.0, "mv")


def test_activity_is_unknown_before_any_sample_on():
    acc = _acc()
    acc.update(TS, "warm", False, NONE, NONE)
    w = _window(acc.report(), "since start")
    assert w["service_factor"] == 0.0 and w["samples_on"] == 0
    assert _activity(w, "P")["active"] is None
    empty = _window(_acc().report(), "since start")
    assert empty["service_factor"] is None and empty["hours"] == 0.0


def test_cost_is_time_mean_against_the_base_case():
    acc = _acc()
    for k, c in enumerate([90.0, 90.0, 120.0, math.nan], start=1):
        acc.update(k * TS, "on", False, NONE, NONE, cost_usd_h=c)
    acc.update(5 * TS + 40 * 60.0, "on", False, NONE, NONE, cost_usd_h=60.0)  # after a gap
    rep = acc.report()
    cost = _window(rep, "since start")["cost"]
    # four costed samples of one period each (the gap's down time carries no cost)
    assert cost["mean_usd_h"] == pytest.approx((90 + 90 + 120 + 60) / 4)
    assert cost["base_usd_h"] == 100.0
    assert cost["vs_base_usd_h"] == pytest.approx(90.0 - 100.0)
    assert cost["hours"] == pytest.approx(4 / 60)
    assert rep["cost_now_usd_h"] == 60.0 and rep["base_cost_usd_h"] == 100.0
    none = KPIAccumulator(KPISettings(TS), VARS)
    none.update(TS, "on", False, NONE, NONE)
    c = _window(none.report(), "since start")["cost"]
    assert c == {"mean_usd_h": None, "base_usd_h": None, "vs_base_usd_h": None, "hours": 0.0}


def test_prediction_error_mean_per_model_skips_missing_values():
    acc = _acc()
    acc.update(TS, "on", False, NONE, NONE, prediction_rms=[1.0, math.nan], models=("a", "b"))
    acc.update(2 * TS, "on", False, NONE, NONE, prediction_rms=[3.0, 4.0], models=("a", "b"))
    acc.update(3 * TS, "off", False, NONE, NONE)  # off: nothing computed
    acc.update(4 * TS, "on", False, NONE, NONE, prediction_rms=[9.0], models=("c",))  # other
    rep = acc.report()
    assert _window(rep, "since start")["prediction_rms"] == {"a": 2.0, "b": 4.0}
    assert rep["prediction_rms_now"] == {"a": 3.0, "b": 4.0}


def test_checkpoint_and_restore_go_on_counting(tmp_path):
    acc = _acc(windows_h=(1.0, 24.0), buckets=24)
    t = 0.0
    for k in range(150):
        t += TS
        mode = "warm" if 40 <= k < 70 else "on"
        acc.update(t, mode, k == 100, [k % 3 == 0, False, False], [False, k % 5 == 0, False],
                   cost_usd_h=80.0 + k % 7, prediction_rms=[0.1 * (k % 4)], models=("m",))
    saved = json.loads(json.dumps(acc.checkpoint()))  # through JSON, as the store keeps it
    again = _acc(windows_h=(1.0, 24.0), buckets=24)
    again.restore(saved)
    assert again.report()["windows"] == acc.report()["windows"]
    for a in (acc, again):  # both go on the same way
        for k in range(150, 200):
            a.update((k + 1) * TS, "on", False, NONE, NONE, cost_usd_h=95.0,
                     prediction_rms=[0.2], models=("m",))
    assert again.report() == acc.report()
    assert again.report()["samples"] == 200


def test_restore_refuses_what_does_not_fit():
    acc = _acc()
    acc.update(TS, "on", False, NONE, NONE)
    cp = acc.checkpoint()
    other = KPIAccumulator(KPISettings(TS), [("P", "cv")])
    with pytest.raises(ValueError, match="other variables"):
        other.restore(cp)
    bad = json.loads(json.dumps(cp))
    bad["totals"] = [1.0] * 3
    with pytest.raises(ValueError, match="totals"):
        _acc().restore(bad)
    neg = json.loads(json.dumps(cp))
    neg["totals"] = [-1.0] * len(acc.totals)
    with pytest.raises(ValueError, match="totals"):
        _acc().restore(neg)
    # other windows: the totals go on, the trailing windows start afresh
    wider = _acc(windows_h=(2.0,), buckets=10)
    wider.restore(cp)
    rep = wider.report()
    assert _window(rep, "since start")["hours"] == pytest.approx(1 / 60)
    assert _window(rep, "2 h")["hours"] == 0.0


def test_bad_settings_and_input_are_refused():
    for kw, field in [({"sample_period_s": 0.0}, "sample_period_s"),
                      ({"sample_period_s": math.inf}, "sample_period_s"),
                      ({"sample_period_s": 1.0, "windows_h": (24.0, 1.0)}, "windows_h"),
                      ({"sample_period_s": 1.0, "windows_h": (-1.0,)}, "windows_h"),
                      ({"sample_period_s": 1.0, "buckets": 1}, "buckets"),
                      ({"sample_period_s": 1.0, "buckets": True}, "buckets"),
                      ({"sample_period_s": 1.0, "gap_samples": 0.5}, "gap_samples"),
                      ({"sample_period_s": 1.0, "base_cost_usd_h": math.nan}, "base_cost")]:
        with pytest.raises(ValueError, match=field):
            KPISettings(**kw)
    acc = _acc()
    with pytest.raises(ValueError, match="mode"):
        acc.update(TS, "auto", False)
    with pytest.raises(ValueError, match="t_s"):
        acc.update(math.nan, "on", False)


def test_updates_keep_no_samples():
    # a day of samples: the state is the same size as after one
    acc = _acc()
    acc.update(TS, "on", False, NONE, NONE)
    size = len(json.dumps(acc.checkpoint()))
    for k in range(2, 24 * 60 + 2):
        acc.update(k * TS, "on", False, NONE, NONE, cost_usd_h=100.0)
    assert abs(len(json.dumps(acc.checkpoint())) - size) < 64  # digits of the numbers


def test_vector_at_limit_flags_agree_with_the_status_rule():
    rng = np.random.default_rng(3)
    inf = math.inf
    lims = [(0.0, 100.0), (-inf, 2950.0), (10.0, inf), (-inf, inf), (0.0, 0.0), (-5.0, -1.0)]
    values, lo, hi = [], [], []
    for a, b in lims:
        for x in [a, b, a - 1, b + 1, 0.0, 0.3, 99.6, 2936.0, 2935.0, 10.04, 10.06, math.nan,
                  inf, *rng.uniform(-10, 3000, 5)]:
            values.append(x)
            lo.append(a)
            hi.append(b)
    at_lo, at_hi = at_limit_flags(values, lo, hi)
    for x, a, b, fl, fh in zip(values, lo, hi, at_lo, at_hi):
        want = at_limit(x, a, b)
        assert (want == "lo", want == "hi") == (bool(fl), bool(fh)), (x, a, b)


def test_text_view_fits_100_columns_and_lists_the_active_variables_first():
    from services.cli.kpis import TOP_VARIABLES, kpi_lines

    names = [(f"V{i:02d}_WITH_A_LONG_NAME", "cv") for i in range(20)]
    acc = KPIAccumulator(KPISettings(TS, base_cost_usd_h=170.6, base_cost_origin="o" * 200),
                         names)
    for k in range(1, 101):  # variable i at its high limit in i % 15 of 15 samples
        hi = [(k % 15) < (i % 15) for i in range(20)]
        acc.update(k * TS, "on", False, [False] * 20, hi, cost_usd_h=150.0,
                   prediction_rms=[1.0], models=("m" * 60,))
    doc = {"unit": "te", "sample": 100, **acc.report()}
    lines = kpi_lines(doc)
    assert max(len(ln) for ln in lines) <= 100
    rows = [ln for ln in lines if ln.startswith("V") and "_WITH" in ln]
    assert len(rows) == TOP_VARIABLES  # the most active; the rest named by a count
    # i = 14 is the most active: high but at k % 15 == 14, 6 of the 100 samples
    assert rows[0].startswith("V14_") and "0.0/94.0" in rows[0]
    assert rows[1].startswith("V13_")
    # 18 were ever at a limit (not i = 0 and 15)
    assert any(ln.startswith(f"({18 - TOP_VARIABLES} more at a limit") for ln in lines)
    assert any("-20.6" in ln for ln in lines)  # 150 $/h against 170.6: cheaper
    every = kpi_lines(doc, show_all=True)
    assert sum(ln.startswith("V") and "_WITH" in ln for ln in every) == 20
