"""The TE regulatory layer: discrete PI loops run at the integration step (seed ch. 7.4).

Table 7.10 of the seed (R7.11): reactor temperature -> reactor cooling water
(XMV 10), -0.5 %/degC; reactor level -> D feed (XMV 1), 4 %/%; separator level ->
separator underflow (XMV 7), -5 %/%; stripper level -> stripper underflow (XMV 8),
-1.5 %/%; all with an integral time of 1 h (the OCR prints "i" for the
temperature loop; 1 h is taken, as in the facts).

Each loop is a velocity-form PI, ``u_k = u_{k-1} + Kc ((e_k - e_{k-1}) + dt/Ti e_k)``
with ``e = set point - measurement``, run before each Euler step on the
measurements of the previous evaluation, as the original demo driver runs its
controllers. The output is limited to 0-100 %; in velocity form a limited output
does not wind up. The first execution takes ``e_{k-1} = e_k`` (no proportional kick).
Set points are inputs (the MPC writes them); by default they are the noise-free
measurements at the start, so closing the loops is bumpless.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman.simulator import NCOL, TESimulator, euler_run

__all__ = ["PILoop", "TABLE_7_10", "RegulatoryLayer"]


@dataclass(frozen=True)
class PILoop:
    """One PI loop.

    Parameters
    ----------
    name : str
    cv : int
        Controlled XMEAS number (1-based).
    mv : int
        Manipulated XMV number (1-based).
    gain : float
        Controller gain, % of valve per unit of the CV.
    ti_h : float
        Integral time (h, > 0).
    """

    name: str
    cv: int
    mv: int
    gain: float
    ti_h: float

    def __post_init__(self) -> None:
        if not 1 <= int(self.cv) <= 41:
            raise PlantInputError(f"cv: XMEAS number must be 1..41, got {self.cv!r}")
        if not 1 <= int(self.mv) <= 12:
            raise PlantInputError(f"mv: XMV number must be 1..12, got {self.mv!r}")
        if not math.isfinite(self.gain):
            raise PlantInputError(f"gain: must be finite, got {self.gain!r}")
        if not (math.isfinite(self.ti_h) and self.ti_h > 0):
            raise PlantInputError(f"ti_h: integral time must be > 0 h, got {self.ti_h!r}")


#: Seed Table 7.10 (R7.11).
TABLE_7_10 = (
    PILoop("reactor temperature", cv=9, mv=10, gain=-0.5, ti_h=1.0),
    PILoop("reactor level", cv=8, mv=1, gain=4.0, ti_h=1.0),
    PILoop("separator level", cv=12, mv=7, gain=-5.0, ti_h=1.0),
    PILoop("stripper level", cv=15, mv=8, gain=-1.5, ti_h=1.0),
)


@njit(cache=True)
def _regulated_run(K, noise_on, dt, n_steps, rec_every, stop_on_trip, yy, xmv, idv, idv_on,
                   idv_off, mem, work, xmeas, yp, rows, cv, mv, gain, ti, sp, e_prev, started):
    no_t = np.zeros(0)
    no_v = np.zeros((0, 12))
    one_row = np.zeros((1, rows.shape[1]))
    n_rows = 0
    for s in range(n_steps):
        for j in range(cv.shape[0]):
            e = sp[j] - xmeas[cv[j]]
            if not started[j]:
                e_prev[j] = e
                started[j] = True
            u = xmv[mv[j]] + gain[j] * ((e - e_prev[j]) + dt / ti[j] * e)
            if u < 0.0:
                u = 0.0
            elif u > 100.0:
                u = 100.0
            xmv[mv[j]] = u
            e_prev[j] = e
        rec = rec_every if (rec_every > 0 and n_rows < rows.shape[0]) else 0
        target = one_row if rec > 0 else rows[:0]
        r, done = euler_run(K, noise_on, dt, 1, rec, stop_on_trip, yy, xmv, idv, idv_on,
                            idv_off, no_t, no_v, mem, work, xmeas, yp, target)
        if r > 0:
            rows[n_rows, :] = one_row[0, :]
            n_rows += 1
        if done == 0:
            return n_rows, s
    return n_rows, n_steps


class RegulatoryLayer:
    """PI loops around a :class:`TESimulator`, executed every integration step.

    Parameters
    ----------
    sim : TESimulator
        The plant; the loops overwrite its XMVs of their MVs.
    loops : sequence of PILoop
        Default: seed Table 7.10.
    setpoints : sequence of float, optional
        One per loop; default: the noise-free measurements at the plant's start.
    """

    def __init__(self, sim: TESimulator, loops=TABLE_7_10, setpoints=None) -> None:
        self.sim = sim
        self.loops = tuple(loops)
        mvs = [lp.mv for lp in self.loops]
        if len(set(mvs)) != len(mvs):
            raise PlantInputError("loops: two loops drive the same XMV")
        self._cv = np.array([lp.cv - 1 for lp in self.loops], dtype=np.int64)
        self._mv = np.array([lp.mv - 1 for lp in self.loops], dtype=np.int64)
        self._gain = np.array([lp.gain for lp in self.loops], dtype=float)
        self._ti = np.array([lp.ti_h for lp in self.loops], dtype=float)
        if setpoints is None:
            self._sp = sim.initial_xmeas[self._cv].copy()
        else:
            self._sp = np.zeros(len(self.loops))
            self.set_setpoints(setpoints)
        self._e_prev = np.zeros(len(self.loops))
        self._started = np.zeros(len(self.loops), dtype=np.bool_)

    @property
    def setpoints(self) -> np.ndarray:
        """Set points, one per loop (CV units), a copy."""
        return self._sp.copy()

    def set_setpoints(self, values) -> None:
        """Set all set points (one per loop).

        Raises
        ------
        PlantInputError
            Wrong length or a non-finite value (the loop is named).
        """
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.shape[0] != len(self.loops):
            raise PlantInputError(f"setpoints: expected {len(self.loops)}, got {arr.shape[0]}")
        for lp, v in zip(self.loops, arr, strict=True):
            if not math.isfinite(v):
                raise PlantInputError(f"setpoints: {lp.name} set point is not finite ({v})")
        self._sp[:] = arr

    def run_steps(self, n: int, record_every: int = 0, stop_on_trip: bool = False) -> np.ndarray:
        """``n`` steps with the loops closed; rows as :meth:`TESimulator.run_steps`."""
        sim = self.sim
        n = int(n)
        if n < 0:
            raise PlantInputError(f"n: number of steps must be >= 0, got {n}")
        rows = np.empty(((n // record_every + 2) if record_every > 0 else 0, NCOL))
        n_rows, _ = _regulated_run(
            sim._K, sim.settings.noise, sim.dt_h, n, int(record_every), stop_on_trip, sim.x,
            sim._xmv, sim._idv, sim._idv_on, sim._idv_off, sim._mem, sim._work, sim._xmeas,
            sim._yp, rows, self._cv, self._mv, self._gain, self._ti, self._sp, self._e_prev,
            self._started)
        return rows[:n_rows]
