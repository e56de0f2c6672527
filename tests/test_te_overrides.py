"""The TE feed overrides: a short A+C feed made up by its valve, a lost A feed reported
with the A-in-feed trim held, and nothing done while the feeds deliver what their
valves ask."""

from __future__ import annotations

import json

import numpy as np
import pytest

from controller.units.te.control import make_te_controller
from controller.units.te.grades import TransitionPlan, grade
from controller.units.te.overrides import (
    A_FULL_KSCMH,
    AC_FULL_KSCMH,
    FeedOverrides,
    FeedOverrideSettings,
)


@pytest.mark.parametrize("kw, field", [({"filter_h": 0.0}, "filter_h"),
                                       ({"min_valve": 100.0}, "min_valve"),
                                       ({"lost_ratio": 0.7}, "lost_ratio/restored_ratio"),
                                       ({"short_ratio": 0.96}, "short_ratio/short_release"),
                                       ({"short_release": float("nan")}, "short_release"),
                                       ({"lost_ratio": True}, "lost_ratio")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        FeedOverrideSettings(**kw)


def _feed(x, u, share_a=1.0, share_ac=1.0):
    """XMEAS ``x`` with the A and A+C feeds delivering these shares of valves ``u``."""
    x = x.copy()
    x[0] = share_a * u[2] / 100.0 * A_FULL_KSCMH
    x[3] = share_ac * u[3] / 100.0 * AC_FULL_KSCMH
    return x


def _run(ctl, x0, n, k0=0, **shares):
    u = ctl.step(k0, k0 * ctl.sample_h, x0, None).u
    ctl.finish_sample()
    for k in range(k0 + 1, k0 + n):
        dec = ctl.step(k, k * ctl.sample_h, _feed(x0, u, **shares), None)
        ctl.finish_sample()
        u = dec.u
    return dec


def test_a_short_ac_feed_is_made_up_by_its_valve_and_released_when_it_delivers_again():
    x0 = np.array(grade(3).xmeas, dtype=float)
    plan_valve = float(grade(3).xmv[3])
    ctl, _ = make_te_controller("plan", TransitionPlan("mode3"))
    dec = _run(ctl, x0, 40, share_ac=0.8)          # a C header at 80 %
    assert dec.u[3] == pytest.approx(plan_valve / 0.8, rel=0.01)
    assert any("A+C feed delivers 80 %" in a for a in dec.alarms)
    # the header back: the valve returns to the plan's and the alarm clears
    dec = _run(ctl, x0, 40, k0=40)
    assert dec.u[3] == plan_valve
    assert not any("A+C feed" in a for a in dec.alarms)
    # the state goes through a checkpoint
    _run(ctl, x0, 40, k0=80, share_ac=0.8)
    again, _ = make_te_controller("plan", TransitionPlan("mode3"))
    again.restore(json.loads(json.dumps(ctl.checkpoint())))
    assert again.feeds.ac_short and again.feeds.r_ac == pytest.approx(0.8, abs=0.01)


def test_healthy_feeds_with_measurement_noise_change_nothing():
    rng = np.random.default_rng(3)
    x0 = np.array(grade(0).xmeas, dtype=float)
    ctl, _ = make_te_controller("plan", TransitionPlan("mode0"))
    bare, _ = make_te_controller("plan", TransitionPlan("mode0"))
    u = ctl.step(0, 0.0, x0, None).u
    bare.step(0, 0.0, x0, None)
    for k in range(1, 200):
        x = _feed(x0, u)
        x[0] += rng.normal() * 0.0012     # the plant's noise on XMEAS 1 and 4
        x[3] += rng.normal() * 0.05
        dec = ctl.step(k, k * 0.01, x, None)
        ref = bare.step(k, k * 0.01, x, None)
        assert not ctl.feeds.active
        np.testing.assert_array_equal(dec.u, ref.u)
        u = dec.u


def test_a_lost_a_feed_raises_the_alarm_and_holds_the_a_trim():
    x0 = np.array(grade(0).xmeas, dtype=float)
    x0[22] -= 3.0                                    # A in the reactor feed below its reference
    trims = {}
    for share in (1.0, 0.0):
        ctl, _ = make_te_controller("ssmpc", TransitionPlan("mode0"))
        dec = _run(ctl, x0, 30, share_a=share)
        trims[share] = ctl.a_trim
        lost = [a for a in dec.alarms if a.startswith("A feed lost")]
        assert bool(lost) == (share == 0.0)
    assert trims[1.0] > 1.0                          # the loop opens the A valve
    assert abs(trims[0.0]) < 0.05 * trims[1.0]       # held (but the first samples' share)


def test_no_share_is_formed_for_a_nearly_shut_valve():
    f = FeedOverrides(sample_h=0.01)
    f.applied(1.0, 1.0)                              # below min_valve: no meaning in a share
    f.observe(np.zeros(41))
    assert f.r_a is None and f.r_ac is None and not f.active
