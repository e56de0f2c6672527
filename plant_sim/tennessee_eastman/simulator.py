"""Euler driver of the Tennessee Eastman model, as the original demo driver runs it.

Per step the driver evaluates the model at the current time, adds the step to
the time (a double accumulated step by step, never recomputed as k * dt), then
updates every state by ``x <- x + dx/dt * dt`` (TEMAIN/INTGTR). Initialization
evaluates the model once at t = 0 (TEINIT), so the first step evaluates it at
t = 0 a second time.

:class:`TESimulator` is one plant: its state, the model memory (random
processes, analyzers, valve commands, generator), XMVs and IDVs. Long runs with
the XMVs held go through :meth:`TESimulator.run_steps`, which loops inside
compiled code; closed loops call :meth:`TESimulator.step` once per step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from plant_sim.base import PlantInputError, as_vector
from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman import model as M
from plant_sim.tennessee_eastman.modes import parse_mode, start_state
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED

__all__ = ["TESimulator", "Shutdown", "SimSettings", "ROW_COLUMNS", "NCOL", "euler_run",
           "cost_from_measurements", "cost_from_rows", "DEFAULT_DT_S"]

DEFAULT_DT_S = 1.8
#: Columns of a recorded row (the layout of the reference CSV files).
ROW_COLUMNS = (("time",) + tuple(f"XMEAS{i}" for i in range(1, 42))
               + tuple(f"XMV{i}" for i in range(1, 13)) + tuple(f"X{i}" for i in range(1, 51)))
NCOL = len(ROW_COLUMNS)  # 104


@dataclass(frozen=True)
class SimSettings:
    """Settings of a Tennessee Eastman run; validated on construction.

    Parameters
    ----------
    dt_s : float
        Euler step in seconds (> 0; the original driver uses 1.8).
    noise : bool
        Measurement noise on. The random draws happen either way, as in the original.
    seed : float
        Initial value of the generator state ``G`` (finite, >= 0). Default: the
        original 1431655765.
    literals : {"single", "double"}
        Published build (single-precision literals) or the all-double variant.
    mode : str
        Start mode: ``base`` or ``1`` ... ``6``.
    step_h : float, optional
        The Euler step in hours exactly as given, overriding ``dt_s / 3600``. The
        demo driver ``temain.f`` writes ``DELTAT = 1. / 3600.``, which its compiler
        folds in single precision: ``step_h=float(np.float32(1) / np.float32(3600))``
        reproduces it (``dt_s`` is then ignored).
    """

    dt_s: float = DEFAULT_DT_S
    noise: bool = False
    seed: float = ORIGINAL_SEED
    literals: str = "single"
    mode: str = "base"
    step_h: float | None = None

    def __post_init__(self) -> None:
        try:
            dt = float(self.dt_s)
        except (TypeError, ValueError) as exc:
            raise PlantInputError(f"dt: not a number ({self.dt_s!r})") from exc
        if not math.isfinite(dt) or dt <= 0.0:
            raise PlantInputError(f"dt: Euler step must be a positive number of seconds, "
                                  f"got {self.dt_s!r}")
        object.__setattr__(self, "dt_s", dt)
        seed = float(self.seed)
        if not math.isfinite(seed) or seed < 0.0:
            raise PlantInputError(f"seed: must be a finite number >= 0, got {self.seed!r}")
        object.__setattr__(self, "seed", seed)
        if self.literals not in C.LITERAL_MODES:
            raise PlantInputError(f"literals: expected one of {', '.join(C.LITERAL_MODES)}, "
                                  f"got {self.literals!r}")
        object.__setattr__(self, "mode", parse_mode(self.mode))
        object.__setattr__(self, "noise", bool(self.noise))
        if self.step_h is not None:
            h = float(self.step_h)
            if not math.isfinite(h) or h <= 0.0:
                raise PlantInputError(f"step_h: Euler step must be a positive number of hours, "
                                      f"got {self.step_h!r}")
            object.__setattr__(self, "step_h", h)
            object.__setattr__(self, "dt_s", h * 3600.0)

    @property
    def dt_h(self) -> float:
        """Euler step in hours: ``step_h`` if given, else dt_s / 3600 in double."""
        return self.step_h if self.step_h is not None else self.dt_s / 3600.0


@dataclass(frozen=True)
class Shutdown:
    """The first interlock trip of a run.

    Attributes
    ----------
    time_h : float
        Time of the model evaluation that tripped (h).
    reason : str
        Which limit, e.g. ``"reactor pressure high"``.
    variable : str
        The checked variable and its unit.
    value, limit : float
        Its noise-free value at the trip and the limit it crossed.
    code : int
        1..8, the original's order of checks.
    """

    time_h: float
    reason: str
    variable: str
    value: float
    limit: float
    code: int

    def as_dict(self) -> dict:
        return {"time_h": self.time_h, "reason": self.reason, "variable": self.variable,
                "value": self.value, "limit": self.limit}


def _shutdown_from_memory(mem: np.ndarray) -> Shutdown | None:
    code = int(mem[M.M_TRIP_CODE])
    if code == 0:
        return None
    return Shutdown(time_h=float(mem[M.M_TRIP_TIME]), reason=M.TRIP_REASONS[code],
                    variable=M.TRIP_VARIABLES[code], value=float(mem[M.M_TRIP_VALUE]),
                    limit=M.TRIP_LIMITS[code], code=code)


@njit(cache=True)
def euler_run(K, noise_on, dt, n_steps, rec_every, stop_on_trip, yy, xmv, idv, idv_on,
              idv_off, sched_t, sched_v, mem, work, xmeas, yp, rows):
    """``n_steps`` Euler steps of the driver, with optional recording.

    IDV ``k`` is on while ``idv_on[k] <= t < idv_off[k]``. XMV schedule entry ``j``
    (``sched_t[j]``, ``sched_v[j]``, times ascending) is applied before the first
    step with ``t >= sched_t[j]``. A row (time, XMEAS, XMV, X before the step) is
    written to ``rows`` every ``rec_every`` steps counted from t = 0
    (``rec_every`` <= 0: none) and, with ``stop_on_trip``, at the first trip,
    where the run then stops without applying that step.

    Returns
    -------
    (int, int)
        Rows written, steps taken.
    """
    n_rows = 0
    n_sched = sched_t.shape[0]
    for s in range(n_steps):
        t = mem[M.M_TIME]
        j = int(mem[M.M_SCHED])
        while j < n_sched and t >= sched_t[j]:
            for i in range(12):
                xmv[i] = sched_v[j, i]
            j += 1
        mem[M.M_SCHED] = j
        for k in range(20):
            idv[k] = 1 if (t >= idv_on[k] and t < idv_off[k]) else 0
        had_trip = mem[M.M_TRIP_CODE] != 0.0
        isd = M.tefunc(K, noise_on, t, yy, xmv, idv, mem, work, xmeas, yp)
        first_trip = isd != 0 and not had_trip
        step = int(mem[M.M_STEPS])
        if rec_every > 0 and n_rows < rows.shape[0] and (
                step % rec_every == 0 or (first_trip and stop_on_trip)):
            rows[n_rows, 0] = t
            for i in range(41):
                rows[n_rows, 1 + i] = xmeas[i]
            for i in range(12):
                rows[n_rows, 42 + i] = xmv[i]
            for i in range(50):
                rows[n_rows, 54 + i] = yy[i]
            n_rows += 1
        if stop_on_trip and isd != 0:
            return n_rows, s
        mem[M.M_TIME] = t + dt
        for i in range(50):
            yy[i] = yy[i] + yp[i] * dt
        mem[M.M_STEPS] = step + 1
    return n_rows, n_steps


def cost_from_measurements(xmeas, product_flow_lbmol_h: float) -> float:
    """Downs & Vogel operating cost in $/h from the measurements (te.md 9).

    Parameters
    ----------
    xmeas : array_like, shape (41,)
        Measurements (XMEAS 10, 19, 20, 29-36, 37-39 are used).
    product_flow_lbmol_h : float
        Stripper product flow (stream 11) in lb-mol/h.
    """
    x = np.asarray(xmeas, dtype=float)
    purge_price = (2.206, 0.0, 6.177, 22.06, 14.56, 17.89, 30.44, 22.94)  # $/kmol, A..H
    purge_kmol_h = 44.79 * x[9]
    purge = purge_kmol_h * sum(p * x[28 + i] / 100.0 for i, p in enumerate(purge_price))
    product_kmol_h = product_flow_lbmol_h * 0.454
    product = product_kmol_h * sum(p * x[36 + i] / 100.0
                                   for i, p in enumerate(purge_price[3:6]))
    return float(purge + product + 0.0536 * x[19] + 0.0318 * x[18])


def cost_from_rows(xmeas_rows, product_flows_lbmol_h) -> np.ndarray:
    """:func:`cost_from_measurements` of many samples at once, $/h.

    The same operations in the same order, element by element, so each value is bit
    for bit that of :func:`cost_from_measurements` on its row (a closed loop records
    the rows and flows and prices them after the run).

    Parameters
    ----------
    xmeas_rows : array_like, shape (K, 41)
        Measurements, one row per sample.
    product_flows_lbmol_h : array_like, shape (K,)
        Stripper product flow (stream 11) of each sample, lb-mol/h.

    Returns
    -------
    ndarray, shape (K,)
    """
    x = np.asarray(xmeas_rows, dtype=float).reshape(-1, 41)
    flow = np.asarray(product_flows_lbmol_h, dtype=float).reshape(-1)
    if flow.shape[0] != x.shape[0]:
        raise PlantInputError(f"product_flows_lbmol_h: expected {x.shape[0]} values, got "
                              f"{flow.shape[0]}")
    purge_price = (2.206, 0.0, 6.177, 22.06, 14.56, 17.89, 30.44, 22.94)  # $/kmol, A..H
    purge_sum = np.zeros(x.shape[0])  # 0 + first term, as sum() starts
    for i, p in enumerate(purge_price):
        purge_sum = purge_sum + p * x[:, 28 + i] / 100.0
    product_sum = np.zeros(x.shape[0])
    for i, p in enumerate(purge_price[3:6]):
        product_sum = product_sum + p * x[:, 36 + i] / 100.0
    purge = 44.79 * x[:, 9] * purge_sum
    product = flow * 0.454 * product_sum
    return purge + product + 0.0536 * x[:, 19] + 0.0318 * x[:, 18]


class TESimulator:
    """One Tennessee Eastman plant integrated by Euler as the original driver does.

    Parameters
    ----------
    settings : SimSettings, optional
        Step, noise, seed, literal build, start mode. Keyword arguments of the
        same names build one (``TESimulator(noise=True, mode="3")``).

    Notes
    -----
    XMVs outside 0-100 % are accepted and kept as given; the model clips the
    *commanded valve value* to 0-100 % as the original does (the XMV array itself
    is not clipped). NaN or infinite XMVs raise :class:`PlantInputError`.
    After an interlock trip the derivatives are zero (the plant freezes) while the
    trip condition holds, as in the original; :attr:`shutdown` records the first
    trip.
    """

    def __init__(self, settings: SimSettings | None = None, **kwargs) -> None:
        if settings is None:
            settings = SimSettings(**kwargs)
        elif kwargs:
            raise TypeError("give either settings or keyword arguments, not both")
        self.settings = settings
        self._K = C.materialize(settings.literals)
        self._dt_h = settings.dt_h
        self.x = start_state(settings.mode, settings.literals)
        self._xmv = self.x[38:50].copy()
        self._idv = np.zeros(20, dtype=np.int64)
        self._idv_on = np.full(20, np.inf)
        self._idv_off = np.full(20, np.inf)
        self._mem = M.new_memory(self._K, settings.seed)
        self._work = M.new_work()
        self._xmeas = np.zeros(41)
        self._yp = np.zeros(50)
        self._no_sched_t = np.zeros(0)
        self._no_sched_v = np.zeros((0, 12))
        self._no_rows = np.zeros((0, NCOL))
        # TEINIT: one evaluation at t = 0
        M.tefunc(self._K, settings.noise, 0.0, self.x, self._xmv, self._idv, self._mem,
                 self._work, self._xmeas, self._yp)
        self.initial_derivative = self._yp.copy()
        self.initial_xmeas = self._xmeas.copy()

    # -- state -------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time (h)."""
        return float(self._mem[M.M_TIME])

    @property
    def steps(self) -> int:
        """Euler steps taken."""
        return int(self._mem[M.M_STEPS])

    @property
    def dt_h(self) -> float:
        return self._dt_h

    @property
    def xmeas(self) -> np.ndarray:
        """Measurements of the last evaluation (41,), a copy."""
        return self._xmeas.copy()

    @property
    def derivative(self) -> np.ndarray:
        """Derivatives of the last evaluation (50,), a copy."""
        return self._yp.copy()

    @property
    def xmv(self) -> np.ndarray:
        """Current XMVs (12,), a copy."""
        return self._xmv.copy()

    @property
    def shutdown(self) -> Shutdown | None:
        """The first interlock trip, or None."""
        return _shutdown_from_memory(self._mem)

    @property
    def generator_state(self) -> float:
        """Current value of the generator state ``G``."""
        return float(self._mem[M.M_G])

    @property
    def idv(self) -> np.ndarray:
        """IDV flags (20,) at the current time."""
        t = self.time
        return ((self._idv_on <= t) & (t < self._idv_off)).astype(np.int64)

    # -- inputs ------------------------------------------------------------------------
    def set_xmv(self, xmv) -> None:
        """Set all 12 XMVs (%). Values outside 0-100 are clipped by the valve model.

        Raises
        ------
        PlantInputError
            Wrong length or a NaN/infinite XMV (the message names its index, 1-based).
        """
        arr = np.asarray(xmv, dtype=float).reshape(-1)
        if arr.shape[0] != 12:
            raise PlantInputError(f"xmv: expected 12 values, got {arr.shape[0]}")
        if not all(map(math.isfinite, arr.tolist())):  # (faster than numpy's for 12)
            bad = np.flatnonzero(~np.isfinite(arr))
            raise PlantInputError(f"xmv: XMV({int(bad[0]) + 1}) is not finite ({arr[bad[0]]})")
        self._xmv[:] = arr

    def set_idv(self, k: int, on: bool = True, at_h: float | None = None) -> None:
        """Switch IDV(``k``) on or off, now or at time ``at_h`` (h).

        Raises
        ------
        PlantInputError
            If ``k`` is not 1..20 or ``at_h`` is not finite.
        """
        k = _check_idv(k)
        t = self.time if at_h is None else float(at_h)
        if not math.isfinite(t):
            raise PlantInputError(f"idv: switch time must be finite, got {at_h!r}")
        if on:
            self._idv_on[k - 1] = t
            self._idv_off[k - 1] = np.inf
        else:
            self._idv_off[k - 1] = t

    # -- stepping ----------------------------------------------------------------------
    def step(self, xmv=None) -> np.ndarray:
        """One Euler step (optionally setting the XMVs first).

        Returns
        -------
        ndarray, shape (41,)
            The measurements computed at the start of the step (the original's
            XMEAS after a step belong to the state at its start).
        """
        if xmv is not None:
            self.set_xmv(xmv)
        euler_run(self._K, self.settings.noise, self._dt_h, 1, 0, False, self.x, self._xmv,
                  self._idv, self._idv_on, self._idv_off, self._no_sched_t, self._no_sched_v,
                  self._mem, self._work, self._xmeas, self._yp, self._no_rows)
        return self._xmeas.copy()

    def run_steps(self, n: int, record_every: int = 0, stop_on_trip: bool = False,
                  xmv_schedule=None) -> np.ndarray:
        """``n`` Euler steps with the XMVs held (or following ``xmv_schedule``).

        Parameters
        ----------
        n : int
            Steps (>= 0).
        record_every : int
            Record a row every this many steps counted from t = 0 (0: none).
        stop_on_trip : bool
            Stop at the first interlock trip (its row is recorded).
        xmv_schedule : sequence of (time_h, xmv12), optional
            XMV changes applied at the first step at or after each time.

        Returns
        -------
        ndarray, shape (rows, 104)
            Recorded rows in the layout of :data:`ROW_COLUMNS`.
        """
        n = int(n)
        if n < 0:
            raise PlantInputError(f"n: number of steps must be >= 0, got {n}")
        record_every = int(record_every)
        if record_every > 0:
            first = self.steps
            n_regular = len(range(first + (-first) % record_every, first + n, record_every))
            rows = np.empty((n_regular + 1, NCOL))
        else:
            rows = self._no_rows
        sched_t, sched_v = _schedule(xmv_schedule)
        self._mem[M.M_SCHED] = 0
        n_rows, _ = euler_run(self._K, self.settings.noise, self._dt_h, n, record_every,
                              stop_on_trip, self.x, self._xmv, self._idv, self._idv_on,
                              self._idv_off, sched_t, sched_v, self._mem, self._work,
                              self._xmeas, self._yp, rows)
        return rows[:n_rows]

    @property
    def product_flow_lbmol_h(self) -> float:
        """Stripper product flow (stream 11) of the last evaluation, lb-mol/h (what
        :meth:`cost` prices; :func:`cost_from_rows` takes it per sample)."""
        return float(self._mem[M.M_FTM13])

    def cost(self) -> float:
        """Operating cost ($/h) from the current measurements (Downs & Vogel)."""
        return cost_from_measurements(self._xmeas, float(self._mem[M.M_FTM13]))


def _check_idv(k) -> int:
    try:
        ki = int(k)
    except (TypeError, ValueError) as exc:
        raise PlantInputError(f"idv: not an integer ({k!r})") from exc
    if ki != k or not 1 <= ki <= 20:
        raise PlantInputError(f"idv: unknown disturbance IDV({k}); known: 1..20")
    return ki


def _schedule(xmv_schedule) -> tuple[np.ndarray, np.ndarray]:
    if not xmv_schedule:
        return np.zeros(0), np.zeros((0, 12))
    times = []
    values = []
    for j, (t, v) in enumerate(xmv_schedule):
        tf = float(t)
        if not math.isfinite(tf):
            raise PlantInputError(f"xmv_schedule[{j}]: time must be finite, got {t!r}")
        arr = as_vector(v, 12, f"xmv_schedule[{j}]")
        times.append(tf)
        values.append(arr)
    order = np.argsort(times, kind="stable")
    return np.asarray(times)[order], np.asarray(values)[order]
