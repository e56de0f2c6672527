"""Operator control of an APC controller: controller mode and per-variable modes and limits.

What a console operator sets on a multivariable controller, as commercial APC packages
(DMC-type controllers) offer it:

- the **controller mode** (:data:`CONTROLLER_MODES`): ``off`` (nothing computed,
  nothing written: the plant keeps its regulatory layer and last values), ``warm``
  (computes and reports, writes nothing; the model states track the plant's measured
  inputs and outputs) and ``on``;
- per **CV**: ``auto`` (in the objective and its limits) or ``off`` (out of both);
- per **MV**: ``auto`` (the controller moves it), ``manual`` (held at the operator's
  value; the controller plans the other MVs around it) or ``off`` (out of the problem,
  held at its last value);
- per CV and MV, operator limits ``lo``/``hi`` inside the variable's engineering
  range, moved from the limit in force to the new one at ``ramp_per_h`` (engineering
  units per process hour), so that a tightened limit never bumps the plant.

This module is the pure part: validation, the state and its checkpoint, the ramps.
Times are process hours. Everything is immutable; a command returns a new
:class:`OperatorState`, so a reader on another thread sees either the old state or
the new one, never half of it.

Ramp rule (:meth:`OperatorState.command`): a relaxed limit moves from the limit in
force at that moment (the operator's ramp so far, or the variable's own limit) to the
new value at ``ramp_per_h``; a tightened one from the limit in force or, when the
variable's value is inside that, from the value (a limit that does not bind yet need
not wait), and at once when the value already satisfies the new limit. A limit
removed goes at once, and without a rate (none given now or before) every limit moves
at once. Hand check: a high limit tightened from 100 to 60 at 20 per hour with the
value at 95 is 95, 85, 75, 60 at 0, 0.5, 1, >= 1.75 h (``tests/test_operator_modes.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any

__all__ = ["CONTROLLER_MODES", "CV_MODES", "MV_MODES", "OperatorError", "UnknownVariable",
           "RampedLimit", "VariableSpec", "VariableControl", "VariableCommand",
           "OperatorState"]

CONTROLLER_MODES = ("off", "warm", "on")
CV_MODES = ("auto", "off")
MV_MODES = ("auto", "manual", "off")


class OperatorError(ValueError):
    """An operator command that cannot be applied; ``status`` is the HTTP meaning (422)."""

    status = 422


class UnknownVariable(OperatorError):
    """No such variable on this unit (404)."""

    status = 404


def _number(name: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise OperatorError(f"{name}: expected a number")
    v = float(value)
    if not math.isfinite(v):
        raise OperatorError(f"{name}: must be finite")
    return v


@dataclass(frozen=True)
class RampedLimit:
    """A limit moving from ``start`` to ``end`` at ``rate_per_h`` from ``t0_h`` on.

    Attributes
    ----------
    start, end : float
        Engineering units; ``end`` may be ±inf (no operator limit; ``start`` is then
        ignored: a limit removed is removed at once).
    t0_h : float
        Process time the ramp starts, h.
    rate_per_h : float
        Engineering units per hour, > 0; ``inf``: ``end`` at once.
    """

    start: float
    end: float
    t0_h: float = 0.0
    rate_per_h: float = math.inf

    def __post_init__(self) -> None:
        if math.isnan(self.start) or math.isnan(self.end) or not math.isfinite(self.t0_h):
            raise OperatorError("limit: NaN or a non-finite start time")
        if not self.rate_per_h > 0:
            raise OperatorError(f"ramp_per_h: must be > 0, got {self.rate_per_h!r}")

    def at(self, t_h: float) -> float:
        """The limit in force at ``t_h`` (h); before ``t0_h`` the ramp's start."""
        if not (math.isfinite(self.end) and math.isfinite(self.start)) \
                or math.isinf(self.rate_per_h) or self.start == self.end:
            return self.end
        gap = self.end - self.start
        moved = self.rate_per_h * max(t_h - self.t0_h, 0.0)
        if moved >= abs(gap):
            return self.end
        return self.start + math.copysign(moved, gap)

    def as_dict(self) -> dict:
        return {"start": _json(self.start), "end": _json(self.end), "t0_h": self.t0_h,
                "rate_per_h": _json(self.rate_per_h)}

    @classmethod
    def from_dict(cls, d: dict, sign: float) -> RampedLimit:
        """``sign`` -1 for a low limit (missing values: -inf), +1 for a high one."""
        def val(x, default):
            return default if x is None else float(x)
        return cls(val(d["start"], sign * math.inf), val(d["end"], sign * math.inf),
                   float(d["t0_h"]), val(d["rate_per_h"], math.inf))


def _json(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


@dataclass(frozen=True)
class VariableSpec:
    """What an operator may do with one variable.

    Attributes
    ----------
    name, kind : str
        Wire name; ``"cv"``, ``"mv"`` or ``"dv"``.
    lo, hi : float
        The controller's own limits (engineering units, ±inf: none).
    eng_lo, eng_hi : float
        The engineering range operator limits and manual values must lie in.
    modes : tuple of str
        Modes the unit's controller offers for it (empty: none to choose).
    limits : bool
        Whether the unit's controller works to operator limits on it.
    controlled : bool
        The controller acts on it (its mode reads ``auto`` when no modes are offered);
        False: measured only (mode None).
    note : str
        Why a mode or limit is not offered (the 422's message).
    """

    name: str
    kind: str
    lo: float = -math.inf
    hi: float = math.inf
    eng_lo: float = -math.inf
    eng_hi: float = math.inf
    modes: tuple[str, ...] = ()
    limits: bool = False
    controlled: bool = False
    note: str = ""

    def __post_init__(self) -> None:
        if self.kind not in ("cv", "mv", "dv"):
            raise ValueError(f"kind: expected cv, mv or dv, got {self.kind!r}")
        allowed = CV_MODES if self.kind == "cv" else MV_MODES if self.kind == "mv" else ()
        if any(m not in allowed for m in self.modes):
            raise ValueError(f"modes: {self.name} ({self.kind}) allows only {allowed}")
        if self.eng_lo > self.eng_hi:
            raise ValueError(f"{self.name}: engineering range {self.eng_lo} > {self.eng_hi}")


@dataclass(frozen=True)
class VariableControl:
    """The operator's settings of one variable (``mode``, manual ``value``, limits)."""

    name: str
    kind: str
    mode: str = "auto"
    value: float | None = None
    lo: RampedLimit = field(default_factory=lambda: RampedLimit(-math.inf, -math.inf))
    hi: RampedLimit = field(default_factory=lambda: RampedLimit(math.inf, math.inf))
    ramp_per_h: float = math.inf

    def limits_at(self, t_h: float) -> tuple[float, float]:
        """Operator limits ``(lo, hi)`` in force at ``t_h`` (±inf: none)."""
        return self.lo.at(t_h), self.hi.at(t_h)

    def as_dict(self) -> dict:
        return {"name": self.name, "kind": self.kind, "mode": self.mode, "value": self.value,
                "lo": self.lo.as_dict(), "hi": self.hi.as_dict(),
                "ramp_per_h": _json(self.ramp_per_h)}

    @classmethod
    def from_dict(cls, d: dict) -> VariableControl:
        value = d.get("value")
        rate = d.get("ramp_per_h")
        return cls(str(d["name"]), str(d["kind"]), str(d["mode"]),
                   None if value is None else float(value), RampedLimit.from_dict(d["lo"], -1),
                   RampedLimit.from_dict(d["hi"], 1), math.inf if rate is None else float(rate))


@dataclass(frozen=True)
class VariableCommand:
    """One operator action on a variable; fields left None are unchanged.

    Built from the request's JSON arguments with :meth:`from_args`, which refuses
    unknown fields, wrong types and non-finite numbers (:class:`OperatorError`).
    """

    mode: str | None = None
    value: float | None = None
    lo: float | None = None
    hi: float | None = None
    ramp_per_h: float | None = None

    FIELDS = ("mode", "value", "lo", "hi", "ramp_per_h")

    @classmethod
    def from_args(cls, args: dict) -> VariableCommand:
        if not isinstance(args, dict):
            raise OperatorError("body: expected an object")
        unknown = sorted(set(args) - set(cls.FIELDS))
        if unknown:
            raise OperatorError(f"{unknown[0]}: unknown field (known: {', '.join(cls.FIELDS)})")
        out: dict[str, Any] = {}
        mode = args.get("mode")
        if mode is not None:
            if mode not in MV_MODES:
                raise OperatorError(f"mode: expected one of {', '.join(MV_MODES)}")
            out["mode"] = mode
        for name in ("value", "lo", "hi", "ramp_per_h"):
            if args.get(name) is not None:
                out[name] = _number(name, args[name])
        if not out:
            raise OperatorError("body: nothing to change (give mode, value, lo, hi or "
                                "ramp_per_h)")
        if "ramp_per_h" in out and not out["ramp_per_h"] > 0:
            raise OperatorError("ramp_per_h: must be > 0 (engineering units per hour)")
        return cls(**out)


@dataclass(frozen=True)
class OperatorState:
    """Controller mode and every variable's operator settings (immutable).

    Parameters
    ----------
    specs : tuple of VariableSpec
        The unit's variables, CVs then MVs (then DVs), in the order of its vectors.
    mode : str
        Controller mode, one of :data:`CONTROLLER_MODES`.
    controls : dict name -> VariableControl
        Settings differing from the defaults (``auto``, no operator limits).
    """

    specs: tuple[VariableSpec, ...]
    mode: str = "on"
    controls: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.mode not in CONTROLLER_MODES:
            raise OperatorError(f"mode: expected one of {', '.join(CONTROLLER_MODES)}")

    # -- reading ----------------------------------------------------------------------
    @cached_property
    def _by_name(self) -> dict[str, VariableSpec]:
        return {s.name: s for s in self.specs}

    def spec(self, name: str) -> VariableSpec:
        s = self._by_name.get(name) if isinstance(name, str) else None
        if s is None:
            raise UnknownVariable(f"variable: no variable {name!r} on this unit")
        return s

    def control(self, name: str) -> VariableControl:
        """The operator's settings of ``name`` (the defaults when never set)."""
        c = self.controls.get(name)
        if c is not None:
            return c
        s = self.spec(name)
        return VariableControl(s.name, s.kind)

    def effective_limits(self, name: str, t_h: float) -> tuple[float, float]:
        """The limits in force at ``t_h``: the operator's inside the controller's own."""
        s = self.spec(name)
        lo, hi = self.control(name).limits_at(t_h)
        return max(s.lo, lo), min(s.hi, hi)

    def variable_mode(self, name: str) -> str | None:
        """``auto``/``manual``/``off``; a controlled variable without modes ``auto``, a
        measured-only one None."""
        s = self.spec(name)
        if s.modes:
            return self.control(name).mode
        return "auto" if s.controlled else None

    # -- commands ---------------------------------------------------------------------
    def with_mode(self, mode: str) -> OperatorState:
        if mode not in CONTROLLER_MODES:
            raise OperatorError(f"mode: expected one of {', '.join(CONTROLLER_MODES)}")
        return replace(self, mode=mode)

    def command(self, name: str, cmd: VariableCommand, t_h: float,
                current: float | None) -> OperatorState:
        """The state after ``cmd`` on ``name`` at process time ``t_h``.

        Parameters
        ----------
        current : float or None
            The variable's value now (a CV's measurement, an MV's applied value): the
            manual value when none is given, and where a new limit starts when no
            finite limit is in force (module docstring).

        Raises
        ------
        UnknownVariable
            No such variable.
        OperatorError
            A mode or limit the unit's controller does not offer for it, a value or
            limit outside the engineering range, ``lo > hi``, a value without
            ``manual``.
        """
        s = self.spec(name)
        old = self.control(name)
        if cmd.mode is not None and cmd.mode not in s.modes:
            why = f" ({s.note})" if s.note else ""
            offered = ", ".join(s.modes) if s.modes else "none"
            raise OperatorError(f"mode: {name} cannot be {cmd.mode!r}{why}; modes offered: "
                                f"{offered}")
        if (cmd.lo is not None or cmd.hi is not None) and not s.limits:
            why = f" ({s.note})" if s.note else ""
            raise OperatorError(f"lo/hi: {name} takes no operator limits{why}")
        mode = cmd.mode if cmd.mode is not None else old.mode
        # manual: the operator's value (kept while manual); an MV off: its value when
        # it was switched off
        value = old.value if mode == old.mode and mode in ("manual", "off") else None
        if cmd.value is not None:
            if mode != "manual":
                raise OperatorError(f"value: {name} is {mode}; a value needs mode 'manual'")
            value = cmd.value
        elif value is None and s.kind == "mv" and mode in ("manual", "off"):
            if current is None or not math.isfinite(current):
                raise OperatorError(f"value: {name} has no current value to hold; give one")
            value = float(current)
        if mode == "manual" and not s.eng_lo <= value <= s.eng_hi:
            raise OperatorError(f"value: {value:g} is outside {name}'s engineering range "
                                f"[{s.eng_lo:g}, {s.eng_hi:g}]")
        rate = cmd.ramp_per_h if cmd.ramp_per_h is not None else old.ramp_per_h
        ends = {"lo": old.lo.end, "hi": old.hi.end}
        for side in ("lo", "hi"):
            v = getattr(cmd, side)
            if v is None:
                continue
            if not s.eng_lo <= v <= s.eng_hi:
                raise OperatorError(f"{side}: {v:g} is outside {name}'s engineering range "
                                    f"[{s.eng_lo:g}, {s.eng_hi:g}]")
            ends[side] = v
        if ends["lo"] > ends["hi"]:
            raise OperatorError(f"lo/hi: lo {ends['lo']:g} above hi {ends['hi']:g}")
        lo_ramp, hi_ramp = old.lo, old.hi
        in_force = self.effective_limits(name, t_h)
        if cmd.lo is not None or cmd.ramp_per_h is not None:
            lo_ramp = _ramp(in_force[0], ends["lo"], t_h, rate, current, -1.0)
        if cmd.hi is not None or cmd.ramp_per_h is not None:
            hi_ramp = _ramp(in_force[1], ends["hi"], t_h, rate, current, 1.0)
        new = VariableControl(name, s.kind, mode, value, lo_ramp, hi_ramp, rate)
        return replace(self, controls={**self.controls, name: new})

    # -- persistence ------------------------------------------------------------------
    def checkpoint(self) -> dict:
        return {"mode": self.mode,
                "variables": [c.as_dict() for c in self.controls.values()]}

    def restore(self, state: dict) -> OperatorState:
        """The state of a :meth:`checkpoint` on these specs (ValueError if it does not fit)."""
        if not isinstance(state, dict):
            raise ValueError("operator: expected an object")
        try:
            controls = {}
            for d in state.get("variables", []):
                c = VariableControl.from_dict(d)
                s = self.spec(c.name)
                if c.kind != s.kind or (c.mode != "auto" and c.mode not in s.modes):
                    raise ValueError(f"{c.name}: mode {c.mode!r} not offered")
                controls[c.name] = c
            return replace(self, mode=str(state.get("mode", "on")), controls=controls)
        except (KeyError, TypeError) as exc:
            raise ValueError(f"operator: malformed ({type(exc).__name__}: {exc})") from None


def _ramp(in_force: float, end: float, t_h: float, rate: float, current: float | None,
          sign: float) -> RampedLimit:
    """A limit from the one in force to ``end`` (module docstring's rule); ``sign`` -1
    for a low limit, +1 for a high one (the arithmetic is done on ``sign * limit``,
    where a high limit tightens downward)."""
    known = current is not None and math.isfinite(current)
    if not math.isfinite(end) or sign * end >= sign * in_force:
        start = in_force  # relaxed (or removed, at once): from the limit in force
    elif known:
        # tightened: from the limit in force, or from the value when that is inside it
        # (the limit does not bind before it reaches the value); at once when the
        # value is inside the new limit already
        start = sign * max(sign * end, min(sign * in_force, sign * float(current)))
    else:
        start = in_force if math.isfinite(in_force) else end
    return RampedLimit(start if math.isfinite(start) else end, end, t_h, rate)
