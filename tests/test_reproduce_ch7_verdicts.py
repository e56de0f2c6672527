"""The chapter-7 verdicts (services.reproduce.ch7_verdicts) follow the strategies'
numbers, not the seed's: constructed metrics where one strategy is made worse or
better, and constructed runs for the metrics behind them. No closed-loop runs."""

import math
from types import SimpleNamespace

import numpy as np
import pytest

from services.reproduce import ch7, ch7_figures
from services.reproduce import ch7_verdicts as V


def transition(**kw) -> dict:
    """Metrics of one transition run that meets every R7.16 claim of the seed."""
    met = {"completed": True, "time_to_g_h": [7.0], "cost_start": 170.0, "cost_peak": 320.0,
           "cost_end": 180.0, "cost_36h": 60.0, "e_valve_at_limit_h": 0.0,
           "mv_total_variation": 600.0, "production_change_pct": -1.0, "final_model": None,
           "active_share": {}, "switches": 0}
    met.update(kw)
    return met


def ssmpc(**kw) -> dict:
    base = {"active_share": {"reinit": 0.97, "mode0": 0.01, "mode2": 0.01, "mode3": 0.01},
            "adaptive_index_share": 0.95, "adaptive_started_active": True,
            "adaptive_share_after_first_switch": math.nan, "adaptive_first_index_h": 0.1,
            "final_model": "reinit"}
    base.update(kw)
    return transition(**base)


def r7_16_metrics(ssmpc_kw=None, fixed_kw=None) -> dict:
    fixed = {"e_valve_at_limit_h": 0.5, "mv_total_variation": 900.0, "time_to_g_h": [8.0]}
    fixed.update(fixed_kw or {})
    return {"ssmpc": ssmpc(**(ssmpc_kw or {})), "fixed": transition(**fixed),
            "pi": transition(time_to_g_h=[9.0]), "plan": transition(time_to_g_h=[10.0]),
            "decentralized": transition(time_to_g_h=[18.0], mv_total_variation=1500.0)}


def claim(j, start: str) -> bool:
    return next(c.holds for c in j.claims if c.name.startswith(start))


# -- R7.16 ------------------------------------------------------------------------------
def test_r7_16_ssmpc_better_than_fixed_and_faster_than_the_seed_is_beaten():
    j = V.judge_r7_16(r7_16_metrics())
    assert j.verdict == "beaten", j.why
    assert "SSMPC beats fixed-model MPC" in j.why


def test_r7_16_ssmpc_less_smooth_than_fixed_differs_and_says_so():
    # everything the seed printed holds for SSMPC, but the fixed-model MPC moves less
    j = V.judge_r7_16(r7_16_metrics(ssmpc_kw={"mv_total_variation": 900.0},
                                    fixed_kw={"mv_total_variation": 600.0}))
    assert j.verdict == "differs"
    assert not claim(j, "SSMPC's moves smoother")
    assert not claim(j, "SSMPC beats the fixed-model MPC")
    assert "fixed-model MPC better on MV total variation (900 vs 600 %)" in j.why


def test_r7_16_slower_than_fixed_differs_even_within_the_seeds_time():
    j = V.judge_r7_16(r7_16_metrics(ssmpc_kw={"time_to_g_h": [7.4]},
                                    fixed_kw={"time_to_g_h": [5.0]}))
    assert j.verdict == "differs"
    assert claim(j, "SSMPC: G within")  # 7.4 h <= 7.5 h: the seed's own number holds
    assert not claim(j, "SSMPC reaches G no later")


def test_r7_16_a_share_the_start_slot_gave_is_not_earned():
    # active all the time, but the index ranks it first in only 30 % of samples
    j = V.judge_r7_16(r7_16_metrics(ssmpc_kw={"adaptive_index_share": 0.3}))
    assert j.verdict == "differs"
    assert claim(j, "the adaptive model active almost all the time")
    assert not claim(j, "the index earns it")


def test_r7_16_at_the_seeds_time_is_reproduced_not_beaten():
    j = V.judge_r7_16(r7_16_metrics(ssmpc_kw={"time_to_g_h": [7.5]}))
    assert j.verdict == "reproduced", j.why


def test_r7_16_e_valve_at_its_bound_differs():
    j = V.judge_r7_16(r7_16_metrics(ssmpc_kw={"e_valve_at_limit_h": 0.2}))
    assert j.verdict == "differs"
    assert not claim(j, "SSMPC: the E feed valve never")


# -- R7.13 ------------------------------------------------------------------------------
def idv6(**kw) -> dict:
    met = {"completed": True, "time_to_g_h": [], "cost_start": 44.0, "cost_end": 264.0,
           "cost_peak": 264.0, "e_valve_at_limit_h": 0.0, "mv_total_variation": 100.0,
           "production_change_pct": -4.25, "final_model": "mode2", "active_share": {}}
    met.update(kw)
    return met


def r7_13_metrics(**fixed_kw) -> dict:
    return {"fixed": idv6(**fixed_kw), "ssmpc": idv6(final_model="reinit"),
            "pi": idv6(production_change_pct=-8.0), "plan": idv6(production_change_pct=-9.0),
            "decentralized": idv6(production_change_pct=-23.8)}


def test_r7_13_the_seeds_numbers_reproduce():
    j = V.judge_r7_13(r7_13_metrics())
    assert j.verdict == "reproduced", j.why


def test_r7_13_less_production_lost_and_cheaper_is_beaten():
    j = V.judge_r7_13(r7_13_metrics(production_change_pct=-1.0, cost_end=132.0))
    assert j.verdict == "beaten", j.why


def test_r7_13_larger_drop_than_the_seeds_differs_within_mcavoy_and_ye():
    j = V.judge_r7_13(r7_13_metrics(production_change_pct=-10.0))
    assert j.verdict == "differs"
    assert claim(j, "fixed-model MPC: production drop at most McAvoy")
    assert not claim(j, "fixed-model MPC: production drop at most the seed's")


def test_r7_13_decentralized_keeping_more_production_differs():
    met = r7_13_metrics()
    met["decentralized"] = idv6(production_change_pct=-1.0)
    j = V.judge_r7_13(met)
    assert j.verdict == "differs"
    assert "decentralized loops beats fixed-model MPC" in j.why


def test_r7_13_shutdown_and_other_final_model_differ():
    j = V.judge_r7_13(r7_13_metrics(completed=False))
    assert j.verdict == "differs" and not claim(j, "fixed-model MPC: no shutdown")
    j = V.judge_r7_13(r7_13_metrics(final_model="mode3"))
    assert j.verdict == "differs" and not claim(j, "fixed-model MPC: final model")


def test_r7_13_verdict_judges_fixed_but_the_why_ranks_ssmpc():
    met = r7_13_metrics()
    met["ssmpc"] = idv6(production_change_pct=-0.5, cost_end=100.0, final_model="reinit")
    j = V.judge_r7_13(met)
    assert j.verdict == "reproduced"  # the seed's claims are the fixed-model MPC's
    assert "SSMPC beats fixed-model MPC" in j.why


# -- R7.14 ------------------------------------------------------------------------------
def r7_14_metrics(fixed02=None) -> dict:
    others = {s: transition() for s in V.STRATEGIES if s != "fixed"}
    f02 = {"e_valve_at_limit_h": 0.4}
    f02.update(fixed02 or {})
    return {"0-2": {"fixed": transition(**f02), **others},
            "0-2-3": {"fixed": transition(time_to_g_h=[7.0, 15.0], cost_start=165.0,
                                          cost_36h=50.0),
                      **{s: transition(time_to_g_h=[7.0, 15.0]) for s in others}}}


def test_r7_14_claims_follow_the_fixed_model_runs():
    assert V.judge_r7_14(r7_14_metrics()).verdict == "reproduced"
    j = V.judge_r7_14(r7_14_metrics({"e_valve_at_limit_h": 0.0}))
    assert j.verdict == "differs" and not claim(j, "0 -> 2: the fixed-model MPC's E feed")
    j = V.judge_r7_14(r7_14_metrics({"time_to_g_h": [math.inf]}))
    assert j.verdict == "differs" and not claim(j, "[0-2] fixed-model MPC completes")


def test_r7_14_cost_peak_is_judged_one_sided():
    met = r7_14_metrics()
    met["0-2-3"]["fixed"]["cost_peak"] = 200.0  # far below the printed 320: no worse
    assert claim(V.judge_r7_14(met), "0 -> 2 -> 3: cost peak at most")
    met["0-2-3"]["fixed"]["cost_peak"] = 400.0  # 25 % above
    j = V.judge_r7_14(met)
    assert j.verdict == "differs" and not claim(j, "0 -> 2 -> 3: cost peak at most")


# -- comparisons -------------------------------------------------------------------------
def test_compare_ties_within_the_resolution_and_failures_lose():
    leg = V.MEASURES["leg 1"]
    assert V.compare(leg, 6.0, 6.2) == 0  # within the analyzer's 0.25 h sample
    assert V.compare(leg, 6.0, 7.0) == 1 and V.compare(leg, 7.0, 6.0) == -1
    assert V.compare(leg, math.inf, 7.0) == -1 and V.compare(leg, math.inf, math.nan) == 0
    prod = V.MEASURES["production"]  # higher is better
    assert V.compare(prod, -1.0, -5.0) == 1
    tv = V.MEASURES["smoothness"]  # relative tie
    assert V.compare(tv, 1000.0, 1005.0) == 0 and V.compare(tv, 1000.0, 1100.0) == 1


def test_measure_rejects_a_negative_tie():
    with pytest.raises(ValueError, match="tie"):
        V.Measure("x", "-", lambda m: 0.0, tie=-1.0)


# -- metrics of constructed runs ---------------------------------------------------------
def run_like(active, rms, names=("reinit", "mode0", "mode2", "mode3")):
    k = len(active)
    return SimpleNamespace(active=np.asarray(active), t=0.01 * np.arange(k),
                           model_names=names, prediction_rms=np.asarray(rms, dtype=float))


def test_adaptive_selection_counts_what_the_index_ranks_not_the_start_slot():
    # adaptive model 0 active throughout, but ahead of the best fixed model by the 20 %
    # margin (J ratio 0.25 < 0.8) only in the last 6 of 10 samples; tied before
    rms = [[1.0, 1.0, 2.0, 3.0]] * 4 + [[0.5, 1.0, 2.0, 3.0]] * 6
    sel = ch7.adaptive_selection(run_like([0] * 10, rms), hysteresis=0.2)
    assert sel["adaptive_started_active"] is True and sel["switches"] == 0
    assert sel["adaptive_index_share"] == pytest.approx(0.6)
    assert sel["adaptive_first_index_h"] == pytest.approx(0.04)
    assert math.isnan(sel["adaptive_share_after_first_switch"])


def test_adaptive_selection_inside_the_margin_is_not_ahead():
    # J ratio 0.9^2 = 0.81 > 0.8: better, but not by the switching margin
    rms = [[0.9, 1.0, 2.0, 3.0]] * 10
    assert ch7.adaptive_selection(run_like([0] * 10, rms), 0.2)["adaptive_index_share"] == 0


def test_adaptive_selection_share_after_the_first_switch():
    active = [3, 3, 3, 0, 0, 0, 0, 1, 0, 0]  # starts on fixed mode3, switched in at 3
    sel = ch7.adaptive_selection(run_like(active, [[0.1, 1, 1, 1]] * 10), 0.2)
    assert sel["adaptive_started_active"] is False and sel["switches"] == 3
    assert sel["adaptive_share_after_first_switch"] == pytest.approx(6 / 7)


def test_adaptive_selection_without_an_adaptive_model():
    sel = ch7.adaptive_selection(run_like([0] * 5, [[1, 1, 1]] * 5, ("mode0", "mode2",
                                                                       "mode3")))
    assert sel["adaptive_started_active"] is None and math.isnan(sel["adaptive_index_share"])


def synthetic_run(strategy="fixed", hours=5.0, trip=True, setpoints=5, g_at=11.66):
    """A TERun of ``hours`` at the 0.01 h sample: G at ``g_at`` from 2 h on."""
    from controller.units.te.control import TERun
    from controller.units.te.grades import grade

    t = 0.01 * np.arange(int(round(hours / 0.01)))
    x = np.tile(np.asarray(grade("mode0").xmeas, dtype=float), (t.size, 1))
    x[t >= 2.0, 39] = g_at
    xmv = np.full((t.size, 12), 50.0)
    shutdown = SimpleNamespace(time_h=hours, as_dict=lambda: {"time_h": hours,
                                                              "reason": "test"})
    names = ("mode0", "mode2", "mode3") if strategy == "fixed" else ()
    return TERun(strategy, t, x, xmv, np.zeros((t.size, setpoints)), x.copy(),
                 np.full(t.size, 170.0), np.zeros(t.size, dtype=int) if names else
                 np.full(t.size, -1), np.zeros(t.size), shutdown if trip else None, names,
                 meta={"sample_h": 0.01})


def test_a_tripped_run_never_reached_its_grade_and_lost_its_production():
    # G sits in the band from 2 h on, but the plant trips at 5 h of the 40 h case
    met = ch7.case_metrics(synthetic_run(), ch7.CASES["0-2"])
    assert met["completed"] is False
    assert met["time_to_g_h"] == [math.inf]
    assert met["production_change_pct"] == -100.0
    assert math.isnan(met["cost_ratio"])


# -- figures ------------------------------------------------------------------------------
def test_figures_draw_every_strategy_with_a_legend(tmp_path, monkeypatch):
    runs = {s: synthetic_run(s, hours=1.0, trip=False,
                             setpoints=14 if s == "decentralized" else 5)
            for s in V.STRATEGIES}
    legends = []
    real_save = ch7_figures._save

    def save(plt, fig, path):
        legends.append([[t.get_text() for t in ax.get_legend().get_texts()]
                        for ax in fig.axes if ax.get_legend() is not None])
        return real_save(plt, fig, path)

    monkeypatch.setattr(ch7_figures, "_save", save)
    paths = ch7_figures.plot_case(runs, ch7.CASES["0-2"], tmp_path, "t", "test", "fixed")
    assert len(paths) == 3 and all((tmp_path / p).exists() for p in paths)
    every = {V.LABEL[s] for s in V.STRATEGIES}
    # CV and valve figures: the first panel's legend; the third: the cost panel's
    assert every <= set(legends[0][0]) and every <= set(legends[1][0])
    assert any(every <= set(labels) for labels in legends[2])


def test_input_noise_that_never_reached_a_strategy_is_named():
    clean = {"fixed": SimpleNamespace(xmv=np.zeros((4, 12))),
             "decentralized": SimpleNamespace(xmv=np.ones((4, 12)))}
    noisy = {"fixed": SimpleNamespace(xmv=np.full((4, 12), 0.1)),
             "decentralized": SimpleNamespace(xmv=np.ones((4, 12)))}
    notes = ch7._noise_not_applied("0-2 input noise", noisy, clean)
    assert len(notes) == 1 and "decentralized loops" in notes[0]


def test_the_e_valve_time_is_compared_to_a_quarter_hour():
    e_valve = V.MEASURES["E valve"]
    assert V.compare(e_valve, 13.76, 13.82) == 0  # R7.14's 0 -> 2 with noise: a tie
    assert V.compare(e_valve, 0.0, 0.4) == 1 and V.compare(e_valve, 0.4, 0.0) == -1


def test_a_difference_of_exactly_the_tie_is_a_tie():
    # times on the 0.01 h sample grid, as the runs' are: 0.25 h apart up to rounding
    leg = V.MEASURES["leg 2"]
    assert V.compare(leg, 9.76, 9.76 + 0.25 + 1e-12) == 0
    assert V.compare(leg, 9.76, 9.76 + 0.26) == 1
