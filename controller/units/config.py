"""A unit's validated configuration and its grade, scale and range helpers.

A *unit* is one plant of :mod:`plant_sim` run by one controller. Its
:class:`UnitConfig` is what the plant side and the controller agree on; it is
validated on construction (a wrong field raises ``ValueError`` naming the field).
The helpers here derive from it what both sides need: the grades (operating
points with their CV set points and steady MVs), the CVs' engineering scales and
instrument ranges, and the names and units of a built unit (:class:`UnitInfo`).

Process time is in seconds: :func:`time_scale_s` converts the plant's own time
unit (3600 for ``h``; 1 for ``s``; the CSTR's dimensionless time is taken as
seconds).
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any

import numpy as np

from controller.units.te import structure as te_structure

__all__ = [
    "CONTROLLERS",
    "TIME_SCALE",
    "UNIT_NAME_RE",
    "UnitConfig",
    "UnitInfo",
    "build_plant",
    "check_unit_name",
    "cv_indices",
    "cv_scales",
    "grade_setpoints",
    "mv_indices",
    "plausible_ranges",
    "time_scale_s",
    "unit_info",
]

#: Unit names are single key-expression chunks: no ``/``, ``*``, ``$``, ``?`` or ``#``.
UNIT_NAME_RE = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]{0,63}$")


def check_unit_name(unit: str) -> str:
    """Return ``unit`` if it is a valid key segment, else raise ValueError naming ``unit``."""
    if not isinstance(unit, str) or not UNIT_NAME_RE.match(unit):
        raise ValueError(f"unit: {unit!r} is not a valid unit name "
                         "(letters, digits, _ . -; at most 64 characters)")
    return unit


#: Controller kinds of ``UnitConfig.controller`` (builders: :mod:`services.registry`).
CONTROLLERS = ("pi", "hold", "hinf", "mrac", "ssmpc", "te")

TIME_SCALE = {"h": 3600.0, "s": 1.0, "-": 1.0, "min": 60.0}


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
        MPC, §7.5) or ``pi`` (decentralized PI baseline) of the TE controller
        (:mod:`controller.units.te.control`).
    substeps : int
        Plant-node integration steps per sample (for ODE plants: solver calls).
    status_every, checkpoint_every, telemetry_every : int
        Samples between status messages, SQLite checkpoints and Rerun batches.
    transition_queue_limit : int
        Transitions that may wait (``queue=True``) behind the one under way; one more
        is refused (REST 429), so a flood of requests cannot grow the store and the
        controller's work without bound.
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
    transition_queue_limit: int = 8
    description: str = ""

    def __post_init__(self) -> None:
        check_unit_name(self.unit)
        _check_types(self)
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
                     "telemetry_every", "transition_queue_limit"):
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
            te_structure.check_config(self)

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


_TEXT_FIELDS = ("plant", "initial_grade", "controller", "strategy", "description")
_NAME_LIST_FIELDS = ("cvs", "mvs", "track")
_NUMBER_FIELDS = ("sample_period_s", "budget_fraction", "transition_duration_s",
                  "settle_tolerance", "pi_gain", "pi_integral_time_s", "plausible_factor")


def _is_number(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _check_types(cfg: UnitConfig) -> None:
    """``ValueError`` naming the first field of a JSON type the field cannot hold (a
    unit configuration file is read as it is written): text, a list of names, a number,
    a list of numbers. The values themselves are checked after this."""
    for name in _TEXT_FIELDS:
        v = getattr(cfg, name)
        if not isinstance(v, str):
            raise ValueError(f"{name}: expected text, got {v!r}")
    for name in _NAME_LIST_FIELDS:
        v = getattr(cfg, name)
        if not isinstance(v, list | tuple) or not all(isinstance(n, str) for n in v):
            raise ValueError(f"{name}: expected a list of names, got {v!r}")
    for name in _NUMBER_FIELDS:
        v = getattr(cfg, name)
        if not _is_number(v):
            raise ValueError(f"{name}: expected a number, got {v!r}")
    v = cfg.cv_scales
    if not isinstance(v, list | tuple) or not all(_is_number(x) for x in v):
        raise ValueError(f"cv_scales: expected a list of numbers, got {v!r}")


# -- plant side ---------------------------------------------------------------------------
def build_plant(cfg: UnitConfig):
    from plant_sim import get_plant

    return get_plant(cfg.plant)


def time_scale_s(plant) -> float:
    """Process seconds per unit of the plant's own time."""
    if plant.time_unit not in TIME_SCALE:
        raise ValueError(f"time_unit: unsupported plant time unit {plant.time_unit!r}")
    return TIME_SCALE[plant.time_unit]


def cv_indices(cfg: UnitConfig, plant) -> list[int]:
    names = cfg.cvs or tuple(plant.names("output"))
    return [plant.index("output", n) for n in names]


def mv_indices(cfg: UnitConfig, plant) -> list[int]:
    names = cfg.mvs or tuple(plant.names("input"))
    return [plant.index("input", n) for n in names]


def grade_setpoints(cfg: UnitConfig, plant) -> dict[str, dict[str, Any]]:
    """Valid grades of the unit with their CV set points and steady MVs."""
    if cfg.plant == "te":
        return te_structure.grade_values(cfg)
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
        mvs = te_structure.te_mv_names(cfg)
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
