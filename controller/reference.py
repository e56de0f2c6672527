"""Reference trajectories for transitions: set-point schedules and first-order filters.

A :class:`SetpointSchedule` is a piecewise-constant set point over time (a
single step, a staircase as in seed Fig. 5.21, a pulse train as in Fig. 5.22).
A :class:`ReferenceTrajectory` smooths it with a first-order filter per output,

    tau dr/dt = s(t) - r         (seed §5.2: "first-order transfer functions")

discretized exactly for a set point held over each sample:

    r(k+1) = a r(k) + (1 - a) s(t_k),   a = exp(-dt / tau)

and evaluates it over a horizon of ``P`` future samples so that an MPC sees the
time-varying reference (rows = samples ``k+1 ... k+P``, columns = outputs).
``tau = 0`` gives the raw set point (a step).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = ["SetpointSchedule", "ReferenceTrajectory"]


@dataclass(frozen=True)
class SetpointSchedule:
    """Piecewise-constant set points.

    Parameters
    ----------
    times : sequence of float, shape (K,)
        Times at which each value starts; strictly increasing. Before
        ``times[0]`` the first value holds.
    values : array_like, shape (K,) or (K, ny)
        Set point from each time on.
    """

    times: tuple[float, ...]
    values: np.ndarray

    def __post_init__(self) -> None:
        times = tuple(float(t) for t in self.times)
        values = np.asarray(self.values, dtype=float)
        if values.ndim == 1:
            values = values[:, None]
        if len(times) == 0 or values.ndim != 2 or values.shape[0] != len(times):
            raise ValueError("values: need one row per entry of times (and at least one)")
        if not all(math.isfinite(t) for t in times) or any(
            b <= a for a, b in zip(times[:-1], times[1:])
        ):
            raise ValueError("times: must be finite and strictly increasing")
        if not np.isfinite(values).all():
            raise ValueError("values: must be finite")
        values.setflags(write=False)
        object.__setattr__(self, "times", times)
        object.__setattr__(self, "values", values)

    @property
    def ny(self) -> int:
        return self.values.shape[1]

    def at(self, t: float) -> np.ndarray:
        """Set point in force at time ``t``, shape (ny,)."""
        i = int(np.searchsorted(self.times, t, side="right")) - 1
        return self.values[max(i, 0)].copy()

    @classmethod
    def constant(cls, value) -> SetpointSchedule:
        return cls((0.0,), np.atleast_1d(np.asarray(value, dtype=float))[None, :])

    @classmethod
    def step(cls, start, stop, t_step: float) -> SetpointSchedule:
        """``start`` until ``t_step``, then ``stop``."""
        start = np.atleast_1d(np.asarray(start, dtype=float))
        stop = np.atleast_1d(np.asarray(stop, dtype=float))
        if t_step <= 0:
            return cls((0.0,), stop[None, :])
        return cls((0.0, float(t_step)), np.vstack([start, stop]))

    @classmethod
    def sequence(cls, values: Sequence, times: Sequence[float]) -> SetpointSchedule:
        """Arbitrary levels ``values[i]`` from ``times[i]`` (e.g. 1.3 -> 2 -> 5 -> 1.3)."""
        return cls(tuple(times), np.asarray(values, dtype=float))

    @classmethod
    def staircase(cls, start: float, stop: float, n_steps: int, t_first: float,
                  step_duration: float) -> SetpointSchedule:
        """``n_steps`` equal steps from ``start`` to ``stop`` (SISO), one every ``step_duration``.

        The first step happens at ``t_first``; the levels are
        ``start + i (stop - start) / n_steps`` for ``i = 1 .. n_steps``.
        """
        if n_steps < 1:
            raise ValueError(f"n_steps: must be >= 1, got {n_steps}")
        if not step_duration > 0:
            raise ValueError(f"step_duration: must be > 0, got {step_duration}")
        if not t_first > 0:
            raise ValueError(f"t_first: must be > 0, got {t_first}")
        levels = [start] + [start + i * (stop - start) / n_steps for i in range(1, n_steps + 1)]
        times = [0.0] + [t_first + i * step_duration for i in range(n_steps)]
        return cls(tuple(times), np.asarray(levels, dtype=float))

    @classmethod
    def pulses(cls, base: float, level: float, t_first: float, width: float, period: float,
               count: int) -> SetpointSchedule:
        """``count`` square pulses from ``base`` to ``level`` (SISO), each ``width`` long.

        Pulse ``i`` starts at ``t_first + i * period``; ``width < period``.
        """
        if count < 1:
            raise ValueError(f"count: must be >= 1, got {count}")
        if not 0 < width < period:
            raise ValueError(f"width: must satisfy 0 < width < period, got {width}, {period}")
        if t_first <= 0:
            raise ValueError(f"t_first: must be > 0, got {t_first}")
        times, levels = [0.0], [base]
        for i in range(count):
            t0 = t_first + i * period
            times += [t0, t0 + width]
            levels += [level, base]
        return cls(tuple(times), np.asarray(levels, dtype=float))


class ReferenceTrajectory:
    """First-order filtered reference toward a set-point schedule.

    Parameters
    ----------
    schedule : SetpointSchedule
    time_constant : float or array_like, shape (ny,)
        Filter time constant per output (time units), >= 0; 0 = no filter.
    dt : float
        Sample time.
    initial : array_like, shape (ny,), optional
        Reference at time ``t0``; default the schedule's value at ``t0``.
    t0 : float
        Time of the first sample.
    """

    def __init__(self, schedule: SetpointSchedule, time_constant, dt: float,
                 initial=None, t0: float = 0.0) -> None:
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        tau = np.broadcast_to(np.asarray(time_constant, dtype=float), (schedule.ny,)).copy()
        if not np.isfinite(tau).all() or np.any(tau < 0):
            raise ValueError(f"time_constant: must be finite and >= 0, got {time_constant!r}")
        self.schedule = schedule
        self.tau = tau
        self.dt = float(dt)
        with np.errstate(divide="ignore"):
            self.a = np.where(tau > 0, np.exp(-self.dt / np.where(tau > 0, tau, 1.0)), 0.0)
        self.t = float(t0)
        r0 = schedule.at(t0) if initial is None else np.asarray(initial, dtype=float).reshape(-1)
        if r0.shape != (schedule.ny,) or not np.isfinite(r0).all():
            raise ValueError(f"initial: expected {schedule.ny} finite values")
        self.r = r0.copy()

    @property
    def ny(self) -> int:
        return self.schedule.ny

    def _next(self, r: np.ndarray, t: float) -> np.ndarray:
        return self.a * r + (1.0 - self.a) * self.schedule.at(t)

    def horizon(self, P: int) -> np.ndarray:
        """References for the next ``P`` samples ``t + dt ... t + P dt``, shape (P, ny).

        Set-point changes scheduled within the horizon are previewed.
        """
        if P < 1:
            raise ValueError(f"P: must be >= 1, got {P}")
        out = np.empty((P, self.ny))
        r, t = self.r, self.t
        for i in range(P):
            r = self._next(r, t)
            t = t + self.dt
            out[i] = r
        return out

    def advance(self) -> np.ndarray:
        """Move one sample forward; returns the new current reference (ny,)."""
        self.r = self._next(self.r, self.t)
        self.t += self.dt
        return self.r.copy()

    def retarget(self, schedule: SetpointSchedule) -> None:
        """Change the schedule from now on, continuing smoothly from the current reference."""
        if schedule.ny != self.ny:
            raise ValueError(f"schedule: expected {self.ny} outputs, got {schedule.ny}")
        self.schedule = schedule

    def checkpoint(self) -> dict[str, Any]:
        return {"t": self.t, "r": self.r.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        r = np.asarray(state["r"], dtype=float).reshape(-1)
        if r.shape != (self.ny,) or not np.isfinite(r).all():
            raise ValueError(f"state: expected {self.ny} finite reference values")
        self.t, self.r = float(state["t"]), r.copy()
