"""The MPC strategies' own D-share path through a TE grade change
(:mod:`controller.units.te.d_share_path`): its steps worked by hand, its waits, its
lead, its settings and its checkpoint."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import make_te_controller
from controller.units.te.d_share_path import DSharePath, DSharePathSettings
from controller.units.te.grades import Leg, TransitionPlan, grade
from controller.units.te.spec import D_FULL_KG_H

DT = 0.01  # h, the supervisory sample
FREE = dict(hold=0.0, d_feed_kg_h=3000.0, level_pct=65.0, level_sp_pct=65.0)


def test_first_order_steps_toward_the_grade_slower_upward():
    p = DSharePath(DSharePathSettings(tau_h=1.0, tau_rise_h=2.0, lead=0.0), DT)
    p.start(0.5)
    assert p.step(0.3, **FREE) == pytest.approx(0.5 - 0.2 * (1 - math.exp(-0.01)), abs=1e-15)
    p.start(0.5)
    assert p.step(0.7, **FREE) == pytest.approx(0.5 + 0.2 * (1 - math.exp(-0.005)), abs=1e-15)
    # 300 samples (3 h = 3 tau) from 0.5 toward 0.3: 95 % of the way
    p.start(0.5)
    for _ in range(300):
        v = p.step(0.3, **FREE)
    assert v == pytest.approx(0.3 + 0.2 * math.exp(-3.0), rel=1e-9)


def test_the_plan_hold_slows_the_path_in_its_share():
    p = DSharePath(DSharePathSettings(), DT)
    p.start(0.5)
    full = 0.5 - p.step(0.3, **FREE)
    p.start(0.5)
    half = 0.5 - p.step(0.3, **{**FREE, "hold": 0.5})
    assert half == pytest.approx(0.5 * full, rel=1e-12)
    p.start(0.5)
    assert p.step(0.3, **{**FREE, "hold": 1.0}) == 0.5


def test_a_rise_waits_while_the_d_feed_is_at_its_limit_and_the_level_falls():
    p = DSharePath(DSharePathSettings(d_feed_high=0.95, level_low_pct=2.0), DT)
    short = {**FREE, "d_feed_kg_h": 0.96 * D_FULL_KG_H, "level_pct": 60.0}
    p.start(0.5)
    assert p.step(0.8, **short) == 0.5 and p.waiting
    # a fall of the D share (more E) does not wait: it gives the level more liquid
    assert p.step(0.2, **short) < 0.5 and not p.waiting
    # the level within 2 % of its set point, or the D feed below 95 %: no wait
    p.start(0.5)
    assert p.step(0.8, **{**short, "level_pct": 63.5}) > 0.5
    p.start(0.5)
    assert p.step(0.8, **{**short, "d_feed_kg_h": 0.9 * D_FULL_KG_H}) > 0.5
    # a measurement that is not finite does not make it wait
    p.start(0.5)
    assert p.step(0.8, **{**short, "level_pct": float("nan")}) > 0.5


def _changed(settings, s_from=0.5, s_to=0.3, g_from=50.0, g_to=10.0,
             limits=(0.03, 0.97)):
    """A path at ``s_from`` (grade with G ``g_from``) and the first sample after a
    change to the grade (``s_to``, ``g_to``); returns the path and that sample's share."""
    p = DSharePath(settings, DT, limits)
    p.step(s_from, **FREE, g_mol=g_from, g_grade_mol=g_from)
    return p, p.step(s_to, **FREE, g_mol=g_from, g_grade_mol=g_to)


def test_the_lead_aims_beyond_the_grade_until_g_has_covered_its_share_of_the_way():
    a = 1 - math.exp(-DT / 1.0)  # toward less D share: tau_h
    p, v = _changed(DSharePathSettings(tau_h=1.0, lead=0.5, lead_until=0.9,
                                       lead_until_fall=0.3))
    # aim 0.3 + 0.5 (0.3 - 0.5) = 0.2
    assert v == pytest.approx(0.5 + a * (0.2 - 0.5), abs=1e-15)
    # G 29 % of the way from 50 to 10 mol %: the lead goes on
    v2 = p.step(0.3, **FREE, g_mol=50.0 - 0.29 * 40.0, g_grade_mol=10.0)
    assert v2 == pytest.approx(v + a * (0.2 - v), abs=1e-15)
    # 30 %: it ends, for good (G going back does not start it again)
    v3 = p.step(0.3, **FREE, g_mol=50.0 - 0.30 * 40.0, g_grade_mol=10.0)
    assert v3 == pytest.approx(v2 + a * (0.3 - v2), abs=1e-15)
    v4 = p.step(0.3, **FREE, g_mol=50.0, g_grade_mol=10.0)
    assert v4 == pytest.approx(v3 + a * (0.3 - v3), abs=1e-15)


@pytest.mark.parametrize("s_to, g_to", [(0.3, 10.0), (0.7, 90.0)])
def test_the_lead_ends_later_toward_a_lower_d_share(s_to, g_to):
    # the default ends: 30 % of G's way toward more D share, 50 % toward less
    st = DSharePathSettings()
    assert (st.lead_until, st.lead_until_fall) == (0.3, 0.5)
    falling = s_to < 0.5
    p, _ = _changed(st, 0.5, s_to, 50.0, g_to)
    for covered in (0.29, 0.35, 0.45, 0.49):
        p.step(s_to, **FREE, g_mol=50.0 + covered * (g_to - 50.0), g_grade_mol=g_to)
        assert (p.lead is not None) == (falling or covered < 0.3), covered
    p.step(s_to, **FREE, g_mol=50.0 + 0.5 * (g_to - 50.0), g_grade_mol=g_to)
    assert p.lead is None


def test_the_lead_stays_within_the_share_limits_and_ends_at_its_longest():
    b = 1 - math.exp(-DT / 1.5)  # toward more D share: tau_rise_h
    # 0.5 -> 0.9: the aim 0.9 + 0.5 x 0.4 = 1.1 is cut to the limit 0.97
    p, v = _changed(DSharePathSettings(lead=0.5, lead_max_h=0.05), 0.5, 0.9, 50.0, 90.0)
    assert v == pytest.approx(0.5 + b * (0.97 - 0.5), abs=1e-15)
    # G not finite (the analyzer out): the lead goes on to lead_max_h (5 samples)
    vals = [p.step(0.9, **FREE, g_mol=math.nan, g_grade_mol=90.0) for _ in range(6)]
    prev = v
    for i, x in enumerate(vals):
        aim = 0.97 if i < 4 else 0.9
        assert x == pytest.approx(prev + b * (aim - prev), abs=1e-15)
        prev = x


@pytest.mark.parametrize("g_at_change", [math.nan, 10.0])
def test_no_lead_without_g_at_the_change_or_with_a_grade_of_the_same_g(g_at_change):
    a = 1 - math.exp(-DT / 1.0)
    p = DSharePath(DSharePathSettings(lead=0.5), DT, (0.03, 0.97))
    p.step(0.5, **FREE, g_mol=10.0, g_grade_mol=10.0)
    v = p.step(0.3, **FREE, g_mol=g_at_change, g_grade_mol=10.0)
    assert v == pytest.approx(0.5 + a * (0.3 - 0.5), abs=1e-15)
    assert p.lead is None


def test_a_restored_path_goes_on_with_its_lead():
    p, _ = _changed(DSharePathSettings())
    q = DSharePath(DSharePathSettings(), DT, (0.03, 0.97))
    q.restore(p.checkpoint())
    steps = dict(**FREE, g_mol=45.0, g_grade_mol=10.0)
    assert [q.step(0.3, **steps) for _ in range(5)] == [p.step(0.3, **steps) for _ in range(5)]
    assert q.lead == p.lead and q.lead is not None
    # a checkpoint written before the lead existed: the path goes on without one
    r = DSharePath(DSharePathSettings(), DT, (0.03, 0.97))
    r.restore({"value": 0.4})
    assert r.step(0.3, **steps) == pytest.approx(0.4 + (1 - math.exp(-DT)) * (0.3 - 0.4),
                                                 abs=1e-15)


@pytest.mark.parametrize("kw, field", [({"tau_h": 0.0}, "tau_h"),
                                       ({"tau_rise_h": float("nan")}, "tau_rise_h"),
                                       ({"d_feed_high": 1.5}, "d_feed_high"),
                                       ({"level_low_pct": -1.0}, "level_low_pct"),
                                       ({"lead": -0.1}, "lead"),
                                       ({"lead_until": 0.0}, "lead_until"),
                                       ({"lead_until_fall": 1.5}, "lead_until_fall"),
                                       ({"lead_max_h": math.inf}, "lead_max_h")])
def test_bad_settings_name_their_field(kw, field):
    with pytest.raises(ValueError, match=field):
        DSharePathSettings(**kw)


def _run(ctl, t0, n, x):
    out = []
    for k in range(n):
        dec = ctl.step(k, t0 + k * ctl.sample_h, x, None)
        ctl.finish_sample()
        out.append(float(dec.extra["d_share"]))
    return out


def test_the_mpc_strategies_move_the_d_share_faster_than_the_plan_and_resume_from_a_checkpoint():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    x = np.array(grade("mode0").xmeas, dtype=float)  # G far from mode 2's: no G loop
    s0, s2 = grade("mode0").d_fraction, grade("mode2").d_fraction
    mpc, _ = make_te_controller("fixed", plan)
    # 1 h into the change: the path (1 h) has gone 63 % of the way to its lead's aim (G
    # stands still here, so the lead lasts): half the change beyond mode 2's share, cut
    # to the ratio's lower limit 0.03; the plan's (3 h) 28 % of the way to mode 2's
    s_mpc = _run(mpc, 1.0 - mpc.sample_h, 102, x)[-1]  # from a sample before the change
    assert s2 - 0.5 * (s0 - s2) < 0.03
    assert (s0 - s_mpc) / (s0 - 0.03) == pytest.approx(1 - math.exp(-1.0), abs=0.01)
    assert (s0 - plan.d_fraction_ref(2.0)) / (s0 - s2) == pytest.approx(1 - math.exp(-1 / 3),
                                                                        abs=0.01)
    # a controller restored from the checkpoint goes on where the first one does
    state = mpc.checkpoint()
    again, _ = make_te_controller("fixed", plan)
    again.restore(state)
    t1 = 1.0 + 101 * mpc.sample_h
    assert _run(again, t1, 5, x) == _run(mpc, t1, 5, x)
    # the baselines keep the plan's path
    assert make_te_controller("pi", plan)[0].d_path is None


def test_an_aborted_transition_holds_the_d_share_where_it_is():
    from controller.units.te.service import HeldPlan

    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    x = np.array(grade("mode0").xmeas, dtype=float)
    ctl, _ = make_te_controller("ssmpc", plan)
    s = _run(ctl, 1.0, 50, x)[-1]
    t1 = 1.0 + 50 * ctl.sample_h
    ctl.retarget(HeldPlan(plan, t1))
    assert _run(ctl, t1, 20, x) == [pytest.approx(s, abs=1e-15)] * 20


def _leg(strategy: str, a: int, b: int, hours: float, seed: int = 1, **options) -> dict:
    """One leg a -> b (noise on, the change at 1 h; ``options`` to ``run_te``): its
    campaign metrics row; it must not trip."""
    from controller.units.te.control import plant_seed_for, run_te
    from services.campaign import metrics

    plan = TransitionPlan(f"mode{a}", (Leg(1.0, f"mode{b}"),))
    r = run_te(strategy, plan, hours, noise=True, seed=seed, plant_seed=plant_seed_for(seed),
               **options)
    assert r.shutdown is None
    return metrics.te_metrics(r.t, r.xmeas, r.cost, r.active, r.model_names,
                              r.meta["sample_h"], (1.0, f"mode{b}"), None, xmv=r.xmv,
                              previous_grade=f"mode{a}")


def test_leaving_mode_3_the_mpc_strategies_reach_the_grade_hours_before_the_plan():
    # 3 -> 1, noise on, seed 1 (docs/campaigns.md: 8.1 h against the plan's 13.8 h);
    # with the plan's path the MPC strategies took 14.0 h
    mpc = _leg("fixed", 3, 1, 18.0)["time_to_grade_h"]
    plan = _leg("plan", 3, 1, 18.0)["time_to_grade_h"]
    assert mpc is not None and mpc < 10.0
    assert plan is None or plan > mpc + 3.0


def test_the_lead_brings_g_to_the_grade_sooner_leaving_mode_2():
    # 2 -> 1, noise on, seed 1 (docs/te_matrix.md: 5.8 h with the lead, 8.3 h without,
    # median of seeds 1-3)
    with_lead, without = (_leg("ssmpc", 2, 1, 14.0, d_share_path=DSharePathSettings(lead=lead))
                          ["time_to_grade_h"] for lead in (0.5, 0.0))
    assert with_lead is not None and without is not None
    assert with_lead < without - 1.5


def test_the_later_end_of_the_lead_into_mode_2_brings_g_to_the_grade_sooner():
    # 1 -> 2, noise on, seed 3 (measured: 7.81 h and 1971 $ with the lead ending at half
    # of G's way, 9.03 h and 2290 $ at 30 %): the path passes mode 2's share before the
    # lead ends, and G comes into its band without the tail
    half, early = (_leg("ssmpc", 1, 2, 12.0, seed=3,
                        d_share_path=DSharePathSettings(lead_until_fall=until))
                   for until in (0.5, 0.3))
    t_half, t_early = half["time_to_grade_h"], early["time_to_grade_h"]
    assert t_half is not None and t_early is not None
    assert t_half < 8.3 and t_half < t_early - 0.8
    assert half["transition_cost_usd"] < 0.9 * early["transition_cost_usd"]


def test_a_new_grade_request_mid_path_goes_on_from_where_the_path_is():
    # 0 -> 2 under way, then mode 3 requested: the share turns from its value, no jump
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    x = np.array(grade("mode0").xmeas, dtype=float)
    ctl, _ = make_te_controller("ssmpc", plan)
    s = _run(ctl, 1.0, 60, x)
    t1 = 1.0 + 60 * ctl.sample_h
    # requested half a sample before the next one (a leg at the sample's own time may
    # fall a round-off after the grid time the plan is read at)
    ctl.retarget(TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(t1 - 0.5 * ctl.sample_h,
                                                                  "mode3"))))
    after = _run(ctl, t1, 3, x)
    step = s[-1] - s[-2]  # the last step toward mode 2 (down)
    assert step < 0 and grade("mode3").d_fraction > s[-1]
    assert 0 < after[0] - s[-1] < 3 * abs(step)  # turned up, by a path's step
    assert after[0] < after[1] < after[2]
