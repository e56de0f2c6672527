"""The metrics of one campaign run (DESIGN.md "Campaigns"), from its sampled series.

Pure functions of arrays; every run of a campaign is scored here and nowhere else.
Samples are taken to hold over their period ``dt`` (zero-order hold), so an
integral is the rectangle sum ``sum_k rate_k dt`` over the samples in the window.

- ``tripped`` / ``trip``: the plant's first interlock trip ``{"at_h", "reason"}``.
- ``time_to_grade_h``: hours from the start of the last leg until every grade
  signal stays within its band of the new grade's value to the end of the run
  (TE: G in product, XMEAS 40, ±1 mol %, and the product flow, XMEAS 17, ±5 %,
  each as its trailing mean over :data:`TE_GRADE_WINDOW_H`, as the seed's
  R7.14/R7.16 read the noisy analyzer; a unit plant: its tracked CVs within the
  service's settle band); ``None`` when the last sample is outside, when the run
  tripped, and for cases without legs. 0 when every sample from the leg on is
  inside. A TE leg between two grades that make the same product (their G and
  product flow within those bands of each other: modes 0 and 1) changes no product
  signal; what it changes is the operating point, so its grade signals add the
  reactor level (XMEAS 8, ±:data:`TE_LEVEL_BAND_PCT`) and the reactor temperature
  (XMEAS 9, ±:data:`TE_TEMPERATURE_BAND_C`), the set points in which those grades
  differ (:func:`te_grade_signals`).
- ``peak_pressure_kpa``: largest reactor pressure (XMEAS 7, kPa gauge) sampled.
- ``mean_cost_usd_h``: mean operating cost (Downs & Vogel, $/h) over the run;
  ``final_cost_usd_h``: its mean over the last hour of the run (the whole run if
  shorter), less noisy than the last sample alone.
- ``transition_cost_usd``: the cost integrated from the start of the last leg to
  the leg start + ``time_to_grade_h``, or to the end of the run when the grade is
  not reached; ``None`` without legs.
- ``active_model_share``: fraction of the samples each model was active, by model
  name; ``{}`` for strategies without models (active index < 0).
- ``product_variability`` (TE): ``{"g_std_mol", "production_std_pct"}``, the
  standard deviation of G in product (XMEAS 40, mol %) and of the product flow
  (XMEAS 17, % of its mean) over the samples from the first disturbance's onset
  to the end of the run (to the trip, where it tripped; the whole run for a case
  without disturbances) - the "product variability" Ricker (1996) and Downs &
  Vogel (1993) score a TE controller on under a disturbance. Both are the raw
  samples, analyzer and flow noise included, so runs compare only on the same
  noise setting. ``None`` with fewer than two samples in the window.
- ``limit_bound_share``, ``binding_limit``, ``limit_shares`` (TE): how much of the
  transition window a plant limit binds. The window is that of
  ``transition_cost_usd`` (the start of the last leg to the grade reached, or to the
  end of the run or its trip). A limit binds in a sample when a valve a loop or the
  controller manipulates (:data:`controller.units.te.grades.CONTROLLED_VALVES`) is
  within :data:`TE_VALVE_RANGE_TOL` % of 0 or 100 %, or the reactor pressure
  (XMEAS 7) is within :data:`TE_PRESSURE_BAND_KPA` of the targets' 2895 kPa limit
  or above it (from 2880 kPa, where the transition guards' plan hold starts).
  ``limit_bound_share``: the fraction of the window's samples in which any limit
  binds; ``limit_shares``: that fraction per limit (``XMV1`` ... ``XMV11``,
  ``reactor pressure``; the limits that bind at all); ``binding_limit``: the one
  that binds longest (None when none does). None / ``{}`` when the window holds no
  sample (at grade from the leg on), without legs, and for unit plants. A
  controller that holds a limit through most of the window could not go faster
  there without crossing it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["trip_record", "time_to_grade_h", "integrate_rate", "active_model_share",
           "final_mean", "te_grade_targets", "te_metrics", "unit_metrics", "product_variability",
           "limit_binding", "te_limits_at_bound",
           "TE_G_BAND_MOL", "TE_FLOW_BAND_REL", "FINAL_WINDOW_H", "TE_GRADE_WINDOW_H",
           "TE_VALVE_RANGE_TOL", "TE_PRESSURE_LIMIT_KPA", "TE_PRESSURE_BAND_KPA",
           "TE_LEVEL_BAND_PCT", "TE_TEMPERATURE_BAND_C", "te_grade_signals", "te_same_product"]

#: Band on G in product, mol % (XMEAS 40).
TE_G_BAND_MOL = 1.0
#: Band on the product flow, relative (XMEAS 17).
TE_FLOW_BAND_REL = 0.05
#: Window of ``final_cost_usd_h``, h.
FINAL_WINDOW_H = 1.0
#: Trailing window of the TE grade signals judged by ``time_to_grade_h``, h. Judged
#: sample by sample, the analyzer's and the flow's measurement noise put single
#: samples outside the bands late in every run (measured: 15-23 h "to grade" in 24 h
#: runs of every strategy, where the G analyzer's trailing mean is in band after 5-7 h).
TE_GRADE_WINDOW_H = 1.0
#: Band on the reactor level (XMEAS 8), % of range, and on the reactor temperature
#: (XMEAS 9), degC: the grade signals of a leg that keeps the product (modes 0 and 1:
#: 75 -> 65 %, 120.4 -> 122.9 degC; a tenth and a fifth of those changes).
TE_LEVEL_BAND_PCT = 1.0
TE_TEMPERATURE_BAND_C = 0.5
#: A valve binds within this of 0 % or 100 % (% of its range).
TE_VALVE_RANGE_TOL = 1.0
#: The reactor pressure's limit at the steady-state targets, kPa (Downs & Vogel's
#: normal operating high limit; :class:`controller.units.te.targets.CoreTargetSettings`).
TE_PRESSURE_LIMIT_KPA = 2895.0
#: The reactor pressure binds from this far below its limit, kPa (2880 kPa: where the
#: plan hold of :class:`controller.units.te.control.TransitionGuards` starts).
TE_PRESSURE_BAND_KPA = 15.0


def trip_record(at_h: float | None, reason: str | None) -> dict | None:
    """``{"at_h": h, "reason": text}``, or None when the plant did not trip."""
    if at_h is None:
        return None
    return {"at_h": float(at_h), "reason": str(reason)}


def time_to_grade_h(t, signals, targets, bands, t_leg: float) -> float | None:
    """Time from ``t_leg`` until all signals stay within their bands to the end (h).

    Parameters
    ----------
    t : array_like, shape (K,)
        Sample times, h.
    signals : array_like, shape (K, m)
        The grade signals.
    targets, bands : array_like, shape (m,)
        The new grade's values and the half-widths of the bands (signal units).
    t_leg : float
        Start of the last leg, h.

    Returns
    -------
    float or None
        ``t_j - t_leg`` for the first sample ``j`` (at or after ``t_leg``) from
        which every later sample is inside; None if the last sample is outside or
        no sample is at or after ``t_leg``.
    """
    t = np.asarray(t, dtype=float)
    s = np.asarray(signals, dtype=float).reshape(t.size, -1)
    after = t >= t_leg
    if not after.any():
        return None
    t, s = t[after], s[after]
    outside = np.any(~(np.abs(s - np.asarray(targets, float)) <= np.asarray(bands, float)),
                     axis=1)
    if outside[-1]:
        return None
    idx = np.flatnonzero(outside)
    first = 0 if idx.size == 0 else int(idx[-1]) + 1
    return float(t[first] - t_leg)


def integrate_rate(t, rate, dt: float, t_from: float, t_to: float) -> float:
    """Rectangle sum of ``rate`` over the samples with ``t_from <= t_k < t_to`` (rate x h)."""
    t = np.asarray(t, dtype=float)
    r = np.asarray(rate, dtype=float)
    mask = (t >= t_from) & (t < t_to)
    return float(np.sum(r[mask]) * dt)


def final_mean(t, values, dt: float, window_h: float = FINAL_WINDOW_H) -> float | None:
    """Mean of ``values`` over the samples of the run's last ``window_h`` hours."""
    t = np.asarray(t, dtype=float)
    v = np.asarray(values, dtype=float)
    if t.size == 0:
        return None
    end = t[-1] + dt
    mask = t >= end - window_h - 1e-9
    return float(np.mean(v[mask]))


def active_model_share(active, model_names) -> dict[str, float]:
    """Fraction of samples each model was active (index into ``model_names``; < 0: none)."""
    a = np.asarray(active, dtype=int)
    names = tuple(model_names)
    if a.size == 0 or not names or np.all(a < 0):
        return {}
    return {name: float(np.count_nonzero(a == j)) / a.size for j, name in enumerate(names)}


def product_variability(t, xmeas, from_h: float = 0.0) -> dict | None:
    """Standard deviations of G in product and of the product flow from ``from_h`` on.

    Parameters
    ----------
    t : array_like, shape (K,)
        Sample times, h.
    xmeas : array_like, shape (K, 41)
        XMEAS 1-41 (G in product is XMEAS 40, mol %; the product flow XMEAS 17, m3/h).
    from_h : float
        Start of the window, h.

    Returns
    -------
    dict or None
        ``{"g_std_mol": mol %, "production_std_pct": % of the window's mean flow}``;
        None with fewer than two samples at or after ``from_h``.
    """
    t = np.asarray(t, dtype=float)
    x = np.asarray(xmeas, dtype=float).reshape(-1, 41)
    win = x[t >= from_h - 1e-9]
    if win.shape[0] < 2:
        return None
    flow = win[:, 16]
    mean_flow = float(np.mean(flow))
    pct = float(np.std(flow) / abs(mean_flow) * 100.0) if mean_flow != 0.0 else None
    return {"g_std_mol": float(np.std(win[:, 39])), "production_std_pct": pct}


def limit_binding(t, at_limit: dict, t_from: float, t_to: float
                  ) -> tuple[float | None, str | None, dict[str, float]]:
    """How much of the window ``t_from <= t_k < t_to`` limits bind.

    Parameters
    ----------
    t : array_like, shape (K,)
        Sample times, h.
    at_limit : dict
        Limit name -> bool array (K,): the samples in which that limit binds.
    t_from, t_to : float
        The window, h.

    Returns
    -------
    (share, name, shares)
        The fraction of the window's samples in which any limit binds, the limit that
        binds in the most of them (the first named on a tie; None when none binds),
        and the fraction per limit that binds at all. ``(None, None, {})`` when the
        window holds no sample.
    """
    t = np.asarray(t, dtype=float)
    mask = (t >= t_from) & (t < t_to)
    n = int(np.count_nonzero(mask))
    if n == 0:
        return None, None, {}
    shares = {}
    anyb = np.zeros(n, dtype=bool)
    for name, b in at_limit.items():
        bw = np.asarray(b, dtype=bool).reshape(-1)[mask]
        anyb |= bw
        c = int(np.count_nonzero(bw))
        if c:
            shares[str(name)] = c / n
    best = max(shares, key=shares.get) if shares else None
    return float(np.count_nonzero(anyb)) / n, best, shares


def te_limits_at_bound(xmeas, xmv) -> dict[str, np.ndarray]:
    """The TE limits of :func:`limit_binding`, sample by sample: ``XMVn`` for the
    controlled valves (within :data:`TE_VALVE_RANGE_TOL` of 0 or 100 %) and ``reactor
    pressure`` (from :data:`TE_PRESSURE_LIMIT_KPA` - :data:`TE_PRESSURE_BAND_KPA`).
    ``xmeas`` (K, 41), ``xmv`` (K, 12) %. A value that is not finite does not bind."""
    from controller.units.te.grades import CONTROLLED_VALVES

    x = np.asarray(xmeas, dtype=float).reshape(-1, 41)
    u = np.asarray(xmv, dtype=float).reshape(-1, 12)
    with np.errstate(invalid="ignore"):
        out = {f"XMV{v}": (u[:, v - 1] <= TE_VALVE_RANGE_TOL)
               | (u[:, v - 1] >= 100.0 - TE_VALVE_RANGE_TOL) for v in CONTROLLED_VALVES}
        out["reactor pressure"] = x[:, 6] >= TE_PRESSURE_LIMIT_KPA - TE_PRESSURE_BAND_KPA
    return out


def te_grade_targets(grade_name: str) -> tuple[np.ndarray, np.ndarray]:
    """Targets and bands of the TE grade signals (G mol %, product flow) of a grade."""
    from controller.units.te.grades import grade

    g = grade(grade_name)
    flow = float(g.xmeas[16])
    return (np.array([g.g_mol, flow]),
            np.array([TE_G_BAND_MOL, TE_FLOW_BAND_REL * abs(flow)]))


def te_same_product(grade_a: str, grade_b: str) -> bool:
    """Whether two TE grades make the same product: G in product and the product flow
    of each within the other's bands (:func:`te_grade_targets`)."""
    ta, bands = te_grade_targets(grade_a)
    tb, _ = te_grade_targets(grade_b)
    return bool(np.all(np.abs(ta - tb) <= bands))


def te_grade_signals(grade_name: str, previous: str | None = None
                     ) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The XMEAS columns (0-based), targets and bands that say a TE leg to
    ``grade_name`` is done: G in product and the product flow; from a ``previous``
    grade that makes the same product (:func:`te_same_product`), also the reactor
    level and temperature of the new grade."""
    from controller.units.te.grades import grade

    targets, bands = te_grade_targets(grade_name)
    cols = [39, 16]
    if previous is not None and te_same_product(previous, grade_name):
        g = grade(grade_name)
        cols += [7, 8]
        targets = np.append(targets, [g.reactor_level, g.reactor_temperature])
        bands = np.append(bands, [TE_LEVEL_BAND_PCT, TE_TEMPERATURE_BAND_C])
    return cols, targets, bands


def _common(t, dt, cost, last_leg, signals, targets, bands, tripped) -> dict:
    if last_leg is None or tripped:
        ttg = None
    else:
        ttg = time_to_grade_h(t, signals, targets, bands, last_leg)
    out: dict = {"time_to_grade_h": ttg}
    if cost is None:
        out.update(mean_cost_usd_h=None, final_cost_usd_h=None, transition_cost_usd=None)
        return out
    t = np.asarray(t, dtype=float)
    out["mean_cost_usd_h"] = float(np.mean(cost)) if t.size else None
    out["final_cost_usd_h"] = final_mean(t, cost, dt)
    if last_leg is None or t.size == 0:
        out["transition_cost_usd"] = None
    else:
        t_to = last_leg + ttg if ttg is not None else float(t[-1]) + dt
        out["transition_cost_usd"] = integrate_rate(t, cost, dt, last_leg, t_to)
    return out


def te_metrics(t, xmeas, cost, active, model_names, dt: float,
               last_leg: tuple[float, str] | None, trip: dict | None,
               disturbance_on_h: float | None = None, xmv=None,
               previous_grade: str | None = None) -> dict:
    """The metrics of a TE run.

    Parameters
    ----------
    t : array_like, shape (K,)
        Sample times, h.
    xmeas : array_like, shape (K, 41)
        XMEAS 1-41.
    cost : array_like, shape (K,)
        Operating cost, $/h.
    active : array_like of int, shape (K,)
    model_names : sequence of str
    dt : float
        Sample period, h.
    last_leg : (t_h, grade) or None
    trip : dict or None
        :func:`trip_record`.
    disturbance_on_h : float or None
        Onset of the run's first disturbance, h: the start of ``product_variability``'s
        window (None: the whole run).
    xmv : array_like, shape (K, 12), optional
        XMV 1-12 in force, %; without it the valves bind nowhere (the pressure may).
    previous_grade : str, optional
        The grade before the last leg; with one that makes the same product the
        operating point is judged too (:func:`te_grade_signals`).
    """
    x = np.asarray(xmeas, dtype=float).reshape(-1, 41)
    tripped = trip is not None
    if last_leg is None:
        sig, targets, bands, t_leg = None, None, None, None
    else:
        t_leg = float(last_leg[0])
        cols, targets, bands = te_grade_signals(last_leg[1], previous_grade)
        from controller.units.te.grades import trailing_mean

        sig = trailing_mean(x[:, cols], round(TE_GRADE_WINDOW_H / dt))
    out = {"tripped": tripped, "trip": trip,
           "peak_pressure_kpa": float(np.max(x[:, 6])) if x.shape[0] else None}
    out.update(_common(t, dt, np.asarray(cost, dtype=float), t_leg, sig, targets, bands,
                       tripped))
    out["active_model_share"] = active_model_share(active, model_names)
    out["product_variability"] = product_variability(
        t, x, 0.0 if disturbance_on_h is None else float(disturbance_on_h))
    out.update(limit_bound_share=None, binding_limit=None, limit_shares={})
    t = np.asarray(t, dtype=float)
    if t_leg is not None and t.size:
        ttg = out["time_to_grade_h"]
        t_to = t_leg + ttg if ttg is not None else float(t[-1]) + dt
        u = np.full((x.shape[0], 12), np.nan) if xmv is None else xmv
        share, name, shares = limit_binding(t, te_limits_at_bound(x, u), t_leg, t_to)
        out.update(limit_bound_share=share, binding_limit=name, limit_shares=shares)
    return {k: out[k] for k in _ORDER}


def unit_metrics(t, y, active, model_names, dt: float, last_leg_h: float | None,
                 targets=None, bands=None) -> dict:
    """The metrics of a unit-plant run (no interlocks, no cost, no reactor pressure).

    ``t`` in h, ``y`` (K, m) the tracked CVs, ``targets``/``bands`` (m,) of the last
    leg's grade (the service's settle rule).
    """
    out = {"tripped": False, "trip": None, "peak_pressure_kpa": None}
    out.update(_common(t, dt, None, last_leg_h, y, targets, bands, False))
    out["active_model_share"] = active_model_share(active, model_names)
    out["product_variability"] = None
    out.update(limit_bound_share=None, binding_limit=None, limit_shares={})
    return {k: out[k] for k in _ORDER}


_ORDER = ("tripped", "trip", "time_to_grade_h", "peak_pressure_kpa", "mean_cost_usd_h",
          "final_cost_usd_h", "transition_cost_usd", "active_model_share",
          "product_variability", "limit_bound_share", "binding_limit", "limit_shares")
