"""``ssmpc bench mpc-step``: one controller sample of the state-shared MPC, in ms.

A sample is what the controller node does between a measurement and the move (the
critical path, ``total``): a-priori model errors, adaptation of the adaptive model
(normalized least squares, eq. 4.1, its covariance products prepared the sample
before), performance index and switching (eq. 4.6) and the Δu MPC (vectors + QP with
DAQP) on the active model. After the move (``after_move``, as
:meth:`controller.multimodel.MultiModelController.finish_sample`): the shared-state
update (eq. 3.10, ``update``), the covariance step and the next step's products
(``covariance``) and the adaptive model's QP rebuild when its Θ moved
(``rebuild``). Each case reports the total (median, p99, max) and the medians/p99
of the parts, ``cpu_median_ms``/``cpu_p99_ms`` (the thread's CPU time over the critical
path: a wall tail with the usual CPU time was the machine's, not the sample's) and
``preempted_samples`` (samples during which the thread was switched out involuntarily),
and ``after_rebuild_mpc_median_ms`` (the MPC part of the ``after_rebuild_samples``
samples right after a QP rebuild: their solver's first solve).
The samples run under the controller node's process settings, made once after set-up
(:func:`services.realtime_process.settle_for_samples`: the set-up frozen out of the
collector, BLAS on the calling thread), so they are timed as the node runs them.

Measured (shared 2-core AMD EPYC; more in ``docs/realtime.md``), total median / p99
in ms, wall and CPU time of the critical path, samples preempted of 600::

    case              load      wall                    CPU                   preempted
    TE                1.3-1.5   0.105-0.190 / 0.27-0.36  -                     -
    TE [a]            2.4-2.9   0.099-0.106 / 0.22-0.26  0.100-0.107 / same    1-16 of 2950
    TE                6.4-7.0   0.156-0.165 / 0.41-4.6   0.159-0.168 / 0.36-0.51  8-32
    TE [b]            2.3-4.9   0.088-0.127 / 0.185-0.226 0.090-0.129 / 0.185-0.229  0-6
    two-phase [b]     2.3-4.9   0.102-0.151 / 0.302-0.355 0.104-0.153 / 0.305-0.416  0-22
                                (and one p99 of 4.3 ms with 22 samples preempted)
    synthetic n = 40 [b] 2.3-4.9 0.148-0.248 / 0.430-0.575 0.150-0.251 / 0.417-0.581 0-19
    two-phase         1.3-1.5   0.126-0.192 / 0.29-0.37  -                     -
    two-phase         6.4-7.0   0.148-0.351 / 4.3-8.5    0.150-0.354 / 0.39-0.65  11-56
    synthetic n = 40  ~3        0.19-0.26 / 1.0-4.8      -                     -
    synthetic n = 40  6.4-7.0   0.268-0.321 / 4.7-4.8    0.272-0.324 / 0.70-0.83  24-59

    [a] the critical path timed part by part in one process, 2,950 samples, the
        collector frozen, BLAS on one thread, the plan's prediction still in the sample
    [b] with the finiteness checks compiled (controller.finite_kernel) and the plan's
        prediction off the sample; five of six runs (one run preempted throughout left out)

The rebuilt QP's DAQP workspace is set up at the rebuild (``MPCLaw(setup_ahead=True)``),
not in the next sample. Two-phase, 4 alternated pairs in one process, load 4.0-4.8, MPC
part median of the 26 samples after a rebuild against that of all samples: 1.24-1.52x
with the set-up in the sample, 1.11-1.23x with it at the rebuild (what is left: a cold
working set). The case's wall p99 was 4.7-9.9 ms either way at that load (61-114 of
1,200 samples preempted), CPU p99 0.78-0.84 ms against 0.66-0.80 ms.

On a loaded machine the wall p99 is the scheduler's (4-8 ms slices) while the CPU p99
stays below 1 ms; at load ~2.5 the CPU p99 is the wall p99 and its samples are slower
in every part alike (errors, adaptation, MPC, each about twice its median), clustered
in time: the machine's other work, not a path of the code. QP iterations do not make
the tail (TE: 1-32 iterations, 63 of 3,000 samples with 10 or more, their median
0.139 ms against 0.133 ms).

Cases
    ``two-phase``: the chapter-6 reactor study in closed loop with the nonlinear plant
    (plant integration not timed): state-shared model of the OPI/OPII linearizations
    (order 24) plus one free-running adaptive model, P = 40, M = 4, 3 MVs;
    transitions 100 → 130 → 100 kmol/h repeated.

    ``two-phase targets``: the same with the unit's steady-state targets above the MPC
    (:mod:`controller.units.mpc_targets`, the product default), their part of the
    ``mpc`` time also as ``targets_median_ms``/``targets_p99_ms``; the two cases run in
    one call, side by side.

    ``te``: the chapter-3 TE state-shared model (``controller.units.te.linear_models``: modes 0,
    2, 3 + one adaptive model, n = 8, m = 5, shared order 80, 208 parameters per
    model; 5 MVs: XMV 3, 4, 6, T_r*, XMV 11), P = 10, M = 4 (QP: 21 variables, input,
    rate and soft output limits). The state-shared model is square (as many MVs as
    CVs), so 7 MVs with 5 CVs is not expressible; the 29-variable QP alone is in
    ``ssmpc bench qp``. The plant is the mode-3 model (the stable one) with output
    disturbances; set points move every 50 samples. Building the TE linear models
    takes ~30 s before timing starts. ``--synthetic-te`` adds a random n = 40 model
    (order 400, 1045 adapted parameters), the seed's size.
"""

from __future__ import annotations

import time

import numpy as np

from services.realtime_process import settle_for_samples
from services.timing import thread_switches

NAME = "mpc-step"
DESCRIPTION = "state-shared update + adapt + switch + MPC QP per sample (two-phase, TE size), ms"


def add_arguments(parser) -> None:
    parser.add_argument("--samples", type=int, default=600,
                        help="timed samples per case (two-phase: rounded to transitions)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (TE-size models)")
    parser.add_argument("--no-adapt", action="store_true",
                        help="skip the adaptation step (to see its share)")
    parser.add_argument("--synthetic-te", action="store_true",
                        help="also a random n = 40 model (shared order 400, the seed's size)")


class _Timer:
    def __init__(self) -> None:
        self.parts: dict[str, list[float]] = {}

    def add(self, name: str, t0: float, t1: float) -> None:
        self.parts.setdefault(name, []).append((t1 - t0) * 1e3)


def _sample(ssm, est, j_ad, index, switcher, law, y, reference, u, k, timer, adapt=True):
    """One controller sample as :class:`controller.multimodel.MultiModelController` runs
    it; returns the move. Times each part into ``timer``: ``total`` is the critical path
    (measurement to move: errors, the prepared adaptation step, index and switch, the
    MPC); ``after_move`` is the bookkeeping after the move is out (shared-state update,
    the covariance step, the next step's products, the law's QP rebuilds)."""
    clock = time.perf_counter
    switches0 = thread_switches()[1]
    c0 = time.thread_time()
    t0 = clock()
    errors = ssm.errors(y)
    t1 = clock()
    if adapt and est is not None:
        step = est.update_prepared(y, defer=True)
        if step.updated or step.reset:
            ssm.set_params(j_ad, est.p)
    t2 = clock()
    J = index.update(errors)
    dec = switcher.step(J)
    t3 = clock()
    u_new, info = law.compute(k, dec.active, ssm, y, reference, u)
    t4 = clock()
    c4 = time.thread_time()
    preempted = thread_switches()[1] > switches0
    # the move is out: bookkeeping for the next sample
    ssm.update(u_new, y)
    t5 = clock()
    if est is not None:
        est.commit()
        est.prepare(ssm.regressor())
    t6 = clock()
    rebuilds = law.counters().get("mpc_rebuilds", 0)
    law.finish_sample(ssm, dec.active)
    t7 = clock()
    timer.parts.setdefault("rebuilt", []).append(
        float(law.counters().get("mpc_rebuilds", 0) > rebuilds))
    timer.add("errors", t0, t1)
    timer.add("adapt", t1, t2)
    timer.add("switch", t2, t3)
    timer.add("mpc", t3, t4)
    timer.add("update", t4, t5)
    timer.add("covariance", t5, t6)
    timer.add("rebuild", t6, t7)
    timer.add("after_move", t4, t7)
    timer.add("total", t0, t4)
    timer.add("cpu", c0, c4)
    timer.parts.setdefault("preempted", []).append(float(preempted))
    return u_new, dec.active, info


def _case(name: str, timer: _Timer, **extra) -> dict:
    from services.bench._common import latency_case

    times = {p: v for p, v in timer.parts.items() if p not in ("total", "preempted", "rebuilt")}
    parts = {f"{p}_median_ms": float(np.median(v)) for p, v in times.items()}
    parts.update({f"{p}_p99_ms": float(np.percentile(v, 99)) for p, v in times.items()})
    parts["preempted_samples"] = int(sum(timer.parts.get("preempted", ())))
    # the MPC part of the samples right after a QP rebuild (its solver's first solve)
    rebuilt = np.asarray(timer.parts.get("rebuilt", ()), dtype=bool)[:-1]
    after = np.asarray(timer.parts["mpc"])[1:][rebuilt[:len(timer.parts["mpc"]) - 1]]
    parts["after_rebuild_samples"] = int(after.size)
    parts["after_rebuild_mpc_median_ms"] = float(np.median(after)) if after.size else None
    return latency_case(name, timer.parts["total"], unit="ms", **parts, **extra)


def two_phase_case(samples: int, adapt: bool = True, targets: bool = False) -> dict:
    from controller.adaptation import NLSSettings, NormalizedLeastSquares
    from controller.reference import ReferenceTrajectory, SetpointSchedule
    from controller.state_shared import ModelSpec, StateSharedModel
    from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
    from controller.units.two_phase_reactor import (
        PRODUCT_TARGETS,
        SEED_TARGETS,
        ReactorCase,
        reactor_law,
        reactor_models,
        reactor_settings,
    )
    from plant_sim.integrate import step as plant_step

    case = ReactorCase(targets=PRODUCT_TARGETS if targets else SEED_TARGETS, realtime=True)
    specs, a, plant = reactor_models(case.order)
    specs = list(specs) + [ModelSpec("adaptive", specs[0].theta, specs[0].bias, "adaptive")]
    ssm = StateSharedModel(a, 3, case.dt, specs)
    ops = plant.operating_points
    y1 = plant.outputs(ops["OPI"].x, ops["OPI"].u)
    y2 = plant.outputs(ops["OPII"].x, ops["OPII"].u)
    settings = reactor_settings(case, y1, y2)
    law = reactor_law(settings, case.targets)
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
    warm = 50  # not timed, as in te_case: first calls (QP set-up, kernels' first types)
    n_tr = max(2, int(np.ceil((samples + warm) / per)))
    times = [per * i * case.dt for i in range(n_tr)]
    levels = [y2 if i % 2 == 0 else y1 for i in range(n_tr)]
    reference = ReferenceTrajectory(SetpointSchedule.sequence(levels, times), case.tau_ref,
                                    case.dt, initial=y1)
    x = ops["OPI"].x.copy()
    u = ops["OPI"].u[:3].copy()
    x4bar = float(ops["OPI"].u[3])
    ssm.initialize(u, y1)
    law.reset(u, y1)
    est.prepare(ssm.regressor())
    settle_for_samples()  # as a node does once set up
    timer = _Timer()
    fallbacks = relaxed = 0
    actives = set()
    for k in range(per * n_tr):
        y = plant.outputs(x, np.r_[u, x4bar])
        t_part = _Timer() if k < warm else timer
        u, active, info = _sample(ssm, est, j_ad, index, switcher, law, y,
                                  reference.horizon(settings.P), u, k, t_part, adapt)
        u = np.clip(u, 0.0, 100.0)
        fallbacks += bool(info.get("fallback"))
        if targets:
            t_part.parts.setdefault("targets", []).append(info["targets"]["solve_ms"])
            relaxed += bool(info["targets"].get("relaxed"))
        actives.add(active)
        x = plant_step(plant, x, np.r_[u, x4bar], case.dt, t=k * case.dt)
        reference.advance()
    extra = {"relaxed_samples": relaxed} if targets else {}
    return _case("two-phase targets" if targets else "two-phase", timer,
                 state_order=ssm.order, models=ssm.k, P=settings.P,
                 M=settings.M, qp_variables=settings.M * settings.nu + 1,
                 fallbacks=fallbacks, models_used=sorted(actives), adapt=adapt,
                 rebuilds=law.mpc.counters["rebuilds"], **extra)


def _te_controller(ssm, P: int, M: int, u_op, y_op):
    from controller.mpc import MPCSettings
    from controller.mpc.law import MPCLaw

    m = ssm.m
    scale = np.maximum(np.abs(np.asarray(y_op)) * 0.01, 1e-3)  # 1 % of the operating value
    settings = MPCSettings(nu=m, ny=m, P=P, M=M, Xi=1.0 / scale ** 2,
                           Lambda=np.full(m, 1.0 / 10.0 ** 2),
                           u_min=np.asarray(u_op) - 20.0, u_max=np.asarray(u_op) + 20.0,
                           du_max=np.full(m, 2.0), y_min=np.asarray(y_op) - 5 * scale,
                           y_max=np.asarray(y_op) + 5 * scale, slack_scale=scale,
                           slack_linear=1e3, slack_quadratic=10.0, budget_ms=5.0)
    return settings, MPCLaw(settings)


def te_case(samples: int, seed: int = 0, adapt: bool = True, synthetic: bool = False) -> dict:
    """TE-size sample: the chapter-3 TE state-shared model (modes 0, 2, 3 + adaptive;
    n = 8, m = 5: shared order 80, 208 parameters per model), or with ``synthetic`` a
    random n = 40 model (order 400, 1045 parameters) of the seed's size."""
    from controller.adaptation import NLSSettings, NormalizedLeastSquares
    from controller.state_shared import ModelSpec, StateSharedModel, designer_polynomial
    from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex

    P, M, dt = 10, 4, 0.01
    rng = np.random.default_rng(seed)
    if synthetic:
        n, m = 40, 5
        ssm = StateSharedModel(designer_polynomial(-np.geomspace(0.5, 5.0, n)), m, dt)
        for j in range(4):
            p = 1e-3 * rng.standard_normal(ssm.n_params + m)
            p[-m:] = 50.0 + rng.standard_normal(m)
            theta, bias = ssm.theta_from_params(p)
            ssm.add_model(ModelSpec(f"M{j}", theta, bias, "adaptive" if j == 3 else "fixed"))
        plant_j = 0
    else:
        from controller.units.te.linear_models import te_state_shared_model

        ssm = te_state_shared_model(dt=dt)
        plant_j = ssm.names.index("mode3")  # the stable one of the three
    m, k_models = ssm.m, ssm.k
    # The plant: one model's exact prediction form on its own copy of the shared state.
    pf = ssm.prediction_form(plant_j)
    Phi, Gam, C, b, f = (np.asarray(v) for v in (pf[0], pf[1], pf[2], pf[3], pf.f))
    # Operating point of the plant model: u_op from a steady state with y = C n + b.
    u_op = np.zeros(m) if synthetic else _te_u_op(ssm.names[plant_j])
    A_ss = Phi - np.eye(Phi.shape[0])
    n_ss = -np.linalg.solve(A_ss, Gam @ u_op + f)
    y_op = C @ n_ss + b
    settings, law = _te_controller(ssm, P, M, u_op, y_op)
    t0 = time.perf_counter()
    law.prepare(ssm)
    prepare_ms = (time.perf_counter() - t0) * 1e3 / k_models
    index = PerformanceIndex(IndexSettings(output_weights=tuple(1.0 / np.maximum(
        np.abs(y_op) * 0.01, 1e-3) ** 2)), k_models, dt)
    switcher = ModelSwitcher(k_models, 0.05, dt, initial=plant_j)
    j_ad = k_models - 1
    est = NormalizedLeastSquares(NLSSettings(), ssm.params_from_theta(ssm.theta(j_ad),
                                                                     ssm.bias(j_ad)), dt)
    u = u_op.copy()
    x_plant = n_ss.copy()
    y = C @ x_plant + b
    ssm.initialize(u, y)
    law.reset(u, y)
    est.prepare(ssm.regressor())
    d = np.zeros(m)
    sp = y.copy()
    settle_for_samples()  # as a node does once set up
    timer = _Timer()
    fallbacks = 0
    warm = 50
    scale = np.maximum(np.abs(y_op) * 0.01, 1e-3)
    for k in range(samples + warm):
        if k % 50 == 0:
            sp = y_op + scale * rng.uniform(-2.0, 2.0, size=m)
            d = d + 0.2 * scale * rng.standard_normal(m)
        y = C @ x_plant + b + d
        ref = np.tile(sp, (P, 1))
        t_part = _Timer() if k < warm else timer
        u, _active, info = _sample(ssm, est, j_ad, index, switcher, law, y, ref, u, k, t_part,
                                   adapt)
        fallbacks += bool(info.get("fallback")) and k >= warm
        x_plant = Phi @ x_plant + Gam @ u + f
    name = "te synthetic n40" if synthetic else "te"
    return _case(name, timer, state_order=ssm.order, models=k_models, P=P, M=M,
                 qp_variables=M * m + 1, adapted_parameters=est.n_params,
                 fallbacks=fallbacks, adapt=adapt, prepare_ms_per_model=prepare_ms,
                 rebuilds=law.mpc.counters["rebuilds"], plant_model=ssm.names[plant_j])


def _te_u_op(mode: str) -> np.ndarray:
    from controller.units.te.linear_models import te_closed_loop

    return np.asarray(te_closed_loop(mode).u_op, dtype=float)


def run(args) -> list[dict]:
    samples = getattr(args, "samples", 600)
    if samples < 1:
        raise ValueError(f"samples: must be >= 1, got {samples}")
    adapt = not getattr(args, "no_adapt", False)
    seed = getattr(args, "seed", 0)
    cases = [two_phase_case(samples, adapt), two_phase_case(samples, adapt, targets=True),
             te_case(samples, seed, adapt)]
    if getattr(args, "synthetic_te", False):
        cases.append(te_case(samples, seed, adapt, synthetic=True))
    return cases
