"""Many Tennessee Eastman scenarios at once, on all cores.

A :class:`Scenario` is one run: seed, noise, IDVs switched on at given times, a
piecewise-constant XMV profile and a start mode. :func:`run_batch` runs them all
with the same step and literal build, each exactly as :class:`TESimulator`
would (same initialization evaluation, same draws), so results do not depend on
how scenarios are grouped or on the number of threads.

Backends: ``"threads"`` (default) is a numba ``prange`` over scenarios in one
process; ``"serial"`` is the same kernel on one core. A process pool was
measured against the threads (32 four-hour scenarios, noise on, 2 workers, the
machine's two cores shared with other jobs): 64-182 simulated hours per second
including the workers' start and cache load, against 114-185 for the threads;
the threads were kept (no start cost, no copying of results).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
from numba import njit, prange

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman import model as M
from plant_sim.tennessee_eastman.modes import parse_mode, start_state
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED
from plant_sim.tennessee_eastman.simulator import (
    DEFAULT_DT_S,
    NCOL,
    Shutdown,
    SimSettings,
    _check_idv,
    _schedule,
    _shutdown_from_memory,
    euler_run,
)

__all__ = ["Scenario", "ScenarioResult", "run_batch", "BACKENDS"]

BACKENDS = ("threads", "serial")


@dataclass(frozen=True)
class Scenario:
    """One run of a batch.

    Parameters
    ----------
    seed : float
        Generator seed (default: the original).
    noise : bool
        Measurement noise.
    idv : mapping of int to float
        IDV number (1..20) -> time (h) at which it switches on (and stays on).
    xmv_profile : sequence of (time_h, xmv12)
        XMV changes; before the first, the XMVs equal the start valve positions.
    mode : str
        Start mode (``base``, ``1`` ... ``6``).
    """

    seed: float = ORIGINAL_SEED
    noise: bool = False
    idv: Mapping[int, float] = field(default_factory=dict)
    xmv_profile: Sequence = ()
    mode: str = "base"

    def __post_init__(self) -> None:
        SimSettings(seed=self.seed, mode=self.mode)  # validates seed and mode
        object.__setattr__(self, "mode", parse_mode(self.mode))
        clean = {}
        for k, t in dict(self.idv).items():
            tf = float(t)
            if not math.isfinite(tf):
                raise PlantInputError(f"idv: switch time of IDV({k}) must be finite, got {t!r}")
            clean[_check_idv(k)] = tf
        object.__setattr__(self, "idv", clean)
        _schedule(self.xmv_profile)  # validates


@dataclass(frozen=True)
class ScenarioResult:
    """Outcome of one scenario.

    Attributes
    ----------
    scenario : Scenario
    shutdown : Shutdown or None
        First interlock trip.
    time_h : float
        Time reached (the trip time if the run stopped there).
    steps : int
        Euler steps taken.
    x, xmeas, xmv : ndarray
        Final state (50,), last measurements (41,), XMVs (12,).
    rows : ndarray, shape (n, 104)
        Recorded rows (empty unless recording was asked for).
    """

    scenario: Scenario
    shutdown: Shutdown | None
    time_h: float
    steps: int
    x: np.ndarray
    xmeas: np.ndarray
    xmv: np.ndarray
    rows: np.ndarray


@njit(cache=True)
def _one(K, noise_on, dt, n_steps, rec_every, stop_on_trip, yy, xmv, idv_on, idv_off,
         sched_t, sched_v, mem, xmeas, rows):
    work = np.zeros(M.NWORK)
    idv = np.zeros(20, dtype=np.int64)
    yp = np.zeros(50)
    M.tefunc(K, noise_on, 0.0, yy, xmv, idv, mem, work, xmeas, yp)  # TEINIT
    return euler_run(K, noise_on, dt, n_steps, rec_every, stop_on_trip, yy, xmv, idv, idv_on,
                     idv_off, sched_t, sched_v, mem, work, xmeas, yp, rows)


@njit(cache=True, parallel=True)
def _batch_threads(K, noise, dt, n_steps, rec_every, stop_on_trip, YY, XMV, IDV_ON, IDV_OFF,
                   SCHED_T, SCHED_V, MEM, XMEAS, ROWS, OUT):
    for s in prange(YY.shape[0]):
        n_rows, n_done = _one(K, noise[s], dt, n_steps, rec_every, stop_on_trip, YY[s], XMV[s],
                              IDV_ON[s], IDV_OFF[s], SCHED_T[s], SCHED_V[s], MEM[s], XMEAS[s],
                              ROWS[s])
        OUT[s, 0] = n_rows
        OUT[s, 1] = n_done


@njit(cache=True)
def _batch_serial(K, noise, dt, n_steps, rec_every, stop_on_trip, YY, XMV, IDV_ON, IDV_OFF,
                  SCHED_T, SCHED_V, MEM, XMEAS, ROWS, OUT):
    for s in range(YY.shape[0]):
        n_rows, n_done = _one(K, noise[s], dt, n_steps, rec_every, stop_on_trip, YY[s], XMV[s],
                              IDV_ON[s], IDV_OFF[s], SCHED_T[s], SCHED_V[s], MEM[s], XMEAS[s],
                              ROWS[s])
        OUT[s, 0] = n_rows
        OUT[s, 1] = n_done


def run_batch(scenarios: Sequence[Scenario], hours: float, *, dt_s: float = DEFAULT_DT_S,
              literals: str = "single", record_every_steps: int = 0,
              stop_on_trip: bool = True, backend: str = "threads") -> list[ScenarioResult]:
    """Run every scenario for ``hours`` (h) of simulated time.

    Parameters
    ----------
    scenarios : sequence of Scenario
    hours : float
        Duration (h, >= 0); the number of steps is ``round(hours / dt_h)``.
    dt_s : float
        Euler step (s).
    literals : {"single", "double"}
    record_every_steps : int
        Record a row every this many steps (0: none); with ``stop_on_trip`` the
        trip row is added.
    stop_on_trip : bool
        Stop each scenario at its first interlock trip.
    backend : {"threads", "serial"}

    Returns
    -------
    list of ScenarioResult
        In the order of ``scenarios``.
    """
    settings = SimSettings(dt_s=dt_s, literals=literals)
    if backend not in BACKENDS:
        raise PlantInputError(f"backend: expected one of {', '.join(BACKENDS)}, got {backend!r}")
    h = float(hours)
    if not math.isfinite(h) or h < 0:
        raise PlantInputError(f"hours: must be a finite number >= 0, got {hours!r}")
    scenarios = list(scenarios)
    for j, sc in enumerate(scenarios):
        if not isinstance(sc, Scenario):
            raise PlantInputError(f"scenarios[{j}]: expected a Scenario, got {type(sc).__name__}")
    n_steps = int(round(h / settings.dt_h))
    rec = int(record_every_steps)
    K = C.materialize(literals)
    S = len(scenarios)
    if S == 0:
        return []
    YY = np.zeros((S, 50))
    XMV = np.zeros((S, 12))
    IDV_ON = np.full((S, 20), np.inf)
    IDV_OFF = np.full((S, 20), np.inf)
    scheds = [_schedule(sc.xmv_profile) for sc in scenarios]
    m = max(1, max(len(t) for t, _ in scheds))
    SCHED_T = np.full((S, m), np.inf)
    SCHED_V = np.zeros((S, m, 12))
    MEM = np.zeros((S, M.NMEM))
    XMEAS = np.zeros((S, 41))
    noise = np.zeros(S, dtype=np.bool_)
    for s, sc in enumerate(scenarios):
        YY[s] = start_state(sc.mode, literals)
        XMV[s] = YY[s, 38:50]
        for k, t in sc.idv.items():
            IDV_ON[s, k - 1] = t
        t_s, v_s = scheds[s]
        SCHED_T[s, :len(t_s)] = t_s
        SCHED_V[s, :len(t_s)] = v_s
        MEM[s] = M.new_memory(K, sc.seed)
        noise[s] = sc.noise
    n_rows_max = (n_steps // rec + 2) if rec > 0 else 0
    ROWS = np.zeros((S, n_rows_max, NCOL))
    OUT = np.zeros((S, 2), dtype=np.int64)
    kernel = _batch_threads if backend == "threads" else _batch_serial
    kernel(K, noise, settings.dt_h, n_steps, rec, stop_on_trip, YY, XMV, IDV_ON, IDV_OFF,
           SCHED_T, SCHED_V, MEM, XMEAS, ROWS, OUT)
    results = []
    for s, sc in enumerate(scenarios):
        results.append(ScenarioResult(
            scenario=sc, shutdown=_shutdown_from_memory(MEM[s]),
            time_h=float(MEM[s, M.M_TIME]), steps=int(MEM[s, M.M_STEPS]), x=YY[s].copy(),
            xmeas=XMEAS[s].copy(), xmv=XMV[s].copy(), rows=ROWS[s, :OUT[s, 0]].copy()))
    return results
