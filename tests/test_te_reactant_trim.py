"""The TE reactant trim: A+C short in the reactor feed with the D feed at its limit raises
the A+C feed's target (through a grade change too), A+C in excess lowers it at a steady
grade only; the trim returns when the deficit or excess is gone, and does nothing
otherwise."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from controller.units.te.grades import grade
from controller.units.te.reactant_trim import ReactantTrim, ReactantTrimSettings
from controller.units.te.spec import D_FULL_KG_H


@pytest.mark.parametrize("kw, field", [({"d_limit": 100.0}, "d_limit"),
                                       ({"deadband": -1.0}, "deadband"),
                                       ({"gain": 0.0}, "gain"),
                                       ({"trim_max": 200.0}, "trim_max"),
                                       ({"settle_h": float("nan")}, "settle_h"),
                                       ({"raise_settle_h": -1.0}, "raise_settle_h"),
                                       ({"excess_max": -1.0}, "excess_max"),
                                       ({"excess_max": 101.0}, "excess_max"),
                                       ({"excess_deadband": -1.0}, "excess_deadband"),
                                       ({"settle_window_h": -1.0}, "settle_window_h"),
                                       ({"gain": True}, "gain")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        ReactantTrimSettings(**kw)


def _xmeas(d_pct: float, short: float) -> tuple[np.ndarray, np.ndarray]:
    ym = np.array(grade(3).xmeas, dtype=float)
    x = ym.copy()
    x[1] = d_pct / 100.0 * D_FULL_KG_H
    x[24] -= short                                   # C in the reactor feed short
    return x, ym


def _run(trim, x, ym, n, since=np.inf, hold_cut=False):
    for _ in range(n):
        out = trim.step(x, ym, since, hold_cut=hold_cut)
    return out


def test_a_short_feed_with_the_d_valve_at_its_limit_raises_the_target_then_it_returns():
    # raise only (no cut), so that the return ends at 0 with A+C in excess
    trim = ReactantTrim(ReactantTrimSettings(excess_max=0.0), sample_h=0.01)
    x, ym = _xmeas(97.0, 3.0)
    assert _run(trim, x, ym, 100) > 5.0              # one hour, 2 mol % beyond the deadband
    assert any("A+C feed target raised" in a for a in trim.alarms())
    again = ReactantTrim(sample_h=0.01)
    again.restore(json.loads(json.dumps(trim.checkpoint())))
    assert again.trim == trim.trim
    x, ym = _xmeas(90.0, -0.8)                       # A+C back above the plan's
    assert _run(trim, x, ym, 300) == 0.0
    assert trim.alarms() == []


@pytest.mark.parametrize("d_pct, short, since", [(80.0, 3.0, np.inf),   # D valve has room
                                                 (97.0, 0.5, np.inf),   # within the deadband
                                                 (80.0, 3.0, 5.0)])     # the same in a change
def test_nothing_is_done_otherwise(d_pct, short, since):
    trim = ReactantTrim(sample_h=0.01)
    x, ym = _xmeas(d_pct, short)
    assert _run(trim, x, ym, 200, since) == 0.0 and not trim.active


def test_the_raise_acts_through_a_grade_change_unless_told_to_wait():
    # a grade change 5 h ago, the D valve at its limit and C 3 mol % short: the raise
    # (2 mol % beyond the deadband, 5 %/(mol % h), 2 h: 20 % by hand) does not wait
    # for the steady grade the cut waits for
    x, ym = _xmeas(97.0, 3.0)
    trim = ReactantTrim(sample_h=0.01)
    assert _run(trim, x, ym, 200, 5.0) == pytest.approx(20.0, abs=1e-9)
    waiting = ReactantTrim(ReactantTrimSettings(raise_settle_h=24.0), sample_h=0.01)
    assert _run(waiting, x, ym, 200, 5.0) == 0.0 and not waiting.active
    assert _run(waiting, x, ym, 200, 24.0) > 0.0


def test_no_cut_through_a_grade_change():
    x, ym = _xmeas(60.0, -5.0)                       # A+C in excess, a change 5 h ago
    trim = ReactantTrim(sample_h=0.01)
    assert _run(trim, x, ym, 200, 5.0) == 0.0


def _settled(excess_max=None):
    """A trim whose grade settled with A+C at its reference (its settling hour)."""
    settings = (ReactantTrimSettings() if excess_max is None
                else ReactantTrimSettings(excess_max=excess_max))
    trim = ReactantTrim(settings, sample_h=0.01)
    _run(trim, *_xmeas(60.0, 0.0), 100)              # its settling window, 1 h
    return trim


def test_an_excess_lowers_the_target_then_it_returns():
    trim = _settled()
    x, ym = _xmeas(60.0, -1.0)                       # 1 mol % too much A+C, D has room
    # one hour, 0.9 mol % beyond the cut's 0.1 mol % deadband at 5 %/(mol % h): 4.5 %
    # by hand
    assert _run(trim, x, ym, 100) == pytest.approx(-4.5, abs=1e-9)
    assert any("A+C feed target lowered" in a for a in trim.alarms())
    assert _run(trim, x, ym, 200) == -6.0            # at its limit, excess_max
    x, ym = _xmeas(60.0, 2.0)                        # short again, D has room
    assert _run(trim, x, ym, 300) == 0.0             # back to 0, not past it
    assert trim.alarms() == []


def test_a_grade_that_settles_with_an_excess_is_cut_only_for_more():
    # the grade became steady with 3 mol % of A+C above the plan's (the plant's own
    # steady state): no cut for that, nor within the 0.1 mol % deadband beyond it;
    # 0.5 mol % more than that is cut (0.4 beyond the deadband, 5 %/(mol % h), 1 h)
    trim = ReactantTrim(sample_h=0.01)
    assert _run(trim, *_xmeas(60.0, -3.0), 200) == 0.0
    assert _run(trim, *_xmeas(60.0, -3.08), 200) == 0.0
    assert _run(trim, *_xmeas(60.0, -3.5), 100) == pytest.approx(-2.0, abs=1e-9)
    # a grade change forgets the settled excess and ends the cut
    assert _run(trim, *_xmeas(60.0, -3.5), 1, since=5.0) == 0.0
    assert trim.checkpoint()["settled"] is None and trim.alarms() == []


@pytest.mark.parametrize("since, hold_cut, excess_max",
                         [(5.0, False, 15.0),        # a grade change 5 h ago
                          (np.inf, True, 15.0),      # held (the A feed lost)
                          (np.inf, False, 0.0)])     # no cut in the settings
def test_no_cut_otherwise(since, hold_cut, excess_max):
    trim = _settled(excess_max)
    x, ym = _xmeas(60.0, -3.0)
    assert _run(trim, x, ym, 200, since, hold_cut) == 0.0 and not trim.active


def test_a_held_cut_stands_and_a_restored_trim_goes_on():
    trim = _settled()
    x, ym = _xmeas(60.0, -1.0)
    cut = _run(trim, x, ym, 50)
    assert _run(trim, x, ym, 100, hold_cut=True) == cut < 0.0
    again = ReactantTrim(sample_h=0.01)
    again.restore(json.loads(json.dumps(trim.checkpoint())))
    assert _run(again, x, ym, 10) == _run(trim, x, ym, 10) < cut


#: What a controller's start holds: no trim, no settled excess, the window empty.
FRESH = {"trim": 0.0, "settled": None, "window_sum": 0.0, "window_n": 0}


@pytest.mark.parametrize("damage", [
    {"trim": "-1.2"}, {"trim": math.nan}, {"trim": 31.0}, {"trim": -6.5}, {"trim": True},
    {"settled": "x"}, {"settled": math.inf}, {"window_sum": None}, {"window_n": -1},
    {"window_n": 2.5}, {"window_n": False}, "not a checkpoint", [1, 2]])
def test_a_damaged_checkpoint_starts_the_trim_again(damage):
    # a cut in force with its settled excess: one field damaged (or the whole state not
    # a mapping) and the trim starts again as a controller's start does, not half read
    trim = _settled()
    x, ym = _xmeas(60.0, -1.0)
    assert _run(trim, x, ym, 50) < 0.0
    state = ({**json.loads(json.dumps(trim.checkpoint())), **damage}
             if isinstance(damage, dict) else damage)
    again = ReactantTrim(sample_h=0.01)
    again.restore(state)
    assert again.checkpoint() == FRESH and not again.active
    assert _run(again, x, ym, 10) == 0.0  # goes on: no cut within the settling hour


def test_a_checkpoint_without_the_window_restores_the_trim():
    # a checkpoint written before the settling window was kept (trim and settled only)
    again = ReactantTrim(sample_h=0.01)
    again.restore({"trim": -1.5, "settled": -1.0})
    assert again.checkpoint() == {"trim": -1.5, "settled": -1.0, "window_sum": 0.0,
                                  "window_n": 0}


@pytest.mark.timeout(300)
def test_under_idv1_the_cut_keeps_c_from_gathering():
    # IDV(1) from 2 h at mode 0, noise off, 16 h: the A loop raises the A feed, and
    # without the cut C in the reactor feed settled 6.5 mol % above its reference
    # (32.9 against 26.4) with the purge at 79 % over 12-16 h (measured); the cut
    # brings C back toward it and the purge down
    from controller.units.te.control import run_te
    from controller.units.te.grades import TransitionPlan

    run = run_te("ssmpc", TransitionPlan("mode0"), 16.0, idv={1: 2.0})
    assert run.shutdown is None
    assert any("A+C feed target lowered" in a for a in run.alarms)
    late = run.t > 12.0
    c_ref = grade("mode0").xmeas[24]
    assert run.xmeas[late, 24].mean() - c_ref < 4.5      # measured 3.1 mol %
    assert run.xmv[late, 5].mean() < 70.0                # purge, measured 60 %


def test_the_settled_excess_is_the_mean_of_the_settling_hour_and_no_cut_acts_within_it():
    # A+C 1 mol % above the plan's, with +-0.3 mol % of noise on it: no cut in the first
    # hour however far a sample strays, then the hour's mean (-1.0) is the settled
    # excess, and the same noise (within 0.1 + 0.3 of it) cuts only while beyond the
    # deadband: -1.4 mol % for 0.1 h is 0.3 beyond it at 5 %/(mol % h), 0.15 % by hand
    trim = ReactantTrim(sample_h=0.01)
    for k in range(100):
        assert _run(trim, *_xmeas(60.0, -1.0 + (0.3 if k % 2 else -0.3)), 1) == 0.0
    assert trim.checkpoint()["settled"] == pytest.approx(-1.0)
    assert _run(trim, *_xmeas(60.0, -1.05), 50) == 0.0
    assert _run(trim, *_xmeas(60.0, -1.4), 10) == pytest.approx(-0.15, abs=1e-9)
    # a restored trim keeps a window under way
    half = ReactantTrim(sample_h=0.01)
    _run(half, *_xmeas(60.0, -2.0), 50)
    again = ReactantTrim(sample_h=0.01)
    again.restore(json.loads(json.dumps(half.checkpoint())))
    _run(again, *_xmeas(60.0, 0.0), 50)
    assert again.checkpoint()["settled"] == pytest.approx(-1.0)
