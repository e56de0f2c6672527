"""One campaign run: the offline closed loop the studies use, scored by the metrics.

TE: :func:`controller.units.te.control.run_te` (the original plant at its 1.8 s
Euler step, the regulatory layer of seed Table 7.10, the supervisory controller
of the strategy every 36 s), stopped at the first interlock trip. The campaign
seed ``s`` seeds the plant's own generator (measurement noise and the random
IDVs) with :func:`controller.units.te.control.plant_seed_for` (campaigns add no
input noise on the valve commands).

Unit plants: the service's own pieces without the network: the plant node's
integrator (:class:`services.nodes.plant.ODERunner`), the controller node's
transition manager (:class:`services.transitions.TransitionManager`, first-order
references toward the grade, ``duration = transition_duration_s``) and the unit's
controller of the registry (:func:`services.registry.build_controller`). The legs
are requested at their times (queued behind a running transition).

:func:`execute` never raises for a run that fails: its row carries the error.
The first run of a (unit, strategy) in a process is preceded by a short untimed
run (:func:`ensure_warm`: numba kernels loaded, models built), so ``wall_s`` is
the run's own time.
"""

from __future__ import annotations

import math
import time
import traceback
from dataclasses import dataclass, replace

import numpy as np

from services.campaign import metrics
from services.campaign.identity import RunSpec
from services.cluster import single_threaded_process

__all__ = ["RunOutcome", "execute", "ensure_warm", "base_row", "failed_metrics"]

_WARM: set[tuple[str, str]] = set()


@dataclass(frozen=True)
class RunOutcome:
    """A run's result row (the ``runs`` entry of ``results.json``) and its time series.

    ``series``: name -> ndarray (see :mod:`services.campaign.store` for the layout);
    empty for a failed run.
    """

    row: dict
    series: dict


def _te_plan(case):
    from controller.units.te.grades import Leg, TransitionPlan

    return TransitionPlan(case.start, tuple(Leg(lg.at_h, lg.grade) for lg in case.legs))


def _run_te(run: RunSpec, hours: float | None = None) -> RunOutcome:
    from controller.units.te.control import plant_seed_for, run_te

    case = run.case
    idv = {e.idv: e.on_h for e in case.idvs}
    idv_off = {e.idv: e.off_h for e in case.idvs if e.off_h is not None}
    r = run_te(run.strategy, _te_plan(case), case.hours if hours is None else hours,
               noise=case.noise, idv=idv, idv_off=idv_off, seed=run.seed,
               plant_seed=plant_seed_for(run.seed))
    sd = r.shutdown
    trip = None if sd is None else metrics.trip_record(sd.time_h, sd.reason)
    last_leg = None if not case.legs else (case.legs[-1].at_h, case.legs[-1].grade)
    grades = (case.start, *(lg.grade for lg in case.legs))
    before = grades[-2] if case.legs else None  # the grade the last leg leaves
    onset = min((e.on_h for e in case.idvs), default=None)
    row = metrics.te_metrics(r.t, r.xmeas, r.cost, r.active, r.model_names,
                             r.meta["sample_h"], last_leg, trip, disturbance_on_h=onset,
                             xmv=r.xmv, previous_grade=before)
    series = {"t_h": r.t, "xmeas": r.xmeas, "xmv": r.xmv, "setpoints": r.setpoints,
              "ref": r.ref, "cost_usd_h": r.cost, "active": r.active,
              "solve_ms": r.solve_ms, "model_names": np.array(r.model_names, dtype=str)}
    if r.constraint_slack is not None:
        series["constraint_slack"] = r.constraint_slack
    return RunOutcome(row, series)


def _unit_config(run: RunSpec):
    from services.registry import get_unit

    cfg = get_unit(run.unit)
    controller = cfg.controller if run.strategy == "ssmpc" else run.strategy
    return replace(cfg, controller=controller, initial_grade=run.case.start)


def _run_unit(run: RunSpec, hours: float | None = None) -> RunOutcome:
    from controller.units.config import build_plant, cv_scales, unit_info
    from services.nodes.plant import ODERunner
    from services.registry import build_controller
    from services.transitions import TransitionManager

    cfg = _unit_config(run)
    plant = build_plant(cfg)
    info = unit_info(cfg, plant)
    grades = info.grades
    runner = ODERunner(cfg, plant)
    ctl = build_controller(cfg, plant, runner.u, grades)
    horizon = int(getattr(ctl, "horizon", 1))
    track = cfg.track or info.cv_names
    tix = [info.cv_names.index(n) for n in track]
    tracked = {k: [g["setpoints"][i] for i in tix] for k, g in grades.items()}
    scales = cv_scales(cfg, {k: {"setpoints": v} for k, v in tracked.items()})
    tm = TransitionManager(cfg.unit, tracked, scales, cfg.initial_grade, cfg.sample_period_s,
                           cfg.transition_duration_s, cfg.settle_tolerance, cfg.settle_samples)
    ts = cfg.sample_period_s
    n = int(math.floor((run.case.hours if hours is None else hours) * 3600.0 / ts + 1e-9))
    legs = list(run.case.legs)
    T = np.empty(n)
    Y = np.empty((n, len(info.cv_names)))
    U = np.empty((n, len(info.mv_names)))
    R = np.empty((n, len(tix)))
    act = np.empty(n, dtype=int)
    ms = np.empty(n)
    names: tuple[str, ...] = ()
    for k in range(n):
        t = k * ts
        while legs and legs[0].at_h * 3600.0 <= t + 1e-9:
            tm.request(legs.pop(0).grade, t, queue=True)
        y = runner.y()
        tm.update(t, y[tix])
        ref = tm.reference_at(t, horizon)
        dec = ctl.step(k, t, y, ref)
        finish = getattr(ctl, "finish_sample", None)
        if callable(finish):
            finish()
        u = np.asarray(dec.u, dtype=float)
        if u.shape != runner.u.shape or not np.all(np.isfinite(u)):
            u = runner.u  # the controller node holds an invalid move
        T[k], Y[k], U[k], R[k] = t / 3600.0, y, u, ref[0]
        act[k], ms[k] = dec.active_model, dec.solve_ms
        names = dec.model_names or names
        runner.advance(u, ts)
    case = run.case
    last = case.legs[-1] if case.legs else None
    targets = bands = None
    if last is not None:
        targets = np.asarray(tracked[last.grade], dtype=float)
        bands = cfg.settle_tolerance * np.asarray(scales, dtype=float)
    # the PI baseline reports one pseudo-model; it has none to share
    names = () if run.strategy == "pi" else names
    row = metrics.unit_metrics(T, Y[:, tix], act, names, ts / 3600.0,
                               None if last is None else last.at_h, targets, bands)
    series = {"t_h": T, "y": Y, "u": U, "ref": R, "active": act, "solve_ms": ms,
              "model_names": np.array(names, dtype=str),
              "cv_names": np.array(info.cv_names, dtype=str),
              "mv_names": np.array(info.mv_names, dtype=str)}
    return RunOutcome(row, series)


def _loop(run: RunSpec, hours: float | None = None) -> RunOutcome:
    return _run_te(run, hours) if run.unit == "te" else _run_unit(run, hours)


def ensure_warm(run: RunSpec) -> float:
    """Once per process and (unit, strategy): a short untimed run. Returns its wall s."""
    single_threaded_process()
    key = (run.unit, run.strategy)
    if key in _WARM:
        return 0.0
    t0 = time.perf_counter()
    # TE: 5 supervisory samples; a unit plant: 3 of its samples
    short = 0.05 if run.unit == "te" else 3.0 * _unit_config(run).sample_period_s / 3600.0
    _loop(run, short)
    _WARM.add(key)
    return time.perf_counter() - t0


def base_row(run: RunSpec) -> dict:
    return {"run": run.run_id, "case": run.case.name, "strategy": run.strategy,
            "seed": run.seed, "hours": run.case.hours, "noise": run.case.noise,
            "legs": len(run.case.legs)}


def execute(run: RunSpec) -> RunOutcome:
    """Run one campaign run; a run that raises becomes a row with its ``error``."""
    row = base_row(run)
    try:
        warm_s = ensure_warm(run)
        t0 = time.perf_counter()
        out = _loop(run)
        wall = time.perf_counter() - t0
    except Exception as exc:  # the campaign goes on; the row says what went wrong
        row.update(failed_metrics())
        row.update(wall_s=None, error=f"{type(exc).__name__}: {exc}",
                   traceback=traceback.format_exc(limit=8))
        return RunOutcome(row, {})
    row.update(out.row)
    row.update(wall_s=round(wall, 4), warm_s=round(warm_s, 3), error=None)
    return RunOutcome(row, out.series)


def failed_metrics() -> dict:
    return {"tripped": None, "trip": None, "time_to_grade_h": None, "peak_pressure_kpa": None,
            "mean_cost_usd_h": None, "final_cost_usd_h": None, "transition_cost_usd": None,
            "active_model_share": {}, "product_variability": None,
            "limit_bound_share": None, "binding_limit": None, "limit_shares": {}}
