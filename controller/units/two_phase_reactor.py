"""The chapter-6 tuning of Ricker's two-phase reactor: state-shared Δu MPC (seed §6.1.2).

Plant :class:`plant_sim.two_phase_reactor.TwoPhaseReactor` (Ricker's model, level
P-loop closed). Manipulated variables: feed-1 valve x1, feed-2 (pure A) valve x2 and
purge valve x3; the product valve bias x4bar stays at its OPI value and the level loop
moves the effluent valve. Why not the seed's "feed, purge, reactor effluent": with x2
held, the 130 kmol/h point (OPII, P 2850 kPa, yA3 63.5 %) has no steady state with
the purge open (a least-squares search ends with x3 = 0 and a residual), so both
feeds must move; Ricker's own pairing uses the same three valves.

Models: linearizations at OPI and OPII (inputs x1, x2, x3; outputs P, yA3, F4),
reduced by balanced truncation (DC gain kept) and placed in one state-shared model
(seed: order 2 per model, F_j = [[0, 1], [−1, −1]]); the active model is chosen by
the performance index (eq. 4.6) with a dwell time; the MPC runs on the active model's
prediction form. Output weights Ξ = 3, 1, 10 on outputs scaled by their set-point
change; equal move weights. Pressure limit 2950 kPa as a soft output limit (the
seed's limit is lost; Ricker's shutdown is 3000 kPa).

Steady-state targets (:mod:`controller.units.mpc_targets`, a unit setting:
``ReactorCase.targets``, ``build(..., targets=)``): each sample the active model's DC
gain, the set points (rank 2), P <= P_LIMIT (rank 1) and the valve ranges give MV and
CV targets; the MV targets are the MPC's input targets, a relaxed set point's CV target
cuts its reference, and the relaxation is an alarm and ``extra["targets"]``. No
economic term: with three set points on three valves the targets are fixed by the set
points wherever they hold, and where they cannot the ranked relaxation (in the MPC's
own output weights) decides; Ricker's purge loss of A (yA3 F3) would only choose among
targets with a CV switched off, and is left out. Product default: on
(:data:`PRODUCT_TARGETS`). The chapter-6 studies keep the seed's MPC alone
(:data:`SEED_TARGETS`): the seed has no target layer, and R6.1 reports the targets'
run beside it.

Measured, noise-free closed loop on the nonlinear plant (:func:`run_reactor`: OPI
start, first-order reference, τ 1 h; IAE over 15 h, kPa h, mol % h, kmol/h h;
"settles": within ±1 kmol/h, ±15 kPa)::

    case                                 targets  F4 settles  P settles  P max   IAE P, yA3, F4
    R6.1 (OPII: 2850, 63.5, 130)         off        7.2 h      4.8 h    2871.2  215, 25.9, 70.5
                                         on         6.7 h      3.7 h    2866.9  194, 28.3, 66.3
    R6.3, yA3 inferred                   off        7.2 h      4.5 h    2868.7  211, 26.2, 69.8
                                         on         6.4 h      3.6 h    2867.8  193, 28.8, 65.9
    order-2 models (seed's structure)    off        9.4 h      3.8 h    2867.6  223, 43.7, 62.1
                                         on         8.6 h      3.7 h    2885.1  184, 45.3, 50.3

    unreachable set points     targets  P, yA3, F4 at 25 h     targets of the last sample  P max
    P above its limit          off      2950.0, 63.66, 139.68  -                           2954.5
    (3000, 63.5, 140)          on       2950.0, 63.50, 140.00  2950.0, 63.50, 140.00       2953.7
    x3 at 100 %                off      2858.6, 53.29, 128.36  -                           2874.7
    (2850, 47, 130)            on       2857.2, 53.43, 128.41  2857.2, 53.41, 128.42       2884.8

With noise (R6.2, medians of 5 seeds): F4 10.6 h off, 10.5 h on; P 8.3 h both. The
verdicts with targets on: R6.1 beaten, R6.2 differs, R6.4 reproduced, as without; R6.3
beaten (6.4 h against the seed's 8) where without it is reproduced (7.2 h). Above its
limit the MPC alone trades the unreachable pressure set point against the others by its
weights (yA3 and F4 stay off); with targets the set points that can hold do. Where a
valve limits, the targets say in advance where the plant will settle, and the valve
stays off its stop (x3 at 100 % in 94 % of the samples without targets, never with them:
tests/test_two_phase_targets.py). The pressure's transient peak a few kPa over the
soft limit is the MPC's, the same either way.

:func:`build` makes the service's controller; :func:`run_reactor` is the offline
closed loop of the chapter-6 study (:mod:`services.reproduce.ch6`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from controller.blas import single_threaded
from controller.interfaces import ControlDecision
from controller.linear import balanced_truncation
from controller.mpc import OFFLINE_BUDGET_MS, FirstOrderFilter, MPCSettings
from controller.mpc.law import MPCLaw
from controller.multimodel import MultiModelController, MultiModelSettings
from controller.reference import ReferenceTrajectory, SetpointSchedule
from controller.state_shared import StateSharedModel
from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
from controller.units.config import time_scale_s
from controller.units.mpc_targets import TargetingLaw, TargetSettings

__all__ = ["CV", "CV_UNITS", "MV", "PRODUCT_TARGETS", "P_LIMIT", "REALTIME_BUDGET_MS",
           "SEED_TARGETS", "ReactorCase",
           "ReactorController", "ReactorRun", "TargetSettings", "build", "reactor_law",
           "reactor_models", "reactor_settings", "run_reactor"]

MV = ("x1", "x2", "x3")
CV = ("P", "yA3", "F4")
CV_UNITS = ("kPa", "mol %", "kmol/h")
P_LIMIT = 2950.0  # kPa, soft limit in the MPC; the check uses the same number
REALTIME_BUDGET_MS = 50.0  # ms, an MPC step's wall-clock budget in the service's node
#: The MPC alone on its set points (the seed's path).
SEED_TARGETS = TargetSettings(enabled=False)
#: The product's steady-state targets above the MPC: the pressure limit rank 1, the set
#: points rank 2, no back-off (docs/two_phase_targets.md).
PRODUCT_TARGETS = TargetSettings(enabled=True)


# -- two-phase reactor -------------------------------------------------------------------
@dataclass(frozen=True)
class ReactorCase:
    """One closed-loop run of §6.1.2.

    Parameters
    ----------
    noise : bool
        Add measurement noise at SNR 10:1 (R6.2) and filter it (α = 0.2).
    noise_level : float
        Noise size relative to each output's set-point change: the standard deviation
        for ``noise_dist="normal"``, the peak for ``"uniform"`` (SNR 10:1 -> 0.1).
    noise_dist : {"normal", "uniform"}
        Distribution of the measurement noise.
    infer : bool
        Replace the yA3 measurement by an inferential estimate (R6.3).
    order : int
        Order of each reduced model in the state-shared model (seed: 2).
    P, M : int
        Horizons in samples.
    move_weight : float
        Equal Λ on the three valve moves (per (% / 100)²).
    tau_ref : float
        Time constant of the first-order reference trajectories, h.
    dt : float
        Sample time, h.
    t_end : float
        Length of the run, h.
    t_step : float
        Time of the set-point change, h.
    seed : int
        Noise seed.
    setpoint : tuple of 3 float, optional
        Set points (P kPa, yA3 mol %, F4 kmol/h) after the step; default OPII's
        outputs (the seed's transition). Weights stay scaled by the OPI -> OPII change.
    targets : TargetSettings
        The steady-state target optimizer above the MPC
        (:mod:`controller.units.mpc_targets`); ``TargetSettings(enabled=False)`` is the
        seed's MPC alone.
    realtime : bool
        Hold each MPC step to the wall-clock budget :data:`REALTIME_BUDGET_MS` and move
        on the previous plan when a step overruns it, as a service node does. Off by
        default (offline runs in simulated time, the studies): a busy machine then
        slows the run instead of changing its moves, so the result depends on the
        case alone.
    """

    noise: bool = False
    infer: bool = False
    order: int = 4
    P: int = 40
    M: int = 4
    move_weight: float = 30.0
    tau_ref: float = 1.0
    dt: float = 0.1
    t_end: float = 15.0
    t_step: float = 0.5
    du_max: float = 5.0
    seed: int = 0
    noise_level: float = 0.1
    noise_dist: str = "normal"
    weights: tuple[float, float, float] = (3.0, 1.0, 10.0)
    index_mu: float = 0.0
    index_nu: float = 1.0
    dwell: float = 0.5
    setpoint: tuple[float, float, float] | None = None
    targets: TargetSettings = SEED_TARGETS
    realtime: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.targets, TargetSettings):
            raise ValueError(f"targets: must be a TargetSettings, got {self.targets!r}")
        if self.setpoint is not None:
            sp = tuple(self.setpoint)
            if len(sp) != 3 or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                       and math.isfinite(v) for v in sp):
                raise ValueError(f"setpoint: expected 3 finite numbers (P, yA3, F4), got "
                                 f"{self.setpoint!r}")
            object.__setattr__(self, "setpoint", tuple(float(v) for v in sp))
        if self.noise_dist not in ("normal", "uniform"):
            raise ValueError(f"noise_dist: must be 'normal' or 'uniform', got {self.noise_dist!r}")
        if not (math.isfinite(self.noise_level) and self.noise_level >= 0):
            raise ValueError(f"noise_level: must be a finite number >= 0, got {self.noise_level!r}")


@dataclass(frozen=True)
class ReactorRun:
    """Signals of one reactor run (K samples)."""

    case: ReactorCase
    t: np.ndarray
    y_true: np.ndarray      # (K, 3) plant outputs P, yA3, F4
    y_meas: np.ndarray      # (K, 3) what the controller received (noise, inferred yA3)
    reference: np.ndarray   # (K, 3) current reference trajectory
    setpoint: np.ndarray    # (K, 3)
    u: np.ndarray           # (K, 3) valves x1, x2, x3 (%)
    active: np.ndarray      # (K,) active model index
    fallback: np.ndarray    # (K,) bool
    solve_ms: np.ndarray
    model_names: tuple[str, ...] = ()
    counters: dict = field(default_factory=dict)
    u_target: np.ndarray | None = None  # (K, 3) MV targets (NaN: none), targets on
    y_target: np.ndarray | None = None  # (K, 3) CV targets
    alarms: tuple[str, ...] = ()        # every distinct alarm text, in order
    relaxed: np.ndarray | None = None   # (K,) bool: some specification relaxed

    def settling_time(self, output: int, band: float, window: float = 0.0) -> float:
        """Time from the set-point change after which ``|y_true − set point| <= band``
        for good (h); with ``window`` > 0 (h) the trailing moving average of the true
        output is used (noisy runs)."""
        y = self.y_true[:, output]
        n = int(round(window / self.case.dt))
        if n > 1:
            c = np.cumsum(np.r_[0.0, y])
            idx = np.arange(y.size)
            lo = np.maximum(idx + 1 - n, 0)
            y = (c[idx + 1] - c[lo]) / (idx + 1 - lo)
        err = np.abs(y - self.setpoint[-1, output])
        outside = np.flatnonzero(err > band)
        if outside.size == 0:
            return float(self.t[0])
        if outside[-1] == self.t.size - 1:
            return math.inf
        return float(self.t[outside[-1] + 1] - self.case.t_step)

    def reach_time(self, output: int, band: float) -> float:
        """First time after the set-point change at which the true output is within
        ``band`` of its final set point (h; inf if never): "achieves its set point"."""
        y = self.y_true[:, output]
        after = self.t >= self.case.t_step
        inside = np.flatnonzero(after & (np.abs(y - self.setpoint[-1, output]) <= band))
        return float(self.t[inside[0]] - self.case.t_step) if inside.size else math.inf

    def sse(self, output: int) -> float:
        """Sum of squared errors between reference and measured value (Table 6.1)."""
        return float(np.sum((self.reference[:, output] - self.y_true[:, output]) ** 2))


def reactor_models(order: int = 2, a=None):
    """State-shared model of the reactor's OPI and OPII linearizations.

    Returns
    -------
    specs : list of ModelSpec
    a : ndarray
        Designer polynomial (lowest power first).
    plant : TwoPhaseReactor
    """
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("two_phase_reactor")
    if a is None:
        a = (1.0, 1.0) if order == 2 else tuple(np.poly(-np.ones(order))[::-1][:-1])
    specs = []
    for name in ("OPI", "OPII"):
        lm = linearize(plant, name).select(MV, CV)
        red = balanced_truncation(lm.A, lm.B, lm.C, order=order, method="matchdc").reduced
        specs.append(StateSharedModel.model_from_linear(name, red.A, red.B, red.C, lm.u_op,
                                                        lm.y_op, a))
    return specs, np.asarray(a, dtype=float), plant


class _CompositionObserver:
    """Inferential yA3 from measured P, F4, liquid level and valve positions (R6.3).

    Two steps, both from the plant's own balances (facts §1.2):

    - the inert: ``dNB/dt = yB1 F1 − (NB/NV) F3`` integrated with the measured pressure
      and level (``NV = P (V − VL)/(R T)``); it is stable (purge), so yB3 = NB/NV
      forgets its initial error;
    - the reaction rate from the liquid balance, ``rD = F4 + ρL dVL/dt``, and then yC3
      from ``rD = k0 (P yA3)^1.2 (P yC3)^0.4`` with ``yA3 = 1 − yB3 − yC3``, taking the
      root on the C-rich branch (``yC3 > (1 − yB3)/4``) where the plant operates.

    So ``yA3 = 1 − yB3 − yC3``. Integrating the C balance instead is unstable with the
    pressure held at its measured value (the rate falls as C accumulates).
    """

    def __init__(self, plant, x0) -> None:
        from plant_sim.two_phase_reactor import PARAMETERS

        self.K = PARAMETERS
        self.NB = float(x0[1])
        self.VL_prev: float | None = None

    def _nv(self, P, VL):
        K = self.K
        return P * (K["V"] - VL) / (K["R"] * K["T"])

    def estimate(self, P: float, VL: float, F4: float, dt: float) -> float:
        K = self.K
        dVL = 0.0 if self.VL_prev is None else (VL - self.VL_prev) / dt
        self.VL_prev = VL
        rD = max(F4 + K["rhoL"] * dVL, 0.0)
        yB = min(max(self.NB / self._nv(P, VL), 0.0), 1.0)
        rest = 1.0 - yB
        c = K["k0"] * max(P, 0.0) ** 1.6
        lo, hi = 0.25 * rest, rest  # rate falls monotonically from its peak to zero here
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            if c * (rest - mid) ** 1.2 * mid ** 0.4 > rD:
                lo = mid
            else:
                hi = mid
        return 100.0 * max(rest - 0.5 * (lo + hi), 0.0)

    def advance(self, P: float, VL: float, u4, dt: float, substeps: int = 10) -> None:
        K = self.K
        nv = self._nv(P, VL)
        F1 = K["Cv1"] * u4[0]
        F3 = K["Cv3"] * u4[2] * math.sqrt(max(P - K["Pr"], 0.0))
        h = dt / substeps
        for _ in range(substeps):
            self.NB += h * (K["yB1"] * F1 - self.NB / nv * F3)


def reactor_settings(case: ReactorCase, y1, y2) -> MPCSettings:
    """MPC settings of §6.1.2 for a transition between outputs ``y1`` and ``y2``.

    Output weights Ξ = 3, 1, 10 act on outputs scaled by their set-point change (the
    units differ by 100x); equal move weights on valve moves in units of 100 %.
    """
    span = np.abs(np.asarray(y2) - np.asarray(y1))
    return MPCSettings(
        nu=3, ny=3, P=case.P, M=case.M, Xi=np.asarray(case.weights) / span ** 2,
        Lambda=np.full(3, case.move_weight / 100.0 ** 2), u_min=np.zeros(3),
        u_max=np.full(3, 100.0), du_max=np.full(3, case.du_max),
        y_max=[P_LIMIT, np.inf, np.inf], slack_scale=[span[0], 1.0, 1.0], slack_linear=1e3,
        slack_quadratic=1.0, filter_alpha=0.2 if case.noise else 1.0,
        budget_ms=REALTIME_BUDGET_MS if case.realtime else OFFLINE_BUDGET_MS,
        u_target_weight=np.full(3, case.targets.input_weight if case.targets.enabled else 0.0))


def reactor_law(settings: MPCSettings, targets: TargetSettings):
    """The unit's control law: the MPC, with the steady-state targets when enabled."""
    law = MPCLaw(settings)
    if not targets.enabled:
        return law
    return TargetingLaw(law, targets, CV, MV, CV_UNITS)


@single_threaded
def run_reactor(case: ReactorCase = ReactorCase()) -> ReactorRun:
    """Closed loop F4 100 → 130 kmol/h with the state-shared MPC (Figs. 6.1–6.3)."""
    from plant_sim.integrate import step as plant_step

    specs, a, plant = reactor_models(case.order)
    ops = plant.operating_points
    op1, op2 = ops["OPI"], ops["OPII"]
    y1 = plant.outputs(op1.x, op1.u)
    y2 = plant.outputs(op2.x, op2.u)
    x4bar = float(op1.u[3])
    dt = case.dt
    ssm = StateSharedModel(a, 3, dt, specs)

    settings = reactor_settings(case, y1, y2)
    span = np.abs(y2 - y1)
    if case.setpoint is not None:
        y2 = np.asarray(case.setpoint, dtype=float)
    law = reactor_law(settings, case.targets)
    law.prepare(ssm)
    index = PerformanceIndex(IndexSettings(mu=case.index_mu, nu=case.index_nu,
                                           output_weights=tuple(1.0 / span ** 2)), ssm.k, dt)
    switcher = ModelSwitcher(ssm.k, case.dwell, dt, initial=0)
    reference = ReferenceTrajectory(SetpointSchedule.step(y1, y2, case.t_step), case.tau_ref,
                                    dt, initial=y1)
    rng = np.random.default_rng(case.seed)
    noise_size = span * case.noise_level  # SNR 10:1 on the transition's amplitude
    # The state-shared model is driven by the same (filtered) signal the MPC sees.
    meas_filter = FirstOrderFilter(0.2) if case.noise else None
    observer = _CompositionObserver(plant, op1.x) if case.infer else None

    x = op1.x.copy()
    u = op1.u[:3].copy()
    K = int(round(case.t_end / dt)) + 1
    out = {k: [] for k in ("t", "yt", "ym", "r", "sp", "u", "act", "fb", "ms", "ut", "yt_",
                           "rx")}
    alarms: dict[str, None] = {}
    nan3 = np.full(3, np.nan)
    initialized = False
    for k in range(K):
        t = k * dt
        u4 = np.r_[u, x4bar]
        y_true = plant.outputs(x, u4)
        y = y_true.copy()
        if case.noise:
            draw = (rng.normal(size=3) if case.noise_dist == "normal"
                    else rng.uniform(-1.0, 1.0, size=3))
            y = y + draw * noise_size
        if observer is not None:
            y[1] = observer.estimate(y[0], x[3], y[2], dt)
        y_model = meas_filter.update(y) if meas_filter is not None else y
        if not initialized:
            ssm.initialize(u, y_model)
            law.reset(u, y_model)
            initialized = True
        J = index.update(ssm.errors(y_model))
        dec = switcher.step(J)
        u_new, info = law.compute(k, dec.active, ssm, y, reference.horizon(settings.P), u)
        u_new = np.clip(u_new, 0.0, 100.0)
        ssm.update(u_new, y_model)
        out["t"].append(t)
        out["yt"].append(y_true)
        out["ym"].append(y)
        out["r"].append(reference.r.copy())
        out["sp"].append(reference.schedule.at(t))
        out["u"].append(u_new.copy())
        out["act"].append(dec.active)
        out["fb"].append(bool(info.get("fallback", False)))
        out["ms"].append(float(info.get("solve_ms", 0.0)))
        alarms.update(dict.fromkeys(info.get("alarms", ())))
        tg = info.get("targets")
        ok = tg is not None and "mv" in tg
        out["ut"].append(np.array([tg["mv"][n] for n in MV]) if ok else nan3)
        out["yt_"].append(np.array([tg["cv"][n] for n in CV]) if ok else nan3)
        out["rx"].append(bool(ok and any(r["kind"] == "spec" for r in tg["relaxed"])))
        if k == K - 1:
            break
        if observer is not None:
            observer.advance(y[0], x[3], np.r_[u_new, x4bar], dt)
        x = plant_step(plant, x, np.r_[u_new, x4bar], dt, t=t)
        u = u_new
        reference.advance()
    return ReactorRun(
        case=case, t=np.asarray(out["t"]), y_true=np.vstack(out["yt"]),
        y_meas=np.vstack(out["ym"]), reference=np.vstack(out["r"]),
        setpoint=np.vstack(out["sp"]), u=np.vstack(out["u"]),
        active=np.asarray(out["act"], dtype=int), fallback=np.asarray(out["fb"]),
        solve_ms=np.asarray(out["ms"]), model_names=tuple(ssm.names),
        counters=law.counters(), u_target=np.vstack(out["ut"]),
        y_target=np.vstack(out["yt_"]), alarms=tuple(alarms), relaxed=np.asarray(out["rx"]))


class ReactorController(MultiModelController):
    """The unit's multiple-model controller; with targets on, each decision carries the
    sample's steady-state targets as ``extra["targets"]`` (status, MV and CV targets,
    bias, relaxed limits: :class:`controller.units.mpc_targets.TargetingLaw`) and a
    relaxed set point as an alarm naming it."""

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        report = getattr(self.law, "report", None)
        dec = super().step(k, t, y, reference)
        now = getattr(self.law, "report", None)
        if now is None or now is report:  # targets off, or not computed this sample
            return dec
        dec.extra["targets"] = now
        return dec


def build(cfg, plant, u0, grades, targets: TargetSettings = PRODUCT_TARGETS
          ) -> ReactorController:
    """Chapter 6's state-shared MPC on the two-phase reactor (OPI/OPII reduced models),
    with the steady-state targets of ``targets`` above it (the product's by default)."""
    if cfg.plant != "two_phase_reactor":
        raise ValueError("controller: ssmpc is configured for the two_phase_reactor unit here; "
                         "the TE unit uses controller 'te'")
    case = ReactorCase(targets=targets)
    specs, a, _ = reactor_models(case.order)
    dt = cfg.sample_period_s / time_scale_s(plant)
    ssm = StateSharedModel(a, 3, dt, specs)
    y = np.array([g["setpoints"] for g in grades.values()])
    span = np.maximum(y.max(axis=0) - y.min(axis=0), 1e-6)
    settings = MPCSettings(
        nu=3, ny=3, P=case.P, M=case.M, Xi=np.asarray(case.weights) / span ** 2,
        Lambda=np.full(3, case.move_weight / 100.0 ** 2), u_min=np.zeros(3),
        u_max=np.full(3, 100.0), du_max=np.full(3, case.du_max),
        y_max=[P_LIMIT, np.inf, np.inf], slack_scale=[span[0], 1.0, 1.0],
        slack_linear=1e3, slack_quadratic=1.0, budget_ms=REALTIME_BUDGET_MS,
        u_target=np.asarray(u0, float),
        u_target_weight=np.full(3, targets.input_weight if targets.enabled else 0.0))
    law = reactor_law(settings, targets)
    law.prepare(ssm)
    index = IndexSettings(mu=case.index_mu, nu=case.index_nu,
                          output_weights=tuple(1.0 / span ** 2), min_dwell=case.dwell)
    ctl = ReactorController(ssm, law, np.asarray(u0, float),
                            MultiModelSettings(index=index, u_min=0.0, u_max=100.0),
                            kinds=["fixed"] * ssm.k)
    ctl.horizon = case.P  # the node passes this many reference rows
    return ctl
