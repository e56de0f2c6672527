"""Seed chapter 7: Tennessee Eastman grade transitions and IDV(6) (R7.1-R7.16).

Plant: the original Downs & Vogel process (:mod:`plant_sim.tennessee_eastman`, exact
port, interlocks active). Control: the cascade of :mod:`controller.units.te.control`
(inner PI loops at the 1.8 s step, supervisory sample 36 s) with

- strategy (a) ``fixed``: MPC with three fixed models (modes 0, 2, 3) switched by
  the performance index (§7.5-7.6);
- strategy (b) ``ssmpc``: the same plus a re-initialized adaptive model (§7.7);
- the decentralized PI baseline (:mod:`controller.units.te.pi_baseline`) on the
  same plant, inner loops and grade references.

Cases (seed_results.md): R7.13 IDV(6) at mode 3; R7.14 mode 0 -> 2 and 0 -> 2 -> 3,
also with the original measurement noise and with input noise (SNR 100); R7.16 SSMPC
0 -> 2. Reported per run: shutdown and the closest approach to each interlock,
time until G in product stays within +-1 mol% of the new grade, ISE per CV, E-feed
valve time at 100 %, operating cost ($/h), production change, active model share.
Cheap checks: R7.1, R7.3 (Table 7.3 at each mode's state), R7.8 (cost), R7.10
(spectra), R7.11 (Table 7.10 loops hold mode 0), R7.15 (SSMPC structure).

Deviations from the seed, with evidence in :mod:`controller.units.te.control`:
reactor-temperature loop gain -2 %/degC (Table 7.10's -0.5 leaves the loop
unstable at modes 0 and 2), a reactor pressure -> purge inner loop whose set point
the MPC writes, separator/stripper pressure weights 0.01, input targets from the
grade plan, an outer A-in-feed loop and a high-pressure override on the A+C feed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from controller.units.te.control import CORE_CVS, TERun, run_te
from controller.units.te.grades import (
    GRADES,
    Leg,
    TransitionPlan,
    grade,
    ise,
    production_change,
    saturation_time,
    time_to_band,
    trailing_mean,
)
from services.reproduce import ReproduceResult, Row, StudyContext

__all__ = ["RESULTS", "Case", "CASES", "run_case", "case_metrics", "G_BAND"]

G_BAND = 1.0  # mol%, the ±1 mol% band of R7.14/R7.16
G_WINDOW_H = 1.0  # h, trailing mean of the G analyzer in runs with measurement noise
CV_NAMES = ("reactor pressure", "separator temperature", "separator pressure",
            "stripper pressure", "stripper temperature")
CV_UNITS = ("kPa", "degC", "kPa", "kPa", "degC")


@dataclass(frozen=True)
class Case:
    """One closed-loop scenario.

    Parameters
    ----------
    start : str
        Start grade.
    legs : tuple of (time_h, grade)
    hours : float
    noise : bool
        Original measurement noise.
    input_snr : float or None
        Input noise SNR (amplitude) on the supervisory valve commands.
    idv : tuple of (number, time_h)
    """

    start: str
    legs: tuple = ()
    hours: float = 40.0
    noise: bool = False
    input_snr: float | None = None
    idv: tuple = ()

    def plan(self) -> TransitionPlan:
        return TransitionPlan(self.start, tuple(Leg(t, g) for t, g in self.legs))


CASES = {
    "idv6": Case("mode3", (), 40.0, idv=((6, 1.0),)),
    "0-2": Case("mode0", ((1.0, "mode2"),), 40.0),
    "0-2-3": Case("mode0", ((1.0, "mode2"), (25.0, "mode3")), 72.0),
    "0-2-3 noise": Case("mode0", ((1.0, "mode2"), (25.0, "mode3")), 72.0, noise=True),
    "0-2-3 input noise": Case("mode0", ((1.0, "mode2"), (25.0, "mode3")), 72.0,
                              input_snr=100.0),
    "0-2 noise": Case("mode0", ((1.0, "mode2"),), 40.0, noise=True),
    "0-2 input noise": Case("mode0", ((1.0, "mode2"),), 40.0, input_snr=100.0),
}


@lru_cache(maxsize=32)
def run_case(name: str, strategy: str, seed: int = 0) -> TERun:
    """Run (and cache within the process) one case with one strategy."""
    c = CASES[name]
    return run_te(strategy, c.plan(), c.hours, noise=c.noise, input_snr=c.input_snr,
                  idv=dict(c.idv), seed=seed)


def case_metrics(run: TERun, case: Case) -> dict:
    """The numbers the chapter-7 rows report for one run."""
    t = run.t
    x = run.xmeas
    out: dict = {"shutdown": None if run.shutdown is None else run.shutdown.as_dict(),
                 "t_end": float(t[-1]) + run.meta["sample_h"], "margins": run.margins}
    out["completed"] = run.shutdown is None and out["t_end"] >= case.hours - 1e-6
    # time to G: per leg, from the request to staying within the band until the next leg
    legs = list(case.legs)
    g = x[:, 39]
    if case.noise:  # analyzer noise (0.5 mol% s.d.): judge the trailing 1 h mean
        g = trailing_mean(g, round(G_WINDOW_H / run.meta["sample_h"]))
    g_times = []
    for i, (t0, gr) in enumerate(legs):
        t1 = legs[i + 1][0] if i + 1 < len(legs) else math.inf
        sel = (t >= t0) & (t < t1)
        g_times.append(time_to_band(t[sel], g[sel], grade(gr).g_mol, G_BAND, t0)
                       if sel.sum() > 1 else math.inf)
    out["time_to_g_h"] = g_times
    out["g_end"] = float(np.mean(x[-25:, 39]))
    out["ise"] = {n: ise(t, x[:, cv - 1], run.ref[:, cv - 1])
                  for n, cv in zip(CV_NAMES, CORE_CVS, strict=True)}
    out["ise"]["G in product"] = ise(t, x[:, 39], run.ref[:, 39])
    out["e_valve_at_limit_h"] = saturation_time(t, run.xmv[:, 1], low=-1.0, high=100.0)
    out["purge_at_limit_h"] = saturation_time(t, run.xmv[:, 5], low=-1.0, high=100.0)
    out["cost_start"] = float(np.mean(run.cost[:10]))
    out["cost_peak"] = float(np.max(run.cost))
    out["cost_end"] = float(np.mean(run.cost[-25:]))
    i36 = np.searchsorted(t, 36.0)
    out["cost_36h"] = float(run.cost[i36]) if i36 < t.size else math.nan
    t_change = legs[0][0] if legs else (case.idv[0][1] if case.idv else 0.0)
    try:
        out["production_change_pct"] = production_change(t, x[:, 16], t_change, 1.0)
    except ValueError:
        out["production_change_pct"] = math.nan
    names = run.model_names
    out["active_share"] = {n: float(np.mean(run.active == j)) for j, n in enumerate(names)}
    out["final_model"] = names[int(run.active[-1])] if names and run.active[-1] >= 0 else None
    out["mv_total_variation"] = float(np.sum(np.abs(np.diff(run.xmv[:, [1, 2, 3, 5, 10]],
                                                            axis=0))))
    # each model's index as an RMS prediction error (units of the CV scales), median
    # over the plant's way between grades: from the first request to 8 h later (the
    # plans take 5-7 h), or from the disturbance to the end
    out["prediction_rms"] = {}
    if run.prediction_rms is not None and names:
        sel = (t >= t_change) & (t < (t_change + 8.0 if legs else math.inf))
        if sel.any():
            med = np.nanmedian(run.prediction_rms[sel], axis=0)
            out["prediction_rms"] = {n: float(v) for n, v in zip(names, med, strict=True)}
    out["controller_ms_median"] = float(np.median(run.solve_ms))
    out["controller_ms_max"] = float(np.max(run.solve_ms))
    out["alarms"] = len(run.alarms)
    return out


def _fmt_margin(m: dict) -> str:
    parts = [f"{k} {v['margin']:.1f} {v['unit']} from {v['limit']:g}" for k, v in m.items()]
    return "; ".join(parts)


def _figs(ctx: StudyContext, name: str, runs: dict, case: Case, title: str) -> list[str]:
    if ctx.plot_dir is None:
        return []
    from services.reproduce.ch7_figures import plot_case

    return plot_case(runs, case, ctx.plot_dir, name, title)


def _shutdown_rows(prefix: str, met: dict) -> list[Row]:
    p = met["margins"]["reactor pressure"]
    return [Row(f"{prefix}run completed without shutdown (1 = yes)", "-", None,
                1.0 if met["completed"] else 0.0),
            Row(f"{prefix}max reactor pressure", "kPa", None, p["max"])]


def _ise_rows(prefix: str, met: dict) -> list[Row]:
    return [Row(f"{prefix}ISE {n}", f"{u}^2 h", None, met["ise"][n])
            for n, u in zip(CV_NAMES, CV_UNITS, strict=True)] + [
        Row(f"{prefix}ISE G in product", "mol%^2 h", None, met["ise"]["G in product"])]


# -- cheap checks ------------------------------------------------------------------------
def _product_kg_h(xmeas, ftm13_lbmol_h: float) -> tuple[float, float]:
    kmol = ftm13_lbmol_h * 0.454
    return kmol * xmeas[39] / 100 * 62.0, kmol * xmeas[40] / 100 * 76.0


def _initial_eval(mode: str):
    from plant_sim.tennessee_eastman import TESimulator
    from plant_sim.tennessee_eastman import model as M

    sim = TESimulator(mode="base" if mode == "mode0" else mode[4:])
    return sim.initial_xmeas, float(sim._mem[M.M_FTM13]), sim.cost()


def r7_1(ctx: StudyContext) -> ReproduceResult:
    seed_g = {"mode0": 7038.0, "mode2": 1048.0, "mode3": 10000.0}
    seed_h = {"mode0": 7038.0, "mode2": 12669.0, "mode3": 1111.0}
    rows = []
    ok = True
    for m in ("mode0", "mode2", "mode3"):
        x, ftm, _ = _initial_eval(m)
        g, h = _product_kg_h(x, ftm)
        rows += [Row(f"{m} G production", "kg/h", seed_g[m], g),
                 Row(f"{m} H production", "kg/h", seed_h[m], h)]
        ok &= abs(h - seed_h[m]) / seed_h[m] < 0.02
    why = ("Product G and H at the start state of each grade (stripper product flow x "
           "XMEAS 40/41 x molar mass). H matches Table 7.1 within 2 %; the mode-2 G entry "
           "1048 is the facts' flagged transposition (1408 gives the 10/90 ratio).")
    return ReproduceResult("R7.1", rows, "reproduced" if ok else "differs", why)


def r7_3(ctx: StudyContext) -> ReproduceResult:
    rows = []
    worst = 0.0
    worst_where = ""
    for m in GRADES:
        x, _, _ = _initial_eval(m)
        tab = grade(m).xmeas
        for i in (6, 8, 10, 12, 15, 17):  # pressures, temperatures
            rel = abs(x[i] - tab[i]) / abs(tab[i])
            if rel > worst:
                worst, worst_where = rel, f"{m} XMEAS{i + 1}"
        rows.append(Row(f"{m} G in product", "mol%", float(tab[39]), float(x[39])))
        rows.append(Row(f"{m} reactor pressure", "kPa", float(tab[6]), float(x[6])))
    ok = worst < 0.01
    why = (f"XMEAS at each grade's start state vs Table 7.3; pressures and temperatures "
           f"within {100 * worst:.2f} % (worst {worst_where}); check ±1 %.")
    return ReproduceResult("R7.3", rows, "reproduced" if ok else "differs", why)


def r7_8(ctx: StudyContext) -> ReproduceResult:
    _, _, c0 = _initial_eval("mode0")
    rows = [Row("operating cost at mode 0", "$/h", 170.6, c0)]
    ok = abs(c0 - 170.6) <= 2.0
    why = ("Downs & Vogel cost with component prices x stream compositions "
           "(TESimulator.cost) at the base case; check 170.6 ± 2 $/h.")
    return ReproduceResult("R7.8", rows, "reproduced" if ok else "differs", why)


def r7_10(ctx: StudyContext) -> ReproduceResult:
    from controller.units.te import models as te_models
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("te")
    lm = linearize(plant, plant.operating_point("mode0"))
    ev = np.linalg.eigvals(lm.A).real
    rows = [Row("open-loop eigenvalue, most negative", "1/h", -1968.0, float(ev.min())),
            Row("open-loop eigenvalue, most positive", "1/h", 3.11, float(ev.max()))]
    hur = True
    for g in te_models.MODEL_GRADES:
        sysm, _, _ = te_models.closed_loop(g)
        mx = float(np.max(np.linalg.eigvals(sysm.A).real))
        hur &= mx < 0
        rows.append(Row(f"{g} cascade model, largest real part", "1/h", None, mx))
    ok = abs(ev.max() - 3.11) / 3.11 < 0.3 and hur
    why = ("Jacobian of the port at mode 0 (50 states incl. valve lags) and the cascade "
           "models of te_models (loops closed, E/D ratio, 1/300 h pressure filter): "
           "Hurwitz at modes 0, 2, 3 with the reactor-temperature gain -2 %/degC (with "
           "Table 7.10's -0.5 they are not, see te_control).")
    return ReproduceResult("R7.10", rows, "reproduced" if ok else "differs", why)


def r7_11(ctx: StudyContext) -> ReproduceResult:
    from plant_sim.tennessee_eastman import TESimulator
    from plant_sim.tennessee_eastman.regulatory import RegulatoryLayer

    sim = TESimulator()
    rows_ = RegulatoryLayer(sim).run_steps(48000, record_every=200, stop_on_trip=True)
    dev = max(float(np.max(np.abs(rows_[:, 1 + c] - sp))) for c, sp in
              ((7, 75.0), (11, 50.0), (14, 50.0)))
    more = RegulatoryLayer(sim).run_steps(48000, stop_on_trip=True)
    del more
    trip = sim.shutdown
    rows = [Row("largest level deviation over 24 h, Table 7.10 loops as printed "
                "(check: <= 2)", "%", None, dev),
            Row("time of the first trip within 48 h (inf = none)", "h", None,
                math.inf if trip is None else trip.time_h)]
    ok = dev <= 2.0
    why = ("Table 7.10 loops (reactor temperature -0.5 %/degC, Ti 1 h) with all other "
           "valves held: the levels hold within ±2 % for 24 h (check), but a growing "
           "3 h oscillation (linearization: +0.35 ± 2.08j 1/h) trips the plant on "
           "reactor pressure before 48 h, which is why the cascade uses -2 %/degC.")
    return ReproduceResult("R7.11", rows, "reproduced" if ok else "differs", why)


#: A representation is faithful when its frequency response is within this (relative to
#: the response's peak) of the reduced model it represents.
R7_15_RTOL = 1e-6


def _representation_error(ssm, models) -> float:
    """Largest relative frequency-response error of the state-shared models against the
    reduced models they represent, over 1e-3..1e4 1/h (61 points)."""
    from controller.linear import Realization

    w = np.logspace(-3, 4, 61)
    worst = 0.0
    for j, red in enumerate(models):
        A, B, C, _, _ = ssm.continuous_form(j)
        ref = Realization(red.A, red.B, red.C, None).frequency_response(w)
        ours = Realization(A, B, C, None).frequency_response(w)
        err = float(np.max(np.abs(ours - ref)) / np.max(np.abs(ref)))
        worst = max(worst, err if math.isfinite(err) else math.inf)
    return worst


def r7_15(ctx: StudyContext) -> ReproduceResult:
    """The seed's TE state-shared structure (§7.7): n = 40 per model, m = 5, 2nm = 400.

    Built here at the seed's order from the TE linear models (balanced truncation to
    n = 40 of the three modes' linearizations), in the orthonormal basis and in the
    companion basis of eq. 3.12-3.13, and at the order the controller uses; each row is
    what the build gave, and the verdict depends on the measured representation error.
    """
    from controller.units.te.control import make_te_controller
    from controller.units.te.linear_models import TE_MODES, te_reduced, te_state_shared_model

    n_seed, m = 40, 5
    reduced = [te_reduced(mode, n_seed).reduced for mode in TE_MODES]
    ortho = te_state_shared_model(dt=0.01, order=n_seed, basis="orthonormal")
    err_ortho = _representation_error(ortho, reduced)
    try:
        comp = te_state_shared_model(dt=0.01, order=n_seed, basis="companion")
        err_comp = _representation_error(comp, reduced)
    except (ValueError, np.linalg.LinAlgError, FloatingPointError):
        err_comp = math.inf
    ctl, _ = make_te_controller("ssmpc")
    used = ctl.core.ssm
    n_used = used.order // (2 * m)
    rows = [Row("state-shared order 2nm at n = 40 (built)", "-", 400.0, float(ortho.order)),
            Row("parameters per model n(m^2+1) at n = 40 (built)", "-", 1040.0,
                float(ortho.n_params)),
            Row("representation error at n = 40, orthonormal basis", "-", None, err_ortho),
            Row("representation error at n = 40, companion basis", "-", None, err_comp),
            Row("order n per model used by the controller", "-", 40.0, float(n_used)),
            Row("models: fixed + re-initialized adaptive", "-", 4.0, float(used.k))]
    s = ctl.core.law.settings
    rows += [Row("prediction horizon P", "samples", 10.0, float(s.P)),
             Row("control horizon M", "samples", 4.0, float(s.M))]
    faithful = err_ortho <= R7_15_RTOL and ortho.order == 2 * n_seed * m
    verdict = "reproduced" if faithful and n_used == n_seed else "differs"
    why = (f"The seed's structure built at n = 40 (order {ortho.order}) represents the three "
           f"modes' n = 40 models to {err_ortho:.1e} in the orthonormal basis (needed: "
           f"<= {R7_15_RTOL:g}); in the seed's companion basis the error is "
           f"{err_comp:.1e}. The controller runs n = {n_used} per model (order "
           f"{used.order}, {used.basis.kind} basis)"
           + ("" if n_used == n_seed else ", not the seed's 40: its MPC is tuned on the "
              "n = 8 models") + ".")
    return ReproduceResult("R7.15", rows, verdict, why)


# -- full cases ------------------------------------------------------------------------
def _compare(ours: float, base: float, lower_is_better: bool = True) -> bool:
    if not (math.isfinite(ours) and math.isfinite(base)):
        return math.isfinite(ours) and not math.isfinite(base)
    return ours < base if lower_is_better else ours > base


def r7_13(ctx: StudyContext) -> ReproduceResult:
    case = CASES["idv6"]
    runs = {s: run_case("idv6", s, ctx.seed) for s in ("fixed", "ssmpc", "pi")}
    met = {s: case_metrics(r, case) for s, r in runs.items()}
    a, pi = met["fixed"], met["pi"]
    rows = _shutdown_rows("", a) + [
        Row("production change under IDV(6)", "%", -4.25, a["production_change_pct"]),
        Row("McAvoy & Ye production set-point cut", "%", -23.8, a["production_change_pct"]),
        Row("final / initial operating cost", "-", 7.0, a["cost_end"] / a["cost_start"]),
        Row("final operating cost", "$/h", None, a["cost_end"]),
        Row("purge valve time at 100 %", "h", None, a["purge_at_limit_h"]),
    ] + _ise_rows("", a)
    for nm, share in a["active_share"].items():
        rows.append(Row(f"active share of model {nm}", "-", None, share))
    rows += _shutdown_rows("SSMPC: ", met["ssmpc"]) + [
        Row("SSMPC: production change", "%", -4.25, met["ssmpc"]["production_change_pct"])]
    rows += _shutdown_rows("PI baseline: ", pi) + [
        Row("PI baseline: production change", "%", -4.25, pi["production_change_pct"]),
        Row("PI baseline: final / initial operating cost", "-", 7.0,
            pi["cost_end"] / pi["cost_start"])]
    ok = a["completed"] and a["production_change_pct"] >= -23.8
    passes = ok and a["production_change_pct"] >= -4.25
    ratio = a["cost_end"] / a["cost_start"]
    verdict = "beaten" if passes and a["production_change_pct"] > -4.25 and ratio < 7.0 \
        else ("reproduced" if passes else "differs")
    why = (f"IDV(6) (A feed lost) from 1 h at Ricker's mode-3 state, 40 h. Fixed-model MPC: "
           f"{'no shutdown' if a['completed'] else 'SHUTDOWN'}; closest approaches: "
           f"{_fmt_margin(a['margins'])}. Production changes by "
           f"{a['production_change_pct']:+.2f} % (seed -4.25 %, McAvoy & Ye -23.8 %); "
           f"cost ratio {a['cost_end'] / a['cost_start']:.2f} (seed ~7); final model "
           f"{a['final_model']} (seed: mode 2). PI baseline production change "
           f"{pi['production_change_pct']:.2f} % (the production loop on the A+C feed is "
           f"shared, so the PI baseline holds production as well).")
    if not passes:
        why += " Differs: production drop larger than the seed's 4.25 % (within 23.8 %)." \
            if ok else " Differs: see shutdown/production rows."
    return ReproduceResult("R7.13", rows, verdict, why,
                           _figs(ctx, "R7.13", runs, case, "IDV(6) at mode 3"))


def _transition_rows(prefix: str, met: dict, seed_time: float | None) -> list[Row]:
    rows = _shutdown_rows(prefix, met)
    for i, tg in enumerate(met["time_to_g_h"]):
        rows.append(Row(f"{prefix}time to G set point, leg {i + 1}", "h",
                        seed_time if i == 0 else None, tg))
    rows += [Row(f"{prefix}G in product at the end", "mol%", None, met["g_end"]),
             Row(f"{prefix}E feed valve time at 100 %", "h", None, met["e_valve_at_limit_h"]),
             Row(f"{prefix}operating cost at start", "$/h", None, met["cost_start"]),
             Row(f"{prefix}operating cost peak", "$/h", None, met["cost_peak"]),
             Row(f"{prefix}operating cost at the end", "$/h", None, met["cost_end"]),
             Row(f"{prefix}production change", "%", None, met["production_change_pct"]),
             Row(f"{prefix}MV total variation", "%", None, met["mv_total_variation"])]
    return rows + _ise_rows(prefix, met)


#: Relative band of the seed's "about" cost levels read off its figures (R7.14).
COST_BAND = 0.15


def _claims_verdict(claims: list[tuple[str, bool]]) -> tuple[list[Row], list[str]]:
    """Rows ``claim holds (1 = yes)`` and the names of the claims that fail."""
    rows = [Row(f"claim holds (1 = yes): {name}", "-", None, 1.0 if ok else 0.0)
            for name, ok in claims]
    return rows, [name for name, ok in claims if not ok]


def _shares(met: dict) -> str:
    return ", ".join(f"{n} {100 * v:.0f} %" for n, v in met["active_share"].items())


def r7_14(ctx: StudyContext) -> ReproduceResult:
    rows: list[Row] = []
    figs: list[str] = []
    notes = []
    completed = True
    met_by_case = {}
    for name in ("0-2", "0-2 noise", "0-2 input noise", "0-2-3", "0-2-3 noise",
                 "0-2-3 input noise"):
        case = CASES[name]
        runs = {s: run_case(name, s, ctx.seed) for s in ("fixed", "pi")}
        a, pi = case_metrics(runs["fixed"], case), case_metrics(runs["pi"], case)
        met_by_case[name] = (a, pi)
        p = f"[{name}] "
        rows += _transition_rows(p, a, None)
        rows += _transition_rows(f"{p}PI baseline: ", pi, None)
        if name == "0-2-3":
            rows += [Row(f"{p}cost at mode 0", "$/h", 165.0, a["cost_start"]),
                     Row(f"{p}cost peak", "$/h", 320.0, a["cost_peak"]),
                     Row(f"{p}cost at 36 h", "$/h", 60.0, a["cost_36h"]),
                     Row(f"{p}PI baseline: cost at 36 h", "$/h", 60.0, pi["cost_36h"])]
        completed &= a["completed"] and all(math.isfinite(v) for v in a["time_to_g_h"])
        sd = a["shutdown"]
        if a["completed"]:
            mpc_note = f"MPC completed, G in band after {a['time_to_g_h'][0]:.2f} h"
        elif sd:
            mpc_note = f"MPC SHUTDOWN at {sd['time_h']:.1f} h ({sd['reason']})"
        else:
            mpc_note = "MPC incomplete"
        pi_note = (f"PI {pi['time_to_g_h'][0]:.2f} h" if pi["completed"]
                   else "PI shutdown")
        notes.append(f"{name}: {mpc_note}, {pi_note}")
        figs += _figs(ctx, f"R7.14_{name.replace(' ', '_')}", runs, case,
                      f"mode {name.replace('-', ' -> ')} (fixed models + MPC vs PI)")
    a02, _ = met_by_case["0-2"]
    a023, _ = met_by_case["0-2-3"]

    def about(ours: float, seed: float) -> bool:
        return math.isfinite(ours) and abs(ours / seed - 1.0) <= COST_BAND

    claims = [
        ("all six runs complete, the G set point reached on every leg", completed),
        ("0 -> 2: the E feed valve clamps at its upper bound",
         a02["e_valve_at_limit_h"] > 0.0),
        ("0 -> 2 -> 3: cost about 165 $/h at mode 0", about(a023["cost_start"], 165.0)),
        ("0 -> 2 -> 3: cost peak about 320 $/h", about(a023["cost_peak"], 320.0)),
        ("0 -> 2 -> 3: cost about 60 $/h (or lower) at 36 h",
         math.isfinite(a023["cost_36h"]) and a023["cost_36h"] <= 60.0 * (1 + COST_BAND)),
    ]
    claim_rows, failed = _claims_verdict(claims)
    rows = claim_rows + rows
    why = ("Fixed-model MPC (strategy a) and the PI baseline on the original plant, "
           "grade 2 requested at 1 h, grade 3 at 25 h. " + "; ".join(notes) + ". "
           f"E feed valve at 100 % in 0 -> 2 for {a02['e_valve_at_limit_h']:.2f} h. "
           f"Costs of 0 -> 2 -> 3: {a023['cost_start']:.0f} $/h at mode 0 (seed 165), "
           f"peak {a023['cost_peak']:.0f} (seed 320), {a023['cost_36h']:.0f} at 36 h "
           f"(seed 60); cost levels judged within {100 * COST_BAND:.0f} % (read off the "
           f"seed's figures). Active fixed models in 0 -> 2: {_shares(a02)}. "
           "Costs: Downs & Vogel $/h from the simulator.")
    if failed:
        why += " Differs: " + "; ".join(failed) + " does not hold."
    return ReproduceResult("R7.14", rows, "differs" if failed else "reproduced", why, figs)


def r7_16(ctx: StudyContext) -> ReproduceResult:
    case = CASES["0-2"]
    runs = {s: run_case("0-2", s, ctx.seed) for s in ("ssmpc", "fixed", "pi")}
    met = {s: case_metrics(r, case) for s, r in runs.items()}
    b, a, pi = met["ssmpc"], met["fixed"], met["pi"]
    adaptive_share = b["active_share"].get("reinit", 0.0)
    rows = _transition_rows("", b, 7.5) + [
        Row("E feed valve time at 100 % (seed: never)", "h", 0.0, b["e_valve_at_limit_h"]),
        Row("adaptive model active share", "-", None, adaptive_share),
        Row("MV total variation / fixed-model MPC's", "-", None,
            b["mv_total_variation"] / a["mv_total_variation"])]
    rows += _transition_rows("fixed-model MPC: ", a, None)
    rows += _transition_rows("PI baseline: ", pi, None)
    tg = b["time_to_g_h"][0]
    rms = b["prediction_rms"]
    fixed_rms = [v for n, v in rms.items() if n != "reinit"]
    earned = ("reinit" in rms and bool(fixed_rms)
              and rms["reinit"] < min(fixed_rms))
    rows += [Row(f"prediction error of model {n} between grades (RMS, CV scales)", "-",
                 None, v) for n, v in rms.items()]
    claims = [
        ("no shutdown", b["completed"]),
        ("G within +-1 mol% of the mode-2 set point 7.5 h after the request",
         math.isfinite(tg) and tg <= 7.5),
        ("the E feed valve never at its upper bound", b["e_valve_at_limit_h"] == 0.0),
        ("moves smoother than the fixed-model MPC's (total variation)",
         b["mv_total_variation"] < a["mv_total_variation"]),
        ("the adaptive model selected almost all the time (>= 80 %)", adaptive_share >= 0.8),
        ("the adaptive model earns it: its prediction error between grades below every "
         "fixed model's", earned),
    ]
    claim_rows, failed = _claims_verdict(claims)
    rows = claim_rows + rows
    passes = not failed
    beaten = passes and tg < 7.5
    faster_than_pi = _compare(tg, pi["time_to_g_h"][0])
    cheaper_than_pi = b["cost_end"] < pi["cost_end"]
    verdict = "beaten" if beaten else ("reproduced" if passes else "differs")
    why = (f"SSMPC 0 -> 2 requested at 1 h: {'no shutdown' if b['completed'] else 'SHUTDOWN'}"
           f" (closest: {_fmt_margin(b['margins'])}); G within ±1 mol% of 11.66 after "
           f"{tg:.2f} h (seed 7.5 h; PI baseline {pi['time_to_g_h'][0]:.2f} h, fixed-model "
           f"MPC {a['time_to_g_h'][0]:.2f} h); E valve at 100 % for "
           f"{b['e_valve_at_limit_h']:.2f} h (fixed-model MPC {a['e_valve_at_limit_h']:.2f} h)"
           f"; adaptive model active {100 * adaptive_share:.0f} % of samples, its "
           f"prediction error between grades {rms.get('reinit', math.nan):.2f} against "
           f"{min(fixed_rms, default=math.nan):.2f} for the best fixed model (RMS in "
           f"units of the CV scales); MV total variation "
           f"{b['mv_total_variation']:.0f} against the fixed-model MPC's "
           f"{a['mv_total_variation']:.0f}. "
           f"{'Faster' if faster_than_pi else 'Not faster'} and "
           f"{'cheaper' if cheaper_than_pi else 'not cheaper'} at the end than the PI "
           f"baseline.")
    if failed:
        why += " Differs: " + "; ".join(failed) + " does not hold."
    return ReproduceResult("R7.16", rows, verdict, why,
                           _figs(ctx, "R7.16", runs, case, "SSMPC mode 0 -> 2"))


RESULTS = {"R7.1": r7_1, "R7.3": r7_3, "R7.8": r7_8, "R7.10": r7_10, "R7.11": r7_11,
           "R7.13": r7_13, "R7.14": r7_14, "R7.15": r7_15, "R7.16": r7_16}
