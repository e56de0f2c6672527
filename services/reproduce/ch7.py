"""Seed chapter 7: Tennessee Eastman grade transitions and IDV(6) (R7.1-R7.16).

Plant: the original Downs & Vogel process (:mod:`plant_sim.tennessee_eastman`, exact
port, interlocks active). Every closed-loop case runs each strategy of
:func:`controller.units.te.control.run_te` on the same plant, noise and seed
(:data:`services.reproduce.ch7_verdicts.STRATEGIES`):

- ``fixed`` (strategy a): the cascade of :mod:`controller.units.te.control` (inner PI
  loops at the 1.8 s step, supervisory sample 36 s) with MPC on three fixed models
  (modes 0, 2, 3) switched by the performance index (§7.5-7.6);
- ``ssmpc`` (strategy b): the same plus a re-initialized adaptive model (§7.7);
- baselines: ``pi`` (:mod:`controller.units.te.pi_baseline` on the cascade's handles),
  ``plan`` (the grade plan's feedforward alone) and ``decentralized`` (the
  ``temain_mod.f`` loops, :mod:`controller.units.te.decentralized`).

Cases (seed_results.md): R7.13 IDV(6) at mode 3; R7.14 mode 0 -> 2 and 0 -> 2 -> 3,
also with the original measurement noise and with input noise (SNR 100); R7.16 SSMPC
0 -> 2. Reported per run: shutdown and the closest approach to each interlock,
time until G in product stays within +-1 mol% of the new grade, ISE per CV, E-feed
valve time at 100 %, operating cost ($/h), production change, MV total variation,
active model share and how the index ranked the adaptive model
(:func:`adaptive_selection`). The verdicts are computed from these numbers by
:mod:`services.reproduce.ch7_verdicts`. Cheap checks: R7.1, R7.3 (Table 7.3 at each
mode's state), R7.8 (cost), R7.10 (spectra), R7.11 (Table 7.10 loops hold mode 0),
R7.15 (SSMPC structure).

Runs are cached per process (:func:`run_case`), so R7.14 and R7.16 share the 0 -> 2 runs
when one process asks for both; with ``--workers N`` (``StudyContext.workers``) a study
makes its runs in N processes first (:func:`prefetch`), with the same numbers. Measured
(offline, ``realtime=False``, the shared 2-core machine at load 4.5-5): one 40 h run
takes fixed 12-24 s, ssmpc 8-18 s, pi and plan 1-2 s, decentralized under 1 s; through
the CLI R7.13 takes 20-33 s, R7.16 52-59 s, R7.14 157-253 s (30 runs). Results and what
they show: ``docs/reproduce_ch7.md``.

Deviations from the seed, with evidence in :mod:`controller.units.te.control`:
reactor-temperature loop gain -2 %/degC (Table 7.10's -0.5 leaves the loop
unstable at modes 0 and 2), a reactor pressure -> purge inner loop whose set point
the MPC writes, separator/stripper pressure weights 0.01, input targets from the
grade plan, an outer A-in-feed loop and a high-pressure override on the A+C feed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.units.te.control import CORE_CVS, TEMPCOptions, TERun, run_te
from controller.units.te.grades import (
    GRADES,
    Leg,
    TransitionPlan,
    grade,
    ise,
    production_change,
    ricker_optimum,
    saturation_time,
    time_to_band,
    trailing_mean,
)
from services.reproduce import ReproduceResult, Row, StudyContext
from services.reproduce.ch7_verdicts import (
    ADAPTIVE,
    LABEL,
    STRATEGIES,
    judge_r7_13,
    judge_r7_14,
    judge_r7_16,
)

__all__ = ["RESULTS", "Case", "CASES", "run_case", "case_runs", "prefetch", "case_metrics",
           "adaptive_selection", "G_BAND"]

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


#: Runs made in this process, by (case, strategy, seed): every strategy on each case.
_RUNS: dict[tuple[str, str, int], TERun] = {}


def _simulate(key: tuple[str, str, int]) -> TERun:
    name, strategy, seed = key
    c = CASES[name]
    return run_te(strategy, c.plan(), c.hours, noise=c.noise, input_snr=c.input_snr,
                  idv=dict(c.idv), seed=seed)


def run_case(name: str, strategy: str, seed: int = 0) -> TERun:
    """Run (and cache within the process) one case with one strategy."""
    key = (name, strategy, int(seed))
    if key not in _RUNS:
        _RUNS[key] = _simulate(key)
    return _RUNS[key]


def prefetch(names, seed: int, workers: int) -> None:
    """Make the runs of every strategy on the cases ``names`` that this process has not
    made yet, in ``workers`` processes (``StudyContext.workers``), longest first.

    Each run is the same computation in its own process as in this one (a seeded
    simulation from the case's start), so a study's numbers do not depend on
    ``workers``; with 1 the runs are made one by one when the study asks for them."""
    todo = [(n, s, int(seed)) for n in names for s in STRATEGIES
            if (n, s, int(seed)) not in _RUNS]
    if workers <= 1 or len(todo) <= 1:
        return
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    todo.sort(key=lambda k: -CASES[k[0]].hours)
    # spawned, not forked: the caller may hold threads (Zenoh, Dask) a fork would copy
    with ProcessPoolExecutor(max_workers=min(int(workers), len(todo)),
                             mp_context=multiprocessing.get_context("spawn")) as pool:
        for key, run in zip(todo, pool.map(_simulate, todo)):
            _RUNS[key] = run


def adaptive_selection(run: TERun, hysteresis: float | None = None) -> dict:
    """How the index treated the adaptive model, apart from the slot it started in.

    The SSMPC's adaptive model is model 0, active at the start
    (:func:`controller.units.te.control.make_mpc_core`), so its active share alone says
    nothing. The switching rule (:class:`controller.switching.ModelSwitcher`) takes a
    model j over the active one when ``J_j < (1 - hysteresis) J_active``; in a sample
    where the adaptive model's J is below ``(1 - hysteresis)`` times every fixed
    model's, the index would switch it in from any start slot.

    Parameters
    ----------
    run : TERun
        With ``prediction_rms`` (K, n_models) = sqrt(J / common gain) per model.
    hysteresis : float, optional
        The run's switching margin; default :class:`TEMPCOptions`'s (run_te's).

    Returns
    -------
    dict
        ``switches`` (int), ``adaptive_started_active`` (bool or None),
        ``adaptive_share_after_first_switch`` (share of the samples from the first
        switch on; NaN without a switch or adaptive model), ``adaptive_index_share``
        (share of samples the index ranks it ahead of every fixed model by the margin;
        NaN without one) and ``adaptive_first_index_h`` (first such time, h).
    """
    act = np.asarray(run.active)
    sw = np.flatnonzero(np.diff(act) != 0) + 1
    out = {"switches": int(sw.size), "adaptive_started_active": None,
           "adaptive_share_after_first_switch": math.nan, "adaptive_index_share": math.nan,
           "adaptive_first_index_h": math.nan}
    names = run.model_names
    if ADAPTIVE not in names or act.size == 0:
        return out
    j = names.index(ADAPTIVE)
    out["adaptive_started_active"] = bool(act[0] == j)
    if sw.size:
        out["adaptive_share_after_first_switch"] = float(np.mean(act[sw[0]:] == j))
    if run.prediction_rms is None:
        return out
    h = TEMPCOptions().index_hysteresis if hysteresis is None else float(hysteresis)
    J = np.asarray(run.prediction_rms, dtype=float) ** 2
    fixed = [i for i in range(len(names)) if i != j]
    with np.errstate(invalid="ignore"):
        ahead = J[:, j] < (1.0 - h) * np.min(J[:, fixed], axis=1)
    out["adaptive_index_share"] = float(np.mean(ahead))
    if ahead.any():
        out["adaptive_first_index_h"] = float(run.t[int(np.argmax(ahead))])
    return out


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
        # "stays in the band until the next leg": a leg the run did not finish (a trip
        # before the next request or the end) never reached its grade
        covered = out["t_end"] >= min(t1, case.hours) - 1e-6
        g_times.append(time_to_band(t[sel], g[sel], grade(gr).g_mol, G_BAND, t0)
                       if sel.sum() > 1 and covered else math.inf)
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
    out["cost_ratio"] = out["cost_end"] / out["cost_start"] if out["completed"] else math.nan
    if not out["completed"]:  # a trip stops the plant: its production is lost
        out["production_change_pct"] = -100.0
    else:
        try:
            out["production_change_pct"] = production_change(t, x[:, 16], t_change, 1.0)
        except ValueError:
            out["production_change_pct"] = math.nan
    names = run.model_names
    out["active_share"] = {n: float(np.mean(run.active == j)) for j, n in enumerate(names)}
    out["final_model"] = names[int(run.active[-1])] if names and run.active[-1] >= 0 else None
    out.update(adaptive_selection(run))
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


def _figs(ctx: StudyContext, name: str, runs: dict, case: Case, title: str,
          main: str) -> list[str]:
    if ctx.plot_dir is None:
        return []
    from services.reproduce.ch7_figures import plot_case

    return plot_case(runs, case, ctx.plot_dir, name, title, main)


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
        tab = ricker_optimum(m).xmeas  # seed Table 7.3 as printed (modes 4-6 too)
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
def case_runs(name: str, seed: int) -> dict[str, TERun]:
    """Every strategy of :data:`STRATEGIES` on one case (same plant, noise and seed),
    cached across the studies of a process by :func:`run_case`."""
    return {s: run_case(name, s, seed) for s in STRATEGIES}


def _prefix(strategy: str, main: str) -> str:
    return "" if strategy == main else f"{LABEL[strategy]}: "


def _adaptive_rows(prefix: str, met: dict) -> list[Row]:
    """The SSMPC's adaptive model: its share, and how the index ranked it
    (:func:`adaptive_selection`)."""
    return [
        Row(f"{prefix}adaptive model active share", "-", None,
            met["active_share"].get(ADAPTIVE, 0.0)),
        Row(f"{prefix}adaptive model active at the start (1 = yes)", "-", None,
            1.0 if met["adaptive_started_active"] else 0.0),
        Row(f"{prefix}model switches", "-", None, float(met["switches"])),
        Row(f"{prefix}adaptive model share after the first switch (NaN: no switch)", "-",
            None, met["adaptive_share_after_first_switch"]),
        Row(f"{prefix}share of samples the index ranks the adaptive model ahead of every "
            "fixed model by the switching margin", "-", None, met["adaptive_index_share"]),
        Row(f"{prefix}first time the index ranks it so", "h", None,
            met["adaptive_first_index_h"])]


def _claim_rows(judgement) -> list[Row]:
    return [Row(f"claim holds (1 = yes): {c.name}", "-", None, 1.0 if c.holds else 0.0)
            for c in judgement.claims]


def r7_13(ctx: StudyContext) -> ReproduceResult:
    prefetch(("idv6",), ctx.seed, ctx.workers)
    case = CASES["idv6"]
    runs = case_runs("idv6", ctx.seed)
    met = {s: case_metrics(r, case) for s, r in runs.items()}
    a = met["fixed"]
    rows = _shutdown_rows("", a) + [
        Row("production change under IDV(6)", "%", -4.25, a["production_change_pct"]),
        Row("production change against McAvoy & Ye's set-point cut", "%", -23.8,
            a["production_change_pct"]),
        Row("final / initial operating cost", "-", 7.0, a["cost_ratio"]),
        Row("final operating cost", "$/h", None, a["cost_end"]),
        Row("purge valve time at 100 %", "h", None, a["purge_at_limit_h"]),
    ] + _ise_rows("", a)
    for nm, share in a["active_share"].items():
        rows.append(Row(f"active share of model {nm}", "-", None, share))
    for s in STRATEGIES:
        if s == "fixed":
            continue
        m, p = met[s], _prefix(s, "fixed")
        rows += _shutdown_rows(p, m) + [
            Row(f"{p}production change", "%", None, m["production_change_pct"]),
            Row(f"{p}final / initial operating cost", "-", None, m["cost_ratio"]),
            Row(f"{p}final operating cost", "$/h", None, m["cost_end"]),
            Row(f"{p}purge valve time at 100 %", "h", None, m["purge_at_limit_h"])]
    rows += _adaptive_rows(_prefix("ssmpc", "fixed"), met["ssmpc"])
    j = judge_r7_13(met)
    return ReproduceResult("R7.13", _claim_rows(j) + rows, j.verdict, j.why,
                           _figs(ctx, "R7.13", runs, case, "IDV(6) at mode 3", "fixed"))


def _transition_rows(prefix: str, met: dict, seed_time: float | None,
                     ise_rows: bool = True) -> list[Row]:
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
    return rows + (_ise_rows(prefix, met) if ise_rows else [])


def _noise_not_applied(name: str, noisy: dict, clean: dict) -> list[str]:
    """Sentences naming the strategies whose valves the input noise never reached: their
    run is the noise-free one (run_te puts input noise on the supervisory valve commands;
    a strategy that moves its valves by plant-side loops writes none)."""
    return [f"[{name}] the input noise did not reach the {LABEL[s]} (its valves equal the "
            "noise-free run's: they are moved by plant-side loops, which run_te's input noise "
            "does not act on), so that comparison is not on equal terms."
            for s in STRATEGIES
            if s in noisy and s in clean and noisy[s].xmv.shape == clean[s].xmv.shape
            and np.array_equal(noisy[s].xmv, clean[s].xmv)]


R7_14_CASES = ("0-2", "0-2 noise", "0-2 input noise", "0-2-3", "0-2-3 noise",
               "0-2-3 input noise")


def r7_14(ctx: StudyContext) -> ReproduceResult:
    rows: list[Row] = []
    figs: list[str] = []
    met_by_case = {}
    notes = []
    prefetch(R7_14_CASES, ctx.seed, ctx.workers)
    for name in R7_14_CASES:
        case = CASES[name]
        runs = case_runs(name, ctx.seed)
        if case.input_snr is not None:
            notes += _noise_not_applied(name, runs, case_runs(
                name.replace(" input noise", ""), ctx.seed))
        mc = {s: case_metrics(r, case) for s, r in runs.items()}
        met_by_case[name] = mc
        p = f"[{name}] "
        rows += _transition_rows(p, mc["fixed"], None)
        for s in STRATEGIES:
            if s != "fixed":
                rows += _transition_rows(p + _prefix(s, "fixed"), mc[s], None, ise_rows=False)
        if name == "0-2-3":
            a = mc["fixed"]
            rows += [Row(f"{p}cost at mode 0", "$/h", 165.0, a["cost_start"]),
                     Row(f"{p}cost peak", "$/h", 320.0, a["cost_peak"]),
                     Row(f"{p}cost at 36 h", "$/h", 60.0, a["cost_36h"])]
            rows += [Row(f"{p}{LABEL[s]}: cost at 36 h", "$/h", None, mc[s]["cost_36h"])
                     for s in STRATEGIES if s != "fixed"]
        figs += _figs(ctx, f"R7.14_{name.replace(' ', '_')}", runs, case,
                      f"mode {name.replace('-', ' -> ')}", "fixed")
    j = judge_r7_14(met_by_case, notes)
    return ReproduceResult("R7.14", _claim_rows(j) + rows, j.verdict, j.why, figs)


def r7_16(ctx: StudyContext) -> ReproduceResult:
    prefetch(("0-2",), ctx.seed, ctx.workers)
    case = CASES["0-2"]
    runs = case_runs("0-2", ctx.seed)
    met = {s: case_metrics(r, case) for s, r in runs.items()}
    b, a = met["ssmpc"], met["fixed"]
    rows = _transition_rows("", b, 7.5) + [
        Row("E feed valve time at 100 % (seed: never)", "h", 0.0, b["e_valve_at_limit_h"]),
        *_adaptive_rows("", b),
        Row("MV total variation / fixed-model MPC's", "-", None,
            b["mv_total_variation"] / a["mv_total_variation"])]
    rows += [Row(f"prediction error of model {n} between grades (RMS, CV scales)", "-",
                 None, v) for n, v in b["prediction_rms"].items()]
    for s in STRATEGIES:
        if s != "ssmpc":
            rows += _transition_rows(_prefix(s, "ssmpc"), met[s], None)
    j = judge_r7_16(met)
    return ReproduceResult("R7.16", _claim_rows(j) + rows, j.verdict, j.why,
                           _figs(ctx, "R7.16", runs, case, "SSMPC mode 0 -> 2", "ssmpc"))


RESULTS = {"R7.1": r7_1, "R7.3": r7_3, "R7.8": r7_8, "R7.10": r7_10, "R7.11": r7_11,
           "R7.13": r7_13, "R7.14": r7_14, "R7.15": r7_15, "R7.16": r7_16}
