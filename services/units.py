"""Unit registry: which plant, grades, sample period and controller a unit runs.

A *unit* is one plant of :mod:`plant_sim` run by one controller node. Its
:class:`UnitConfig` is validated on construction and can be read from a JSON
file (``--unit-config``) on top of the registry defaults (:data:`UNITS`).

Controllers (``UnitConfig.controller``):

- ``"pi"`` — :class:`PIBaseline`, a discrete multivariable PI with static
  decoupling (velocity form): an honest baseline for any square unit.
- ``"hold"`` — :class:`HoldController`: MVs held ("MPC off"; for TE the
  regulatory layer alone keeps the levels and the reactor temperature).
- ``"hinf"``, ``"mrac"`` — the SISO units (cstr, bioreactor): the state-shared
  multiple-model controller (fixed OPI/OPII models, a free-running and a
  re-initialized adaptive model, eq. 4.1/4.6) with the H-infinity (§5.2) or MRAC
  (§5.1) law, tuned as the chapter-5 study (:mod:`services.studies.ch5`).
- ``"ssmpc"`` — two-phase reactor: the state-shared MPC of the chapter-6 study
  (:mod:`services.studies.ch6`: reduced OPI/OPII models, Δu MPC).
- ``"te"`` — the TE supervisory controller of issue 8
  (``services.studies.te_control``; ``UnitConfig.strategy``: ``ssmpc`` by default,
  ``fixed`` or ``pi``) behind :class:`TEServiceController`.

Defaults (:data:`UNITS`): cstr and bioreactor ``hinf``, two_phase_reactor
``ssmpc``, te ``te``/``ssmpc``. Builders: :data:`CONTROLLER_BUILDERS`.

Process time in the services is in seconds: ``time_scale_s`` converts the
plant's own time unit (3600 for ``h``; 1 for ``s``; the CSTR's dimensionless
time is taken as seconds).
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from controller.interfaces import ControlDecision
from services.keys import check_unit_name

__all__ = [
    "UnitConfig",
    "UNITS",
    "CONTROLLERS",
    "CONTROLLER_BUILDERS",
    "PIBaseline",
    "get_unit",
    "unit_names",
    "load_unit_config",
    "build_plant",
    "build_controller",
    "grade_setpoints",
]

CONTROLLERS = ("pi", "hold", "hinf", "mrac", "ssmpc", "te")
TIME_SCALE = {"h": 3600.0, "s": 1.0, "-": 1.0, "min": 60.0}

TE_EULER_STEP_S = 1.8
TE_STRATEGIES = ("ssmpc", "fixed", "pi")
TE_XMEAS = tuple(f"XMEAS{i}" for i in range(1, 42))


def te_setpoint_name(loop) -> str:
    """MV name of a TE inner loop's set point: ``"reactor level"`` → ``reactor_level_sp``."""
    return loop.name.replace(" ", "_") + "_sp"


def te_structure(strategy: str = "pi") -> tuple[tuple, tuple[int, ...]]:
    """``(inner loops, XMVs the supervisory controller writes)`` of the TE cascade.

    From issue 8's controller spec (``services.studies.te_control``) when present,
    else seed Table 7.10 with every other valve writable. The plant node runs these
    loops; the controller node's MV vector is the written XMVs, then one set point
    per loop (:func:`te_mv_names`).
    """
    try:
        from services.studies.te_control import TEControlSpec
    except ImportError:
        from plant_sim.tennessee_eastman.regulatory import TABLE_7_10

        owned = {lp.mv for lp in TABLE_7_10}
        return TABLE_7_10, tuple(i for i in range(1, 13) if i not in owned)
    spec = TEControlSpec(strategy, TE_EULER_STEP_S * 20 / 3600.0, 20)
    return tuple(spec.loops), tuple(spec.written_xmvs)


def te_mv_names(cfg) -> tuple[str, ...]:
    """The TE unit's MV vector: explicit ``cfg.mvs``, else the cascade's (te_structure)."""
    if cfg.mvs:
        return tuple(cfg.mvs)
    loops, written = te_structure(cfg.strategy)
    return tuple(f"XMV{i}" for i in written) + tuple(te_setpoint_name(lp) for lp in loops)


@dataclass(frozen=True)
class UnitConfig:
    """Everything a plant node and a controller node of one unit agree on.

    Parameters
    ----------
    unit : str
        Unit name (a key-expression segment).
    plant : str
        Plant registry name of :mod:`plant_sim` (``cstr``, ``two_phase_reactor``, ...).
    sample_period_s : float
        Controller sample period, process seconds.
    initial_grade : str
        Grade (operating point) the plant starts at and the set points start from.
    cvs, mvs : tuple of str
        Controlled outputs and manipulated inputs by name (empty = all).
    controller : str
        One of :data:`CONTROLLERS`.
    budget_fraction : float
        Share of the wall-clock sample period the controller may use, (0, 1].
    transition_duration_s : float
        Default transition duration, process seconds (first-order reference,
        98 % after this time).
    settle_tolerance : float
        Settled band, fraction of each CV's scale.
    settle_samples : int
        Consecutive in-band samples to call a transition settled.
    cv_scales : tuple of float
        Engineering scale per CV (ISE and settle band); empty = from the grades.
    pi_gain : float
        PI proportional gain relative to the inverse steady-state gain (dimensionless).
    pi_integral_time_s : float
        PI integral time, process seconds.
    track : tuple of str
        CVs that transitions follow (reference, ISE, settling, progress); empty = all.
    plausible_factor : float
        Instrument range of each CV: the grades' span widened by this many scales
        (scale = max(spread of the grades, largest |value|, 1)), within the plant's
        physical bounds. A reading outside it is a sensor fault and is not acted on.
    strategy : str
        TE only: ``ssmpc`` (state-shared MPC, seed §7.7), ``fixed`` (fixed models +
        MPC, §7.5) or ``pi`` (decentralized PI baseline) of issue 8's TE controller.
    substeps : int
        Plant-node integration steps per sample (for ODE plants: solver calls).
    status_every, checkpoint_every, telemetry_every : int
        Samples between status messages, SQLite checkpoints and Rerun batches.
    """

    unit: str
    plant: str
    sample_period_s: float
    initial_grade: str
    cvs: tuple[str, ...] = ()
    mvs: tuple[str, ...] = ()
    controller: str = "pi"
    budget_fraction: float = 0.5
    transition_duration_s: float = 10.0
    settle_tolerance: float = 0.02
    settle_samples: int = 5
    cv_scales: tuple[float, ...] = ()
    pi_gain: float = 1.0
    pi_integral_time_s: float = 1.0
    substeps: int = 1
    track: tuple[str, ...] = ()
    strategy: str = "ssmpc"
    plausible_factor: float = 100.0
    status_every: int = 10
    checkpoint_every: int = 50
    telemetry_every: int = 50
    description: str = ""

    def __post_init__(self) -> None:
        check_unit_name(self.unit)
        from plant_sim import PLANTS

        if self.plant not in PLANTS:
            raise ValueError(f"plant: unknown plant {self.plant!r}; known: {', '.join(PLANTS)}")
        for name in ("sample_period_s", "transition_duration_s", "pi_integral_time_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        if not (0 < self.budget_fraction <= 1):
            raise ValueError(f"budget_fraction: must be in (0, 1], got {self.budget_fraction}")
        if self.controller not in CONTROLLERS:
            raise ValueError(f"controller: expected one of {CONTROLLERS}, got {self.controller!r}")
        if not (0 < self.settle_tolerance < 1):
            raise ValueError(f"settle_tolerance: must be in (0, 1), got {self.settle_tolerance}")
        for name in ("settle_samples", "substeps", "status_every", "checkpoint_every",
                     "telemetry_every"):
            v = getattr(self, name)
            if not (isinstance(v, int) and not isinstance(v, bool) and v >= 1):
                raise ValueError(f"{name}: must be an integer >= 1, got {v!r}")
        if not (math.isfinite(self.plausible_factor) and self.plausible_factor > 0):
            raise ValueError(f"plausible_factor: must be positive, got {self.plausible_factor}")
        if not math.isfinite(self.pi_gain) or self.pi_gain <= 0:
            raise ValueError(f"pi_gain: must be positive, got {self.pi_gain}")
        object.__setattr__(self, "cvs", tuple(self.cvs))
        object.__setattr__(self, "mvs", tuple(self.mvs))
        object.__setattr__(self, "cv_scales", tuple(float(s) for s in self.cv_scales))
        object.__setattr__(self, "track", tuple(self.track))
        if self.cvs and not set(self.track) <= set(self.cvs):
            raise ValueError(f"track: {sorted(set(self.track) - set(self.cvs))} not among cvs")
        if any(not (math.isfinite(s) and s > 0) for s in self.cv_scales):
            raise ValueError("cv_scales: must be positive numbers")
        if self.plant == "te":
            _check_te_config(self)

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any], base: UnitConfig | None = None) -> UnitConfig:
        """Build from a dict (e.g. JSON); unknown keys are an error naming the key."""
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unit config: unknown field(s) {', '.join(sorted(unknown))}")
        if base is None:
            return cls(**d)
        return replace(base, **d)


def _check_te_config(cfg: UnitConfig) -> None:
    if tuple(cfg.cvs) != TE_XMEAS:
        raise ValueError("cvs: the TE unit measures all 41 XMEAS (XMEAS1..XMEAS41, in order)")
    if cfg.mvs:
        loops, _ = te_structure(cfg.strategy)
        sps = {te_setpoint_name(lp) for lp in loops}
        owned = {f"XMV{lp.mv}" for lp in loops}
        allowed = {f"XMV{i}" for i in range(1, 13)} | sps
        for name in cfg.mvs:
            if name in owned:
                raise ValueError(f"mvs: {name} is driven by an inner loop; write its set "
                                 f"point instead ({', '.join(sorted(sps))})")
            if name not in allowed:
                raise ValueError(f"mvs: unknown TE MV {name!r}; use XMV1..XMV12 or "
                                 f"{', '.join(sorted(sps))}")
    if cfg.strategy not in TE_STRATEGIES:
        raise ValueError(f"strategy: expected one of {TE_STRATEGIES}, got {cfg.strategy!r}")
    n = cfg.sample_period_s / TE_EULER_STEP_S
    if abs(n - round(n)) > 1e-9 or round(n) < 1:
        raise ValueError(f"sample_period_s: must be a multiple of the TE Euler step "
                         f"{TE_EULER_STEP_S} s, got {cfg.sample_period_s}")


# Registry defaults. Sample periods: the seed's where printed, otherwise a choice
# that resolves the plant's dominant dynamics with ~20 samples.
UNITS: dict[str, UnitConfig] = {
    # Chapter 5 tunings (services.studies.ch5): sample 0.05, reference time constant 5
    # (duration 20 = 4 tau), H-infinity law on the state-shared multiple models.
    "cstr": UnitConfig(
        unit="cstr", plant="cstr", sample_period_s=0.05, initial_grade="OPI",
        controller="hinf", transition_duration_s=20.0, pi_gain=3.0, pi_integral_time_s=1.0,
        cv_scales=(1.0,), description="exothermic CSTR (dimensionless time taken as seconds)"),
    "bioreactor": UnitConfig(
        unit="bioreactor", plant="bioreactor", sample_period_s=72.0, initial_grade="OPI",
        controller="hinf", transition_duration_s=8 * 3600.0, pi_gain=0.5,
        pi_integral_time_s=7200.0, description="substrate-inhibited bioreactor (0.02 h sample)"),
    # Chapter 6 (services.studies.ch6): state-shared MPC, 0.1 h sample.
    "two_phase_reactor": UnitConfig(
        unit="two_phase_reactor", plant="two_phase_reactor", sample_period_s=360.0,
        initial_grade="OPI", mvs=("x1", "x2", "x3"), controller="ssmpc",
        transition_duration_s=4 * 3600.0, pi_gain=0.5, pi_integral_time_s=3600.0,
        cv_scales=(100.0, 10.0, 30.0), settle_tolerance=0.1,
        description="Ricker two-phase reactor (level loop in the plant)"),
    # Seed ch. 7: the supervisory controller (issue 8, services.studies.te_control)
    # reads all 41 XMEAS and writes the free valves and the four loop set points;
    # a transition is followed on G in product (XMEAS40), settled within +-1 mol%
    # (seed R7.16 check). 36 s sample = 20 Euler steps (issue 8's choice).
    # Strategy "ssmpc": issue 8's state-shared MPC (seed §7.7), the DESIGN default; "pi"
    # is its decentralized baseline, "fixed" the fixed-model MPC of §7.5.
    "te": UnitConfig(
        unit="te", plant="te", sample_period_s=36.0, initial_grade="mode0", controller="te",
        strategy="ssmpc",
        cvs=TE_XMEAS, track=("XMEAS40",), cv_scales=(10.0,),
        transition_duration_s=12 * 3600.0, settle_tolerance=0.1, settle_samples=50,
        status_every=10, checkpoint_every=100, telemetry_every=100,
        description="Tennessee Eastman with the Table 7.10 regulatory layer (1.8 s Euler)"),
}


def unit_names() -> list[str]:
    return list(UNITS)


def get_unit(unit: str) -> UnitConfig:
    """Registry default of ``unit``; unknown names raise ValueError listing the known ones."""
    if unit not in UNITS:
        raise ValueError(f"unit: unknown unit {unit!r}; known: {', '.join(UNITS)}")
    return UNITS[unit]


def load_unit_config(unit: str, path: str | Path | None = None, **overrides) -> UnitConfig:
    """Registry default, then the JSON file at ``path``, then keyword overrides."""
    cfg = get_unit(unit) if unit in UNITS or path is None else None
    if path is not None:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"unit_config: cannot read {str(path)!r}: {exc}") from exc
        if not isinstance(data, dict):
            raise ValueError("unit_config: expected a JSON object")
        data.setdefault("unit", unit)
        cfg = UnitConfig.from_dict(data, cfg)
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if overrides:
        cfg = replace(cfg, **overrides)
    return cfg


# -- plant side ---------------------------------------------------------------------------
def build_plant(cfg: UnitConfig):
    from plant_sim import get_plant

    return get_plant(cfg.plant)


def time_scale_s(plant) -> float:
    """Process seconds per unit of the plant's own time."""
    if plant.time_unit not in TIME_SCALE:
        raise ValueError(f"time_unit: unsupported plant time unit {plant.time_unit!r}")
    return TIME_SCALE[plant.time_unit]


def te_grade_values(cfg: UnitConfig) -> dict[str, dict[str, Any]]:
    """TE grades: noise-free XMEAS at each mode's start state as CV set points; the
    mode's XMVs and its regulatory set points (the loops' CVs there) as MVs."""
    from plant_sim.tennessee_eastman import SimSettings, TESimulator
    from plant_sim.tennessee_eastman.modes import MODES, grade_name

    cvi = [int(n[5:]) - 1 for n in cfg.cvs]
    mvs = te_mv_names(cfg)
    loops, _ = te_structure(cfg.strategy)
    sp_cv = {te_setpoint_name(lp): lp.cv for lp in loops}
    try:  # issue 8's grade table (seed Table 7.3 rows), else the modes' start measurements
        from services.studies.te_grades import grade as te_grade
    except ImportError:
        te_grade = None
    out = {}
    for mode in MODES:
        sim = TESimulator(SimSettings(mode=mode))
        y0 = sim.initial_xmeas
        if te_grade is not None:
            y0 = np.asarray(te_grade(grade_name(mode)).xmeas, dtype=float)
        mv = []
        for name in mvs:
            if name in sp_cv:
                mv.append(float(y0[sp_cv[name] - 1]))
            else:
                mv.append(float(sim.xmv[int(name[3:]) - 1]))
        out[grade_name(mode)] = {"setpoints": y0[cvi].tolist(), "mv": mv,
                                 "description": f"TE mode {mode}", "stability": "unstable"}
    return out


def cv_indices(cfg: UnitConfig, plant) -> list[int]:
    names = cfg.cvs or tuple(plant.names("output"))
    return [plant.index("output", n) for n in names]


def mv_indices(cfg: UnitConfig, plant) -> list[int]:
    names = cfg.mvs or tuple(plant.names("input"))
    return [plant.index("input", n) for n in names]


def grade_setpoints(cfg: UnitConfig, plant) -> dict[str, dict[str, Any]]:
    """Valid grades of the unit with their CV set points and steady MVs."""
    if cfg.plant == "te":
        return te_grade_values(cfg)
    cvi, mvi = cv_indices(cfg, plant), mv_indices(cfg, plant)
    out = {}
    for name, op in plant.operating_points.items():
        if not op.valid:
            continue
        y = np.asarray(plant.outputs(op.x, op.u), dtype=float)
        out[name] = {"setpoints": y[cvi].tolist(), "mv": np.asarray(op.u)[mvi].tolist(),
                     "description": op.description, "stability": op.stability}
    if cfg.initial_grade not in out:
        raise ValueError(f"initial_grade: {cfg.initial_grade!r} is not a valid grade of "
                         f"{cfg.plant}; valid: {', '.join(out)}")
    return out


def plausible_ranges(cfg: UnitConfig, plant, grades: dict[str, dict[str, Any]]
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Instrument ranges ``(lower, upper)`` of the CVs, shapes (ny,) (see ``plausible_factor``)."""
    sp = np.array([g["setpoints"] for g in grades.values()], dtype=float)
    scale = np.maximum.reduce([sp.max(axis=0) - sp.min(axis=0), np.abs(sp).max(axis=0),
                               np.ones(sp.shape[1])])
    lo = sp.min(axis=0) - cfg.plausible_factor * scale
    hi = sp.max(axis=0) + cfg.plausible_factor * scale
    idx = ([int(n[5:]) - 1 for n in cfg.cvs] if cfg.plant == "te" else cv_indices(cfg, plant))
    phys_lo = np.array([plant.output_vars[i].lower for i in idx], dtype=float)
    phys_hi = np.array([plant.output_vars[i].upper for i in idx], dtype=float)
    return np.maximum(lo, phys_lo), np.minimum(hi, phys_hi)


def cv_scales(cfg: UnitConfig, grades: dict[str, dict[str, Any]]) -> np.ndarray:
    """Per-CV scale: configured, else the spread of the grades' set points (or |value|)."""
    sp = np.array([g["setpoints"] for g in grades.values()], dtype=float)
    if cfg.cv_scales:
        if len(cfg.cv_scales) != sp.shape[1]:
            raise ValueError(f"cv_scales: expected {sp.shape[1]} values, got "
                             f"{len(cfg.cv_scales)}")
        return np.asarray(cfg.cv_scales)
    spread = sp.max(axis=0) - sp.min(axis=0)
    fallback = np.maximum(np.abs(sp).max(axis=0), 1e-6)
    return np.where(spread > 1e-9, spread, fallback)


# -- controller side ----------------------------------------------------------------------
class PIBaseline:
    """Multivariable discrete PI with static decoupling (velocity form).

    Per sample, with ``e = r - y`` (row 0 of the reference)::

        u_k = sat( u_{k-1} + K ( (e_k - e_{k-1}) + Ts / Ti * e_k ) ),   K = g * G0^{-1}

    ``G0`` is the plant's steady-state gain at the initial grade (CV by MV,
    computed from the linearization ``D - C A^{-1} B``) and ``g`` a
    dimensionless gain. The velocity form does not wind up on the limits, and
    its state (``u_{k-1}``, ``e_{k-1}``) is all a restart needs: the first move
    after :meth:`restore` continues from the last one (bumpless).

    An invalid measurement (NaN/inf, wrong length) holds the input and raises an
    alarm (``fallback=True``), as the interface requires.
    """

    def __init__(self, gain_matrix, Ts: float, Ti: float, u0, u_min=None, u_max=None,
                 names: tuple[str, ...] = ("PI",)) -> None:
        self.K = np.atleast_2d(np.asarray(gain_matrix, dtype=float))
        self.nu, self.ny = self.K.shape
        if not np.all(np.isfinite(self.K)):
            raise ValueError("gain_matrix: must be finite (is the steady-state gain singular?)")
        self.ratio = float(Ts) / float(Ti)
        self.u = np.asarray(u0, dtype=float).copy()
        self.u_min = np.full(self.nu, -np.inf) if u_min is None else np.asarray(u_min, float)
        self.u_max = np.full(self.nu, np.inf) if u_max is None else np.asarray(u_max, float)
        self.e_prev: np.ndarray | None = None
        self.names = names

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        t0 = time.perf_counter()
        y = np.asarray(y, dtype=float).reshape(-1)
        r = np.atleast_2d(np.asarray(reference, dtype=float))[0]
        if y.shape != (self.ny,) or not np.all(np.isfinite(y)):
            return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                                   J=np.zeros(1), solve_ms=(time.perf_counter() - t0) * 1e3,
                                   fallback=True, status="invalid_measurement",
                                   alarms=(f"invalid measurement at sample {k}: input held",))
        e = r - y
        if self.e_prev is None:
            self.e_prev = e.copy()
        du = self.K @ ((e - self.e_prev) + self.ratio * e)
        self.u = np.clip(self.u + du, self.u_min, self.u_max)
        self.e_prev = e
        return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                               J=np.array([float(e @ e)]),
                               solve_ms=(time.perf_counter() - t0) * 1e3, status="solved")

    def align(self, u) -> None:
        """Continue from the move the plant holds (a restart); no proportional kick."""
        self.u = np.asarray(u, dtype=float).copy()
        self.e_prev = None

    def checkpoint(self) -> dict[str, Any]:
        return {"u": self.u.tolist(),
                "e_prev": None if self.e_prev is None else self.e_prev.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        self.u = np.asarray(state["u"], dtype=float)
        e = state.get("e_prev")
        self.e_prev = None if e is None else np.asarray(e, dtype=float)


def _build_pi(cfg: UnitConfig, plant, u0, grades) -> PIBaseline:
    from plant_sim.linearize import linearize

    cvi, mvi = cv_indices(cfg, plant), mv_indices(cfg, plant)
    lm = linearize(plant, cfg.initial_grade)
    G = lm.D - lm.C @ np.linalg.solve(lm.A, lm.B)
    G0 = G[np.ix_(cvi, mvi)]
    if G0.shape[0] != G0.shape[1]:
        raise ValueError(f"cvs/mvs: the PI baseline needs as many CVs as MVs, got "
                         f"{G0.shape[0]} and {G0.shape[1]}")
    K = cfg.pi_gain * np.linalg.inv(G0)
    lo = np.array([plant.input_vars[i].lower for i in mvi])
    hi = np.array([plant.input_vars[i].upper for i in mvi])
    return PIBaseline(K, cfg.sample_period_s, cfg.pi_integral_time_s, u0, lo, hi)


class HoldController:
    """Holds the MVs where they are: "MPC off" (for TE: the regulatory layer alone).

    A documented safe mode, not a tracking controller: transitions do not move
    the plant. Invalid measurements raise an alarm; the move is the same anyway.
    """

    def __init__(self, u0, names: tuple[str, ...] = ("hold",)) -> None:
        self.u = np.asarray(u0, dtype=float).copy()
        self.names = names

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        y = np.asarray(y, dtype=float)
        bad = not np.all(np.isfinite(y))
        return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                               J=np.zeros(1), solve_ms=0.0, fallback=bad,
                               status="invalid_measurement" if bad else "hold",
                               alarms=(f"invalid measurement at sample {k}",) if bad else ())

    def align(self, u) -> None:
        self.u = np.asarray(u, dtype=float).copy()

    def checkpoint(self) -> dict[str, Any]:
        return {"u": self.u.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        self.u = np.asarray(state["u"], dtype=float)


class _FrozenPlan:
    """A TE transition plan evaluated at a fixed time: the references hold (abort)."""

    def __init__(self, plan, t_h: float) -> None:
        self.plan, self.t_h = plan, float(t_h)

    def xmeas_ref(self, t):
        return self.plan.xmeas_ref(self.t_h)

    def xmv_ref(self, t):
        return self.plan.xmv_ref(self.t_h)

    def d_fraction_ref(self, t):
        return self.plan.d_fraction_ref(self.t_h)


class TEServiceController:
    """Issue 8's TE supervisory controller behind the service's MV vector.

    ``y`` is the 41 XMEAS; the move is the unit's MVs (:func:`te_mv_names`): the valves
    the controller writes and the four loop set points. Time on the wire is in
    process seconds, the TE controller's in hours. Transitions reach it through
    :meth:`on_transition` as a :class:`~services.studies.te_grades.TransitionPlan`
    (its first-order references), an abort freezes the plan where it is.
    """

    def __init__(self, strategy: str, start_grade: str, mvs: tuple[str, ...],
                 sample_h: float, u0) -> None:
        from services.studies.te_control import make_te_controller
        from services.studies.te_grades import TransitionPlan

        self.strategy = strategy
        self.sample_h = sample_h
        self.plan_def = {"start": start_grade, "legs": [], "freeze_h": None, "tau_h": None}
        self.ctl, self.spec = make_te_controller(strategy, TransitionPlan(start_grade),
                                                 sample_h=sample_h)
        self.mvs = tuple(mvs)
        self.u = np.asarray(u0, dtype=float).copy()
        sp_names = [te_setpoint_name(lp) for lp in self.spec.loops]
        self._map = []
        for name in self.mvs:
            if name in sp_names:
                self._map.append(("sp", sp_names.index(name)))
            elif name.startswith("XMV"):
                self._map.append(("xmv", int(name[3:]) - 1))
            else:
                raise ValueError(f"mvs: {name!r} is neither an XMV nor a set point of the "
                                 f"TE controller's loops ({', '.join(sp_names)})")

    def _apply_plan(self) -> None:
        from services.studies.te_grades import Leg, TransitionPlan

        d = self.plan_def
        extra = {} if d.get("tau_h") is None else {"tau_xmeas_h": d["tau_h"]}
        plan = TransitionPlan(d["start"], tuple(Leg(t, g) for t, g in d["legs"]), **extra)
        self.ctl.retarget(plan if d["freeze_h"] is None else _FrozenPlan(plan, d["freeze_h"]))

    def check_grade(self, grade: str) -> None:
        """Refuse a grade this control structure cannot hold from the current one.

        Raises
        ------
        services.studies.te_grades.GradeError
            (a ``ValueError``) naming the grade and the valve without margin.
        """
        from services.studies.te_grades import check_reachable

        legs = self.plan_def["legs"]
        check_reachable(legs[-1][1] if legs else self.plan_def["start"], grade)

    def on_transition(self, event: str, grade: str, t_s: float,
                      duration_s: float | None = None) -> None:
        """``running``: head for ``grade`` from ``t_s``; ``aborted``/``failed``: hold.

        The references' time constant is a quarter of the transition's duration (98 %
        of the move after it), as for the other units.
        """
        d = self.plan_def
        if event == "running":
            if duration_s is not None:
                d["tau_h"] = duration_s / 4.0 / 3600.0
            # After an abort the references jump from the held values to the plan's
            # path; the new leg then moves them on with first-order dynamics.
            d["freeze_h"] = None
            d["legs"] = [*d["legs"], [t_s / 3600.0, grade]]
        elif event in ("aborted", "failed"):
            d["freeze_h"] = t_s / 3600.0
        self._apply_plan()

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        dec = self.ctl.step(k, t / 3600.0, np.asarray(y, dtype=float), None)
        u_full = np.asarray(dec.u, dtype=float)
        sp = np.asarray(dec.extra.get("setpoints", np.full(len(self.spec.loops), np.nan)),
                        dtype=float)
        u = np.array([sp[j] if kind == "sp" else u_full[j] for kind, j in self._map])
        fallback, alarms = dec.fallback, list(dec.alarms)
        if not np.all(np.isfinite(u)):
            u = np.where(np.isfinite(u), u, self.u)
            fallback = True
            alarms.append(f"TE controller left MVs undefined at sample {k}; held")
        self.u = u
        return ControlDecision(u=u, active_model=dec.active_model, model_names=dec.model_names,
                               J=np.asarray(dec.J), solve_ms=dec.solve_ms, fallback=fallback,
                               status=dec.status, alarms=tuple(alarms), extra=dec.extra)

    def finish_sample(self) -> None:
        """The TE controller's bookkeeping after the move (see
        :meth:`services.studies.te_control.TEController.finish_sample`)."""
        self.ctl.finish_sample()

    def align(self, u) -> None:
        """Take over the plant's move: the core (five handles, issue 8's CORE_NAMES)
        restarts from the matching valves and set points (re-initialized dynamics)."""
        from services.controller_node import align_multimodel

        self.u = np.asarray(u, dtype=float).copy()
        try:
            from services.studies.te_control import CORE_NAMES
        except ImportError:
            return
        alias = {"Tr_sp": "reactor_temperature_sp", "Pr_sp": "reactor_pressure_sp"}
        idx = [self.mvs.index(alias.get(n, n)) if alias.get(n, n) in self.mvs else None
               for n in CORE_NAMES]
        if None not in idx:
            align_multimodel(getattr(self.ctl, "core", None), self.u[idx])

    def checkpoint(self) -> dict[str, Any]:
        return {"ctl": self.ctl.checkpoint(), "plan": self.plan_def, "u": self.u.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        self.plan_def = state["plan"]
        self._apply_plan()
        self.ctl.restore(state["ctl"])
        self.u = np.asarray(state["u"], dtype=float)


def _build_te(cfg: UnitConfig, plant, u0, grades):
    """Issue 8's TE controller (``cfg.strategy``) behind :class:`TEServiceController`."""
    try:
        import services.studies.te_control  # noqa: F401
    except ImportError as exc:
        raise ValueError("controller: the TE controller (services.studies.te_control, "
                         "issue 8) is not available in this build") from exc
    try:
        return TEServiceController(cfg.strategy, cfg.initial_grade, te_mv_names(cfg),
                                   cfg.sample_period_s / 3600.0, u0)
    except ImportError as exc:
        raise ValueError(f"strategy: TE strategy {cfg.strategy!r} is not available in this "
                         f"build ({exc}); use strategy \"pi\"") from exc


def _build_siso_multimodel(cfg: UnitConfig, plant, u0, grades, law_name: str):
    """Chapter 5's multiple-model controller on a SISO unit plant (H-infinity or MRAC law)."""
    from controller.hinf import HInfLaw
    from controller.mrac import MRACLaw
    from controller.multimodel import MultiModelController, MultiModelSettings
    from controller.state_shared import ModelSpec, StateSharedModel
    from plant_sim.linearize import linearize
    from services.studies import ch5

    if plant.nu != 1 or plant.ny != 1:
        raise ValueError(f"controller: {law_name} is for the SISO units, {cfg.plant} is not SISO")
    bio = cfg.plant == "bioreactor"
    dt = cfg.sample_period_s / time_scale_s(plant)
    specs, kinds = [], []
    for name, kind, op in (("M1", "fixed", "OPI"), ("M2", "fixed", "OPII"),
                           ("M3", "free-running", cfg.initial_grade),
                           ("M4", "re-initialized", cfg.initial_grade)):
        lm = linearize(plant, op)
        spec = StateSharedModel.model_from_linear(name, lm.A, lm.B, lm.C, lm.u_op, lm.y_op,
                                                  ch5.A_POLY)
        specs.append(ModelSpec(name, spec.theta, spec.bias,
                               "fixed" if kind == "fixed" else "adaptive"))
        kinds.append(kind)
    ssm = StateSharedModel(ch5.A_POLY, 1, dt, specs)
    lo = float(plant.input_vars[0].lower) if bio else -3.0
    hi = float(plant.input_vars[0].upper) if bio else 3.0
    lo, hi = (0.0, 1.0) if bio and not (math.isfinite(lo) and math.isfinite(hi)) else (lo, hi)
    if law_name == "hinf":
        law = HInfLaw(ch5.BIO_WEIGHTS if bio else ch5.CSTR_WEIGHTS, dt, ch5.RESYNTHESIS, lo, hi)
    else:
        law = MRACLaw(dt, lo, hi)
    settings = MultiModelSettings(ch5.BIO_NLS if bio else ch5.NLS, ch5.INDEX, lo, hi,
                                  param_margin=0.0)
    start = ["OPI", "OPII"].index(cfg.initial_grade) if cfg.initial_grade in ("OPI",
                                                                              "OPII") else 0
    return MultiModelController(ssm, law, np.asarray(u0, float), settings, kinds=kinds,
                                initial_model=start)


def _build_two_phase_ssmpc(cfg: UnitConfig, plant, u0, grades):
    """Chapter 6's state-shared MPC on the two-phase reactor (OPI/OPII reduced models)."""
    from controller.mpc import MPCSettings
    from controller.mpc.law import MPCLaw
    from controller.multimodel import MultiModelController, MultiModelSettings
    from controller.state_shared import StateSharedModel
    from controller.switching import IndexSettings
    from services.studies import ch6

    if cfg.plant != "two_phase_reactor":
        raise ValueError("controller: ssmpc is configured for the two_phase_reactor unit here; "
                         "the TE unit uses controller 'te'")
    case = ch6.ReactorCase()
    specs, a, _ = ch6.reactor_models(case.order)
    dt = cfg.sample_period_s / time_scale_s(plant)
    ssm = StateSharedModel(a, 3, dt, specs)
    y = np.array([g["setpoints"] for g in grades.values()])
    span = np.maximum(y.max(axis=0) - y.min(axis=0), 1e-6)
    settings = MPCSettings(
        nu=3, ny=3, P=case.P, M=case.M, Xi=np.asarray(case.weights) / span ** 2,
        Lambda=np.full(3, case.move_weight / 100.0 ** 2), u_min=np.zeros(3),
        u_max=np.full(3, 100.0), du_max=np.full(3, case.du_max),
        y_max=[ch6.P_LIMIT, np.inf, np.inf], slack_scale=[span[0], 1.0, 1.0],
        slack_linear=1e3, slack_quadratic=1.0, budget_ms=50.0)
    law = MPCLaw(settings)
    law.prepare(ssm)
    index = IndexSettings(mu=case.index_mu, nu=case.index_nu,
                          output_weights=tuple(1.0 / span ** 2), min_dwell=case.dwell)
    ctl = MultiModelController(ssm, law, np.asarray(u0, float),
                               MultiModelSettings(index=index, u_min=0.0, u_max=100.0),
                               kinds=["fixed"] * ssm.k)
    ctl.horizon = case.P  # the node passes this many reference rows
    return ctl


#: Controller builders by ``UnitConfig.controller``: ``fn(cfg, plant, u0, grades)``.
CONTROLLER_BUILDERS: dict[str, Callable] = {
    "pi": _build_pi,
    "hold": lambda cfg, plant, u0, grades: HoldController(u0),
    "hinf": lambda cfg, plant, u0, grades: _build_siso_multimodel(cfg, plant, u0, grades, "hinf"),
    "mrac": lambda cfg, plant, u0, grades: _build_siso_multimodel(cfg, plant, u0, grades, "mrac"),
    "ssmpc": _build_two_phase_ssmpc,
    "te": _build_te,
}


def build_controller(cfg: UnitConfig, plant=None, u0=None, grades=None):
    """The unit's :class:`~controller.interfaces.SampleController`, starting at ``u0``."""
    plant = plant if plant is not None else build_plant(cfg)
    grades = grades if grades is not None else grade_setpoints(cfg, plant)
    if u0 is None:
        u0 = grades[cfg.initial_grade]["mv"]
    return CONTROLLER_BUILDERS[cfg.controller](cfg, plant, np.asarray(u0, float), grades)


@dataclass(frozen=True)
class UnitInfo:
    """Names and sizes of a built unit (what both nodes and the API show)."""

    cv_names: tuple[str, ...]
    mv_names: tuple[str, ...]
    cv_units: tuple[str, ...]
    mv_units: tuple[str, ...]
    grades: dict[str, dict[str, Any]] = field(default_factory=dict)


def unit_info(cfg: UnitConfig, plant) -> UnitInfo:
    if cfg.plant == "te":
        cvi = cv_indices(cfg, plant)
        mvs = te_mv_names(cfg)
        return UnitInfo(
            cv_names=tuple(cfg.cvs), mv_names=mvs,
            cv_units=tuple(plant.output_vars[i].unit for i in cvi),
            mv_units=tuple("%" if n.startswith("XMV") else "CV unit" for n in mvs),
            grades=grade_setpoints(cfg, plant))
    cvi, mvi = cv_indices(cfg, plant), mv_indices(cfg, plant)
    return UnitInfo(
        cv_names=tuple(plant.output_vars[i].name for i in cvi),
        mv_names=tuple(plant.input_vars[i].name for i in mvi),
        cv_units=tuple(plant.output_vars[i].unit for i in cvi),
        mv_units=tuple(plant.input_vars[i].unit for i in mvi),
        grades=grade_setpoints(cfg, plant))
