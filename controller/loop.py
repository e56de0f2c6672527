"""Pure closed-loop runner: plant step -> measurement -> controller -> apply.

The runner knows no plant: it takes a stepping function ``plant_step(x, u, t,
dt) -> x_next`` and a measurement function ``measure(x, t) -> y``. Per sample k
at ``t_k = t0 + k dt``:

1. ``y_k = measure(x_k, t_k)`` (optionally passed through ``fault(k, y)``, used
   to inject bad measurements in tests);
2. the reference over the horizon, rows ``t_(k+1) ... t_(k+P)``;
3. ``decision = controller.step(k, t_k, y_k, reference)`` (the controller
   updates the shared state, adapts, switches and computes u_k);
4. ``x_(k+1) = plant_step(x_k, u_k, t_k, dt)`` with u_k held over the sample;
5. the reference advances.

A plant step that fails or returns a non-finite state ends the run early
(``completed=False``, reason in ``stop_reason``): that is how a diverging loop
is recorded rather than raised. Every signal is kept in a
:class:`ClosedLoopResult`; nothing is written anywhere.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from controller.blas import single_threaded
from controller.interfaces import SampleController
from controller.reference import ReferenceTrajectory

__all__ = ["ClosedLoopResult", "run_closed_loop", "ise", "settling_time"]


@dataclass(frozen=True)
class ClosedLoopResult:
    """Every signal of one closed-loop run (K samples).

    Attributes
    ----------
    t : ndarray, shape (K,)
        Sample times.
    x : ndarray, shape (K, nx)
        Plant state at each sample.
    y : ndarray, shape (K, ny)
        Measurements given to the controller (after any injected fault).
    r : ndarray, shape (K, ny)
        Reference at each sample time.
    setpoint : ndarray, shape (K, ny)
        Raw set point (schedule) at each sample time.
    u : ndarray, shape (K, nu)
        Applied moves.
    active : ndarray of int, shape (K,)
        Active model.
    J : ndarray, shape (K, n_models)
        Performance index after each sample.
    fallback : ndarray of bool, shape (K,)
    status : tuple of str
    alarms : tuple of (int, str)
        (sample, message) for every alarm raised.
    solve_ms : ndarray, shape (K,)
    model_names : tuple of str
    completed : bool
        False when the plant failed or diverged before ``t_end``.
    stop_reason : str
    extras : tuple of dict
        ``decision.extra`` of every sample.
    """

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    r: np.ndarray
    setpoint: np.ndarray
    u: np.ndarray
    active: np.ndarray
    J: np.ndarray
    fallback: np.ndarray
    status: tuple[str, ...]
    alarms: tuple[tuple[int, str], ...]
    solve_ms: np.ndarray
    model_names: tuple[str, ...]
    completed: bool = True
    stop_reason: str = ""
    extras: tuple[dict[str, Any], ...] = field(default_factory=tuple)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0]) if self.t.size > 1 else math.nan

    def ise(self, t_from: float = -math.inf, output: int = 0) -> float:
        """Integral of the squared tracking error ``(r - y)^2`` from ``t_from`` (rectangle rule)."""
        return ise(self.t, self.y[:, output], self.r[:, output], t_from)

    def final_model(self) -> str:
        return self.model_names[int(self.active[-1])] if self.active.size else ""


def ise(t, y, r, t_from: float = -math.inf) -> float:
    """Integral square error ``sum (r - y)^2 dt`` over samples with ``t >= t_from``."""
    t = np.asarray(t, dtype=float)
    e = np.asarray(r, dtype=float) - np.asarray(y, dtype=float)
    if t.size < 2:
        return 0.0
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2]))
    mask = t >= t_from
    return float(np.sum(e[mask] ** 2 * dt[mask]))


def settling_time(t, y, target: float, band: float, t_from: float = -math.inf) -> float:
    """First time after ``t_from`` from which ``|y - target| <= band`` holds to the end.

    Returns ``nan`` if the output is outside the band at the last sample.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    mask = t >= t_from
    t, y = t[mask], y[mask]
    if t.size == 0:
        return math.nan
    outside = np.abs(y - target) > band
    if outside[-1]:
        return math.nan
    idx = np.flatnonzero(outside)
    return float(t[0] if idx.size == 0 else t[idx[-1] + 1])


@single_threaded
def run_closed_loop(
    plant_step: Callable[[np.ndarray, np.ndarray, float, float], np.ndarray],
    measure: Callable[[np.ndarray, float], np.ndarray],
    x0,
    controller: SampleController,
    reference: ReferenceTrajectory,
    t_end: float,
    *,
    horizon: int = 1,
    fault: Callable[[int, np.ndarray], np.ndarray] | None = None,
    state_bounds: tuple[np.ndarray, np.ndarray] | None = None,
) -> ClosedLoopResult:
    """Run ``controller`` against a plant from ``x0`` until ``t_end``.

    Parameters
    ----------
    plant_step : callable
        ``plant_step(x, u, t, dt) -> x_next`` integrates one sample with u held.
    measure : callable
        ``measure(x, t) -> y``.
    x0 : array_like, shape (nx,)
    controller : SampleController
    reference : ReferenceTrajectory
        Its ``dt`` is the sample time and its current time the start time.
    t_end : float
        Time of the last sample.
    horizon : int
        Rows of the reference passed to the controller.
    fault : callable, optional
        ``fault(k, y) -> y`` to corrupt measurements (tests, fault injection).
    state_bounds : (lower, upper), optional
        Stop (``completed=False``) when the plant state leaves these bounds.
    """
    dt = reference.dt
    t0 = reference.t
    n = int(math.floor((t_end - t0) / dt + 1e-9)) + 1
    if n < 1:
        raise ValueError(f"t_end: must be >= the reference's start time {t0}")
    if horizon < 1:
        raise ValueError(f"horizon: must be >= 1, got {horizon}")
    x = np.asarray(x0, dtype=float).reshape(-1).copy()
    ts, xs, ys, rs, sps, us, act, Js, fb, st, ms, extras = ([] for _ in range(12))
    alarms: list[tuple[int, str]] = []
    names: tuple[str, ...] = ()
    completed, reason = True, ""
    for k in range(n):
        t = t0 + k * dt
        y = np.asarray(measure(x, t), dtype=float).reshape(-1)
        if fault is not None:
            y = np.asarray(fault(k, y.copy()), dtype=float).reshape(-1)
        ref = reference.horizon(horizon)
        dec = controller.step(k, t, y, ref)
        finish = getattr(controller, "finish_sample", None)
        if callable(finish):
            finish()  # the bookkeeping a real-time node does after sending the move
        names = dec.model_names or names
        ts.append(t)
        xs.append(x.copy())
        ys.append(y)
        rs.append(reference.r.copy())
        sps.append(reference.schedule.at(t))
        us.append(np.asarray(dec.u, dtype=float).copy())
        act.append(dec.active_model)
        Js.append(np.asarray(dec.J, dtype=float).copy())
        fb.append(dec.fallback)
        st.append(dec.status)
        ms.append(dec.solve_ms)
        extras.append(dict(dec.extra))
        alarms.extend((k, a) for a in dec.alarms)
        if k == n - 1:
            break
        try:
            x_next = np.asarray(plant_step(x, np.asarray(dec.u, dtype=float), t, dt), dtype=float)
        except Exception as exc:  # a diverging plant makes the integrator fail
            completed, reason = False, f"plant step failed at t = {t:.6g}: {exc}"
            break
        if not np.isfinite(x_next).all():
            completed, reason = False, f"plant state not finite at t = {t + dt:.6g}"
            break
        if state_bounds is not None and (np.any(x_next < state_bounds[0])
                                         or np.any(x_next > state_bounds[1])):
            completed, reason = False, f"plant state left its bounds at t = {t + dt:.6g}"
            break
        x = x_next
        reference.advance()
    J = np.vstack(Js) if Js and all(j.size == Js[0].size for j in Js) else np.zeros((len(ts), 0))
    return ClosedLoopResult(
        t=np.asarray(ts), x=np.vstack(xs), y=np.vstack(ys), r=np.vstack(rs),
        setpoint=np.vstack(sps), u=np.vstack(us), active=np.asarray(act, dtype=int), J=J,
        fallback=np.asarray(fb, dtype=bool), status=tuple(st), alarms=tuple(alarms),
        solve_ms=np.asarray(ms), model_names=names, completed=completed, stop_reason=reason,
        extras=tuple(extras))
