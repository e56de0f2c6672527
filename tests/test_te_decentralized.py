"""The decentralized TE scheme of temain_mod.f (Lyman & Georgakis 1995) on this plant."""

import math

import numpy as np
import pytest

from controller.units.config import UnitConfig
from controller.units.te import structure
from controller.units.te.control import STRATEGIES, make_te_controller, run_te
from controller.units.te.decentralized import (
    PLANT_LOOPS,
    TEMAIN_MOD_LOOPS,
    DecentralizedController,
)
from controller.units.te.grades import Leg, TransitionPlan, grade, time_to_band
from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman.regulatory import (
    CascadeLoop,
    PILoop,
    RegulatoryLayer,
    ValveOverride,
)

# Typed from temain_mod.f (Russell, Chiang & Braatz; repository
# camaramm/tennessee-eastman-profBraatz, commit 0643318): set points, gains and reset
# times lines 246-312; errors (CV, span) and outputs in CONTRL1-CONTRL20, lines
# 501-1286; samples from the main loop, lines 369-394 (every 3 s: 1-11, 16, 17, 18;
# every 360 s: 13, 14, 15, 19; every 900 s: 20).
# loop: (XMEAS, "XMV n" or "SP m", gain, reset time s or None, CV span, sample s, set point)
PUBLISHED = {
    1: (2, "XMV 1", 1.0, None, 5811.0, 3, 3664.0),
    2: (3, "XMV 2", 1.0, None, 8354.0, 3, 4509.3),
    3: (1, "XMV 3", 1.0, None, 1.017, 3, 0.25052),
    4: (4, "XMV 4", 1.0, None, 15.25, 3, 9.3477),
    5: (5, "XMV 5", -0.083, 1.0, 53.0, 3, 26.902),
    6: (10, "XMV 6", 1.22, None, 1.0, 3, 0.33712),
    7: (12, "XMV 7", -2.06, None, 70.0, 3, 50.0),
    8: (15, "XMV 8", -1.62, None, 70.0, 3, 50.0),
    9: (19, "XMV 9", 0.41, None, 460.0, 3, 230.31),
    10: (21, "XMV 10", -1.56, 1452.0, 150.0, 3, 94.599),
    11: (17, "XMV 11", 1.09, 2600.0, 46.0, 3, 22.949),
    13: (23, "SP 3", 18.0, 3168.0, 100.0, 360, 32.188),
    14: (26, "SP 1", 8.3, 3168.0, 100.0, 360, 6.8820),
    15: (27, "SP 2", 2.37, 5069.0, 100.0, 360, 18.776),
    16: (18, "SP 9", 0.169, 236.0, 130.0, 3, 65.731),
    17: (8, "SP 4", 1.11, 3168.0, 50.0, 3, 75.0),
    18: (9, "SP 10", 28.3, 982.0, 150.0, 3, 120.40),
    19: (30, "SP 6", -5.54667, 6336.0, 26.0, 360, 13.823),
    20: (38, "SP 16", -3.26, 12408.0, 1.6, 900, 0.83570),
}
# Published closed-loop data of the same repository (48 h test sets, fault at 8 h,
# 3 min samples): d06_te.dat reaches 3000 kPa (XMEAS 7) at row 279, 5.95 h after
# the onset; d01_te.dat and d07_te.dat peak at 2820.5 and 2856.8 kPa, no shutdown.
IDV6_TRIP_AFTER_ONSET_H = 5.95
G_BAND = 1.0  # mol%
MODE0_G = grade(0).g_mol


def trailing_mean(y, n=100):
    """Trailing mean over n samples (1 h at 36 s), the analyzer-noise filter of the
    chapter-7 verdicts."""
    c = np.cumsum(np.r_[0.0, y])
    i = np.arange(y.size)
    lo = np.maximum(i + 1 - n, 0)
    return (c[i + 1] - c[lo]) / (i + 1 - lo)


def test_published_pairings_and_tunings():
    got = {}
    for lp in TEMAIN_MOD_LOOPS:
        out = f"XMV {lp.xmv}" if lp.xmv is not None else f"SP {lp.inner}"
        ti = None if math.isinf(lp.ti_s) else lp.ti_s
        got[lp.number] = (lp.cv, out, lp.gain, ti, lp.span, lp.sample_s, lp.setpoint)
    assert got.keys() == PUBLISHED.keys()
    for n, row in PUBLISHED.items():
        cv, out, gain, ti, span, sample, sp = got[n]
        assert (cv, out, ti, span, sample, sp) == (row[0], row[1], row[3], row[4], row[5],
                                                   row[6]), n
        assert gain == pytest.approx(row[2], rel=1e-5), n


def test_fast_loops_run_on_the_plant_side_in_the_published_order():
    number = {lp.name: lp.number for lp in TEMAIN_MOD_LOOPS}
    fast = [n for n, row in PUBLISHED.items() if row[5] == 3]
    assert [number[lp.name] for lp in PLANT_LOOPS] == sorted(fast)
    _, spec = make_te_controller("decentralized")
    assert spec.loops == PLANT_LOOPS and spec.written_xmvs == (12,)
    assert sorted(spec.loop_xmvs) == list(range(1, 12))


def _base_layer():
    sim = TESimulator()  # noise off, base case
    reg = RegulatoryLayer(sim, loops=PLANT_LOOPS)
    reg.run_steps(1)  # every loop started at its measurement
    return sim, reg


def test_valve_loop_gain_is_the_published_percent_of_span():
    sim, reg = _base_layer()
    sp = reg.setpoints
    xmv1 = sim.xmv[0]
    sp[0] += 0.01 * 5811.0  # D feed set point up 1 % of its span
    reg.set_setpoints(np.where(np.isin(np.arange(sp.size), reg.cascaded), np.nan, sp))
    reg.run_steps(1)
    # gain 1.0 %/% (loop 1, P only): +1 % of valve, less the measurement's own move
    assert sim.xmv[0] - xmv1 == pytest.approx(1.0, abs=0.02)


def test_cascade_writes_the_inner_set_point_in_its_units():
    sim, reg = _base_layer()
    j_level = [lp.name for lp in PLANT_LOOPS].index("reactor level")
    j_ac = [lp.name for lp in PLANT_LOOPS].index("A and C feed")
    sp = reg.setpoints
    ac0 = sp[j_ac]
    sp[j_level] += 0.5  # 1 % of the 50 % level span
    sp[list(reg.cascaded)] = np.nan
    reg.set_setpoints(sp)
    reg.run_steps(1)
    # loop 17: 1.11 %/% of the A+C feed span 15.25 kscmh, plus 1.8 s of 3168 s reset
    expected = 1.11 * (1.0 + 1.8 / 3168.0) * 15.25 / 100.0
    assert reg.setpoints[j_ac] - ac0 == pytest.approx(expected, rel=0.05)
    with pytest.raises(PlantInputError, match="reactor level"):
        bad = reg.setpoints
        bad[j_level] = np.nan  # not written by a cascade: NaN is refused
        reg.set_setpoints(bad)


def test_override_latches_and_restarts_the_loop():
    sim = TESimulator()
    p0 = sim.xmeas[12]
    ovr = ValveOverride(cv=13, high=p0 - 3.0, release=p0 - 8.0, low=p0 - 500.0,
                        restart_output=30.0, restart_setpoint=0.3)
    reg = RegulatoryLayer(sim, loops=(PILoop("purge", cv=10, mv=6, gain=1.0, ti_h=math.inf,
                                             override=ovr),))
    reg.run_steps(1)
    assert sim.xmv[5] == 100.0 and reg.overrides_latched == (1,)
    for _ in range(2000):
        reg.run_steps(1)
        if reg.overrides_latched == (0,):
            break
    assert reg.overrides_latched == (0,)
    assert sim.xmv[5] == 30.0 and reg.setpoints[0] == 0.3
    with pytest.raises(PlantInputError, match="low < release < high"):
        ValveOverride(cv=13, high=1.0, release=2.0, low=0.0, restart_output=1.0,
                      restart_setpoint=0.0)
    with pytest.raises(PlantInputError, match="same set point"):
        RegulatoryLayer(sim, loops=(PILoop("a", cv=1, mv=3, gain=1.0, ti_h=math.inf),
                                    CascadeLoop("b", cv=23, inner="a", gain=1.0, ti_h=1.0),
                                    CascadeLoop("c", cv=24, inner="a", gain=1.0, ti_h=1.0)))


def test_analyzer_loops_run_on_their_published_samples():
    ctl = DecentralizedController(TransitionPlan("mode0"))
    x = np.array(grade(0).xmeas, dtype=float)
    x[22] = PUBLISHED[13][6] - 1.0  # A in reactor feed 1 mol% below its set point
    j_a = [lp.name for lp in PLANT_LOOPS].index("A feed")
    sp = [ctl.step(k, k * 0.01, x).extra["setpoints"][j_a] for k in range(21)]
    assert sp[1:10] == [sp[0]] * 9  # held until 360 s
    # loop 13 at 360 s: reset action 18 * 1 % * 360/3168 of the 1.017 kscmh span
    step = 18.0 * 360.0 / 3168.0 * 1.017 / 100.0
    assert sp[10] - sp[0] == pytest.approx(step, rel=1e-9)
    assert sp[20] - sp[10] == pytest.approx(step, rel=1e-9)


def test_set_points_are_published_at_mode0_and_follow_the_plan():
    ctl = DecentralizedController(TransitionPlan("mode0", (Leg(1.0, "mode2"),)))
    sp0 = ctl.setpoints_at(0.0)
    assert {n: sp0[n] for n in PUBLISHED} == {n: row[6] for n, row in PUBLISHED.items()}
    late = ctl.setpoints_at(60.0)
    x2 = grade(2).xmeas
    for n in (11, 14, 15, 17, 18, 20):  # production, D, E in feed, level, Tr, E in product
        cv, span = PUBLISHED[n][0], PUBLISHED[n][4]
        assert abs(late[n] - x2[cv - 1]) < 0.01 * span, n


def test_registered_as_a_te_strategy():
    assert "decentralized" in STRATEGIES and "decentralized" in structure.TE_STRATEGIES
    cfg = UnitConfig(unit="te", plant="te", strategy="decentralized",
                     cvs=structure.TE_XMEAS, initial_grade="mode0", sample_period_s=36.0)
    names = structure.te_mv_names(cfg)
    # set points an outer plant-side loop writes are not the supervisor's MVs
    assert "A_and_C_feed_sp" not in names and "stripper_steam_sp" not in names
    assert "reactor_level_sp" in names and "purge_rate_sp" in names
    assert names[0] == "XMV12"


def test_base_case_24_h_with_noise():
    run = run_te("decentralized", TransitionPlan("mode0"), 24.0, noise=True)
    assert run.shutdown is None
    late = run.t >= 4.0
    g = trailing_mean(run.xmeas[:, 39])
    # measured: trailing 1 h mean -0.5/+0.8 mol% from 4 h, raw analyzer -1.1/+1.3
    assert np.max(np.abs(g[late] - MODE0_G)) < G_BAND
    assert run.xmeas[:, 6].max() < 2750.0  # d00_te.dat peaks at 2724.7 kPa


@pytest.mark.parametrize("idv,mode", [(1, 0), (7, 0), (1, 2), (7, 2)])
def test_idv_1_and_7_held_48_h(idv, mode):
    run = run_te("decentralized", TransitionPlan(f"mode{mode}"), 48.0, noise=True,
                 idv={idv: 2.0})
    assert run.shutdown is None


def test_idv6_trips_as_the_published_closed_loop():
    # the scheme has no override for a lost A feed: the published data trip too
    run = run_te("decentralized", TransitionPlan("mode0"), 12.0, noise=True, idv={6: 2.0})
    assert run.shutdown is not None and run.shutdown.reason == "reactor pressure high"
    assert run.shutdown.time_h - 2.0 == pytest.approx(IDV6_TRIP_AFTER_ONSET_H, abs=1.0)


def test_grade_change_0_to_2():
    run = run_te("decentralized", TransitionPlan("mode0", (Leg(1.0, "mode2"),)), 48.0,
                 noise=True)
    assert run.shutdown is None
    g = trailing_mean(run.xmeas[:, 39])
    ttg = time_to_band(run.t, g, grade(2).g_mol, G_BAND, 1.0)
    assert ttg < 30.0  # measured: 21.5 h (1 h mean); on the raw analyzer 45.3 h


def test_service_controller_follows_a_transition_and_holds_after_an_abort():
    from controller.units.config import grade_setpoints
    from controller.units.te.service import TEServiceController
    from services.registry import load_unit_config

    cfg = load_unit_config("te", strategy="decentralized")
    g = grade_setpoints(cfg, None)
    mvs = structure.te_mv_names(cfg)
    ctl = TEServiceController("decentralized", "mode0", mvs, 0.01, g["mode0"]["mv"])
    y = np.asarray(g["mode0"]["setpoints"], dtype=float)
    level = mvs.index("reactor_level_sp")
    k, dec = 0, None
    for event, n in (("running", 200), ("aborted", 3), (None, 50)):
        if event:
            ctl.on_transition(event, "mode2", k * 36.0)
        for _ in range(n):
            dec = ctl.step(k, k * 36.0, y, None)
            ctl.finish_sample()
            assert np.all(np.isfinite(dec.u)) and not dec.fallback
            k += 1
        if event == "aborted":
            held = dec.u[level]
    assert dec.u[level] == held < 75.0  # moved toward mode 2's 65 %, then held


def test_plant_node_runner_applies_the_decentralized_moves():
    from services.nodes.plant import make_runner
    from services.registry import build_controller, load_unit_config

    cfg = load_unit_config("te", strategy="decentralized")
    plant = make_runner(cfg)
    ctl = build_controller(cfg)
    for k in range(300):  # 3 h
        dec = ctl.step(k, plant.t, plant.y(), None)
        ctl.finish_sample()
        plant.advance(dec.u, cfg.sample_period_s)
    assert not plant.shutdown
    y = plant.y()
    assert abs(y[7] - 75.0) < 2.0 and abs(y[6] - 2705.0) < 30.0  # reactor level, pressure


def test_the_published_temperature_cascade_in_engineering_units():
    # loop 18: Kc 2.83 on the reactor temperature's 150 degC span, its output in % of
    # loop 10's 150 degC span, x 10 in the source: 28.3 degC of set point per degC;
    # loop 10: Kc -0.156 x 10 on 150 degC, output in % of the valve: -1.04 %/degC
    from controller.units.te.published_loops import published_cascade

    lp = published_cascade(18, 10)
    assert (lp.cv, lp.mv, lp.secondary.cv) == (9, 10, 21)
    assert lp.gain == pytest.approx(28.3, rel=1e-12)
    assert lp.ti_h == pytest.approx(982.0 / 3600.0, rel=1e-12)
    assert lp.secondary.gain == pytest.approx(-1.04, rel=1e-12)
    assert lp.secondary.ti_h == pytest.approx(1452.0 / 3600.0, rel=1e-12)
    with pytest.raises(ValueError, match="loop 18"):
        published_cascade(18, 4)  # loop 18 writes loop 10's set point, not loop 4's
    with pytest.raises(ValueError, match="loop 20"):
        published_cascade(20, 16)  # loop 16 writes loop 9's set point, not a valve
