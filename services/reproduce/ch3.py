"""Seed chapter 3 (state-shared model structure): results R3.0-R3.11.

Two-phase reactor (sec. 3.6.1, Ricker's plant in :mod:`plant_sim.two_phase_reactor`):

- **Inputs are the flows F1 (feed 1), F2 (feed 2, pure A) and F3 (purge), in
  kmol/h**, each flow-controlled: the purge valve moves with pressure so that
  F3 = Cv3 x3 sqrt(P - Pr) follows its set point (:class:`ReactorFlowInputs`).
  Found here, not in the facts: with these inputs the OPI linearization gives
  the seed's eigenvalues to 4 digits (-3.6077, -1.2647, -0.0744, -0.0659), the
  order-2 balanced truncation the printed C matrix to 3-4 digits, Re = 7.66e-3
  (the printed "7.7 x 10^-?" has exponent -3), and the poles -0.0660 and
  -3.6822 implied by the printed Theta (R3.5). With valve inputs (facts §1.7) the
  slow mode is 6.5 % off and C does not match. The product-valve bias x4bar
  stays at its OPI value (the proportional level loop moves the product valve).
- **OPII: P = 2850 kPa, yA3 = 63 %, F4 = 130 kmol/h with x4bar kept at its OPI
  value** (so the P-only level loop settles at VL = 15.9 m^3 instead of 13.25).
  Found by fitting the seed's OPII eigenvalues with the flow-input model: this
  point gives (-4.4578, -1.3004, -0.1107, -0.1002) against the printed
  (-4.4591, -1.3009, -0.1107, -0.1001) and the printed OPII C matrix up to a
  sign per column. The plant module's provisional OPII (yA3 63.5 %, level at
  its set point) is not used. The seed's Fig. 3.11 axis (yA3 46.2-47.6 %) is
  then the figure's, not the point's.
- Outputs P (kPa), yA3 (mol %), F4 (kmol/h), time in h.

Perturbation protocol for the ARe tables (R3.3, R3.6): zero-mean Gaussian
perturbations of the three flows, standard deviation 3 % of each nominal value
(seed text), 1200 samples over 10 h (30 s sampling: the seed's plots span 0-10 h),
each random value held for 0.1 h. The hold is our inference: the seed does not
say; with a new value every 30 s the plant responses are ~3x smaller than the
ranges plotted in Figs. 3.4-3.9 (F4 98-101.5 kmol/h, yA3 46.85-47.25 %), while a
0.1 h hold gives those ranges. ARe is averaged over 5 seeds (``ctx.seed`` ..
``ctx.seed + 4``).

Calcium (sec. 3.6.2, R3.7-R3.10): :mod:`plant_sim.calcium` is a reconstruction
(flux parameters fitted to printed numbers; inputs J and q1 as in chapter 6,
outputs x2, x5, x6). The 5th-order linearization (5L), its minimal realization
(4L) and the order-3 balanced truncation (RE) are compared with the nonlinear
plant (NL) under perturbations of q1 (3 % of nominal; J's nominal value is 0,
the seed's chapter-3 inputs are lost), 1200 samples over 2 s, a new value every
0.02 s. The state-shared model (SS, a = (1, 2, 3)) has 2 inputs and 3 outputs
(the ``p`` extension of :class:`StateSharedModel`; order 15, 21 parameters),
where the seed's had 3 inputs (order 18, 30 parameters, R3.11, pure structure).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from controller.linear import (
    Realization,
    average_relative_error,
    balanced_truncation,
    left_mfd,
    zoh,
)
from controller.state_shared import (
    ModelSpec,
    StateSharedModel,
    companion_pair,
    designer_polynomial,
    theta_from_mfd,
)
from plant_sim.base import OperatingPoint, PlantModel, Variable
from services.reproduce import ReproduceResult, Row, StudyContext

REACTOR_INPUTS = ("F1", "F2", "F3")
OPII_SPEC = {"P": 2850.0, "yA3": 63.0, "F4": 130.0}  # x4bar kept at its OPI value
REACTOR_A = (1.0, 1.0)  # R3.4: a1 = a2 = 1
REACTOR_ORDER = 2  # R3.2
CALCIUM_A = (1.0, 2.0, 3.0)  # R3.11
N_SAMPLES = 1200
HORIZON_H = 10.0
SAMPLE_H = HORIZON_H / N_SAMPLES
HOLD_H = 0.1
PERTURBATION = 0.03
N_SEEDS = 5


# -- models for every case study --------------------------------------------------------
def state_shared_from_plant(plant_name: str, ops, a, dt: float, *, inputs=None, outputs=None,
                            order: int | None = None) -> StateSharedModel:
    """A state-shared model with one fixed model per operating point of a plant.

    Each point is linearized (:func:`plant_sim.linearize.linearize`), restricted to
    ``inputs``/``outputs`` (names; default all), optionally reduced by balanced
    truncation to ``order`` (unstable modes kept), and placed about its own point
    (bias, see :mod:`controller.state_shared`). The degree of ``a`` must be at
    least each model's McMillan degree; lower degrees are padded with a factor
    at the slowest root of omega.
    """
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant(plant_name)
    a = np.asarray(a, dtype=float)
    pad = float(np.min(np.abs(np.roots(np.concatenate(([1.0], a[::-1]))))))
    lms = [linearize(plant, op).select(inputs=inputs, outputs=outputs) for op in ops]
    ssm = StateSharedModel(a, lms[0].C.shape[0], dt)
    for op, lm in zip(ops, lms):
        if np.any(lm.D != 0):
            raise ValueError(f"inputs: the model at {op} has direct feedthrough (D != 0); "
                             "the state-shared form needs a strictly proper model")
        sys = Realization(lm.A, lm.B, lm.C, None)
        if order is not None:
            sys = balanced_truncation(sys, order=order, unstable="keep").reduced
        ssm.add_model(StateSharedModel.model_from_linear(op, sys.A, sys.B, sys.C, lm.u_op,
                                                         lm.y_op, a, pad_root=pad))
    return ssm


# -- shared helpers ----------------------------------------------------------------------
def _verdict(ok: bool, why_ok: str, why_not: str) -> tuple[str, str]:
    return ("reproduced", why_ok) if ok else ("differs", why_not)


def _within(ours: float, seed: float, rel: float) -> bool:
    return abs(ours - seed) <= rel * abs(seed)


@dataclass(frozen=True)
class ReactorModels:
    """Linear models of the two-phase reactor at one operating point."""

    op: str
    x_op: np.ndarray
    u_full: np.ndarray  # all four plant inputs at the point
    u_op: np.ndarray  # the three MVs
    y_op: np.ndarray
    full: Realization
    reduced: Realization
    hsv: np.ndarray
    Re: float
    output_names: tuple[str, ...]
    output_units: tuple[str, ...]


class ReactorFlowInputs(PlantModel):
    """Ricker's reactor driven by flow set points F1, F2, F3 (kmol/h) and x4bar (%).

    Ideal flow control: the valves are ``x1 = F1/Cv1``, ``x2 = F2/Cv2``,
    ``x3 = F3 / (Cv3 sqrt(P - Pr))``; states, outputs and units as the base plant.
    """

    name = "two_phase_reactor_flows"
    title = "Two-phase reactor with flow-controlled feeds and purge"
    time_unit = "h"

    def __init__(self) -> None:
        from plant_sim.two_phase_reactor import PARAMETERS, TwoPhaseReactor

        self.base = TwoPhaseReactor()
        self.p = PARAMETERS
        self.state_vars = self.base.state_vars
        self.output_vars = self.base.output_vars
        self.input_vars = (Variable("F1", "kmol/h", "feed-1 flow (A, B, C)"),
                           Variable("F2", "kmol/h", "feed-2 flow (pure A)"),
                           Variable("F3", "kmol/h", "purge flow"),
                           self.base.input_vars[3])
        self.state_scale = self.base.state_scale
        self.input_scale = np.array([10.0, 1.0, 1.0, 10.0])

    def _dp(self, x) -> float:
        p = self.p
        P = (x[0] + x[1] + x[2]) * p["R"] * p["T"] / (p["V"] - x[3])
        return math.sqrt(max(P - p["Pr"], 1e-12))

    def valves(self, x, u) -> np.ndarray:
        p = self.p
        return np.array([u[0] / p["Cv1"], u[1] / p["Cv2"], u[2] / (p["Cv3"] * self._dp(x)),
                         u[3]])

    def flows(self, x, valves) -> np.ndarray:
        p = self.p
        return np.array([valves[0] * p["Cv1"], valves[1] * p["Cv2"],
                         valves[2] * p["Cv3"] * self._dp(x), valves[3]])

    def rhs(self, t, x, u, d=None):
        return self.base.rhs(t, x, self.valves(x, u), d)

    def outputs(self, x, u):
        return self.base.outputs(x, self.valves(x, u))

    @property
    def operating_points(self) -> dict[str, OperatingPoint]:
        return _reactor_flow_points()


@lru_cache(maxsize=1)
def _reactor_flow_points() -> dict[str, OperatingPoint]:
    from plant_sim.steady_state import find_steady_state

    plant = ReactorFlowInputs()
    base = plant.base
    opi = base.operating_point("OPI")
    guess_x = [61.46, 11.76, 24.31, 15.92]  # near the fitted point
    guess_u = [78.78, 47.28, 58.46, float(opi.u[3])]
    ss = find_steady_state(base, guess_u, guess_x, free_inputs=("x1", "x2", "x3"),
                           targets=OPII_SPEC)
    return {
        "OPI": OperatingPoint("OPI", opi.x, plant.flows(opi.x, opi.u),
                              description="Ricker's base case, flows as inputs"),
        "OPII": OperatingPoint("OPII", ss.x, plant.flows(ss.x, ss.u),
                               description="P 2850 kPa, yA3 63 %, F4 130 kmol/h, x4bar of "
                               "OPI (fitted to the seed's OPII eigenvalues)",
                               confidence="reconstructed"),
    }


@lru_cache(maxsize=4)
def reactor_models(op: str) -> ReactorModels:
    from plant_sim.linearize import linearize

    plant = ReactorFlowInputs()
    point = plant.operating_point(op)
    lm = linearize(plant, point).select(inputs=REACTOR_INPUTS)
    full = Realization(lm.A, lm.B, lm.C, None)
    bt = balanced_truncation(full, order=REACTOR_ORDER)
    return ReactorModels(op, point.x, point.u, lm.u_op, lm.y_op, full, bt.reduced, bt.hsv,
                         bt.Re, lm.output_names, lm.output_units)


def reactor_state_shared(dt: float = SAMPLE_H) -> StateSharedModel:
    """The two-phase reactor's state-shared model: order-2 models at OPI and OPII."""
    ssm = StateSharedModel(REACTOR_A, 3, dt)
    for op in ("OPI", "OPII"):
        mod = reactor_models(op)
        r = mod.reduced
        ssm.add_model(StateSharedModel.model_from_linear(op, r.A, r.B, r.C, mod.u_op,
                                                         mod.y_op, REACTOR_A))
    return ssm


def _linear_response(sys: Realization, du: np.ndarray, dt: float) -> np.ndarray:
    """Deviation outputs at samples 1..K of a ZOH-driven linear model from rest."""
    d = zoh(sys, dt=dt)
    x = np.zeros(sys.order)
    out = np.empty((du.shape[0], sys.n_outputs))
    for k in range(du.shape[0]):
        x = d.Phi @ x + d.Gamma @ du[k]
        out[k] = sys.C @ x
    return out


@lru_cache(maxsize=32)
def reactor_perturbation_run(op: str, seed: int, hold_h: float = HOLD_H) -> dict[str, np.ndarray]:
    """Responses (absolute units, samples 1..K) of NL, FL, RE and SS to one perturbation."""
    from plant_sim.integrate import PiecewiseConstant, simulate

    mod = reactor_models(op)
    rng = np.random.default_rng(seed)
    hold = max(1, round(hold_h / SAMPLE_H))
    n_values = -(-N_SAMPLES // hold)
    du = np.repeat(PERTURBATION * mod.u_op * rng.standard_normal((n_values, 3)), hold,
                   axis=0)[:N_SAMPLES]
    U = np.tile(mod.u_full, (N_SAMPLES, 1))
    U[:, :3] = mod.u_op + du
    t = np.arange(N_SAMPLES) * SAMPLE_H
    sim = simulate(ReactorFlowInputs(), mod.x_op, PiecewiseConstant(t, U),
                   N_SAMPLES * SAMPLE_H, SAMPLE_H)
    y_nl = sim.y
    ssm = reactor_state_shared()
    ssm.initialize(mod.u_op, mod.y_op)
    j = ssm.names.index(op)
    y_ss = np.empty((N_SAMPLES, 3))
    for k in range(N_SAMPLES):
        ssm.update(U[k, :3], y_nl[k])  # after the update: estimates of y at sample k+1
        y_ss[k] = ssm.estimates()[j]
    return {
        "t": sim.t[1:],
        "NL": y_nl[1:],
        "FL": mod.y_op + _linear_response(mod.full, du, SAMPLE_H),
        "RE": mod.y_op + _linear_response(mod.reduced, du, SAMPLE_H),
        "SS": y_ss,
    }


def reactor_are(op: str, seed0: int, hold_h: float = HOLD_H) -> dict[str, np.ndarray]:
    """ARe (%) per output for the pairs of Table 3.3 and SS-NL, averaged over N_SEEDS."""
    pairs = {"NL-FL": ("NL", "FL"), "FL-RE": ("FL", "RE"), "NL-RE": ("NL", "RE"),
             "SS-NL": ("NL", "SS"), "SS-RE": ("RE", "SS")}
    y_op = reactor_models(op).y_op
    acc = {k: [] for k in pairs}
    for s in range(seed0, seed0 + N_SEEDS):
        run = reactor_perturbation_run(op, s, hold_h)
        for k, (a, b) in pairs.items():
            acc[k].append(average_relative_error(run[a], run[b], y_op))
    return {k: np.mean(v, axis=0) for k, v in acc.items()}


def _reactor_figures(ctx: StudyContext, which: str) -> list[str]:
    if ctx.plot_dir is None:
        return []
    from services.reproduce.ch3_figures import plot_responses

    figs = []
    mod = reactor_models("OPI")
    names, units = mod.output_names, mod.output_units
    run = reactor_perturbation_run("OPI", ctx.seed)
    if which in ("linear", "all"):
        figs.append(plot_responses(ctx.plot_dir / "fig3_04-3_09_reactor_OPI_NL_FL_RE.png",
                                   run["t"], {k: run[k] for k in ("NL", "FL", "RE")}, names,
                                   units, "Figs. 3.4-3.9: two-phase reactor near OPI"))
        run2 = reactor_perturbation_run("OPII", ctx.seed)
        figs.append(plot_responses(ctx.plot_dir / "fig3_10-3_12_reactor_OPII_NL_FL_RE.png",
                                   run2["t"], {k: run2[k] for k in ("NL", "FL", "RE")}, names,
                                   units, "Figs. 3.10-3.12: two-phase reactor near OPII "
                                   "(reconstructed point)"))
    if which in ("ss", "all"):
        figs.append(plot_responses(ctx.plot_dir / "fig3_13-3_15_reactor_OPI_NL_SS.png",
                                   run["t"], {k: run[k] for k in ("NL", "SS")}, names, units,
                                   "Figs. 3.13-3.15: state-shared model vs nonlinear, OPI"))
    return figs


# -- R3.0 ----------------------------------------------------------------------------------
def r3_0(ctx: StudyContext) -> ReproduceResult:
    """Structural facts: parameter counts, Theta uniqueness/exactness, truncation stability."""
    rng = np.random.default_rng(ctx.seed)
    worst_tf, stable = 0.0, True
    n, m = 4, 3
    a = designer_polynomial(-np.array([0.5, 1.0, 2.0, 4.0]))
    for _ in range(10):
        poles = -rng.uniform(0.2, 5.0, n)
        Q, _r = np.linalg.qr(rng.standard_normal((n, n)))
        sys = Realization(Q @ np.diag(poles) @ Q.T, rng.standard_normal((n, m)),
                          rng.standard_normal((m, n)), None)
        ssm = StateSharedModel(a, m, 0.1, [ModelSpec("M", theta_from_mfd(left_mfd(sys), a))])
        A, B, C, _b, _f = ssm.continuous_form(0)
        big = Realization(A, B, C, None)
        w = np.logspace(-3, 3, 61)
        ref = sys.frequency_response(w)
        err = np.max(np.abs(big.frequency_response(w) - ref)) / np.max(np.abs(ref))
        worst_tf = max(worst_tf, float(err))
        stable &= balanced_truncation(sys, order=2).reduced.is_stable()
    counts = [(1, 2, None), (3, 2, 20.0), (3, 3, 30.0), (5, 40, 1040.0)]
    rows = []
    for m_, n_, printed in counts:
        ssm = StateSharedModel(designer_polynomial(-np.geomspace(0.5, 5.0, n_)), m_, 1.0)
        label = "2n for m=1" if printed is None else f"m={m_}, n={n_}"
        rows.append(Row(f"N_theta = n(m^2+1), {label}", "-", printed, float(ssm.n_params)))
    seed_order = StateSharedModel(designer_polynomial(-np.geomspace(0.5, 5.0, 40)), 5, 1.0)
    rows.append(Row("state-shared order 2nm, n=40, m=5 (R7.15)", "-", 400.0,
                    float(seed_order.order)))
    rows.append(Row("max relative |H_ss - H| over 10 random 3x3 order-4 models", "-", None,
                    worst_tf))
    rows.append(Row("balanced truncations to order 2 stable (1 = all)", "-", None,
                    float(stable)))
    ok = (all(r.seed == r.ours for r in rows if r.seed is not None) and rows[0].ours == 4
          and worst_tf <= 1e-9 and stable)
    verdict, why = _verdict(ok, "exact: counts n(m^2+1), Theta of eq. 3.16 reproduces H(s) to "
                            f"{worst_tf:.1e}, truncations stable",
                            "a structural check failed (see rows)")
    return ReproduceResult("R3.0", rows, verdict, why)


# -- R3.1 ----------------------------------------------------------------------------------
R31_SEED = {"OPI": (-3.6077, -1.2647, -0.0745, -0.0659),
            "OPII": (-4.4591, -1.3009, -0.1107, -0.1001)}


def r3_1(ctx: StudyContext) -> ReproduceResult:
    """OPI is Ricker's base case (not fitted); OPII's point was fitted to the printed
    OPII eigenvalues, so the OPII rows prove the fit: verdict ``calibrated``."""
    import control

    rows, ok, worst = [], True, {"OPI": 0.0, "OPII": 0.0}
    for op, seed_ev in R31_SEED.items():
        mod = reactor_models(op)
        ev = np.sort(np.linalg.eigvals(mod.full.A).real)
        for i, (s, o) in enumerate(zip(seed_ev, ev)):
            rows.append(Row(f"{op} eigenvalue {i + 1}", "1/h", s, float(o)))
            rel = abs(o - s) / abs(s)
            ok &= rel <= 0.02
            worst[op] = max(worst[op], float(rel))
        rc = np.linalg.matrix_rank(control.ctrb(mod.full.A, mod.full.B))
        ro = np.linalg.matrix_rank(control.obsv(mod.full.A, mod.full.C))
        rows.append(Row(f"{op} rank of controllability matrix", "-", 4.0, float(rc)))
        rows.append(Row(f"{op} rank of observability matrix", "-", 4.0, float(ro)))
        ok &= rc == 4 and ro == 4
    dev = (f"largest deviation OPI {100 * worst['OPI']:.2f} %, OPII {100 * worst['OPII']:.2f} %"
           " (tolerance 2 %)")
    if ok:
        verdict = "calibrated"
        why = (f"all eigenvalues within 2 % ({dev}), ranks 4. OPII's operating point (P 2850 "
               "kPa, yA3 63 %, F4 130 kmol/h, x4bar of OPI; Table 3.1 is lost) was found by "
               "fitting these printed OPII eigenvalues with the flow-input model, so the OPII "
               "rows prove the fit, not the method. OPI (Ricker's base case, flows F1, F2, F3 "
               "as inputs, flow-controlled purge) is not fitted and matches on its own")
    else:
        verdict = "differs"
        why = f"{dev}; see the module notes on the flow inputs and the fitted OPII"
    return ReproduceResult("R3.1", rows, verdict, why)


# -- R3.2 ----------------------------------------------------------------------------------
R32_C = {"OPI": [[3.2755, -7.3066], [-0.1357, -0.0391], [-0.0114, -0.2008]],
         "OPII": [[2.2572, -6.8873], [-0.1252, -0.1170], [0.0187, -0.2578]]}
R32_POLES_DERIVED = (-0.0660, -3.6822)  # from the printed Theta (R3.5), not printed


def _sign_aligned(C: np.ndarray, printed: np.ndarray) -> np.ndarray:
    """C with each column's sign chosen to agree best with the printed matrix (the
    balanced realization is unique only up to a sign per state)."""
    signs = np.where(np.sum(C * printed, axis=0) < 0, -1.0, 1.0)
    return C * signs


def r3_2(ctx: StudyContext) -> ReproduceResult:
    rows = []
    opi = reactor_models("OPI")
    opii = reactor_models("OPII")
    rows.append(Row("OPI order-2 Re (eq. 3.22; seed 7.7e-?, exponent lost)", "-", None,
                    opi.Re))
    rows.append(Row("OPII order-2 Re", "-", None, opii.Re))
    poles = np.sort(np.linalg.eigvals(opi.reduced.A).real)[::-1]
    for p, d in zip(poles, R32_POLES_DERIVED):
        rows.append(Row(f"OPI order-2 pole (derived from printed Theta: {d})", "1/h", None,
                        float(p)))
    for op, mod in (("OPI", opi), ("OPII", opii)):
        C = _sign_aligned(mod.reduced.C, np.array(R32_C[op]))
        for i in range(3):
            for j in range(2):
                rows.append(Row(f"{op} C[{i},{j}] of the order-2 model (column sign aligned)",
                                "-", R32_C[op][i][j], float(C[i, j])))
    re_ok = opi.Re <= 0.077
    poles_ok = all(_within(p, d, 0.05) for p, d in zip(poles, R32_POLES_DERIVED))
    c_match = all(_within(r.ours, r.seed, 0.05) for r in rows if r.seed is not None)
    ok = re_ok and poles_ok
    pole_dev = max(abs(p - d) / abs(d) for p, d in zip(poles, R32_POLES_DERIVED))
    why_c = ("all 12 printed C entries within 5 % (up to a sign per column)" if c_match else
             "some C entries differ by more than 5 % from the print")
    why_ok = (f"order-2 Re at OPI {opi.Re:.3g}, which fixes the printed '7.7 x 10^-?' as "
              f"7.7e-3; order-2 poles within {100 * pole_dev:.2f} % of those implied by the "
              f"printed Theta; {why_c}")
    why_not = (f"order-2 Re at OPI {opi.Re:.3g} ({'<=' if re_ok else '>'} 0.077); order-2 poles "
               f"{100 * pole_dev:.2f} % from the values implied by the printed Theta (tolerance "
               f"5 %); {why_c}")
    verdict, why = _verdict(ok, why_ok, why_not)
    return ReproduceResult("R3.2", rows, verdict, why, _reactor_figures(ctx, "linear"))


# -- R3.3 ----------------------------------------------------------------------------------
R33 = {  # pair -> OPI (P, yA3, F4), OPII (P, yA3, F4), printed Table 3.3
    "NL-FL": ((0.001, 0.001, 0.002), (0.002, 0.004, 0.025)),
    "FL-RE": ((0.003, 0.086, 0.270), (0.000, 0.016, 0.010)),
    "NL-RE": ((0.004, 0.086, 0.270), (0.002, 0.017, 0.022)),
}


def _are_ok(ours: float, printed: float) -> bool:
    """Catalogue check: <= 2x printed, or <= 0.01 % absolute where printed <= 0.005."""
    return ours <= 2 * printed or (printed <= 0.005 and ours <= 0.01)


def r3_3(ctx: StudyContext) -> ReproduceResult:
    rows, fails = [], []
    res = {op: reactor_are(op, ctx.seed) for op in ("OPI", "OPII")}
    names = reactor_models("OPI").output_names
    for pair, printed in R33.items():
        for op, vals in zip(("OPI", "OPII"), printed):
            for i, name in enumerate(names):
                ours = float(res[op][pair][i])
                rows.append(Row(f"ARe {pair} {op} {name}", "%", vals[i], ours))
                if not _are_ok(ours, vals[i]):
                    fails.append(f"{pair} {op} {name} {ours:.3g} vs {vals[i]}")
    order_ok = all(np.all(res[op]["NL-FL"] <= res[op]["NL-RE"]) for op in res)
    better = sum(r.ours < r.seed for r in rows if r.seed)
    if not fails and order_ok:
        verdict, why = "reproduced", (
            f"all 18 ARe within the catalogue's tolerance and NL-FL <= NL-RE; {better} of 18 "
            "below the printed value")
    else:
        verdict = "differs"
        why = ("outside 2x: " + "; ".join(fails) + ". OPI (all 9 rows) is within the "
               "tolerance. OPII's Table 3.1 is lost; our OPII, fitted to the printed "
               "eigenvalues (R3.1) and matching the printed C (R3.2), has an order-2 Re of "
               f"{reactor_models('OPII').Re:.3f} (OPI: {reactor_models('OPI').Re:.4f}), so "
               "its truncation drops more than the seed's apparently did (the seed's OPII "
               "FL-RE errors are below its OPI ones); the perturbation hold time is inferred")
        if not order_ok:
            why += "; ordering NL-FL <= NL-RE violated"
    return ReproduceResult("R3.3", rows, verdict, why, _reactor_figures(ctx, "linear"))


# -- R3.4, R3.5, R3.6 ------------------------------------------------------------------------
def r3_4(ctx: StudyContext) -> ReproduceResult:
    F, G = companion_pair(REACTOR_A, 3)
    ssm = StateSharedModel(REACTOR_A, 3, SAMPLE_H)
    ev = np.linalg.eigvals(F[:2, :2])
    rows = [
        Row("F rows (nm)", "-", 6.0, float(F.shape[0])),
        Row("G columns (m)", "-", 3.0, float(G.shape[1])),
        Row("adaptable parameters n(m^2+1)", "-", 20.0, float(ssm.n_params)),
        Row("state-shared order 2nm", "-", None, float(ssm.order)),
        Row("F block eigenvalue real part (-1/2)", "-", None, float(ev[0].real)),
        Row("F block eigenvalue |imag| (sqrt(3)/2)", "-", None, float(abs(ev[0].imag))),
    ]
    ok = (F.shape == (6, 6) and G.shape == (6, 3) and ssm.n_params == 20
          and abs(ev[0].real + 0.5) < 1e-12 and abs(abs(ev[0].imag) - np.sqrt(3) / 2) < 1e-12)
    verdict, why = _verdict(ok, "exact", "structure differs (see rows)")
    return ReproduceResult("R3.4", rows, verdict, why)


def r3_5(ctx: StudyContext) -> ReproduceResult:
    mod = reactor_models("OPI")
    theta = theta_from_mfd(left_mfd(mod.reduced), REACTOR_A)
    t2 = theta[6:8, 0]
    rows = [Row("Theta2 entry a1 - d1 (OPI)", "-", 0.7569, float(t2[0])),
            Row("Theta2 entry a2 - d2 (OPI)", "-", -2.7482, float(t2[1]))]
    tight = all(abs(r.ours - r.seed) <= 0.02 for r in rows)
    loose = all(_within(r.ours, r.seed, 0.05) for r in rows)
    if tight:
        verdict, why = "reproduced", "both entries within 0.02 of the print"
    elif loose:
        verdict, why = "reproduced", (
            "both entries within 5 % (the catalogue's tolerance when the plant differs "
            "slightly: our slow mode is 6.5 % off the seed's, R3.1); not within 0.02")
    else:
        verdict, why = "differs", "entries more than 5 % from the print; see R3.1/R3.2"
    return ReproduceResult("R3.5", rows, verdict, why)


R36 = (0.079, 0.097, 0.290)


def _error_filter_peak(reduced: Realization) -> tuple[float, float]:
    """(max |d(jw) / omega(jw)|, its w in rad/h) for the reactor's (F, G) and a reduced model."""
    d = left_mfd(reduced).d
    a = np.concatenate((REACTOR_A, [1.0]))
    w = np.logspace(-3, 3, 2001)
    pw = (1j * w)[:, None] ** np.arange(d.size)[None, :]
    mag = np.abs((pw @ d) / (pw @ a))
    return float(mag.max()), float(w[np.argmax(mag)])


def r3_6(ctx: StudyContext) -> ReproduceResult:
    res = reactor_are("OPI", ctx.seed)
    names = reactor_models("OPI").output_names
    rows = [Row(f"ARe SS-NL OPI {n}", "%", s, float(o))
            for n, s, o in zip(names, R36, res["SS-NL"])]
    rows += [Row(f"ARe SS-RE OPI {n} (not printed)", "%", None, float(o))
             for n, o in zip(names, res["SS-RE"])]
    fast = reactor_are("OPI", ctx.seed, SAMPLE_H)["SS-NL"]
    rows += [Row(f"ARe SS-NL OPI {n}, new perturbation every 30 s (sensitivity)", "%", None,
                 float(o)) for n, o in zip(names, fast)]
    gain, w_peak = _error_filter_peak(reactor_models("OPI").reduced)
    rows.append(Row("peak |d(jw)/omega(jw)|: SS error = (d/omega) x RE error", "-", None, gain))
    fails = [r for r in rows[:3] if r.ours > 2 * r.seed]
    if fails:
        verdict = "differs"
        why = ("above 2x printed: " + ", ".join(r.name for r in fails) + ". Driven by the "
               "measured y, each state-shared output error is (d/omega) times the reduced "
               "model's error (y - y_ss = d/omega (y - y_re) for diagonal Theta2), and with "
               f"the seed's a1 = a2 = 1 the filter d/omega peaks at {gain:.2f} at "
               f"{w_peak:.2f} rad/h, "
               "so the SS error exceeds the RE error when the perturbation has content there "
               "(our 0.1 h hold, inferred). With a new perturbation every 30 s the same model "
               "gives " + ", ".join(f"{o:.3g}" for o in fast) + " %, within the print.")
    else:
        below = all(r.ours < r.seed for r in rows[:3])
        verdict = "beaten" if below else "reproduced"
        why = ("state-shared model (order-2 OPI/OPII models, a1 = a2 = 1, exact ZOH, driven "
               "by sampled u and y) within 2x of the printed ARe"
               + ("; all three below the print" if below else ""))
    return ReproduceResult("R3.6", rows, verdict, why, _reactor_figures(ctx, "ss"))


# -- calcium, R3.7-R3.10 ---------------------------------------------------------------------
CA_HORIZON_S = 2.0  # the seed's calcium plots span 0-2 s
CA_SAMPLE_S = CA_HORIZON_S / N_SAMPLES
CA_HOLD_S = CA_HORIZON_S / 100  # as for the reactor: a new value every 1/100 of the horizon
CA_ORDER = 3
CA_OPS = ("OPI", "OPII")
CA_OUTPUTS = ("x2", "x5", "x6")


@dataclass(frozen=True)
class CalciumModels:
    op: str
    x_op: np.ndarray
    u_op: np.ndarray
    y_op: np.ndarray
    full: Realization  # 5th order (5L)
    minimal: Realization  # 4th order (4L)
    reduced: Realization  # order 3 (RE)
    hsv: np.ndarray  # of the minimal model


@lru_cache(maxsize=4)
def calcium_models(op: str) -> CalciumModels:
    from controller.linear import minimal_realization
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("calcium")
    lm = linearize(plant, op)
    full = Realization(lm.A, lm.B, lm.C, None)
    mini = minimal_realization(full)
    bt = balanced_truncation(mini, order=CA_ORDER)
    return CalciumModels(op, plant.operating_point(op).x, lm.u_op, lm.y_op, full, mini,
                         bt.reduced, bt.hsv)


def calcium_state_shared(dt: float = CA_SAMPLE_S) -> StateSharedModel:
    """Calcium state-shared model: order-3 models at OPI and OPII, a = (1, 2, 3).

    Two inputs (J, q1) and three outputs (x2, x5, x6), so n1 has 6 states and n2
    9 (order 15, 21 parameters) instead of the seed's square 18 / 30 (R3.11).
    """
    ssm = StateSharedModel(CALCIUM_A, 2, dt, p=3)
    for op in CA_OPS:
        mod = calcium_models(op)
        r = mod.reduced
        ssm.add_model(StateSharedModel.model_from_linear(op, r.A, r.B, r.C, mod.u_op,
                                                         mod.y_op, CALCIUM_A, square=False))
    return ssm


@lru_cache(maxsize=16)
def calcium_perturbation_run(op: str, seed: int) -> dict[str, np.ndarray]:
    """NL, 5L, 4L, RE and SS responses to a q1 perturbation (J stays at its nominal 0)."""
    from plant_sim import get_plant
    from plant_sim.integrate import PiecewiseConstant, simulate

    mod = calcium_models(op)
    rng = np.random.default_rng(seed)
    hold = max(1, round(CA_HOLD_S / CA_SAMPLE_S))
    n_values = -(-N_SAMPLES // hold)
    du = np.zeros((N_SAMPLES, 2))
    du[:, 1] = np.repeat(PERTURBATION * mod.u_op[1] * rng.standard_normal(n_values),
                         hold)[:N_SAMPLES]
    t = np.arange(N_SAMPLES) * CA_SAMPLE_S
    U = mod.u_op + du
    sim = simulate(get_plant("calcium"), mod.x_op, PiecewiseConstant(t, U),
                   N_SAMPLES * CA_SAMPLE_S, CA_SAMPLE_S)
    ssm = calcium_state_shared()
    ssm.initialize(mod.u_op, mod.y_op)
    j = ssm.names.index(op)
    y_ss = np.empty((N_SAMPLES, 3))
    for k in range(N_SAMPLES):
        ssm.update(U[k], sim.y[k])
        y_ss[k] = ssm.estimates()[j]
    return {
        "SS": y_ss,
        "t": sim.t[1:],
        "NL": sim.y[1:],
        "5L": mod.y_op + _linear_response(mod.full, du, CA_SAMPLE_S),
        "4L": mod.y_op + _linear_response(mod.minimal, du, CA_SAMPLE_S),
        "RE": mod.y_op + _linear_response(mod.reduced, du, CA_SAMPLE_S),
    }


CA_PAIRS = {"5L-4L": ("5L", "4L"), "SS-RE": ("RE", "SS"), "4L-RE": ("4L", "RE"),
            "4L-NL": ("4L", "NL"), "SS-NL": ("NL", "SS"), "RE-NL": ("RE", "NL")}


def calcium_are(op: str, seed0: int) -> dict[str, np.ndarray]:
    y_op = calcium_models(op).y_op
    acc = {k: [] for k in CA_PAIRS}
    for s in range(seed0, seed0 + N_SEEDS):
        run = calcium_perturbation_run(op, s)
        for k, (a, b) in CA_PAIRS.items():
            acc[k].append(average_relative_error(run[a], run[b], y_op))
    return {k: np.mean(v, axis=0) for k, v in acc.items()}


CA_WHY = ("the calcium plant is a reconstruction (plant_sim.calcium: flux parameters fitted "
          "to printed numbers, the chapter-3 complex pole pairs 16 %/51 % off, facts §2.6) "
          "and assigns OPI to x5 = 0.137 uM, the facts the other way round")


def _calcium_figures(ctx: StudyContext) -> list[str]:
    if ctx.plot_dir is None:
        return []
    from services.reproduce.ch3_figures import plot_responses

    run = calcium_perturbation_run("OPI", ctx.seed)
    return [plot_responses(ctx.plot_dir / "fig3_18-3_19_calcium_OPI_NL_SS.png", run["t"],
                           {k: run[k] for k in ("NL", "SS")}, CA_OUTPUTS,
                           ("-", "uM", "uM"), "Figs. 3.18-3.19: calcium near OPI, nonlinear "
                           "vs state-shared (reconstructed plant)", time_unit="s")]


R37 = {"OPI": (-841.32, -1.6876, 2.4192, -0.8245), "OPII": (-685.37, -1.0749, 2.5178, -0.7834)}


def r3_7(ctx: StudyContext) -> ReproduceResult:
    import control

    rows, worst = [], 0.0
    for op, (fast, re_c, im_c, slow) in R37.items():
        mod = calcium_models(op)
        ev = mod.minimal.poles()
        cplx = ev[np.argmax(np.abs(ev.imag))]
        real = np.sort(ev[np.abs(ev.imag) < 1e-9].real)
        ours = (real[0], cplx.real, abs(cplx.imag), real[-1])
        names = ("fast eigenvalue", "complex pair, real part", "complex pair, |imag|",
                 "slow eigenvalue")
        for nm, sv, ov in zip(names, (fast, re_c, im_c, slow), ours):
            rows.append(Row(f"{op} minimal model {nm}", "1/s", sv, float(ov)))
            worst = max(worst, abs(ov - sv) / abs(sv))
        rows.append(Row(f"{op} minimal order", "-", 4.0, float(mod.minimal.order)))
        rc = np.linalg.matrix_rank(control.ctrb(mod.full.A, mod.full.B))
        rows.append(Row(f"{op} rank of the 5th-order controllability matrix", "-", 4.0,
                        float(rc)))
    ok = worst <= 0.02 and all(r.ours == r.seed for r in rows if "order" in r.name
                                or "rank" in r.name)
    # The calcium fluxes were fitted to these printed fast and slow eigenvalues (among
    # other printed numbers): a match proves the fit (calibrated), a miss is 'differs'.
    fitted = ("the fluxes of plant_sim.calcium were fitted to the printed fast and slow "
              "eigenvalues of these minimal models (docs/calcium_reconstruction.md)")
    verdict = "calibrated" if ok else "differs"
    why = (f"eigenvalues within 2 % (largest deviation {100 * worst:.1f} %), minimal order 4: "
           f"{fitted}, so the match proves the fit" if ok else
           f"minimal order 4 and rank 4 as printed, but eigenvalues up to {100 * worst:.0f} % "
           f"off (tolerance 2 %): {CA_WHY}; {fitted}, but the complex pairs are not matched")
    return ReproduceResult("R3.7", rows, verdict, why)


R38 = {("OPI", 2): 15.66, ("OPII", 2): 24.20, ("OPI", 3): 0.39, ("OPII", 3): 0.44}


def r3_8(ctx: StudyContext) -> ReproduceResult:
    from controller.linear import relative_error

    rows = []
    for (op, k), seed in R38.items():
        rows.append(Row(f"Re order {k} {op} (eq. 3.22)", "%", seed,
                        100 * relative_error(calcium_models(op).hsv, k)))
    within = all(_within(r.ours, r.seed, 0.20) for r in rows)
    qual = all(r.ours < 1.0 for r in rows if "order 3" in r.name) and all(
        r.ours > 10.0 for r in rows if "order 2" in r.name)
    if within:
        verdict, why = "reproduced", "all four Re within 20 % of the print"
    else:
        swapped = [100 * relative_error(calcium_models(o).hsv, 2) for o in ("OPII", "OPI")]
        verdict = "differs"
        why = ("qualitative checks " + ("hold" if qual else "FAIL") + " (order 3 below 1 %, "
               "order 2 above 10 %: order 3 is the choice, as in the seed) but not all values "
               f"are within 20 %: {CA_WHY}. With the facts' assignment (OPI = 0.167 uM) the "
               f"order-2 values would be {swapped[0]:.2f} / {swapped[1]:.2f} % against 15.66 "
               "/ 24.20 %")
    return ReproduceResult("R3.8", rows, verdict, why)


R39 = {"OPI": (0.25, 8.25, 0.29), "OPII": (0.95, 10.38, 0.54)}
R310 = {  # Table 3.6 (None where the exponent is lost in OCR)
    "5L-4L": ((None, None, 3.18e-9), (2.076e-9, None, 3.225e-9)),
    "SS-RE": ((2.52e-2, 3.46e-2, 1.51e-2), (3.311e-2, 4.641e-2, 0.015)),
    "4L-RE": ((0.26, 7.95, 0.12), (0.26, 9.63, 0.16)),
    "4L-NL": ((0.31, 0.63, 0.28), (1.15, 1.93, 0.53)),
    "SS-NL": ((0.25, 8.25, 0.29), (0.95, 1.04, 0.54)),
    "RE-NL": ((0.26, 8.25, 0.29), (0.98, 1.04, 0.54)),
}


def r3_9(ctx: StudyContext) -> ReproduceResult:
    rows = []
    for op, printed in R39.items():
        res = calcium_are(op, ctx.seed)["RE-NL"]
        for name, sv, ov in zip(CA_OUTPUTS, printed, res):
            rows.append(Row(f"ARe RE-NL {op} {name}", "%", sv, float(ov)))
    fails = [r.name for r in rows if not (r.seed / 2 <= r.ours <= 2 * r.seed)]
    order_ok = all(rows[i * 3 + 1].ours > max(rows[i * 3].ours, rows[i * 3 + 2].ours)
                   for i in range(2))
    why = ("outside 2x: " + ", ".join(fails) + "; " if fails else "") + (
        "x5 error largest as in the seed" if order_ok else "x5 error not the largest") + (
        f"; {CA_WHY}; the seed's three chapter-3 inputs are lost, so only q1 is perturbed "
        "(3 % of nominal; J's nominal is 0)")
    verdict = "reproduced" if not fails and order_ok else "differs"
    return ReproduceResult("R3.9", rows, verdict, why, _calcium_figures(ctx))


def r3_10(ctx: StudyContext) -> ReproduceResult:
    rows, fails = [], []
    res = {op: calcium_are(op, ctx.seed) for op in CA_OPS}
    for pair, printed in R310.items():
        for op, vals in zip(CA_OPS, printed):
            for name, sv, ov in zip(CA_OUTPUTS, vals, res[op][pair]):
                rows.append(Row(f"ARe {pair} {op} {name}", "%", sv, float(ov)))
                if pair == "5L-4L":
                    if ov >= 1e-6:
                        fails.append(f"{pair} {op} {name}")
                elif pair == "SS-RE":
                    if ov > 0.1:  # catalogue: SS and RE agree closely
                        fails.append(f"{pair} {op} {name}")
                elif sv is not None and not sv / 2 <= ov <= 2 * sv:
                    fails.append(f"{pair} {op} {name}")
    ss_re = max(float(np.max(res[op]["SS-RE"])) for op in CA_OPS)
    why = ("5L-4L at round-off as printed; SS-RE at most "
           f"{ss_re:.3g} % (catalogue: <= 0.1 %). The state-shared model has the plant's two "
           "inputs (J, q1) and three outputs (order 15; the seed's three chapter-3 inputs "
           "are lost). ")
    x5_ratio = res["OPI"]["4L-RE"][1] / res["OPI"]["4L-NL"][1]
    why += (f"Qualitatively as printed: at OPI the reduced model's x5 error is {x5_ratio:.0f}x "
            "the minimal model's (truncation hurts x5). ")
    if fails:
        verdict = "differs"
        why += (f"Outside 2x of the print: {len(fails)} of {len(rows)} rows ("
                + ", ".join(fails[:6]) + (", ..." if len(fails) > 6 else "") + "): "
                f"{CA_WHY}; only q1 is perturbed (3 %), so our responses are much smaller "
                "than the seed's (Fig. 3.18 shows x2 over 0.165-0.195)")
    else:
        verdict = "reproduced"
        why += "All computed rows within 2x of the print."
    return ReproduceResult("R3.10", rows, verdict, why, _calcium_figures(ctx))


# -- R3.11 ---------------------------------------------------------------------------------
def r3_11(ctx: StudyContext) -> ReproduceResult:
    F, G = companion_pair(CALCIUM_A, 3)
    ssm = StateSharedModel(CALCIUM_A, 3, 0.01)
    ev = np.linalg.eigvals(F[:3, :3])
    ev = ev[np.argsort(ev.real)]
    rows = [
        Row("state-shared order 2nm", "-", 18.0, float(ssm.order)),
        Row("F rows", "-", None, float(F.shape[0])),
        Row("G columns", "-", None, float(G.shape[1])),
        Row("adaptable parameters n(m^2+1)", "-", 30.0, float(ssm.n_params)),
        Row("root of s^3+3s^2+2s+1 (real)", "-", None, float(ev[0].real)),
        Row("complex root, real part", "-", None, float(ev[1].real)),
        Row("complex root, |imag|", "-", None, float(abs(ev[1].imag))),
    ]
    ok = ssm.order == 18 and ssm.n_params == 30 and F.shape == (9, 9) and G.shape == (9, 3)
    verdict, why = _verdict(ok, "exact (roots -2.3247, -0.3376 +- 0.5623j as derived in the "
                            "catalogue)", "structure differs")
    return ReproduceResult("R3.11", rows, verdict, why)


RESULTS = {
    "R3.0": r3_0,
    "R3.1": r3_1,
    "R3.2": r3_2,
    "R3.3": r3_3,
    "R3.4": r3_4,
    "R3.5": r3_5,
    "R3.6": r3_6,
    "R3.7": r3_7,
    "R3.8": r3_8,
    "R3.9": r3_9,
    "R3.10": r3_10,
    "R3.11": r3_11,
}
