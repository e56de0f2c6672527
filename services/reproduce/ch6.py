"""Seed chapter 6: state-shared Δu MPC on the two-phase reactor and on calcium (R6.1–R6.6).

Two-phase reactor (§6.1.2, R6.1–R6.4)
    The unit's tuned controller and its offline closed loop,
    :mod:`controller.units.two_phase_reactor` (models, MPC settings, pressure limit);
    the studies here run it and compare with the seed.

Calcium (§6.1.3, R6.5–R6.6)
    Plant: the reconstructed Tang–Othmer model :mod:`plant_sim.calcium` (fluxes fitted
    to the seed's printed numbers), outputs xp5, xp6, inputs J, q1. Following it, OPI
    is the 0.1370 µM point and OPII the 0.1670 µM point (the facts file has them the
    other way round; the seed's Fig. 6.4 text says "OPII to OPI" for 0.1670 → 0.1370),
    and the printed B columns are ordered (q1, J). The MPC runs on a state-shared model
    of the plant's OPI/OPII linearizations reduced to order 3 (F_j companion of
    s³ + 3s² + 2s + 1) with switching; P = 10, M = 4, Ξ = 50 (xp5), 1 (xp6), J >= 0,
    and a small resting weight that returns J to its nominal 0.

Everything here is deterministic for a given ``--seed``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from controller.linear import balanced_truncation
from controller.mpc import OFFLINE_BUDGET_MS, MPCSettings
from controller.mpc.law import MPCLaw
from controller.reference import ReferenceTrajectory, SetpointSchedule
from controller.state_shared import StateSharedModel
from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
from controller.units.two_phase_reactor import (
    P_LIMIT,
    PRODUCT_TARGETS,
    ReactorCase,
    ReactorRun,
    reactor_models,
    reactor_settings,
    run_reactor,
)
from services.reproduce import ReproduceResult, Row, StudyContext

__all__ = ["RESULTS", "ReactorCase", "ReactorRun", "run_reactor", "reactor_models",
           "CalciumCase", "run_calcium", "reactor_settings", "calcium_models"]

# -- calcium --------------------------------------------------------------------------------
#: Set points printed in the captions of Figs. 6.4–6.5, (xp5, xp6) µM. Following the
#: reconstructed plant (plant_sim.calcium), OPI is the 0.1370 µM point.
CA_PRINTED = {"OPI": (0.1370, 38.6162), "OPII": (0.1670, 39.262)}
#: Designer polynomial of the calcium state-shared model, s^3 + 3 s^2 + 2 s + 1 (§2.5).
CA_A_DESIGN = (1.0, 2.0, 3.0)


@dataclass(frozen=True)
class CalciumCase:
    """One MPC transition of §6.1.3 on the reconstructed nonlinear calcium plant.

    The MPC runs on a state-shared model of the plant's OPI and OPII linearizations
    (inputs J, q1; outputs xp5, xp6), each reduced to order 3 by balanced truncation
    (as the seed), with switching by the performance index. J >= 0 (nominal 0) and
    q1 >= 0; J has a small resting-value weight so it returns to 0 (Fig. 6.4).
    Sample time ``dt`` in s.
    """

    start: str = "OPII"
    target: str = "OPI"
    weights: tuple[float, float] = (50.0, 1.0)
    P: int = 10
    M: int = 4
    dt: float = 0.2
    move_weight: float = 0.1
    j_rest_weight: float = 1.0
    tau_ref: float = 0.5
    t_end: float = 10.0
    order: int = 3


@dataclass(frozen=True)
class CalciumRun:
    case: CalciumCase
    t: np.ndarray
    y: np.ndarray          # (K, 2) xp5, xp6 (µM)
    reference: np.ndarray  # (K, 2)
    setpoint: np.ndarray   # (2,)
    y_start: np.ndarray    # (2,)
    u: np.ndarray          # (K, 2) J, q1
    active: np.ndarray
    fallback: np.ndarray
    model_names: tuple[str, ...] = ()

    def _after(self, outside) -> float:
        idx = np.flatnonzero(outside)
        if idx.size == 0:
            return 0.0
        return math.inf if idx[-1] == self.t.size - 1 else float(self.t[idx[-1] + 1])

    def reach_time(self, output: int, rel: float = 0.02) -> float:
        """Time after which the output stays within ``rel`` of its set point (s)."""
        sp = self.setpoint[output]
        return self._after(np.abs(self.y[:, output] - sp) > rel * abs(sp))

    def settle_time(self, output: int, rel: float = 0.02) -> float:
        """Time after which the output stays within ``rel`` of the *change* (s)."""
        sp = self.setpoint[output]
        band = rel * abs(sp - self.y_start[output])
        return self._after(np.abs(self.y[:, output] - sp) > band)

    def ise(self, output: int) -> float:
        return float(np.sum((self.y[:, output] - self.setpoint[output]) ** 2) * self.case.dt)


def calcium_models(order: int = 3):
    """State-shared model data of the calcium plant's OPI/OPII linearizations."""
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("calcium", outputs=("x5", "x6"))
    specs = []
    for name in ("OPI", "OPII"):
        lm = linearize(plant, name)
        red = balanced_truncation(lm.A, lm.B, lm.C, order=order, method="matchdc").reduced
        specs.append(StateSharedModel.model_from_linear(name, red.A, red.B, red.C, lm.u_op,
                                                        lm.y_op, CA_A_DESIGN))
    return specs, plant


def run_calcium(case: CalciumCase = CalciumCase()) -> CalciumRun:
    """Closed-loop transition between the calcium operating points (Figs. 6.4–6.5)."""
    from plant_sim.integrate import step as plant_step

    specs, plant = calcium_models(case.order)
    ops = plant.operating_points
    o1, o2 = ops[case.start], ops[case.target]
    y1, y2 = plant.outputs(o1.x, o1.u), plant.outputs(o2.x, o2.u)
    dt = case.dt
    ssm = StateSharedModel(CA_A_DESIGN, 2, dt, specs)
    settings = MPCSettings(nu=2, ny=2, P=case.P, M=case.M, Xi=case.weights,
                           Lambda=[case.move_weight] * 2, u_min=[0.0, 0.0],
                           u_target=[0.0, 0.0], u_target_weight=[case.j_rest_weight, 0.0],
                           budget_ms=OFFLINE_BUDGET_MS)
    law = MPCLaw(settings)
    law.prepare(ssm)
    span = np.abs(y2 - y1)
    index = PerformanceIndex(IndexSettings(mu=0.0, nu=1.0,
                                           output_weights=tuple(1.0 / span ** 2)), 2, dt)
    switcher = ModelSwitcher(2, 0.5, dt, initial=ssm.names.index(case.start))
    reference = ReferenceTrajectory(SetpointSchedule.step(y1, y2, 0.0), case.tau_ref, dt,
                                    initial=y1)
    x, u = o1.x.copy(), o1.u.copy()
    ssm.initialize(u, y1)
    law.reset(u, y1)
    K = int(round(case.t_end / dt)) + 1
    ts, ys, rs, us, act, fb = [], [], [], [], [], []
    for k in range(K):
        y = plant.outputs(x, u)
        J = index.update(ssm.errors(y))
        dec = switcher.step(J)
        u_new, info = law.compute(k, dec.active, ssm, y, reference.horizon(case.P), u)
        ssm.update(u_new, y)
        ts.append(k * dt)
        ys.append(y)
        rs.append(reference.r.copy())
        us.append(u_new.copy())
        act.append(dec.active)
        fb.append(bool(info.get("fallback", False)))
        if k == K - 1:
            break
        x = plant_step(plant, x, u_new, dt, t=k * dt)
        u = u_new
        reference.advance()
    return CalciumRun(case, np.asarray(ts), np.vstack(ys), np.vstack(rs), y2, y1,
                      np.vstack(us), np.asarray(act, dtype=int), np.asarray(fb),
                      tuple(ssm.names))


# -- reproduce ------------------------------------------------------------------------------
F4_BAND = 1.0      # kmol/h, R6.1/R6.3 check
P_BAND = 15.0      # kPa (10 % of the 150 kPa change), for "P settles" in R6.2
NOISE_WINDOW = 1.0  # h, moving average of the true output in noisy runs
NOISE_SEEDS = 5     # R6.2 is reported as the median over this many noise realisations


def _verdict_time(ours: float, seed: float, violated: bool, slack: float = 1.0) -> str:
    if violated or not math.isfinite(ours) or ours > seed + slack:
        return "differs"
    return "beaten" if ours < seed - slack else "reproduced"


def _plot(ctx: StudyContext, fn: str, *args) -> list[str]:
    """Draw one figure into ``ctx.plot_dir`` (nothing without a plot directory)."""
    if ctx.plot_dir is None:
        return []
    from services.reproduce import ch6_figures

    return getattr(ch6_figures, fn)(*args)


def _path(ctx: StudyContext, name: str):
    return None if ctx.plot_dir is None else ctx.plot_dir / name


def r6_1(ctx: StudyContext) -> ReproduceResult:
    run = run_reactor(ReactorCase(seed=ctx.seed))
    seed_structure = run_reactor(ReactorCase(order=2, seed=ctx.seed))
    targeted = run_reactor(ReactorCase(seed=ctx.seed, targets=PRODUCT_TARGETS))
    t_targets = targeted.settling_time(2, F4_BAND)
    t_f4 = run.settling_time(2, F4_BAND)
    p_max = float(run.y_true[:, 0].max())
    violated = p_max > P_LIMIT
    rows = [
        Row("F4 within ±1 kmol/h of 130 after the set-point change", "h", 10, t_f4),
        Row("maximum reactor pressure", "kPa", None, p_max),
        Row("pressure limit (soft in the MPC)", "kPa", None, P_LIMIT),
        Row("F4 settling with order-2 models (seed's structure)", "h", 10,
            seed_structure.settling_time(2, F4_BAND)),
        Row("F4 settling with the product's steady-state targets above the MPC", "h", 10,
            t_targets),
        Row("maximum reactor pressure with the steady-state targets", "kPa", None,
            float(targeted.y_true[:, 0].max())),
        Row("model switches", "-", None, float(np.sum(np.diff(run.active) != 0))),
        Row("fallback moves (QP not solved; offline, no wall-clock budget)", "-", None,
            float(run.fallback.sum())),
        Row("MPC solve time, max", "ms", None, float(run.solve_ms.max())),
    ]
    verdict = _verdict_time(t_f4, 10.0, violated)
    why = (f"F4 settles {t_f4:.1f} h after the step (seed: about 10 h), pressure peaks at "
           f"{p_max:.0f} kPa (limit {P_LIMIT:.0f}). State-shared model of the full-order "
           "OPI/OPII linearizations (MVs x1, x2, x3; OPII is a reconstruction). With the "
           "seed's order-2 models F4 settles in "
           f"{seed_structure.settling_time(2, F4_BAND):.1f} h, but a 2-state model with 3 "
           "inputs and 3 outputs has a steady-state gain of rank 2, so not all three "
           f"outputs can reach their set points (yA3 ends at "
           f"{seed_structure.y_true[-1, 1]:.1f} %, set point "
           f"{seed_structure.setpoint[-1, 1]:.1f} %). The seed's MPC alone is judged; with "
           f"the product's steady-state targets above it F4 settles in {t_targets:.1f} h.")
    figs = _plot(ctx, "plot_reactor", run, _path(ctx, "fig6_1.png"),
                 "Fig. 6.1: F4 100 -> 130 kmol/h, state-shared MPC", P_LIMIT)
    return ReproduceResult("R6.1", rows, verdict, why, figs)


#: Readings of "SNR 10:1" for R6.2: (label, noise_level, noise_dist). The signal is
#: each output's set-point change; 10:1 as an amplitude ratio (std or peak) or as a
#: power ratio (std = change / sqrt(10)).
NOISE_READINGS = (
    ("std = change/10 (normal)", 0.1, "normal"),
    ("peak = change/10 (uniform)", 0.1, "uniform"),
    ("power ratio 10 (std = change/sqrt 10)", 1.0 / math.sqrt(10.0), "normal"),
)


def _noise_stats(ctx: StudyContext, level: float, dist: str, noise: bool = True):
    """Medians over NOISE_SEEDS runs: F4/P settled (1-h mean in band), F4/P first reach."""
    runs = [run_reactor(ReactorCase(noise=noise, seed=ctx.seed + i, noise_level=level,
                                    noise_dist=dist)) for i in range(NOISE_SEEDS)]
    f4 = [r.settling_time(2, F4_BAND, NOISE_WINDOW) for r in runs]
    p = [r.settling_time(0, P_BAND, NOISE_WINDOW) for r in runs]
    f4_reach = [r.reach_time(2, F4_BAND) for r in runs]
    p_reach = [r.reach_time(0, P_BAND) for r in runs]
    p_max = max(float(r.y_true[:, 0].max()) for r in runs)
    med = lambda v: float(np.median(v))  # noqa: E731
    return runs, f4, {"f4": med(f4), "p": med(p), "f4_reach": med(f4_reach),
                      "p_reach": med(p_reach), "p_max": p_max}


def r6_2(ctx: StudyContext) -> ReproduceResult:
    runs, t_f4, main = _noise_stats(ctx, 0.1, "normal")
    f4, pp = main["f4"], main["p"]
    rows = [
        Row("F4 settles (1-h mean within ±1 kmol/h), median of 5 noise seeds", "h", 8, f4),
        Row("P settles (1-h mean within ±15 kPa), median of 5 noise seeds", "h", 10, pp),
        Row("F4 settling, first noise seed", "h", 8, t_f4[0]),
        Row("maximum true pressure over all seeds", "kPa", None, main["p_max"]),
    ]
    both = []  # readings x definitions where F4 = 8 ± 1 h and P = 10 ± 1 h together
    # the other readings of the noise, and "achieves its set point" as first reach
    _, _, filt = _noise_stats(ctx, 0.0, "normal")
    r6_1_f4 = run_reactor(ReactorCase(seed=ctx.seed)).settling_time(2, F4_BAND)
    rows += [Row("no noise, no filter (R6.1): F4 settles", "h", None, r6_1_f4),
             Row("filter only, no noise: F4 settles", "h", None, filt["f4"]),
             Row("filter only, no noise: P settles", "h", None, filt["p"])]
    for label, level, dist in NOISE_READINGS:
        st = main if (level, dist) == (0.1, "normal") else _noise_stats(ctx, level, dist)[2]
        for kf, kp in (("f4", "p"), ("f4_reach", "p_reach")):
            if abs(st[kf] - 8.0) <= 1.0 and abs(st[kp] - 10.0) <= 1.0:
                both.append(f"{label} ({'settled' if kf == 'f4' else 'first reach'})")
        rows += [Row(f"{label}: maximum true pressure", "kPa", None, st["p_max"]),
                 Row(f"{label}: F4 settles (median)", "h", 8, st["f4"]),
                 Row(f"{label}: P settles (median)", "h", 10, st["p"]),
                 Row(f"{label}: F4 first within ±1 kmol/h (median)", "h", 8, st["f4_reach"]),
                 Row(f"{label}: P first within ±15 kPa (median)", "h", 10, st["p_reach"])]
    violated = main["p_max"] > P_LIMIT
    v1, v2 = _verdict_time(f4, 8.0, violated), _verdict_time(pp, 10.0, violated)
    verdict = "differs" if "differs" in (v1, v2) else (
        "beaten" if v1 == v2 == "beaten" else "reproduced")
    why = (f"Noise SNR 10:1 taken as noise std = 1/10 of each output's set-point change "
           f"(P 15 kPa, yA3 1.65 %, F4 3 kmol/h), filtered with y_f = 0.2 y + 0.8 y_f. "
           f"F4 settles in {f4:.1f} h (seed 8), P in {pp:.1f} h (seed 10), medians over "
           f"{NOISE_SEEDS} noise seeds (F4 range {min(t_f4):.1f}-{max(t_f4):.1f} h); "
           f"no pressure violation: {not violated}. "
           + (f"F4 8 ± 1 h and P 10 ± 1 h together only with: {', '.join(both)}. " if both
              else "No reading of the noise or of 'achieve the set point' gives F4 8 ± 1 h "
                   "and P 10 ± 1 h together (rows). ")
           + f"The "
           f"filter alone costs {filt['f4'] - r6_1_f4:.1f} h of F4 settling ({filt['f4']:.1f} "
           f"h vs {r6_1_f4:.1f} h in R6.1), and at 1/10 of the change the filtered F4 noise "
           f"(std about 3 sqrt(0.2/1.8) = 1 kmol/h) is as wide as the ±1 kmol/h band, so "
           f"'settled' is noise-limited; F4 first reaches the band at {main['f4_reach']:.1f} "
           f"h (seed 8), but P reaches its set point within {main['p_reach']:.1f} h; the P "
           f"response depends on the reconstructed OPII and the lost P, M and sample time. "
           f"Not retuned: the seed's weights and filter are used, and R6.1 keeps its "
           f"tuning.")
    figs = _plot(ctx, "plot_reactor", runs[0], _path(ctx, "fig6_2.png"),
                 "Fig. 6.2: same transition, measurement noise SNR 10:1, filter 0.2", P_LIMIT)
    return ReproduceResult("R6.2", rows, verdict, why, figs)


def r6_3(ctx: StudyContext) -> ReproduceResult:
    run = run_reactor(ReactorCase(infer=True, seed=ctx.seed))
    t_f4 = run.settling_time(2, F4_BAND)
    p_max = float(run.y_true[:, 0].max())
    err = run.y_meas[:, 1] - run.y_true[:, 1]
    rows = [
        Row("F4 within ±1 kmol/h of 130, yA3 inferred", "h", 8, t_f4),
        Row("maximum reactor pressure", "kPa", None, p_max),
        Row("inferred minus true yA3, RMS", "mol %", None, float(np.sqrt(np.mean(err ** 2)))),
        Row("inferred minus true yA3, max |.|", "mol %", None, float(np.max(np.abs(err)))),
    ]
    verdict = _verdict_time(t_f4, 8.0, p_max > P_LIMIT)
    why = ("yA3 inferred from measured P, F4, liquid level and valve positions: the inert "
           "balance gives yB3, the liquid balance the reaction rate rD = F4 + rhoL dVL/dt, "
           "and the rate law then yC3, so yA3 = 1 - yB3 - yC3 (the seed does not describe "
           f"its estimator). F4 settles in {t_f4:.1f} h (seed: within 8 h).")
    figs = _plot(ctx, "plot_reactor", run, _path(ctx, "fig6_3.png"),
                 "Fig. 6.3: same transition, yA3 inferred", P_LIMIT)
    return ReproduceResult("R6.3", rows, verdict, why, figs)


R6_4_FACTOR = 2.0  # F4 SSE with yA3 inferred vs measured, Table 6.1's claim


def r6_4(ctx: StudyContext) -> ReproduceResult:
    measured = run_reactor(ReactorCase(seed=ctx.seed))
    inferred = run_reactor(ReactorCase(infer=True, seed=ctx.seed))
    rows = []
    for i, name, unit in ((0, "P", "kPa^2"), (1, "yA3", "(mol %)^2"), (2, "F4", "(kmol/h)^2")):
        rows.append(Row(f"SSE reference vs measured {name}, yA3 measured", unit, None,
                        measured.sse(i)))
        rows.append(Row(f"SSE reference vs measured {name}, yA3 inferred", unit, None,
                        inferred.sse(i)))
    # Table 6.1's numbers are lost; the claim it supports (text of sec. 6.1.2) is that
    # inferring yA3 costs little: the transition is still made within 8 h. Judged on
    # our runs: the F4 tracking error with yA3 inferred at most R6_4_FACTOR times the
    # one with yA3 measured.
    f4_ratio = inferred.sse(2) / measured.sse(2)
    rows.append(Row("F4 SSE ratio, yA3 inferred / measured", "-", None, float(f4_ratio)))
    ok = bool(np.isfinite(f4_ratio) and f4_ratio <= R6_4_FACTOR)
    why = ("Table 6.1's values are lost in the OCR, so no row has a printed number: these "
           "sums (true output minus reference trajectory, every 0.1 h over 15 h) are the "
           "baseline. The claim the table supports, that inferring yA3 costs the F4 "
           f"transition little, is judged on our runs: F4 SSE inferred / measured = "
           f"{f4_ratio:.2f} (tolerance <= {R6_4_FACTOR:g}).")
    return ReproduceResult("R6.4", rows, "reproduced" if ok else "differs", why, [])


def r6_5(ctx: StudyContext) -> ReproduceResult:
    """Our linearization of the reconstructed calcium plant against the printed models.

    The Hankel singular values and B column ratios of the printed order-3 models are
    among the targets the flux parameters were fitted to (docs/calcium_reconstruction.md,
    the ratios fix q2), so a match is ``calibrated``. The -10.605 cancellation follows
    from the RyR rate constants of the facts file and the operating point, not the fit.
    """
    from controller.linear import hankel_singular_values, minimal_realization
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("calcium", outputs=("x5", "x6"))
    lm = linearize(plant, "OPI")
    mr = minimal_realization(lm.A, lm.B, lm.C)
    full, kept = np.linalg.eigvals(lm.A), np.linalg.eigvals(mr.A)
    removed = [ev for ev in full if np.min(np.abs(kept - ev)) > 1e-6 * max(1.0, abs(ev))]
    cancelled = float(np.real(removed[0])) if len(removed) == 1 else math.nan
    hsv_ours = hankel_singular_values(lm.A, lm.B, lm.C)
    i5 = 3  # x5 row of the state (x1, x2, x3, x5, x6)
    ratio_ours = float(lm.B[i5, 0] / lm.B[i5, 1])  # J/q1
    lm2 = linearize(plant, "OPII")
    ratio_ours2 = float(lm2.B[i5, 0] / lm2.B[i5, 1])
    b_sv = np.linalg.svd(lm.B, compute_uv=False)
    rows = [
        Row("pole-zero pair removed by minimal realization, OPI", "1/s", -10.605, cancelled),
        Row("order after minimal realization", "-", 4.0, float(mr.A.shape[0])),
        Row("Hankel singular value 1, our OPI linearization", "-", 1.265, float(hsv_ours[0])),
        Row("Hankel singular value 2, our OPI linearization", "-", 0.500, float(hsv_ours[1])),
        Row("Hankel singular value 3, our OPI linearization", "-", 0.289, float(hsv_ours[2])),
        Row("B column ratio J/q1, our OPI linearization", "-", -1.19, ratio_ours),
        Row("B column ratio J/q1, our OPII linearization", "-", -1.13, ratio_ours2),
        Row("B: second/first singular value (rank 1)", "-", None, float(b_sv[1] / b_sv[0])),
    ]
    ok = (abs(cancelled + 10.605) <= 0.01 * 10.605
          and all(abs(r.ours - r.seed) <= 0.05 * abs(r.seed) for r in rows[2:5])
          and all(abs(r.ours - r.seed) <= 0.03 * abs(r.seed) for r in rows[5:7])
          and rows[7].ours < 1e-9)
    tol = ("tolerances: cancelled pair 1 %, Hankel singular values 5 %, B ratios 3 %, "
           "rank 1 to 1e-9")
    if ok:
        verdict = "calibrated"
        why = ("Linearization of the reconstructed calcium plant (plant_sim.calcium) at OPI "
               "= 0.137 µM: the -10.605 mode is removed by minimal realization (order 4, "
               "from the facts' RyR rate constants, not fitted), B has rank 1, and its J/q1 "
               "ratios and the order-3 Hankel singular values match the print; those were "
               "targets of the flux fit (q2 from the printed B ratios; vr, gamma0, gamma1, "
               "p1, p2, J_lm least squares on the printed models' poles and Hankel singular "
               "values, docs/calcium_reconstruction.md), so the match proves the fit, not "
               f"the method ({tol}). The printed B columns are ordered (q1, J).")
    else:
        verdict = "differs"
        why = (f"our linearization misses the print ({tol}; see rows), although the flux "
               "parameters of plant_sim.calcium were fitted to these printed models")
    return ReproduceResult("R6.5", rows, verdict, why, [])


def calcium_runs():
    """Fig. 6.4 (OPII→OPI) and Fig. 6.5 (OPI→OPII, weights 50/1 and 1/1)."""
    return {
        "OPII->OPI": run_calcium(CalciumCase(start="OPII", target="OPI")),
        "OPI->OPII": run_calcium(CalciumCase(start="OPI", target="OPII")),
        "OPI->OPII 1/1": run_calcium(CalciumCase(start="OPI", target="OPII",
                                                 weights=(1.0, 1.0))),
    }


def r6_6(ctx: StudyContext) -> ReproduceResult:
    runs = calcium_runs()
    down, up, up1 = runs["OPII->OPI"], runs["OPI->OPII"], runs["OPI->OPII 1/1"]
    j_min = float(min(r.u[:, 0].min() for r in runs.values()))
    t_check = max(down.reach_time(0), down.reach_time(1), up.reach_time(0), up.reach_time(1))
    rows = [
        Row("Fig. 6.4 OPII→OPI: xp5 within ±2 % of its set point", "s", 6, down.reach_time(0)),
        Row("Fig. 6.4 OPII→OPI: xp6 within ±2 % of its set point", "s", 6, down.reach_time(1)),
        Row("Fig. 6.4 OPII→OPI: xp5 within 2 % of its change", "s", 6, down.settle_time(0)),
        Row("Fig. 6.4 OPII→OPI: xp6 within 2 % of its change", "s", 6, down.settle_time(1)),
        Row("Fig. 6.4: J at the end (nominal 0)", "µM/s", 0, float(down.u[-1, 0])),
        Row("Fig. 6.5 OPI→OPII: xp5 within ±2 % of its set point", "s", 6, up.reach_time(0)),
        Row("Fig. 6.5 OPI→OPII: xp6 within ±2 % of its set point", "s", 6, up.reach_time(1)),
        Row("Fig. 6.5 OPI→OPII: xp5 within 2 % of its change", "s", 6, up.settle_time(0)),
        Row("smallest J over all runs (J >= 0)", "µM/s", None, j_min),
        Row("ISE xp5 OPI→OPII, weights 50/1", "µM^2 s", None, up.ise(0)),
        Row("ISE xp5 OPI→OPII, weights 1/1", "µM^2 s", None, up1.ise(0)),
        Row("xp6 set point OPI (plant) vs printed 38.6162", "µM", 38.6162,
            float(down.setpoint[1])),
        Row("xp6 set point OPII (plant) vs printed 39.262", "µM", 39.262, float(up.setpoint[1])),
    ]
    better = up.ise(0) < up1.ise(0)
    xp6_dev = max(abs(r.ours - r.seed) / r.seed for r in rows[-2:])
    violated = j_min < -1e-9
    # Judged on the stricter of the catalogue's ±2 % band and 2 % of xp5's change (the
    # ±2 % band on xp6 is wider than its whole change).
    t_strict = max(t_check, down.settle_time(0), up.settle_time(0))
    verdict = _verdict_time(t_strict, 6.0, violated or not better, slack=2.0)
    why = ("Reconstructed nonlinear calcium plant; MPC (P = 10, M = 4, weights 50/1, dt "
           "0.2 s) on a state-shared model of its OPI/OPII order-3 linearizations with "
           f"switching. Both directions reach ±2 % of the set points in {t_check:.1f} s "
           f"(seed about 6 s; within 2 % of the change: "
           f"{max(down.settle_time(0), up.settle_time(0)):.1f} s for xp5); J >= 0 "
           f"throughout (min {j_min:.2g}) and back at 0 after OPII→OPI; weights 50/1 give "
           f"{'a smaller' if better else 'a larger'} xp5 ISE than 1/1. Set points are the "
           "plant's steady states at xp5 = 0.137 / 0.167 µM (xp6 differs from the print by "
           f"up to {100 * xp6_dev:.1f} %, see rows; the SR Ca levels were among the targets "
           "of the calcium flux fit).")
    figs = _plot(ctx, "plot_calcium", runs, _path(ctx, "fig6_4_6_5.png"))
    return ReproduceResult("R6.6", rows, verdict, why, figs)


RESULTS = {"R6.1": r6_1, "R6.2": r6_2, "R6.3": r6_3, "R6.4": r6_4, "R6.5": r6_5,
           "R6.6": r6_6}
