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

Two extensions carry published multiloop structures (Lyman & Georgakis 1995 as
closed in Russell, Chiang & Braatz's ``temain_mod.f``): a loop without integral
action (``ti_h = inf``, the velocity-form P law ``u_k = u_{k-1} + Kc (e_k - e_{k-1})``),
and a :class:`CascadeLoop`, whose output is the set point of another loop in
the same layer (no limits on a set point), and a :class:`ValveOverride` on a
loop: a latched hysteresis that drives the loop's valve to a fixed opening while a
second measurement is beyond a limit and restarts the loop when it is back. Loops
run in the order given, each on the set point in force when it runs.

A :class:`PILoop` may also close a cascade of its own (:class:`SecondaryLoop`): its
output is then the set point of a secondary PI loop on a faster measurement, which
drives the loop's valve (the reactor temperature over the coolant outlet temperature,
as Lyman & Georgakis close it). The secondary runs right after its primary in the same
step; its set point is the layer's state, not one of the layer's set points, so a
layer with cascaded loops still takes one set point per loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman.simulator import NCOL, TESimulator, euler_run

__all__ = ["PILoop", "SecondaryLoop", "CascadeLoop", "ValveOverride", "TABLE_7_10",
           "RegulatoryLayer"]


@dataclass(frozen=True)
class ValveOverride:
    """Latched hysteresis override of one loop's valve on a second measurement.

    While the watched measurement is at or above ``high`` (latched until it is at or
    below ``release``) the valve is held at ``high_output``; at or below ``low``
    (latched until at or above ``release``) at ``low_output``. On release the valve
    is set to ``restart_output``, the loop's set point to ``restart_setpoint`` and
    its previous error to 0, and the loop runs again from the next step.

    Parameters
    ----------
    cv : int
        Watched XMEAS number (1-based).
    high, release, low : float
        Limits in the watched measurement's units, ``low < release < high``.
    restart_output : float
        Valve opening on release, %.
    restart_setpoint : float
        The loop's set point on release (its CV units).
    high_output, low_output : float
        Valve openings while latched high / low, %.
    """

    cv: int
    high: float
    release: float
    low: float
    restart_output: float
    restart_setpoint: float
    high_output: float = 100.0
    low_output: float = 0.0

    def __post_init__(self) -> None:
        if not 1 <= int(self.cv) <= 41:
            raise PlantInputError(f"cv: XMEAS number must be 1..41, got {self.cv!r}")
        vals = (self.high, self.release, self.low, self.restart_output,
                self.restart_setpoint, self.high_output, self.low_output)
        if not all(math.isfinite(v) for v in vals):
            raise PlantInputError("override: every limit and output must be finite")
        if not self.low < self.release < self.high:
            raise PlantInputError(f"override: need low < release < high, got {self.low}, "
                                  f"{self.release}, {self.high}")
        for name in ("restart_output", "high_output", "low_output"):
            if not 0.0 <= getattr(self, name) <= 100.0:
                raise PlantInputError(f"{name}: a valve opening in 0-100 %, got "
                                      f"{getattr(self, name)!r}")


def _check_ti(ti_h) -> None:
    if not (ti_h > 0 and not math.isnan(ti_h)):
        raise PlantInputError(f"ti_h: integral time must be > 0 h (inf: no integral "
                              f"action), got {ti_h!r}")


def _check_loop(cv, gain, ti_h) -> None:
    """A loop's measurement (XMEAS 1-41), gain (finite) and integral time (> 0 h)."""
    if not 1 <= int(cv) <= 41:
        raise PlantInputError(f"cv: XMEAS number must be 1..41, got {cv!r}")
    if not math.isfinite(gain):
        raise PlantInputError(f"gain: must be finite, got {gain!r}")
    _check_ti(ti_h)


@dataclass(frozen=True)
class SecondaryLoop:
    """The secondary (inner) PI loop of a cascaded :class:`PILoop`: it holds ``cv`` at
    the set point its primary writes, driving the primary's valve.

    Parameters
    ----------
    name : str
    cv : int
        Controlled XMEAS number (1-based).
    gain : float
        Controller gain, % of valve per unit of this CV.
    ti_h : float
        Integral time (h, > 0); ``math.inf``: proportional only.
    """

    name: str
    cv: int
    gain: float
    ti_h: float

    def __post_init__(self) -> None:
        _check_loop(self.cv, self.gain, self.ti_h)


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
        Controller gain, % of valve per unit of the CV; with a ``secondary``, units of
        the secondary's CV per unit of this CV.
    ti_h : float
        Integral time (h, > 0); ``math.inf``: proportional only.
    override : ValveOverride, optional
        A hysteresis override of this loop's valve.
    secondary : SecondaryLoop, optional
        Close the loop as a cascade: this loop writes the secondary's set point and the
        secondary drives ``mv``. Not with an ``override``.
    """

    name: str
    cv: int
    mv: int
    gain: float
    ti_h: float
    override: ValveOverride | None = None
    secondary: SecondaryLoop | None = None

    def __post_init__(self) -> None:
        _check_loop(self.cv, self.gain, self.ti_h)
        if not 1 <= int(self.mv) <= 12:
            raise PlantInputError(f"mv: XMV number must be 1..12, got {self.mv!r}")
        if self.secondary is not None and self.override is not None:
            raise PlantInputError(f"{self.name}: a cascaded loop (secondary) cannot also "
                                  "have a valve override")


@dataclass(frozen=True)
class CascadeLoop:
    """An outer loop of the layer: its output is another loop's set point.

    Parameters
    ----------
    name : str
    cv : int
        Controlled XMEAS number (1-based).
    inner : str
        Name of the loop whose set point it writes.
    gain : float
        Controller gain, inner-loop CV units per unit of this CV.
    ti_h : float
        Integral time (h, > 0); ``math.inf``: proportional only.
    """

    name: str
    cv: int
    inner: str
    gain: float
    ti_h: float

    def __post_init__(self) -> None:
        _check_loop(self.cv, self.gain, self.ti_h)
        if self.inner == self.name:
            raise PlantInputError(f"inner: loop {self.name!r} cannot write its own set point")


#: Seed Table 7.10 (R7.11).
TABLE_7_10 = (
    PILoop("reactor temperature", cv=9, mv=10, gain=-0.5, ti_h=1.0),
    PILoop("reactor level", cv=8, mv=1, gain=4.0, ti_h=1.0),
    PILoop("separator level", cv=12, mv=7, gain=-5.0, ti_h=1.0),
    PILoop("stripper level", cv=15, mv=8, gain=-1.5, ti_h=1.0),
)


@njit(cache=True)
def _regulated_run(K, noise_on, dt, n_steps, rec_every, stop_on_trip, yy, xmv, idv, idv_on,
                   idv_off, mem, work, xmeas, yp, rows, cv, out, to_sp, gain, ti, sp,
                   e_prev, started, ovr, ovr_on, ovr_state):
    no_t = np.zeros(0)
    no_v = np.zeros((0, 12))
    one_row = np.zeros((1, rows.shape[1]))
    n_rows = 0
    for s in range(n_steps):
        for j in range(cv.shape[0]):
            if ovr_on[j]:
                # ovr[j]: watched XMEAS index, high, release, low, high output,
                # low output, restart output, restart set point
                p = xmeas[int(ovr[j, 0])]
                st = ovr_state[j]
                held = -1.0
                if p >= ovr[j, 1]:
                    held, st = ovr[j, 4], 1
                elif st == 1 and p >= ovr[j, 2]:
                    held = ovr[j, 4]
                elif st == 1:
                    held, st = ovr[j, 6], 0
                    sp[j], e_prev[j], started[j] = ovr[j, 7], 0.0, True
                elif p <= ovr[j, 3]:
                    held, st = ovr[j, 5], 2
                elif st == 2 and p <= ovr[j, 2]:
                    held = ovr[j, 5]
                elif st == 2:
                    held, st = ovr[j, 6], 0
                    sp[j], e_prev[j], started[j] = ovr[j, 7], 0.0, True
                ovr_state[j] = st
                if held >= 0.0:
                    xmv[out[j]] = held
                    continue
            e = sp[j] - xmeas[cv[j]]
            if not started[j]:
                e_prev[j] = e
                started[j] = True
            du = gain[j] * ((e - e_prev[j]) + dt / ti[j] * e)
            e_prev[j] = e
            if to_sp[j]:
                sp[out[j]] += du
                continue
            u = xmv[out[j]] + du
            if u < 0.0:
                u = 0.0
            elif u > 100.0:
                u = 100.0
            xmv[out[j]] = u
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
    loops : sequence of PILoop or CascadeLoop
        Default: seed Table 7.10. Run in this order every step.
    setpoints : sequence of float, optional
        One per loop; default: the noise-free measurements at the plant's start.
    """

    def __init__(self, sim: TESimulator, loops=TABLE_7_10, setpoints=None) -> None:
        self.sim = sim
        self.loops = tuple(loops)
        names = [lp.name for lp in self.loops]
        if len(set(names)) != len(names):
            raise PlantInputError("loops: two loops have the same name")
        mvs = [lp.mv for lp in self.loops if isinstance(lp, PILoop)]
        if len(set(mvs)) != len(mvs):
            raise PlantInputError("loops: two loops drive the same XMV")
        inners = [lp.inner for lp in self.loops if isinstance(lp, CascadeLoop)]
        if len(set(inners)) != len(inners):
            raise PlantInputError("loops: two cascade loops write the same set point")
        for name in inners:
            if name not in names:
                raise PlantInputError(f"loops: cascade inner loop {name!r} is not in the layer")
        #: indices of the loops whose set point a cascade loop of the layer writes
        self.cascaded = tuple(names.index(n) for n in inners)
        # The compiled run's loops: the layer's, each cascaded PILoop followed by its
        # secondary; _public[i] is loop i's index among them.
        run, public = [], []
        for lp in self.loops:
            public.append(len(run))
            run.append(lp)
            if isinstance(lp, PILoop) and lp.secondary is not None:
                run.append(lp.secondary)
        self._public = np.array(public, dtype=np.int64)
        self._secondary = np.array([isinstance(lp, SecondaryLoop) for lp in run], dtype=np.bool_)
        n = len(run)
        self._cv = np.array([lp.cv - 1 for lp in run], dtype=np.int64)
        self._to_sp = np.array([isinstance(lp, CascadeLoop)
                                or (isinstance(lp, PILoop) and lp.secondary is not None)
                                for lp in run], dtype=np.bool_)
        mv = []
        for j, lp in enumerate(run):
            if isinstance(lp, CascadeLoop):
                mv.append(public[names.index(lp.inner)])
            elif isinstance(lp, SecondaryLoop):
                mv.append(run[j - 1].mv - 1)
            elif lp.secondary is not None:
                mv.append(j + 1)
            else:
                mv.append(lp.mv - 1)
        self._mv = np.array(mv, dtype=np.int64)
        self._gain = np.array([lp.gain for lp in run], dtype=float)
        self._ti = np.array([lp.ti_h for lp in run], dtype=float)
        self._ovr = np.zeros((n, 8))
        self._ovr_on = np.zeros(n, dtype=np.bool_)
        self._ovr_state = np.zeros(n, dtype=np.int64)
        for j, lp in enumerate(run):
            o = getattr(lp, "override", None)
            if o is not None:
                self._ovr_on[j] = True
                self._ovr[j] = (o.cv - 1, o.high, o.release, o.low, o.high_output,
                                o.low_output, o.restart_output, o.restart_setpoint)
        # every set point starts at its CV's noise-free start value (a secondary's too)
        self._sp = sim.initial_xmeas[self._cv].copy()
        if setpoints is not None:
            self.set_setpoints(setpoints)
        self._e_prev = np.zeros(n)
        self._started = np.zeros(n, dtype=np.bool_)
        # no step: the loops' compiled run is compiled (or loaded from numba's cache)
        # now, for the argument types every run passes, not in the plant's first sample
        self.run_steps(0)

    @property
    def setpoints(self) -> np.ndarray:
        """Set points, one per loop (CV units), a copy."""
        return self._sp[self._public]

    @property
    def secondary_setpoints(self) -> np.ndarray:
        """The set points the cascaded loops write to their secondaries, in loop order
        (CV units of each secondary), a copy."""
        return self._sp[self._secondary]

    @property
    def overrides_latched(self) -> tuple[int, ...]:
        """Per loop: 0 free, 1 latched high, 2 latched low (:class:`ValveOverride`)."""
        return tuple(int(v) for v in self._ovr_state[self._public])

    @property
    def gains(self) -> np.ndarray:
        """Gains in force, one per loop (a cascaded loop's primary), a copy."""
        return self._gain[self._public]

    def set_gains(self, values) -> None:
        """Retune the loops' gains (one per loop; a cascaded loop's primary), a DCS's
        tuning-set switch. NaN keeps a loop's gain in force.

        A loop whose gain changes has its output re-based onto the new gain: it moves by
        ``(K_new - K_old) e`` with ``e`` the loop's last error, to the value a PI with
        the new gain and the same integral gives (``u = I + K e``), and goes on in the
        velocity form from there. Without the re-base the old gain's proportional
        answer to the error at the switch stood as an offset until the (new, slower)
        integral took it away; at a steady grade that error is mostly the
        measurement's noise: the reactor level's loop switched from 4 to 0.5 %/% a day
        into 2 -> 5 left the D feed 1.4 % low, the E feed in ratio to it 10 % low, and
        the level fell from 65 to 60.5 % (seed 1). A loop that has not run yet, or is
        held by its override, moves nothing. Integral times stay.

        Raises
        ------
        PlantInputError
            Wrong length or an infinite value (the loop is named).
        """
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.shape[0] != len(self.loops):
            raise PlantInputError(f"gains: expected {len(self.loops)}, got {arr.shape[0]}")
        for lp, v in zip(self.loops, arr.tolist(), strict=True):
            if math.isinf(v):
                raise PlantInputError(f"gains: {lp.name} gain is not finite ({v})")
        new = np.where(np.isnan(arr), self._gain[self._public], arr)
        for j, k_new in zip(self._public.tolist(), new.tolist(), strict=True):
            k_old = float(self._gain[j])
            if k_new == k_old or not self._started[j] or self._ovr_state[j] != 0:
                continue
            du = (k_new - k_old) * float(self._e_prev[j])
            if not math.isfinite(du):
                continue
            if self._to_sp[j]:
                self._sp[self._mv[j]] += du
            else:
                mv = int(self._mv[j])
                self.sim._xmv[mv] = min(max(float(self.sim._xmv[mv]) + du, 0.0), 100.0)
        self._gain[self._public] = new

    def set_setpoints(self, values) -> None:
        """Set all set points (one per loop).

        A loop whose set point a cascade loop of the layer writes takes NaN to keep
        the cascade's value (a finite value replaces it).

        Raises
        ------
        PlantInputError
            Wrong length or a non-finite value (the loop is named).
        """
        arr = np.asarray(values, dtype=float).reshape(-1)
        if arr.shape[0] != len(self.loops):
            raise PlantInputError(f"setpoints: expected {len(self.loops)}, got {arr.shape[0]}")
        if all(map(math.isfinite, arr.tolist())):  # every set point given (the usual case)
            self._sp[self._public] = arr
            return
        keep = np.zeros(arr.shape[0], dtype=bool)
        for j, (lp, v) in enumerate(zip(self.loops, arr, strict=True)):
            if math.isnan(v) and j in self.cascaded:
                keep[j] = True
            elif not math.isfinite(v):
                raise PlantInputError(f"setpoints: {lp.name} set point is not finite ({v})")
        self._sp[self._public] = np.where(keep, self._sp[self._public], arr)

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
            sim._yp, rows, self._cv, self._mv, self._to_sp, self._gain, self._ti, self._sp,
            self._e_prev, self._started, self._ovr, self._ovr_on, self._ovr_state)
        return rows[:n_rows]
