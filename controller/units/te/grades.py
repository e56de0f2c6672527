"""Tennessee Eastman grades, transition references and run metrics (seed ch. 7.1, 7.6-7.7).

Grades
    ``mode0`` is the Downs & Vogel base case, ``mode1`` ... ``mode6`` Ricker's (1995)
    optimal steady states (seed Table 7.1, R7.1). Per grade: the measured outputs of
    seed Table 7.3 (R7.3, the set points) and Ricker's steady-state valve positions
    (the start state's states 39-50, :mod:`plant_sim.tennessee_eastman.modes`), which
    serve as feedforward targets for the valves the control structure does not close
    a loop on.

Reachability
    A grade is *reachable* by the §7.4/7.7 structure when every valve a loop or the
    MPC manipulates keeps a margin from its range ends at the grade's optimum
    (:data:`CONTROL_MARGIN`). Ricker's maximum-production optima put a feed valve at
    100 % (mode 4 and mode 6: D feed, mode 5: E feed), so nothing is left to control
    with there (:func:`ricker_optimum` keeps them as tabulated); the grades ``mode4``
    ... ``mode6`` run at a documented back-off from them instead, where that valve
    keeps a 5 % margin (:mod:`controller.units.te.max_production`). Asking for an
    unknown mode, or for a grade whose valves have no margin, raises
    :class:`GradeError`.

Transition references
    Between grades every target follows a first-order trajectory,
    ``tau dr/dt = s(t) - r`` with ``s`` the grade in force (seed §7.7: "a first-order
    reference trajectory"), evaluated in closed form so that it is exact at any
    time. This covers the reactor level 75 -> 65 %, the G mol% in product, the
    reactor temperature, the closing ramps of XMV(5) and XMV(9), and the valve
    feedforwards. The compressor recycle valve XMV(5) closes on its own, slower
    time constant (:data:`TAU_DEFAULT_H` ``"recycle"``, 10 h; it opens on the
    valves' 3 h): leaving mode 3 it closes from 77.6 % toward 1 %, which sends
    more of the recycle gas to the reactor, and on 3 h the 3 -> 0 and 3 -> 1 legs
    tripped on reactor pressure with every strategy, the plan's feedforward alone
    included (noise on, seed 1: plan 4.1 h and 3.2 h; with 10 h, and the E-feed
    limit and the plan hold of :mod:`controller.units.te.control`, neither trips).
    Opening it on 10 h instead made 0 -> 3 and 2 -> 3 trip (7.3 h and 2.5 h).

Metrics
    Operating cost ($/h, Downs & Vogel, from the simulator), production (stripper
    underflow, XMEAS 17), ISE per CV, time until the G mol% stays within a band of
    its final set point, valve saturation time and margins to the interlock limits.
"""

from __future__ import annotations

import csv
import dataclasses
import io
import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from controller.units.te.leg_references import LegReferenceSettings
from plant_sim.tennessee_eastman.modes import start_state

__all__ = ["GradeError", "Grade", "GRADES", "CONTROL_MARGIN", "CONTROLLED_VALVES", "grade",
           "ricker_optimum", "BACKOFF_GRADES",
           "parse_grade", "check_reachable", "Leg", "TransitionPlan", "TAU_DEFAULT_H",
           "first_order_path", "time_to_band", "ise", "saturation_time", "SHUTDOWN_LIMITS",
           "limit_margins", "production_change", "trailing_mean"]


class GradeError(ValueError):
    """A grade or a transition that the control structure cannot deliver; names the field."""


#: Seed Table 7.3 (R7.3): XMEAS 1-41 at modes 0-6 (facts, copied as data).
_TABLE_7_3 = """\
1,0.251,0.267,0.309,0.194,0.503,0.325,0.219
2,3664,3657,734,5179,5811,761,5811
3,4509,4440,8038,700,7244,8354,788
4,9.35,9.24,8.55,7.83,14.73,8.83,8.79
5,26.90,32.18,31.69,19.67,29.22,31.27,20.08
6,42.34,47.36,46.08,32.09,53.76,46.24,34.02
7,2705,2800,2800,2800,2800,2800,2800
8,75,65,65,65,65,65,65
9,120.4,122.9,124.2,121.9,128.2,124.6,123
10,0.337,0.211,0.361,0.087,0.462,0.384,0.099
11,80.1,91.7,90.3,83.4,74.1,88.9,80.9
12,50,50,50,50,50,50,50
13,2634,2706,2705,2765,2699,2705,2761
14,25.16,25.28,26.31,17.55,40.06,27.45,19.60
15,50,50,50,50,50,50,50
16,3102,3326,3327,2996,3365,3330,3015
17,22.95,22.89,22.73,18.04,36.04,23.55,20.20
18,65.73,66.5,65.4,62.3,51.5,63.9,60.5
19,230,4.74,4.90,5.34,6.87,5.11,5.59
20,341,278.9,274.7,272.6,263.2,271.17,293.2
21,94.6,102.4,108.6,101.9,96.6,108.5,100.6
22,77.3,92.0,91.6,45.0,73.5,89.8,45.7
23,32.19,32.21,34.82,29.46,35.40,34.78,29.99
24,8.89,14.93,8.18,27.74,8.78,7.85,26.34
25,26.38,18.75,19.43,17.97,22.36,19.54,18.80
26,6.88,6.03,1.20,12.68,7.95,1.24,13.23
27,18.78,16.71,25.47,3.86,17.01,26.03,3.91
28,1.66,4.04,5.60,1.29,3.88,5.60,1.33
29,32.96,32.73,36.63,27.86,40.94,36.71,28.61
30,13.82,21.83,11.77,45.07,15.90,11.47,44.41
31,23.98,13.11,14.63,9.22,15.68,14.57,9.76
32,1.26,0.90,0.13,2.18,0.68,0.13,2.09
33,18.58,16.19,22.37,3.94,15.41,22.92,4.00
34,2.26,5.39,7.37,1.82,5.72,7.44,1.91
35,4.84,6.62,1.32,9.40,3.85,1.26,8.76
36,2.30,3.23,5.79,0.50,1.82,5.51,0.46
37,0.02,0.01,0.00,0.03,0.02,0.00,0.03
38,0.84,0.58,0.92,0.16,1.21,1.01,0.18
39,0.01,0.19,0.29,0.07,0.04,0.32,0.08
40,53.72,53.83,11.66,90.09,53.35,11.65,90.07
41,43.83,43.91,85.64,8.17,43.52,85.53,8.16
"""

GRADES = ("mode0", "mode1", "mode2", "mode3", "mode4", "mode5", "mode6")
#: Valves a loop or the MPC of §7.4/7.7 manipulates (XMV numbers): the level loops'
#: D feed, separator and stripper underflows, reactor coolant; the ratio's E feed;
#: the MPC's A feed, A+C feed, purge, condenser coolant.
CONTROLLED_VALVES = (1, 2, 3, 4, 6, 7, 8, 10, 11)
#: Smallest distance (% of range) a controlled valve must keep from 0 % and 100 %
#: at the grade's optimum for the grade to count as reachable.
CONTROL_MARGIN = 0.5
#: Default time constants (h) of the first-order references: measured outputs, valves,
#: and the compressor recycle valve XMV(5) (see "Transition references").
TAU_DEFAULT_H = {"xmeas": 3.0, "xmv": 3.0, "recycle": 10.0}
#: XMV number of the compressor recycle valve.
RECYCLE_XMV = 5


@lru_cache(maxsize=1)
def _table() -> np.ndarray:
    rows = list(csv.reader(io.StringIO(_TABLE_7_3)))
    arr = np.array([[float(v) for v in r[1:]] for r in rows])
    if arr.shape != (41, 7):
        raise RuntimeError(f"Table 7.3: expected 41 x 7 values, got {arr.shape}")
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Grade:
    """One product grade (operating mode).

    Attributes
    ----------
    name : str
        ``mode0`` ... ``mode6``.
    xmeas : ndarray, shape (41,)
        Seed Table 7.3 outputs (XMEAS 1-41, their units); modes 4-6: the cascade's
        steady state at the back-off.
    xmv : ndarray, shape (12,)
        Ricker's (or the base case's) steady-state valve positions, %; modes 4-6: the
        back-off's.
    """

    name: str
    xmeas: np.ndarray
    xmv: np.ndarray

    @property
    def index(self) -> int:
        return int(self.name[4:])

    @property
    def g_mol(self) -> float:
        """G in product, mol% (Table 7.3 row 40)."""
        return float(self.xmeas[39])

    @property
    def reactor_level(self) -> float:
        """Reactor level set point, % (row 8)."""
        return float(self.xmeas[7])

    @property
    def reactor_temperature(self) -> float:
        """Reactor temperature set point, degC (row 9)."""
        return float(self.xmeas[8])

    @property
    def d_fraction(self) -> float:
        """D share of the D+E feed mass, D/(D+E) (rows 2 and 3)."""
        d, e = float(self.xmeas[1]), float(self.xmeas[2])
        return d / (d + e)

    def unreachable_reason(self) -> str | None:
        """Why the §7.4 structure cannot hold this grade, or None."""
        for v in CONTROLLED_VALVES:
            x = float(self.xmv[v - 1])
            if not CONTROL_MARGIN <= x <= 100.0 - CONTROL_MARGIN:
                return (f"XMV({v}) sits at {x:g} % at the {self.name} optimum, outside "
                        f"[{CONTROL_MARGIN:g}, {100 - CONTROL_MARGIN:g}] %: no control margin")
        return None


def parse_grade(value) -> str:
    """Normalize ``0``, ``"2"``, ``"mode3"``, ``"base"`` to ``"modeN"``.

    Raises
    ------
    GradeError
        Unknown grade; the message lists the known ones.
    """
    text = str(value).strip().lower()
    if text == "base":
        text = "0"
    if text.startswith("mode"):
        text = text[4:]
    name = f"mode{text}"
    if name not in GRADES:
        raise GradeError(f"grade: unknown grade {value!r}; known: {', '.join(GRADES)}")
    return name


#: Ricker's maximum-production modes, run at a documented back-off from the optimum
#: (:mod:`controller.units.te.max_production`).
BACKOFF_GRADES = ("mode4", "mode5", "mode6")


@lru_cache(maxsize=16)
def grade(value) -> Grade:
    """The :class:`Grade` of a mode (see :func:`parse_grade` for accepted names).

    Modes 0-3: :func:`ricker_optimum`. Modes 4-6: the back-off grade of
    :mod:`controller.units.te.max_production` (the cascade's steady state there)."""
    name = parse_grade(value)
    if name in BACKOFF_GRADES:
        from controller.units.te.max_production import steady_state

        xmeas, xmv = steady_state(name)
        xmeas.setflags(write=False)
        xmv.setflags(write=False)
        return Grade(name, xmeas, xmv)
    return ricker_optimum(name)


@lru_cache(maxsize=8)
def ricker_optimum(value) -> Grade:
    """The tabulated optimum of a mode: seed Table 7.3 outputs and Ricker's (or the base
    case's) valves, also for modes 4-6 (whose optimum puts a valve at 100 %)."""
    name = parse_grade(value)
    j = GRADES.index(name)
    xmeas = np.array(_table()[:, j])
    xmv = np.array(start_state("base" if j == 0 else str(j))[38:50])
    xmeas.setflags(write=False)
    xmv.setflags(write=False)
    return Grade(name, xmeas, xmv)


def check_reachable(current, target) -> tuple[Grade, Grade]:
    """Validate a grade change ``current -> target``.

    Returns
    -------
    (Grade, Grade)

    Raises
    ------
    GradeError
        Unknown grade (field ``grade``) or a target the structure cannot hold
        (field ``target``, with the valve that has no margin).
    """
    a, b = grade(current), grade(target)
    for field_name, g in (("current", a), ("target", b)):
        why = g.unreachable_reason()
        if why is not None:
            raise GradeError(f"{field_name}: grade {g.name} is not reachable with this control "
                             f"structure: {why}")
    return a, b


def first_order_path(t, t0: float, r0, switches) -> np.ndarray:
    """First-order trajectory through piecewise-constant targets, in closed form.

    ``tau dr/dt = s(t) - r``, ``r(t0) = r0``, ``s`` = the target of the last switch at
    or before ``t``.

    Parameters
    ----------
    t : float or array_like, shape (K,)
        Time(s) (h), >= t0.
    t0 : float
    r0 : array_like, shape (n,)
    switches : sequence of (time_h, target (n,), tau_h (n,) or float)
        Ascending times >= t0. ``tau = 0`` gives a step.

    Returns
    -------
    ndarray, shape (n,) for a scalar ``t``, (K, n) for an array of times
    """
    scalar = np.ndim(t) == 0
    tt = np.atleast_1d(np.asarray(t, dtype=float))
    r = np.array(np.broadcast_to(np.asarray(r0, dtype=float), (tt.size, np.size(r0))))
    for i, (ts, target, tau) in enumerate(switches):
        if ts < t0:
            raise ValueError(f"switches: time {ts} before t0 = {t0}")
        on = tt >= ts
        if not on.any():
            break
        t_next = switches[i + 1][0] if i + 1 < len(switches) else math.inf
        dt = np.minimum(tt[on], t_next) - ts
        r[on] = _relax(r[on], np.asarray(target, dtype=float), np.asarray(tau, dtype=float),
                       dt[:, None])
    return r[0] if scalar else r


def _relax(r, target, tau, dt):
    if tau.ndim == 0 or np.all(tau == tau.flat[0]):  # one time constant
        t0 = float(tau.flat[0])
        a = np.exp(-dt / t0) if t0 > 0 else np.zeros_like(dt)
    else:
        with np.errstate(divide="ignore", over="ignore"):
            a = np.where(tau > 0, np.exp(-dt / np.where(tau > 0, tau, 1.0)), 0.0)
    return target + (r - target) * a


@dataclass(frozen=True)
class _PathTable:
    """:func:`first_order_path` of one plan tabulated at its switches (per-sample speed).

    Row 0 is the start (from ``-inf``, target = start value); row i > 0 the i-th switch
    with the value the path has there (``start``) and its target. A time is evaluated
    in the segment of the last switch at or before it by :func:`_relax`, as
    :func:`first_order_path` does, so the values are bit for bit the same.
    """

    times: np.ndarray  # (L,), ascending, times[0] = -inf
    start: np.ndarray  # (L, n)
    target: np.ndarray  # (L, n)
    tau: np.ndarray  # 0-d (every column, every segment), or (L, n) per segment and column

    @classmethod
    def build(cls, times, values, tau: float, closing: dict | None = None,
              segment=None) -> _PathTable:
        """``closing``: column -> time constant of the segments that lower that column
        (a valve closing more slowly than it opens); ``segment(i, start)``: column ->
        time constant of the i-th switch's segment (0-based) starting at ``start``."""
        tau0 = np.asarray(float(tau))
        per_column = bool(closing) or segment is not None
        r = np.asarray(values[0], dtype=float)
        start, target, taus = [r], [r], [np.full(r.shape, float(tau))]
        for i, ts in enumerate(times):
            if i > 0:  # the path at this switch: the previous segment relaxed to its end
                r = _relax(r[None, :], target[-1], taus[-1] if per_column else tau0,
                           np.array([[ts - times[i - 1]]]))[0]
            start.append(r)
            target.append(np.asarray(values[i + 1], dtype=float))
            seg = np.full(r.shape, float(tau))
            for col, tau_c in (closing or {}).items():
                if target[-1][col] < r[col]:
                    seg[col] = tau_c
            for col, tau_c in (segment(i, r) if segment is not None else {}).items():
                seg[col] = tau_c
            taus.append(seg)
        return cls(np.array([-math.inf, *times]), np.array(start), np.array(target),
                   np.array(taus) if per_column else tau0)

    def __call__(self, t) -> np.ndarray:
        tt = np.asarray(t, dtype=float)
        scalar = tt.ndim == 0
        tt = tt.reshape(-1)
        i = np.searchsorted(self.times, tt, side="right") - 1
        tau = self.tau if self.tau.ndim == 0 else self.tau[i]
        r = _relax(self.start[i], self.target[i], tau, (tt - self.times[i])[:, None])
        return r[0] if scalar else r


@dataclass(frozen=True)
class Leg:
    """From ``t_h`` on, head for ``grade`` (``modeN``)."""

    t_h: float
    grade: str

    def __post_init__(self) -> None:
        if not (isinstance(self.t_h, int | float) and math.isfinite(self.t_h) and self.t_h >= 0):
            raise GradeError(f"t_h: leg start must be a finite time >= 0 h, got {self.t_h!r}")
        object.__setattr__(self, "grade", parse_grade(self.grade))


@dataclass(frozen=True)
class TransitionPlan:
    """A start grade and timed legs, with first-order references between grades.

    Parameters
    ----------
    start : str
        Grade at t = 0.
    legs : tuple of Leg
        Later grades, strictly increasing times; each change is validated by
        :func:`check_reachable`.
    tau_xmeas_h : float
        Time constant of the measured-output references (h): G mol%, levels,
        reactor temperature, pressures ...
    tau_xmv_h : float
        Time constant of the valve ramps and feedforwards (XMV(9) closing ...).
    tau_recycle_h : float
        Time constant of the compressor recycle valve XMV(5)'s feedforward where a leg
        closes it (it opens on ``tau_xmv_h``).
    leg_references : LegReferenceSettings or None
        The MPC's faster references of the reactor level and temperature through a leg
        (:mod:`controller.units.te.leg_references`; :meth:`with_leg_references`); None:
        every measured output on ``tau_xmeas_h``.
    """

    start: str = "mode0"
    legs: tuple[Leg, ...] = ()
    tau_xmeas_h: float = TAU_DEFAULT_H["xmeas"]
    tau_xmv_h: float = TAU_DEFAULT_H["xmv"]
    tau_recycle_h: float = TAU_DEFAULT_H["recycle"]
    leg_references: LegReferenceSettings | None = None
    _grades: tuple = field(default=(), repr=False, compare=False)
    _tables: dict = field(default_factory=dict, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "start", parse_grade(self.start))
        legs = tuple(lg if isinstance(lg, Leg) else Leg(*lg) for lg in self.legs)
        for a, b in zip(legs[:-1], legs[1:], strict=False):
            if b.t_h <= a.t_h:
                raise GradeError(f"legs: times must increase ({a.t_h} then {b.t_h})")
        for name in ("tau_xmeas_h", "tau_xmv_h", "tau_recycle_h"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise GradeError(f"{name}: must be a finite time >= 0 h, got {v!r}")
        prev = self.start
        grade(prev)
        for lg in legs:
            check_reachable(prev, lg.grade)
            prev = lg.grade
        object.__setattr__(self, "legs", legs)
        if not (self.leg_references is None
                or isinstance(self.leg_references, LegReferenceSettings)):
            raise GradeError("leg_references: must be LegReferenceSettings or None, got "
                             f"{type(self.leg_references).__name__}")
        grades = (grade(self.start),) + tuple(grade(lg.grade) for lg in legs)
        object.__setattr__(self, "_grades", grades)
        times = [lg.t_h for lg in legs]
        if self.leg_references is None:
            xmeas = _PathTable.build(times, [g.xmeas for g in grades], self.tau_xmeas_h)
            after = grades
        else:  # the MPC's own path; the other tables switch with it, on the same targets
            x_times, values, segment, leg_of = self.leg_references.path(
                times, grades, self.tau_xmeas_h)
            xmeas = _PathTable.build(x_times, values, self.tau_xmeas_h, segment=segment)
            times = x_times
            after = (grades[0],) + tuple(grades[i + 1] for i in leg_of)
        object.__setattr__(self, "_tables", {
            "xmeas": xmeas,
            "xmv": _PathTable.build(times, [g.xmv for g in after], self.tau_xmv_h,
                                    closing=({RECYCLE_XMV - 1: self.tau_recycle_h}
                                             if self.tau_recycle_h != self.tau_xmv_h
                                             else None)),
            "d_fraction": _PathTable.build(times, [np.array([g.d_fraction]) for g in after],
                                           self.tau_xmv_h)})

    def with_leg_references(self, settings: LegReferenceSettings | None) -> TransitionPlan:
        """The same plan with the MPC's level and temperature references of
        ``settings`` (None: the plan's own)."""
        return dataclasses.replace(self, leg_references=settings)

    @property
    def final(self) -> Grade:
        return self._grades[-1]

    def hours_since_change(self, t: float) -> float:
        """Hours from the last grade change at or before ``t`` to ``t`` (``inf`` when
        no leg has started: the start grade has always been requested)."""
        last = -math.inf
        for lg in self.legs:
            if lg.t_h <= t:
                last = lg.t_h
        return float(t) - last

    def change_at(self, t: float) -> tuple[Grade, Grade]:
        """The grades before and after the last grade change at or before ``t`` (the
        start grade twice when no leg has started)."""
        before = after = self._grades[0]
        for lg, gr in zip(self.legs, self._grades[1:], strict=True):
            if lg.t_h <= t:
                before, after = after, gr
        return before, after

    def grade_at(self, t: float) -> Grade:
        """Grade requested at time ``t`` (the target, not where the plant is)."""
        g = self._grades[0]
        for lg, gr in zip(self.legs, self._grades[1:], strict=True):
            if lg.t_h <= t:
                g = gr
        return g

    def xmeas_ref(self, t) -> np.ndarray:
        """References of XMEAS 1-41 at ``t`` (41,): Table 7.3 rows, first-order between.

        An array of K times gives a (K, 41) array (one evaluation for a whole horizon)."""
        return self._tables["xmeas"](t)

    def xmv_ref(self, t) -> np.ndarray:
        """Valve references at ``t`` (12,): the grades' steady valves, first-order between
        (XMV(5) and XMV(9) close this way toward modes 1-3). An array of K times gives
        (K, 12)."""
        return self._tables["xmv"](t)

    def d_fraction_ref(self, t: float) -> float:
        """Feedforward D share of the D+E feed mass at ``t``."""
        return float(self._tables["d_fraction"](t)[0])


# -- metrics ------------------------------------------------------------------------------
#: Interlock limits of the original plant (Downs & Vogel), checked on the noise-free
#: values: name -> (low, high, unit).
SHUTDOWN_LIMITS = {
    "reactor pressure": (-math.inf, 3000.0, "kPa"),
    "reactor temperature": (-math.inf, 175.0, "degC"),
    "reactor liquid volume": (2.0, 24.0, "m3"),
    "separator liquid volume": (1.0, 12.0, "m3"),
    "stripper liquid volume": (1.0, 8.0, "m3"),
}


def level_to_volume(level_pct, vessel: str):
    """Liquid volume (m3) from a level (%): te.md §4 spans converted from ft3."""
    ft3 = {"reactor": (84.6, 666.7), "separator": (27.5, 290.0), "stripper": (78.25, 156.5)}
    off, span = ft3[vessel]
    return (off + span * np.asarray(level_pct, dtype=float) / 100.0) * 0.0283168466


def limit_margins(xmeas_rows) -> dict[str, dict]:
    """Closest approach to each interlock limit over a run.

    Parameters
    ----------
    xmeas_rows : array_like, shape (K, 41)

    Returns
    -------
    dict
        name -> {"min", "max", "limit", "margin", "unit"}, where ``margin`` is the
        smallest distance to the nearer limit (negative: crossed).
    """
    y = np.asarray(xmeas_rows, dtype=float)
    series = {"reactor pressure": y[:, 6], "reactor temperature": y[:, 8],
              "reactor liquid volume": level_to_volume(y[:, 7], "reactor"),
              "separator liquid volume": level_to_volume(y[:, 11], "separator"),
              "stripper liquid volume": level_to_volume(y[:, 14], "stripper")}
    out = {}
    for name, s in series.items():
        lo, hi, unit = SHUTDOWN_LIMITS[name]
        m_hi = hi - float(np.max(s))
        m_lo = float(np.min(s)) - lo
        if m_hi <= m_lo:
            limit, margin = hi, m_hi
        else:
            limit, margin = lo, m_lo
        out[name] = {"min": float(np.min(s)), "max": float(np.max(s)), "limit": limit,
                     "margin": margin, "unit": unit}
    return out


def time_to_band(t, y, target: float, band: float, t_request: float) -> float:
    """Time after ``t_request`` from which ``|y - target| <= band`` holds to the end (h).

    ``inf`` if the last sample is outside the band.
    """
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    out = np.flatnonzero(np.abs(y - target) > band)
    if out.size == 0:
        return max(float(t[0]) - t_request, 0.0)
    if out[-1] == y.size - 1:
        return math.inf
    return float(t[out[-1] + 1]) - t_request


def trailing_mean(values, n: int) -> np.ndarray:
    """Mean of each sample with the ``n - 1`` before it (fewer at the start), per column:
    a noisy analyzer or flow read as an operator reads its trend.

    ``values`` (K,) or (K, m); returns the same shape.
    """
    v = np.asarray(values, dtype=float)
    flat = v.ndim == 1
    v = v.reshape(v.shape[0], -1)
    n = max(int(n), 1)
    c = np.vstack([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    idx = np.arange(v.shape[0])
    lo = np.maximum(idx + 1 - n, 0)
    out = (c[idx + 1] - c[lo]) / (idx + 1 - lo)[:, None]
    return out[:, 0] if flat else out


def ise(t, y, r) -> float:
    """Integral of squared error ``∫ (y - r)^2 dt`` by the rectangle rule (unit² h)."""
    t = np.asarray(t, dtype=float)
    e = np.asarray(y, dtype=float) - np.asarray(r, dtype=float)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 0.0))
    return float(np.sum(e * e * dt))


def saturation_time(t, u, low: float = 0.0, high: float = 100.0, tol: float = 1e-6) -> float:
    """Time a valve spends at (or beyond) a limit (h), rectangle rule."""
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    dt = np.diff(t, append=t[-1] + (t[-1] - t[-2] if t.size > 1 else 0.0))
    sat = (u >= high - tol) | (u <= low + tol)
    return float(np.sum(dt[sat]))


def production_change(t, production, t_before: float, window_h: float = 2.0) -> float:
    """Relative change (%) of the mean production over the last ``window_h`` of the run
    against its mean over ``window_h`` before ``t_before``."""
    t = np.asarray(t, dtype=float)
    p = np.asarray(production, dtype=float)
    before = p[(t >= t_before - window_h) & (t < t_before)]
    after = p[t >= t[-1] - window_h]
    if before.size == 0 or after.size == 0:
        raise ValueError("t_before/window_h: no samples in a window")
    return float(100.0 * (after.mean() - before.mean()) / before.mean())
