"""The reactor-feed balance (controller.units.te.feed_balance): its law on given
measurements, its ramp and hold, its settings, its restart, and what it does on the
plant (IDV(20) at mode 0, noise off: the A + C swings of the reactor feed and G's with
them smaller than without it)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from controller.units.te.feed_balance import ReactorFeedBalance, ReactorFeedBalanceSettings

SAMPLE_H = 0.01
#: Round-off allowed on a trim computed by hand from the law, % of the valve.
TRIM_ATOL = 1e-12
#: The first-order washout without the measurement filter (the law computed by hand).
FIRST_ORDER = dict(order=1, filter_h=0.0)


def _xmeas(a, c):
    x = np.full(41, 50.0)
    x[22], x[24] = a, c
    return x


def test_an_operator_hold_keeps_the_trim_and_it_goes_on_from_there():
    # the operator holds the outer loops (warm) while A + C rises by 2 mol %: the trim
    # stays where it was; after the hold the first trim is that one washed by one sample,
    # not the stale lag's -gain x 2 mol %
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=0.0, ramp_h=0.01,
                                   **FIRST_ORDER)
    a = SAMPLE_H / (1.0 + SAMPLE_H)
    for release in ("hold", "take_over"):
        fb = ReactorFeedBalance(s, SAMPLE_H)
        fb.update(_xmeas(30.0, 10.0), math.inf)
        before = fb.update(_xmeas(30.5, 10.5), math.inf)
        assert before == pytest.approx(-4.0 * (1.0 - a), abs=TRIM_ATOL)
        if release == "hold":
            held = [fb.update(_xmeas(31.5, 11.5), math.inf, frozen=True) for _ in range(20)]
            assert held == [before] * 20
        else:  # off: nothing computed meanwhile, then a take-over of the running plant
            fb.take_over()
        first = fb.update(_xmeas(31.5, 11.5), math.inf)
        assert first == pytest.approx(before * (1.0 - a), abs=TRIM_ATOL)
        assert abs(first - before) < 0.05


def test_a_take_over_before_the_trim_came_in_starts_the_lag_afresh():
    # a controller off for a while before the trim's share came in, while A + C moved by
    # 5 mol %: after the take-over the lag starts on the measurement, so the trim ramps
    # in on nothing instead of on the outage's 5 mol % (which would be -20 % of the
    # valve, bounded at 10)
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=24.0, ramp_h=0.25,
                                   filter_h=0.0)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    for _ in range(10):
        assert fb.update(_xmeas(30.0, 10.0), 1.0) == 0.0
    fb.take_over()
    trims = [fb.update(_xmeas(33.0, 12.0), 30.0) for _ in range(100)]
    assert fb.share == 1.0
    assert max(abs(t) for t in trims) < 1e-9


def test_a_step_of_a_plus_c_is_met_by_its_washed_out_share_with_the_opposite_sign():
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=0.0, ramp_h=0.01,
                                   **FIRST_ORDER)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    assert fb.update(_xmeas(30.0, 10.0), math.inf) == 0.0  # the lag starts on the value
    # A + C up by 1 mol %: the lag moves by a = Ts / (T + Ts) of it, the trim is
    # -gain (1 - a) (full share after one ramp of 0.01 h)
    a = SAMPLE_H / (1.0 + SAMPLE_H)
    trim = fb.update(_xmeas(30.5, 10.5), math.inf)
    assert trim == pytest.approx(-4.0 * (1.0 - a), abs=TRIM_ATOL)
    # held there, the trim washes out toward 0 and never changes sign
    trims = [fb.update(_xmeas(30.5, 10.5), math.inf) for _ in range(600)]
    assert all(t < 0 for t in trims) and abs(trims[-1]) < 0.02  # 4 e^-6 after 6 h
    assert np.all(np.diff(trims) > 0)


def _ramp_trims(order: float, rate: float, hours: float, **kw) -> list[float]:
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=0.0, ramp_h=0.01,
                                   order=order, **kw)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    return [fb.update(_xmeas(30.0 + rate * k * SAMPLE_H, 10.0), math.inf)
            for k in range(int(round(hours / SAMPLE_H)))]


def test_the_second_order_washout_passes_no_ramp_where_the_first_order_one_does():
    # a plant still settling after a grade change: A + C falls at 0.35 mol %/h (the
    # reactor feed 20-30 h into 3 -> 0). A first-order lag trails a ramp by
    # rate x washout_h, so its trim settles at gain x 0.35 x 1 = 1.4 % of the valve and
    # holds the A+C feed off its target; the lag that tracks the trend as well trails
    # it by nothing, and its trim dies out
    first = _ramp_trims(1, -0.35, 12.0, filter_h=0.0)
    second = _ramp_trims(2, -0.35, 12.0, filter_h=0.0)
    assert first[-1] == pytest.approx(4.0 * 0.35 * 1.0, rel=0.02)
    assert abs(second[-1]) < 1e-3
    # the filter before the washout does not change that
    assert abs(_ramp_trims(2, -0.35, 12.0, filter_h=0.1)[-1]) < 1e-3


def test_the_second_order_washout_meets_a_step_at_once():
    # one sample after a 1 mol % step the lag has moved by 2 w dt of it (w = 1 /
    # washout_h), so the trim is -gain (1 - 2 w dt); it then washes out, crossing zero
    # once (critically damped: the lag's trend overshoots the step and comes back)
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=0.0, ramp_h=0.01,
                                   order=2, filter_h=0.0)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    fb.update(_xmeas(30.0, 10.0), math.inf)
    first = fb.update(_xmeas(30.5, 10.5), math.inf)
    assert first == pytest.approx(-4.0 * (1.0 - 2.0 * SAMPLE_H), abs=TRIM_ATOL)
    trims = np.array([fb.update(_xmeas(30.5, 10.5), math.inf) for _ in range(1200)])
    assert np.count_nonzero(np.diff(np.sign(trims))) == 1
    assert abs(trims[-1]) < 0.05


def test_the_filter_keeps_the_analyzers_noise_off_the_valve():
    # white noise of 0.3 mol % on A + C held for the analyzer's 0.1 h: with the 0.1 h
    # filter the trim varies little more than half as much as without it (0.54 against
    # 0.98 % of the valve on this stream)
    rng = np.random.default_rng(7)
    held = np.repeat(rng.normal(0.0, 0.3, 100), 10)
    spread = {}
    for filter_h in (0.0, 0.1):
        s = ReactorFeedBalanceSettings(after_h=0.0, ramp_h=0.01, filter_h=filter_h)
        fb = ReactorFeedBalance(s, SAMPLE_H)
        spread[filter_h] = np.std([fb.update(_xmeas(30.0 + n, 10.0), math.inf)
                                   for n in held])
    assert spread[0.1] < 0.6 * spread[0.0]


def test_the_trim_comes_in_after_a_grade_change_and_goes_while_held():
    s = ReactorFeedBalanceSettings(gain=4.0, washout_h=1.0, after_h=24.0, ramp_h=0.25)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    fb.update(_xmeas(30.0, 10.0), 0.0)
    assert fb.update(_xmeas(31.0, 10.0), 10.0) == 0.0 and fb.share == 0.0  # too soon
    shares = []
    for _ in range(30):
        fb.update(_xmeas(31.0, 10.0), 30.0)
        shares.append(fb.share)
    assert shares[0] == pytest.approx(0.04) and shares[-1] == 1.0  # 0.25 h ramp
    for _ in range(10):
        fb.update(_xmeas(31.0, 10.0), 30.0, held=True)
    assert fb.share == pytest.approx(0.6)


def test_a_measurement_that_is_no_number_leaves_lag_and_trim_as_they_were():
    fb = ReactorFeedBalance(ReactorFeedBalanceSettings(after_h=0.0, ramp_h=0.01), SAMPLE_H)
    fb.update(_xmeas(30.0, 10.0), math.inf)
    trim = fb.update(_xmeas(31.0, 10.0), math.inf)
    lag = fb.lag
    assert fb.update(_xmeas(math.nan, 10.0), math.inf) == trim and fb.lag == lag


def test_the_trim_is_bounded():
    s = ReactorFeedBalanceSettings(gain=4.0, after_h=0.0, ramp_h=0.01, trim_max=3.0,
                                   filter_h=0.0)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    fb.update(_xmeas(30.0, 10.0), math.inf)
    assert fb.update(_xmeas(40.0, 10.0), math.inf) == -3.0
    assert fb.update(_xmeas(20.0, 10.0), math.inf) == 3.0


@pytest.mark.parametrize("field, value", [("gain", 0.0), ("gain", math.nan),
                                          ("washout_h", -1.0), ("after_h", -0.5),
                                          ("ramp_h", 0.0), ("trim_max", math.inf),
                                          ("gain", True), ("order", 3),
                                          ("filter_h", -0.1)])
def test_settings_out_of_range_are_refused_naming_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        ReactorFeedBalanceSettings(**{field: value})


def test_a_washout_of_under_two_samples_is_refused():
    # the second-order lag's Euler steps diverge for washout_h under 1.21 samples
    with pytest.raises(ValueError, match="washout_h"):
        ReactorFeedBalance(ReactorFeedBalanceSettings(washout_h=0.015), SAMPLE_H)
    with pytest.raises(ValueError, match="order"):
        ReactorFeedBalanceSettings(order=True)
    ReactorFeedBalance(ReactorFeedBalanceSettings(washout_h=0.02), SAMPLE_H)


def test_a_restart_goes_on_as_before_and_a_damaged_state_starts_afresh():
    s = ReactorFeedBalanceSettings(after_h=0.0, ramp_h=0.1)
    fb = ReactorFeedBalance(s, SAMPLE_H)
    rng = np.random.default_rng(3)
    for _ in range(20):
        fb.update(_xmeas(30 + rng.normal(), 10 + rng.normal()), math.inf)
    again = ReactorFeedBalance(s, SAMPLE_H)
    again.restore(json.loads(json.dumps(fb.checkpoint())))
    for _ in range(20):
        x = _xmeas(30 + rng.normal(), 10 + rng.normal())
        assert again.update(x, math.inf) == fb.update(x, math.inf)
    for bad in ("x", [1], {"share": 2.0, "lag": 1.0, "trim": 0.0},
                {"share": 0.5, "lag": 1.0, "trend": math.nan, "trim": 0.0},
                {"share": 0.5, "lag": "x", "trim": 0.0},
                {"share": 0.5, "lag": 1.0, "trim": 99.0}):
        fresh = ReactorFeedBalance(s, SAMPLE_H)
        fresh.restore(bad)
        assert (fresh.share, fresh.lag, fresh.trim) == (0.0, None, 0.0)


def test_on_the_plant_it_steadies_the_reactor_feed_and_g_under_idv20():
    """IDV(20) at mode 0, noise off, 24 h (seed 1's plant stream): with the balance on,
    the half-hour means of A + C in the reactor feed and of G vary less than with it
    off (measured over hours 4-24: A + C 0.69 -> 0.33 mol %, G 0.20 -> 0.14)."""
    from controller.units.te.control import plant_seed_for, run_te
    from controller.units.te.grades import TransitionPlan

    def half_hour_std(r, x):
        return float(np.std([x[(r.t >= h) & (r.t < h + 0.5)].mean()
                             for h in np.arange(4.0, 24.0, 0.5)]))

    out = {}
    for on in (False, True):
        r = run_te("ssmpc", TransitionPlan("mode0"), 24.0, idv={20: 2.0}, seed=1,
                   plant_seed=plant_seed_for(1), feed_balance=on)
        assert r.shutdown is None
        out[on] = (half_hour_std(r, r.xmeas[:, 22] + r.xmeas[:, 24]),
                   half_hour_std(r, r.xmeas[:, 39]))
    assert out[True][0] < 0.6 * out[False][0]
    assert out[True][1] < 0.85 * out[False][1]
