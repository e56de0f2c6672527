"""``ssmpc bench mpc-step``: one controller sample of the state-shared MPC, in ms.

A sample is what the controller node does between a measurement and the move:
a-priori model errors, adaptation of the adaptive model (normalized least squares,
eq. 4.1), performance index and switching (eq. 4.6), the Δu MPC (vectors + QP with
DAQP) on the active model, and the shared-state update (eq. 3.10). Each case
reports the total (median, p99, max) and the medians/p99 of the parts.

Cases
    ``two-phase``: the chapter-6 reactor study in closed loop with the nonlinear plant
    (plant integration not timed): state-shared model of the OPI/OPII linearizations
    (order 24) plus one free-running adaptive model, P = 40, M = 4, 3 MVs;
    transitions 100 → 130 → 100 kmol/h repeated.

    ``te``: TE size as the state-shared engineer sizes it (n = 40, m = 5: shared order
    400, 3 fixed + 1 adaptive model), P = 10, M = 4, 5 MVs (QP: 21 variables, input,
    rate and soft output limits). The state-shared model is square (as many MVs as
    CVs), so 7 MVs with 5 CVs is not expressible; the 29-variable QP alone is in
    ``ssmpc bench qp``. The plant is model 0 of the set with an output disturbance;
    the set points move every 50 samples. Adaptation of the 1045-parameter model is
    timed as part of the sample.
"""

from __future__ import annotations

import time

import numpy as np

NAME = "mpc-step"
DESCRIPTION = "state-shared update + adapt + switch + MPC QP per sample (two-phase, TE size), ms"


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=600,
                        help="timed samples per case (two-phase: rounded to transitions)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (TE-size models)")
    parser.add_argument("--no-adapt", action="store_true",
                        help="skip the adaptation step (to see its share)")


class _Timer:
    def __init__(self) -> None:
        self.parts: dict[str, list[float]] = {}

    def add(self, name: str, t0: float, t1: float) -> None:
        self.parts.setdefault(name, []).append((t1 - t0) * 1e3)


def _sample(ssm, est, j_ad, index, switcher, law, y, reference, u, k, timer, adapt=True):
    """One controller sample; returns the move. Times each part into ``timer``."""
    clock = time.perf_counter
    t0 = clock()
    errors = ssm.errors(y)
    t1 = clock()
    if adapt and est is not None:
        step = est.update(ssm.regressor(), y)
        if step.updated or step.reset:
            ssm.set_params(j_ad, est.p)
    t2 = clock()
    J = index.update(errors)
    dec = switcher.step(J)
    t3 = clock()
    u_new, info = law.compute(k, dec.active, ssm, y, reference, u)
    t4 = clock()
    ssm.update(u_new, y)
    t5 = clock()
    timer.add("errors", t0, t1)
    timer.add("adapt", t1, t2)
    timer.add("switch", t2, t3)
    timer.add("mpc", t3, t4)
    timer.add("update", t4, t5)
    timer.add("total", t0, t5)
    return u_new, dec.active, info


def _case(name: str, timer: _Timer, **extra) -> dict:
    from services.benchmarking import latency_case

    parts = {f"{p}_median_ms": float(np.median(v)) for p, v in timer.parts.items()
             if p != "total"}
    parts.update({f"{p}_p99_ms": float(np.percentile(v, 99)) for p, v in timer.parts.items()
                  if p != "total"})
    return latency_case(name, timer.parts["total"], unit="ms", **parts, **extra)


def two_phase_case(samples: int, adapt: bool = True) -> dict:
    from controller.adaptation import NLSSettings, NormalizedLeastSquares
    from controller.mpc.law import MPCLaw
    from controller.reference import ReferenceTrajectory, SetpointSchedule
    from controller.state_shared import ModelSpec, StateSharedModel
    from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
    from plant_sim.integrate import step as plant_step
    from services.studies.ch6 import ReactorCase, reactor_models, reactor_settings

    case = ReactorCase()
    specs, a, plant = reactor_models(case.order)
    specs = list(specs) + [ModelSpec("adaptive", specs[0].theta, specs[0].bias, "adaptive")]
    ssm = StateSharedModel(a, 3, case.dt, specs)
    ops = plant.operating_points
    y1 = plant.outputs(ops["OPI"].x, ops["OPI"].u)
    y2 = plant.outputs(ops["OPII"].x, ops["OPII"].u)
    settings = reactor_settings(case, y1, y2)
    law = MPCLaw(settings)
    law.prepare(ssm)
    span = np.abs(y2 - y1)
    index = PerformanceIndex(IndexSettings(mu=case.index_mu, nu=case.index_nu,
                                           output_weights=tuple(1.0 / span ** 2)), ssm.k,
                             case.dt)
    switcher = ModelSwitcher(ssm.k, case.dwell, case.dt)
    j_ad = ssm.k - 1
    est = NormalizedLeastSquares(NLSSettings(), ssm.params_from_theta(ssm.theta(j_ad),
                                                                     ssm.bias(j_ad)), case.dt)
    per = 150  # samples per transition (15 h)
    n_tr = max(2, int(np.ceil(samples / per)))
    times = [per * i * case.dt for i in range(n_tr)]
    levels = [y2 if i % 2 == 0 else y1 for i in range(n_tr)]
    reference = ReferenceTrajectory(SetpointSchedule.sequence(levels, times), case.tau_ref,
                                    case.dt, initial=y1)
    x = ops["OPI"].x.copy()
    u = ops["OPI"].u[:3].copy()
    x4bar = float(ops["OPI"].u[3])
    ssm.initialize(u, y1)
    law.reset(u, y1)
    timer = _Timer()
    fallbacks = 0
    actives = set()
    for k in range(per * n_tr):
        y = plant.outputs(x, np.r_[u, x4bar])
        u, active, info = _sample(ssm, est, j_ad, index, switcher, law, y,
                                  reference.horizon(settings.P), u, k, timer, adapt)
        u = np.clip(u, 0.0, 100.0)
        fallbacks += bool(info.get("fallback"))
        actives.add(active)
        x = plant_step(plant, x, np.r_[u, x4bar], case.dt, t=k * case.dt)
        reference.advance()
    return _case("two-phase", timer, state_order=ssm.order, models=ssm.k, P=settings.P,
                 M=settings.M, qp_variables=settings.M * settings.nu + 1,
                 fallbacks=fallbacks, models_used=sorted(actives), adapt=adapt,
                 rebuilds=law.mpc.counters["rebuilds"])


def te_case(samples: int, seed: int = 0, adapt: bool = True) -> dict:
    from controller.adaptation import NLSSettings, NormalizedLeastSquares
    from controller.mpc import MPCSettings
    from controller.mpc.law import MPCLaw
    from controller.state_shared import ModelSpec, StateSharedModel, designer_polynomial
    from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex

    n, m, k_models, dt = 40, 5, 4, 0.01
    P, M = 10, 4
    rng = np.random.default_rng(seed)
    a = designer_polynomial(-np.geomspace(0.5, 5.0, n))
    ssm = StateSharedModel(a, m, dt)
    for j in range(k_models):
        kind = "adaptive" if j == k_models - 1 else "fixed"
        p = 1e-3 * rng.standard_normal(ssm.n_params + m)
        p[-m:] = rng.standard_normal(m)
        theta, bias = ssm.theta_from_params(p)  # structured: the adaptive one can be adapted
        ssm.add_model(ModelSpec(f"M{j}", theta, bias, kind))
    settings = MPCSettings(nu=m, ny=m, P=P, M=M, Xi=[3.0, 1.0, 10.0, 1.0, 2.0],
                           Lambda=np.full(m, 0.1), u_min=np.full(m, -5.0),
                           u_max=np.full(m, 5.0), du_max=np.full(m, 0.5),
                           y_min=np.full(m, -3.0), y_max=np.full(m, 3.0), slack_linear=1e3,
                           slack_quadratic=10.0, budget_ms=5.0)
    law = MPCLaw(settings, adaptive_refresh=50)
    t0 = time.perf_counter()
    law.prepare(ssm)
    prepare_ms = (time.perf_counter() - t0) * 1e3 / k_models
    index = PerformanceIndex(IndexSettings(), k_models, dt)
    switcher = ModelSwitcher(k_models, 0.05, dt)
    j_ad = k_models - 1
    est = NormalizedLeastSquares(NLSSettings(), ssm.params_from_theta(ssm.theta(j_ad),
                                                                     ssm.bias(j_ad)), dt)
    # Plant: model 0's prediction form on its own copy of the shared state.
    Phi, Gam, C, b = (np.asarray(v) for v in ssm.prediction_form(0)[:4])
    f = np.asarray(ssm.prediction_form(0).f)
    u = np.zeros(m)
    y = np.asarray(b, dtype=float).copy()
    ssm.initialize(u, y)
    x_plant = ssm.n
    law.reset(u, y)
    d = np.zeros(m)
    sp = y.copy()
    timer = _Timer()
    fallbacks = 0
    warm = 50
    for k in range(samples + warm):
        if k % 50 == 0:
            sp = b + rng.uniform(-1.0, 1.0, size=m)
            d = d + 0.05 * rng.standard_normal(m)
        y = C @ x_plant + b + d
        ref = np.tile(sp, (P, 1))
        t_part = _Timer() if k < warm else timer
        u, _active, info = _sample(ssm, est, j_ad, index, switcher, law, y, ref, u, k, t_part,
                                   adapt)
        fallbacks += bool(info.get("fallback")) and k >= warm
        x_plant = Phi @ x_plant + Gam @ u + f
    return _case("te", timer, state_order=ssm.order, models=k_models, P=P, M=M,
                 qp_variables=M * m + 1, adapted_parameters=est.n_params,
                 fallbacks=fallbacks, adapt=adapt, prepare_ms_per_model=prepare_ms,
                 rebuilds=law.mpc.counters["rebuilds"])


def run(args) -> list[dict]:
    samples = getattr(args, "samples", 600)
    if samples < 1:
        raise ValueError(f"samples: must be >= 1, got {samples}")
    adapt = not getattr(args, "no_adapt", False)
    return [two_phase_case(samples, adapt), te_case(samples, getattr(args, "seed", 0), adapt)]
