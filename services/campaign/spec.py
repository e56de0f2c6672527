"""The campaign spec (DESIGN.md "Campaigns"): parsed and validated into frozen records.

A spec is a JSON object::

    {"unit": "te", "hours": 48, "noise": true, "seeds": [1, 2, 3],
     "strategies": ["ssmpc", "fixed", "pi", "plan"],
     "cases": [{"name": "0-2", "start": "mode0", "legs": [{"at_h": 1.0, "grade": "mode2"}]},
               {"name": "idv6@2", "start": "mode2", "idvs": [{"idv": 6, "on_h": 2.0}]}]}

A case may set its own ``hours``, ``noise`` and ``seeds``. Defaults: ``unit``
``"te"``, ``noise`` false, ``seeds`` ``[1]``; ``hours`` and ``strategies`` and
``cases`` are required; ``name`` (optional) names the campaign. Every error is a
:class:`SpecError` whose message starts with the path of the field
(``cases[2].idvs[0].idv: ...``), and nothing is run or written before the whole
spec is valid.

Units and strategies
    ``te``: ``ssmpc``, ``fixed``, ``pi``, ``plan``, ``decentralized``
    (:mod:`controller.units.te.control`; the last the published decentralized structure,
    :mod:`controller.units.te.decentralized`); grades ``mode0`` ... ``mode6`` where the
    control structure can hold them (:func:`controller.units.te.grades.check_reachable`;
    modes 4-6 at their back-off, reached by a leg, not a start);
    IDV 1-20. Unit plants (``cstr``,
    ``bioreactor``, ``two_phase_reactor``): ``ssmpc`` (the unit's state-shared
    multiple-model controller of the registry) and ``pi`` (the multivariable PI
    baseline); grades ``OPI``, ``OPII`` ... (the plant's valid operating points); no
    IDVs and no measurement noise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

__all__ = ["SpecError", "IDVEvent", "Leg", "Case", "CampaignSpec", "parse_spec",
           "TE_STRATEGIES", "UNIT_STRATEGIES", "PLANNED_STRATEGIES", "known_units"]

#: Strategies of the TE campaigns (controller.units.te.control.STRATEGIES).
TE_STRATEGIES = ("ssmpc", "fixed", "pi", "plan", "decentralized")
#: Strategies of the unit plants: the registry's multiple-model controller, the PI baseline.
UNIT_STRATEGIES = ("ssmpc", "pi")
#: Strategies named for the product but not yet in it (none now).
PLANNED_STRATEGIES: tuple[str, ...] = ()
#: Largest number of runs one spec may ask for.
MAX_RUNS = 100_000

_TOP = ("name", "unit", "hours", "noise", "seeds", "strategies", "cases")
_CASE = ("name", "start", "legs", "idvs", "hours", "noise", "seeds")
_LEG = ("at_h", "grade")
_IDV = ("idv", "on_h", "off_h")


class SpecError(ValueError):
    """An invalid campaign spec; the message starts with the field's path."""


@dataclass(frozen=True)
class IDVEvent:
    """TE disturbance IDV(``idv``) on from ``on_h``, off at ``off_h`` (None: stays on)."""

    idv: int
    on_h: float
    off_h: float | None = None


@dataclass(frozen=True)
class Leg:
    """From ``at_h`` (h) on, head for ``grade``."""

    at_h: float
    grade: str


@dataclass(frozen=True)
class Case:
    """One row of the matrix: start grade, legs, disturbances, and its run settings.

    ``hours`` (process h), ``noise`` and ``seeds`` are resolved (the case's own or
    the campaign's).
    """

    name: str
    start: str
    legs: tuple[Leg, ...]
    idvs: tuple[IDVEvent, ...]
    hours: float
    noise: bool
    seeds: tuple[int, ...]

    def contents(self) -> dict[str, Any]:
        """What makes the case's runs what they are (its name is only a label)."""
        return {"start": self.start,
                "legs": [[lg.at_h, lg.grade] for lg in self.legs],
                "idvs": [[e.idv, e.on_h, e.off_h] for e in self.idvs]}


@dataclass(frozen=True)
class CampaignSpec:
    """A validated campaign: unit, strategies and cases (runs = cases × strategies × seeds)."""

    name: str
    unit: str
    strategies: tuple[str, ...]
    cases: tuple[Case, ...]

    @property
    def n_runs(self) -> int:
        return sum(len(c.seeds) for c in self.cases) * len(self.strategies)


def known_units() -> tuple[str, ...]:
    """Units a campaign can run: TE and the registry's unit plants."""
    from services.registry import unit_names

    return tuple(unit_names())


# -- field checks ---------------------------------------------------------------------------
def _fields(obj, allowed: tuple[str, ...], path: str) -> dict:
    if not isinstance(obj, dict):
        raise SpecError(f"{path or 'spec'}: expected a JSON object, got {type(obj).__name__}")
    for key in obj:
        if key not in allowed:
            where = f"{path}.{key}" if path else str(key)
            raise SpecError(f"{where}: unknown field; known: {', '.join(allowed)}")
    return obj


def _number(value, path: str, *, minimum: float = 0.0, strict: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise SpecError(f"{path}: expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v) or v < minimum or (strict and v <= minimum):
        rel = ">" if strict else ">="
        raise SpecError(f"{path}: must be a finite number {rel} {minimum:g}, got {value!r}")
    return v


def _bool(value, path: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{path}: expected true or false, got {value!r}")
    return value


def _seeds(value, path: str) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise SpecError(f"{path}: expected a non-empty list of integers")
    out = []
    for i, s in enumerate(value):
        if isinstance(s, bool) or not isinstance(s, int) or not 0 <= s < 2**31:
            raise SpecError(f"{path}[{i}]: expected an integer in [0, 2^31), got {s!r}")
        if s in out:
            raise SpecError(f"{path}[{i}]: seed {s} given twice")
        out.append(s)
    return tuple(out)


def _name(value, path: str) -> str:
    if not isinstance(value, str) or not value.strip() or len(value) > 80:
        raise SpecError(f"{path}: expected a non-empty name of at most 80 characters, "
                        f"got {value!r}")
    return value


# -- units ---------------------------------------------------------------------------------
class _TEGrades:
    """Grade checks of TE (names, reachability with the control structure)."""

    def start(self, value, path: str) -> str:
        from controller.units.te.grades import BACKOFF_GRADES

        name = self.leg(None, value, path)
        if name in BACKOFF_GRADES:
            # the plant starts from a mode's tabulated state, which for modes 4-6 is
            # Ricker's optimum with a valve at 100 %, not the back-off grade
            raise SpecError(f"{path}: a run cannot start at {name} (the plant's start "
                            f"state of it is Ricker's optimum, not its back-off grade); "
                            f"go there with a leg")
        return name

    def leg(self, prev: str | None, value, path: str) -> str:
        """The grade ``value`` reachable from ``prev`` (None: a start grade, reachable
        from itself)."""
        from controller.units.te.grades import GradeError, check_reachable, parse_grade

        try:
            name = parse_grade(value)
            check_reachable(name if prev is None else prev, name)
        except GradeError as exc:
            raise SpecError(f"{path}: {_strip_field(exc)}") from None
        return name


class _UnitGrades:
    """Grade checks of a unit plant: its valid operating points."""

    def __init__(self, unit: str) -> None:
        from controller.units.config import build_plant, grade_setpoints
        from services.registry import get_unit

        cfg = get_unit(unit)
        self.names = tuple(grade_setpoints(cfg, build_plant(cfg)))
        self.unit = unit

    def start(self, value, path: str) -> str:
        if not isinstance(value, str) or value not in self.names:
            raise SpecError(f"{path}: unknown grade {value!r} of unit {self.unit}; "
                            f"known: {', '.join(self.names)}")
        return value

    def leg(self, prev: str, value, path: str) -> str:
        return self.start(value, path)


def _strip_field(exc: Exception) -> str:
    """A GradeError's message without its own field name (the spec path replaces it)."""
    text = str(exc)
    head, sep, rest = text.partition(": ")
    return rest if sep and " " not in head else text


def _strategies(value, unit: str) -> tuple[str, ...]:
    known = TE_STRATEGIES if unit == "te" else UNIT_STRATEGIES
    if not isinstance(value, list) or not value:
        raise SpecError("strategies: expected a non-empty list of names")
    out = []
    for i, s in enumerate(value):
        path = f"strategies[{i}]"
        if s in PLANNED_STRATEGIES:
            raise SpecError(f"{path}: strategy {s!r} is not available yet; available for "
                            f"{unit}: {', '.join(known)}")
        if s not in known:
            raise SpecError(f"{path}: unknown strategy {s!r} for unit {unit}; "
                            f"available: {', '.join(known)}")
        if s in out:
            raise SpecError(f"{path}: strategy {s!r} given twice")
        out.append(s)
    return tuple(out)


def _case(obj, i: int, unit: str, grades, defaults: dict) -> Case:
    path = f"cases[{i}]"
    obj = _fields(obj, _CASE, path)
    if "name" not in obj:
        raise SpecError(f"{path}.name: required")
    name = _name(obj["name"], f"{path}.name")
    if "start" not in obj:
        raise SpecError(f"{path}.start: required (the grade the run starts at)")
    start = grades.start(obj["start"], f"{path}.start")
    hours = (_number(obj["hours"], f"{path}.hours", strict=True) if "hours" in obj
             else defaults["hours"])
    if hours is None:
        raise SpecError(f"{path}.hours: required (no campaign-wide hours)")
    noise = _bool(obj["noise"], f"{path}.noise") if "noise" in obj else defaults["noise"]
    seeds = _seeds(obj["seeds"], f"{path}.seeds") if "seeds" in obj else defaults["seeds"]
    if noise and unit != "te":
        raise SpecError(f"{path}.noise: measurement noise is available for te only, "
                        f"not for unit {unit}")
    legs_raw = obj.get("legs", [])
    if not isinstance(legs_raw, list):
        raise SpecError(f"{path}.legs: expected a list")
    legs: list[Leg] = []
    prev = start
    for j, lg in enumerate(legs_raw):
        lp = f"{path}.legs[{j}]"
        lg = _fields(lg, _LEG, lp)
        for key in _LEG:
            if key not in lg:
                raise SpecError(f"{lp}.{key}: required")
        at_h = _number(lg["at_h"], f"{lp}.at_h")
        if at_h >= hours:
            raise SpecError(f"{lp}.at_h: {at_h:g} h is not before the end of the run "
                            f"({hours:g} h)")
        if legs and at_h <= legs[-1].at_h:
            raise SpecError(f"{lp}.at_h: leg times must increase ({legs[-1].at_h:g} then "
                            f"{at_h:g})")
        prev = grades.leg(prev, lg["grade"], f"{lp}.grade")
        legs.append(Leg(at_h, prev))
    idvs_raw = obj.get("idvs", [])
    if not isinstance(idvs_raw, list):
        raise SpecError(f"{path}.idvs: expected a list")
    if idvs_raw and unit != "te":
        raise SpecError(f"{path}.idvs: disturbances (IDVs) are available for te only, "
                        f"not for unit {unit}")
    idvs: list[IDVEvent] = []
    for j, ev in enumerate(idvs_raw):
        ip = f"{path}.idvs[{j}]"
        ev = _fields(ev, _IDV, ip)
        for key in ("idv", "on_h"):
            if key not in ev:
                raise SpecError(f"{ip}.{key}: required")
        k = ev["idv"]
        if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= 20:
            raise SpecError(f"{ip}.idv: unknown IDV {k!r}; known: 1 ... 20")
        if any(e.idv == k for e in idvs):
            raise SpecError(f"{ip}.idv: IDV {k} given twice in this case")
        on_h = _number(ev["on_h"], f"{ip}.on_h")
        off_h = None
        if ev.get("off_h") is not None:
            off_h = _number(ev["off_h"], f"{ip}.off_h")
            if off_h <= on_h:
                raise SpecError(f"{ip}.off_h: must be after on_h ({on_h:g} h), got {off_h:g}")
        idvs.append(IDVEvent(int(k), on_h, off_h))
    return Case(name, start, tuple(legs), tuple(idvs), hours, noise, seeds)


def parse_spec(data, default_name: str = "campaign") -> CampaignSpec:
    """Validate a decoded JSON spec; raises :class:`SpecError` naming the field.

    Parameters
    ----------
    data : dict
        The decoded JSON object.
    default_name : str
        Campaign name when the spec has no ``name`` (the command uses the file's stem).
    """
    data = _fields(data, _TOP, "")
    name = _name(data["name"], "name") if "name" in data else default_name
    unit = data.get("unit", "te")
    units = known_units()
    if unit not in units:
        raise SpecError(f"unit: unknown unit {unit!r}; known: {', '.join(units)}")
    hours = _number(data["hours"], "hours", strict=True) if "hours" in data else None
    noise = _bool(data["noise"], "noise") if "noise" in data else False
    if noise and unit != "te":
        raise SpecError(f"noise: measurement noise is available for te only, not for unit {unit}")
    seeds = _seeds(data["seeds"], "seeds") if "seeds" in data else (1,)
    if "strategies" not in data:
        raise SpecError("strategies: required")
    strategies = _strategies(data["strategies"], unit)
    cases_raw = data.get("cases")
    if not isinstance(cases_raw, list) or not cases_raw:
        raise SpecError("cases: expected a non-empty list of cases")
    grades = _TEGrades() if unit == "te" else _UnitGrades(unit)
    defaults = {"hours": hours, "noise": noise, "seeds": seeds}
    cases: list[Case] = []
    for i, c in enumerate(cases_raw):
        case = _case(c, i, unit, grades, defaults)
        if any(o.name == case.name for o in cases):
            raise SpecError(f"cases[{i}].name: case {case.name!r} given twice")
        cases.append(case)
    spec = CampaignSpec(name, unit, strategies, tuple(cases))
    if spec.n_runs > MAX_RUNS:
        raise SpecError(f"cases: {spec.n_runs} runs, more than {MAX_RUNS} in one campaign")
    return spec
