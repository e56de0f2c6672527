"""Open-loop simulation and one-sample stepping of a :class:`~plant_sim.base.PlantModel`.

Inputs and disturbances are held constant between breakpoints (zero-order hold).
Each constant-input segment is integrated separately with :func:`scipy.integrate.solve_ivp`
so that no step of the integrator straddles an input jump. The default method is
``"LSODA"`` (switches between Adams and BDF, copes with the calcium model's fast
-841 1/s mode); ``"BDF"`` and ``"Radau"`` are also accepted.

Everything here is pure: results are returned as :class:`SimulationResult` records;
writing them to CSV is the job of ``services``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from plant_sim.base import PlantInputError, PlantModel, as_vector

__all__ = ["PiecewiseConstant", "SimulationResult", "simulate", "step", "STIFF_METHODS"]

STIFF_METHODS = ("LSODA", "BDF", "Radau")

#: Default relative and absolute integration tolerances (atol is scaled per state).
DEFAULT_RTOL = 1e-9
DEFAULT_ATOL = 1e-12


@dataclass(frozen=True)
class PiecewiseConstant:
    """A zero-order-hold signal: ``values[k]`` holds from ``times[k]`` up to ``times[k+1]``.

    Parameters
    ----------
    times : ndarray, shape (n,)
        Strictly increasing switching times in the plant's time unit.
    values : ndarray, shape (n, m)
        Signal value after each switching time. Before ``times[0]`` the first value holds.
    """

    times: np.ndarray
    values: np.ndarray

    def __post_init__(self) -> None:
        t = np.asarray(self.times, dtype=float).reshape(-1)
        v = np.asarray(self.values, dtype=float)
        if v.ndim == 1:
            v = v.reshape(len(t), -1) if len(t) else v.reshape(0, -1)
        if len(t) == 0:
            raise PlantInputError("inputs: a schedule needs at least one (time, value) step")
        if v.shape[0] != len(t):
            raise PlantInputError(f"inputs: {len(t)} times but {v.shape[0]} values")
        if not np.all(np.isfinite(t)):
            raise PlantInputError("inputs: non-finite switching time")
        if np.any(np.diff(t) <= 0):
            raise PlantInputError("inputs: switching times must be strictly increasing")
        object.__setattr__(self, "times", t)
        object.__setattr__(self, "values", v)

    @classmethod
    def from_steps(cls, steps: Sequence[tuple[float, Sequence[float]]]) -> PiecewiseConstant:
        """Build from a list of ``(t, value)`` pairs (sorted by time; equal times: last wins)."""
        if len(steps) == 0:
            raise PlantInputError("inputs: a schedule needs at least one (time, value) step")
        merged: dict[float, np.ndarray] = {}
        for t, val in sorted(steps, key=lambda s: float(s[0])):
            merged[float(t)] = np.asarray(val, dtype=float).reshape(-1)
        times = np.array(list(merged))
        return cls(times, np.vstack(list(merged.values())))

    @classmethod
    def constant(cls, value: Sequence[float], t0: float = 0.0) -> PiecewiseConstant:
        return cls(np.array([t0]), np.asarray(value, dtype=float).reshape(1, -1))

    @property
    def width(self) -> int:
        return self.values.shape[1]

    def at(self, t: float) -> np.ndarray:
        """Value held at time ``t`` (right-continuous)."""
        k = int(np.searchsorted(self.times, t, side="right")) - 1
        return self.values[max(k, 0)]


def _as_schedule(value, n: int, field_name: str, t0: float) -> PiecewiseConstant:
    if isinstance(value, PiecewiseConstant):
        sched = value
    elif isinstance(value, list | tuple) and value and isinstance(value[0], tuple):
        try:
            sched = PiecewiseConstant.from_steps(value)
        except PlantInputError as exc:
            raise PlantInputError(str(exc).replace("inputs:", f"{field_name}:", 1)) from exc
    else:
        return PiecewiseConstant.constant(as_vector(value, n, field_name), t0)
    if sched.width != n:
        raise PlantInputError(f"{field_name}: expected length {n}, got {sched.width}")
    for k, row in enumerate(sched.values):
        as_vector(row, n, f"{field_name}[{k}]")
    return sched


@dataclass(frozen=True)
class SimulationResult:
    """Trajectory of a simulation, sampled on a uniform grid.

    Attributes
    ----------
    t : ndarray, shape (N,)
        Sample times, in :attr:`time_unit`.
    x, u, d, y : ndarray, shapes (N, nx), (N, nu), (N, nd), (N, ny)
        States, held inputs, held disturbances and outputs at each sample time.
    state_names, input_names, disturbance_names, output_names : tuple of str
    state_units, input_units, disturbance_units, output_units : tuple of str
    time_unit : str
    plant : str
        Registry name of the plant.
    """

    t: np.ndarray
    x: np.ndarray
    u: np.ndarray
    d: np.ndarray
    y: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    disturbance_names: tuple[str, ...]
    output_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_units: tuple[str, ...]
    disturbance_units: tuple[str, ...]
    output_units: tuple[str, ...]
    time_unit: str
    plant: str

    def columns(self) -> list[tuple[str, str, np.ndarray]]:
        """All signals as ``(name, unit, values)``: time, states, inputs, disturbances, outputs.

        Output names that repeat a state name get a ``y_`` prefix so columns stay unique.
        """
        cols = [("t", self.time_unit, self.t)]
        groups = (
            (self.state_names, self.state_units, self.x, ""),
            (self.input_names, self.input_units, self.u, ""),
            (self.disturbance_names, self.disturbance_units, self.d, ""),
            (self.output_names, self.output_units, self.y, "y_"),
        )
        seen = {"t"}
        for names, units, data, prefix in groups:
            for i, (name, unit) in enumerate(zip(names, units, strict=True)):
                col = name if name not in seen else f"{prefix or 'v_'}{name}"
                seen.add(col)
                cols.append((col, unit, data[:, i]))
        return cols

    def signal(self, name: str) -> np.ndarray:
        """One signal by name; outputs are preferred over states of the same name."""
        for names, data in ((self.output_names, self.y), (self.state_names, self.x),
                            (self.input_names, self.u), (self.disturbance_names, self.d)):
            if name in names:
                return data[:, names.index(name)]
        if name == "t":
            return self.t
        raise PlantInputError(f"signal: unknown name {name!r}")


def _check_positive(value: float, field_name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise PlantInputError(f"{field_name}: not a number ({value!r})") from exc
    if not math.isfinite(v) or v <= 0:
        raise PlantInputError(f"{field_name}: must be a positive finite number, got {value!r}")
    return v


def _atol(model: PlantModel, x0: np.ndarray, atol: float) -> np.ndarray:
    scale = np.maximum(np.abs(x0), getattr(model, "state_scale", np.ones(model.nx)))
    return atol * scale


def _integrate_segment(model, x, u, d, t_a, t_b, t_eval, method, rtol, atol_vec):
    def f(t, z):
        return model.rhs(t, z, u, d)

    sol = solve_ivp(f, (t_a, t_b), x, method=method, t_eval=t_eval, rtol=rtol,
                    atol=atol_vec, dense_output=False)
    if not sol.success:
        raise RuntimeError(f"integration failed on [{t_a}, {t_b}]: {sol.message}")
    return sol


def simulate(model: PlantModel, x0, inputs, t_end: float, dt: float, *, d=None,
             t0: float = 0.0, method: str = "LSODA", rtol: float = DEFAULT_RTOL,
             atol: float = DEFAULT_ATOL) -> SimulationResult:
    """Simulate ``model`` from ``x0`` with zero-order-hold inputs.

    Parameters
    ----------
    model : PlantModel
    x0 : array_like, shape (nx,)
        Initial state at ``t0``.
    inputs : array_like, shape (nu,), or list of ``(t, u)`` pairs, or PiecewiseConstant
        A constant input vector, or a piecewise-constant schedule; ``u`` switches to
        the given value at each ``t`` and holds until the next switch.
    t_end : float
        Final time (plant time unit); the result covers ``[t0, t_end]``.
    dt : float
        Output sample period (plant time unit). Breakpoints of the schedules need not
        fall on the grid: the integrator stops at each of them.
    d : array_like, shape (nd,), list of ``(t, d)`` pairs, PiecewiseConstant, optional
        Disturbances; default :meth:`PlantModel.default_disturbance`.
    method : {"LSODA", "BDF", "Radau"}
        :func:`scipy.integrate.solve_ivp` method (all stiff-capable).
    rtol, atol : float
        Integration tolerances; ``atol`` is multiplied by each state's scale.

    Returns
    -------
    SimulationResult

    Raises
    ------
    PlantInputError
        Wrong vector length, non-finite values, ``dt <= 0`` or ``t_end <= t0``.
    """
    if method not in STIFF_METHODS:
        raise PlantInputError(f"method: must be one of {STIFF_METHODS}, got {method!r}")
    dt = _check_positive(dt, "dt")
    t0 = float(t0)
    t_end = float(t_end)
    if not math.isfinite(t_end) or t_end <= t0:
        raise PlantInputError(f"t_end: must be finite and greater than t0={t0}, got {t_end!r}")
    x = as_vector(x0, model.nx, "x0")
    u_s = _as_schedule(inputs, model.nu, "inputs", t0)
    d_s = _as_schedule(model.default_disturbance() if d is None else d, model.nd, "d", t0)

    n = int(math.floor((t_end - t0) / dt + 1e-9))
    grid = t0 + dt * np.arange(n + 1)
    if t_end - grid[-1] > 1e-9 * dt:
        grid = np.append(grid, t_end)
    breaks = sorted({float(b) for b in np.concatenate([u_s.times, d_s.times])
                     if t0 < b < t_end} | {t0, t_end})

    atol_vec = _atol(model, x, atol)
    xs = np.empty((len(grid), model.nx))
    xs[0] = x
    filled = 1
    for t_a, t_b in zip(breaks[:-1], breaks[1:]):
        u = u_s.at(t_a)
        dd = d_s.at(t_a)
        # grid points in (t_a, t_b]
        lo = int(np.searchsorted(grid, t_a, side="right"))
        hi = int(np.searchsorted(grid, t_b, side="right"))
        t_eval = grid[lo:hi]
        with_end = t_eval if (t_eval.size and t_eval[-1] == t_b) else np.append(t_eval, t_b)
        sol = _integrate_segment(model, x, u, dd, t_a, t_b, with_end, method, rtol, atol_vec)
        if hi > lo:
            xs[lo:hi] = sol.y[:, : hi - lo].T
            filled = hi
        x = sol.y[:, -1]
    if filled != len(grid):  # pragma: no cover - guards the grid bookkeeping
        raise RuntimeError("simulate: output grid not filled")
    us = np.vstack([u_s.at(t) for t in grid])
    ds = np.vstack([d_s.at(t) for t in grid]) if model.nd else np.zeros((len(grid), 0))
    ys = np.vstack([model.outputs(xs[k], us[k]) for k in range(len(grid))])
    return SimulationResult(
        t=grid, x=xs, u=us, d=ds, y=ys,
        state_names=tuple(model.names("state")),
        input_names=tuple(model.names("input")),
        disturbance_names=tuple(model.names("disturbance")),
        output_names=tuple(model.names("output")),
        state_units=tuple(v.unit for v in model.state_vars),
        input_units=tuple(v.unit for v in model.input_vars),
        disturbance_units=tuple(v.unit for v in model.disturbance_vars),
        output_units=tuple(v.unit for v in model.output_vars),
        time_unit=model.time_unit,
        plant=model.name,
    )


def _endpoint(model, x, u, d, t_a, t_b, method, rtol, atol_vec) -> np.ndarray:
    sol = _integrate_segment(model, x, u, d, t_a, t_b, np.array([t_b]), method, rtol, atol_vec)
    return sol.y[:, -1]


def step(model: PlantModel, x, u, dt: float, d=None, *, t: float = 0.0,
         method: str = "LSODA", rtol: float = DEFAULT_RTOL,
         atol: float = DEFAULT_ATOL) -> np.ndarray:
    """Integrate one sample of length ``dt`` with ``u`` and ``d`` held; return the new state.

    Parameters
    ----------
    model : PlantModel
    x : array_like, shape (nx,)
    u : array_like, shape (nu,)
    dt : float
        Sample period (> 0), plant time unit.
    d : array_like, shape (nd,), optional
        Disturbances; default :meth:`PlantModel.default_disturbance`.
    t : float
        Time at the start of the sample (only matters for time-varying models).

    Returns
    -------
    ndarray, shape (nx,)
    """
    if method not in STIFF_METHODS:
        raise PlantInputError(f"method: must be one of {STIFF_METHODS}, got {method!r}")
    dt = _check_positive(dt, "dt")
    xv = as_vector(x, model.nx, "x")
    uv = as_vector(u, model.nu, "u")
    dv = as_vector(model.default_disturbance() if d is None else d, model.nd, "d")
    return _endpoint(model, xv, uv, dv, float(t), float(t) + dt, method, rtol,
                     _atol(model, xv, atol))
