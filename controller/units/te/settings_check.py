"""The checks shared by the TE guards' settings dataclasses: every field a finite number
(or None where a setting may be off), and each field within its range.

The guards (:mod:`controller.units.te.overrides`, :mod:`controller.units.te.production_index`,
:mod:`controller.units.te.reactant_trim`, :mod:`controller.units.te.level_sag`,
:mod:`controller.units.te.floating_pressure`, and the transition guards of
:class:`controller.units.te.control.TransitionGuards`) and the composition core
(:mod:`controller.units.te.composition_core`) hold numeric settings, a few flags and
named options; each names its
fields' ranges in the notation the error message shows (``"(2000, 3000)"``, ``"[0, 100]"``,
``"> 0"``, ``">= 0"``), so the range a user reads is the range checked.
"""

from __future__ import annotations

import re
from dataclasses import fields

from controller.readback import finite_number

__all__ = ["check_finite_fields", "check_range", "is_finite_number"]

_NUM = r"[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?"
_INTERVAL = re.compile(rf"^([(\[])\s*({_NUM})\s*,\s*({_NUM})\s*([)\]])$")
_BOUND = re.compile(rf"^(>=|>|<=|<)\s*({_NUM})$")


#: Whether a value is a finite int or float (a bool is not a number here): the test of a
#: setting, and of a value read back from a checkpoint (:func:`controller.readback.finite_number`).
is_finite_number = finite_number


def check_finite_fields(settings, label: str = "", optional=(), flags=(),
                        choices=None) -> None:
    """Raise ``ValueError`` naming the first field of the dataclass ``settings`` that is
    not a finite int or float (a bool is not a number here).

    Parameters
    ----------
    settings : dataclass instance
    label : str
        Put before the field's name in the message (e.g. ``"level sag "``).
    optional : sequence of str
        Fields that may also be None (a setting that is off).
    flags : sequence of str
        Fields that must be a bool instead.
    choices : dict of str to tuple, optional
        Fields that must instead be one of the given values (a named option).
    """
    for f in fields(settings):
        v = getattr(settings, f.name)
        if choices and f.name in choices:
            # of the same type too: True is not the choice 1
            if not any(type(v) is type(c) and v == c for c in choices[f.name]):
                allowed = ", ".join(repr(c) for c in choices[f.name])
                raise ValueError(f"{label}{f.name}: must be one of {allowed}, got {v!r}")
            continue
        if f.name in flags:
            if not isinstance(v, bool):
                raise ValueError(f"{label}{f.name}: must be true or false, got {v!r}")
            continue
        if v is None and f.name in optional:
            continue
        if not is_finite_number(v):
            none = " or None" if f.name in optional else ""
            raise ValueError(f"{label}{f.name}: must be a finite number{none}, got {v!r}")


def _holds(v: float, interval: str) -> bool:
    m = _INTERVAL.match(interval)
    if m:
        lo, hi = float(m.group(2)), float(m.group(3))
        above = lo <= v if m.group(1) == "[" else lo < v
        below = v <= hi if m.group(4) == "]" else v < hi
        return above and below
    m = _BOUND.match(interval)
    if m is None:
        raise ValueError(f"range {interval!r}: not an interval such as '(0, 1]' or '>= 0'")
    op, b = m.group(1), float(m.group(2))
    return {">": v > b, ">=": v >= b, "<": v < b, "<=": v <= b}[op]


def check_range(settings, names, interval: str, unit: str = "", label: str = "",
                note: str = "") -> None:
    """Raise ``ValueError`` naming the first of ``names`` (fields of ``settings``) whose
    value is outside ``interval``.

    Parameters
    ----------
    settings : dataclass instance
        Its fields already checked finite (:func:`check_finite_fields`); a field that is
        None (an optional setting that is off) passes.
    names : str or sequence of str
        The fields that share the range.
    interval : str
        ``"(lo, hi)"`` with ``(``/``)`` open and ``[``/``]`` closed ends, or one bound,
        ``"> b"``, ``">= b"``, ``"< b"``, ``"<= b"``; shown as written in the message.
    unit : str
        The fields' unit, shown after the range (``"kPa"``, ``"%"``, ``"h"``).
    label : str
        Put before the field's name in the message, as in :func:`check_finite_fields`.
    note : str
        Shown in brackets after the range and unit (why the range ends where it does).

    Examples
    --------
    A field out of its range is named with the range it must be in:

    >>> from dataclasses import dataclass
    >>> @dataclass
    ... class S:
    ...     p: float = 3100.0
    >>> check_range(S(), "p", "(2000, 3000)", "kPa", note="interlock 3000")
    Traceback (most recent call last):
    ...
    ValueError: p: must be in (2000, 3000) kPa (interlock 3000), got 3100.0
    """
    kind = "" if interval[:1] in "<>" else "in "
    tail = (f" {unit}" if unit else "") + (f" ({note})" if note else "")
    for name in (names,) if isinstance(names, str) else names:
        v = getattr(settings, name)
        if v is not None and not _holds(float(v), interval):
            raise ValueError(f"{label}{name}: must be {kind}{interval}{tail}, got {v!r}")
