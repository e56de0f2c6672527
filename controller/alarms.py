"""Alarm identity: which alarm texts of successive samples are the same alarm.

A controller reports its alarms as texts each sample, and most carry the value that
raised them ("reactor pressure 2912 kPa: grade plan held 40 %"), which changes from one
sample to the next while the alarm stands. An alarm's key is its text with every
standalone number masked, so a standing alarm keeps its key and a log records it once,
when it is raised (the service's event log, ``services.events.AlarmTracker``; the
offline run's alarm log, :func:`controller.units.te.control.run_te`). A number that is
part of a name (XMEAS7, IDV(6)'s 6 inside a word) is kept.
"""

from __future__ import annotations

import re
from collections.abc import Iterable

__all__ = ["alarm_key", "keyed_alarms"]

#: A number standing alone (not part of a name such as XMEAS7): masked in alarm keys.
_NUMBER = re.compile(r"(?<![A-Za-z0-9_.])[-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")


def alarm_key(text: str) -> str:
    """An alarm's key: its text with standalone numbers masked as ``#``.

    >>> alarm_key("reactor pressure 2912 kPa: grade plan held 40 % (behind by 0.25 h)")
    'reactor pressure # kPa: grade plan held # % (behind by # h)'
    >>> alarm_key("XMEAS7 high")
    'XMEAS7 high'
    """
    return _NUMBER.sub("#", text)


def keyed_alarms(texts: Iterable[str]) -> dict[str, str]:
    """One sample's alarms by key (:func:`alarm_key`), each with the first text that has
    it: a log compares these keys with the last sample's to find what was raised or
    cleared.

    >>> keyed_alarms(["P 2901 kPa high", "P 2903 kPa high", "level low"])
    {'P # kPa high': 'P 2901 kPa high', 'level low': 'level low'}
    """
    out: dict[str, str] = {}
    for text in texts:
        out.setdefault(alarm_key(text), text)
    return out
