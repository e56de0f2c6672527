"""The G loop on the E/D feed ratio: its settings, and the MPC strategies' tuning (half
the gain, twice the integral time; through a grade change only near the new grade's G)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.units.te.control import (
    RATIO_MPC,
    RATIO_PATH_WINDOW_MOL,
    RATIO_STEADY_AFTER_H,
    RatioSettings,
    make_te_controller,
)
from controller.units.te.grades import Leg, TransitionPlan, grade


@pytest.mark.parametrize("kw, field", [({"gain": -0.1}, "gain"),
                                       ({"ti_h": 0.0}, "ti_h"),
                                       ({"steady_gain": -0.001}, "steady_gain"),
                                       ({"steady_gain": float("nan")}, "steady_gain"),
                                       ({"steady_ti_h": 0.0}, "steady_ti_h"),
                                       ({"steady_ti_h": float("inf")}, "steady_ti_h"),
                                       ({"s_min": 0.5, "s_max": 0.4}, "s_min/s_max")])
def test_bad_ratio_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        RatioSettings(**kw)


def test_the_tuning_in_force():
    r = RatioSettings(gain=0.004, ti_h=1.0, steady_gain=0.002, steady_ti_h=2.0)
    assert r.tuning(False) == (0.004, 1.0)
    assert r.tuning(True) == (0.002, 2.0)
    assert RatioSettings().tuning(True) == RatioSettings().tuning(False)  # none given


def _d_share_moved(strategy: str, plan: TransitionPlan, t0: float, n: int = 10,
                   **options) -> float:
    """How far the G loop moves the D share in ``n`` samples from ``t0`` with G in
    product (XMEAS 40) 2 mol % under the plan's: the D share with that error less the
    D share without it (the plan's feedforward cancels)."""
    shares = []
    for error in (2.0, 0.0):
        ctl, _ = make_te_controller(strategy, plan, **options)
        x = np.array(grade(plan.start).xmeas, dtype=float)
        x[39] -= error
        for k in range(n):
            dec = ctl.step(k, t0 + k * ctl.sample_h, x, None)
            ctl.finish_sample()
        shares.append(float(dec.extra["d_share"]))
    return shares[0] - shares[1]


def test_the_mpc_strategies_use_the_steady_grade_tuning():
    assert make_te_controller("ssmpc")[0].ratio == RATIO_MPC
    assert make_te_controller("fixed")[0].ratio == RATIO_MPC
    for baseline in ("pi", "plan"):
        assert make_te_controller(baseline)[0].ratio == RatioSettings()


def test_at_a_steady_grade_the_g_loop_of_the_mpc_strategies_acts_more_gently():
    # G under its reference: more D share (more G). A constant error gives no
    # proportional step (the first sample is its own previous error) and 10 samples of
    # integral action: 10 x gain x 0.01 h / ti x 2 mol %
    steady = _d_share_moved("fixed", TransitionPlan("mode0"), 2.0)
    assert steady == pytest.approx(10 * 0.002 * 0.01 / 2.0 * 2.0, rel=0.05)
    change = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    after = _d_share_moved("fixed", change, 1.0 + RATIO_STEADY_AFTER_H + 0.5)
    assert after == pytest.approx(steady, rel=0.05)
    # the baselines keep one tuning, the grade-change one, throughout
    assert _d_share_moved("pi", TransitionPlan("mode0"), 2.0) == pytest.approx(
        10 * 0.004 * 0.01 / 1.0 * 2.0, rel=0.05)
    assert _d_share_moved("plan", change, 2.0) == pytest.approx(
        10 * 0.004 * 0.01 / 1.0 * 2.0, rel=0.05)


def test_through_a_grade_change_the_mpc_strategies_g_loop_waits_until_g_is_near_the_grade():
    # modes 0 and 1 make G at 53.8 and 53.9 mol %: 2 mol % under it is inside the
    # window, and the loop acts on it with its steady-grade tuning (the D-share path
    # alone: with the composition core that leg's share is the core's)
    change = TransitionPlan("mode0", (Leg(1.0, "mode1"),))
    g0, g1 = grade("mode0").g_mol, grade("mode1").g_mol
    assert abs(g1 - g0) < 0.5
    near = _d_share_moved("ssmpc", change, 2.0, composition=False)
    assert near == pytest.approx(10 * 0.002 * 0.01 / 2.0 * 2.0, rel=0.05)
    # 0 -> 2 (G 53.8 -> 11.7 mol %): G still at mode 0's is far from mode 2's, no move
    far = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    assert abs(grade("mode2").g_mol - g0) > RATIO_PATH_WINDOW_MOL
    assert _d_share_moved("ssmpc", far, 2.0) == 0.0
