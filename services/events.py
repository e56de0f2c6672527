"""The unit's event log: transition state changes, operator actions and alarms.

What an operator reads back after a shift (the REST ``GET .../events`` and
``ssmpc events``): every event has a stable id, a wall time (UTC, whole
microseconds), the process time, a ``kind``, a ``detail`` object and the identity
behind it (the authenticated REST caller for an operator action, ``controller`` for
what the controller did itself). The controller node commits them to its SQLite
store (:class:`services.store.UnitStore`) before it acknowledges the action.

Kinds:

=================================  =================================================
``transition.<state>``             a transition reached ``pending``, ``running``,
                                   ``settled``, ``aborted`` or ``failed``
``action.transition.create``       an operator requested a transition
``action.transition.queue``        ... with ``queue`` while another was under way
``action.transition.abort``        an operator aborted one (a no-op abort of an ended
                                   transition changes nothing and is not recorded)
``action.<what>``                  any other operator action (:func:`action_event`)
``alarm.raised`` / ``alarm.cleared``  a controller alarm appeared / went away
=================================  =================================================

Stable ids, so a restart that replays a state change stores it once: a transition
reaches each state at most once (``transition-<id>-<state>``), an operator acts on a
transition once per kind (``action-<id>-<verb>``). An alarm is followed by its *key*,
its text with the standalone numbers masked (``XMEAS7 = 2861.3 above ...`` and
``XMEAS7 = 2870.0 above ...`` are one alarm), and is raised once until it clears; the
alarms raised and not cleared are read back from the store at start
(:meth:`services.store.UnitStore.active_alarms`), so an alarm that holds across a
restart is not raised twice.

Costs, measured on the 2-core machine under other work (one process, SQLite in WAL):

==============================================  ===========
:meth:`AlarmTracker.update`, nothing in alarm    0.16 µs
... three TE alarm texts holding (keys masked)   14 µs
one commit of an event (``add_events``)          0.11 ms
read and view 100 / 1000 / 10000 of 100k events  2.5 / 28 / 540 ms
reopen a store of 100k events (integrity check)  0.9 s
==============================================  ===========

The tracker runs in the controller's sample after the move is published (outside
the deadline); a read answers an ``events`` query on a Zenoh thread.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
import time
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime, timedelta
from typing import Any

from controller.alarms import alarm_key, keyed_alarms

__all__ = ["Event", "AlarmTracker", "SYSTEM_IDENTITY", "UNIDENTIFIED", "ALARM_RAISED",
           "ALARM_CLEARED", "now_us", "iso_utc", "parse_since_us", "identity_of",
           "transition_event", "action_event", "alarm_key", "fold_alarms", "describe",
           "MAX_LIMIT"]

#: Identity of the events the controller makes itself (state changes, alarms).
SYSTEM_IDENTITY = "controller"
#: Identity of an operator action whose request named none (a query made on the mesh
#: directly, not through the api node).
UNIDENTIFIED = "unidentified"
ALARM_RAISED = "alarm.raised"
ALARM_CLEARED = "alarm.cleared"
#: Most events one read returns.
MAX_LIMIT = 10_000

_KIND = re.compile(r"^[a-z][a-z0-9_]*(\.[a-z][a-z0-9_]*)*$")
_EPOCH = datetime(1970, 1, 1, tzinfo=UTC)


def now_us() -> int:
    """Wall time now, whole microseconds since the Unix epoch (UTC)."""
    return time.time_ns() // 1000


def iso_utc(time_us: int) -> str:
    """``time_us`` (µs since the epoch) as ISO 8601 UTC with microseconds and ``Z``."""
    return (_EPOCH + timedelta(microseconds=int(time_us))).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def parse_since_us(text: str) -> int:
    """An ISO 8601 time (``2026-12-01T22:30:00Z``, ``...+01:00``; without a zone: UTC)
    as µs since the epoch; ValueError with a message otherwise."""
    if not isinstance(text, str) or not 0 < len(text) <= 64:
        raise ValueError("since: expected an ISO 8601 time such as 2026-12-01T22:30:00Z")
    try:
        when = datetime.fromisoformat(text.strip())
    except ValueError:
        raise ValueError(f"since: not an ISO 8601 time: {text[:64]!r} (e.g. "
                         "2026-12-01T22:30:00Z)") from None
    if when.tzinfo is None:
        when = when.replace(tzinfo=UTC)
    return (when - _EPOCH) // timedelta(microseconds=1)


def identity_of(args: dict) -> str:
    """The identity a command's ``args`` carry (set by the api node from the token the
    request authenticated with), or :data:`UNIDENTIFIED`."""
    who = args.get("identity") if isinstance(args, dict) else None
    if isinstance(who, str) and 0 < len(who) <= 128 and who.isprintable():
        return who
    return UNIDENTIFIED


def _check_detail(detail: Any) -> None:
    if not isinstance(detail, dict):
        raise ValueError(f"detail: expected a JSON object, got {type(detail).__name__}")
    try:
        json.dumps(detail, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"detail: not JSON of finite numbers ({exc})") from None


@dataclass(frozen=True)
class Event:
    """One event of a unit (see the module notes).

    Parameters
    ----------
    id : str
        Stable id, 1..200 characters (unique per unit).
    time_us : int
        Wall time, µs since the Unix epoch (UTC).
    process_time_s : float or None
        The unit's process time at the event, s (None when unknown).
    kind : str
        Dotted lower-case name, e.g. ``transition.settled``.
    detail : dict
        JSON object of finite numbers and text.
    identity : str
        Who made it: the REST caller's identity, or :data:`SYSTEM_IDENTITY`.
    """

    id: str
    time_us: int
    process_time_s: float | None
    kind: str
    detail: dict = field(default_factory=dict)
    identity: str = SYSTEM_IDENTITY

    def __post_init__(self) -> None:
        if not isinstance(self.id, str) or not 0 < len(self.id) <= 200:
            raise ValueError(f"id: expected 1..200 characters, got {self.id!r}")
        if isinstance(self.time_us, bool) or not isinstance(self.time_us, int):
            raise ValueError(f"time_us: expected an integer, got {self.time_us!r}")
        if self.process_time_s is not None and (
                isinstance(self.process_time_s, bool)
                or not isinstance(self.process_time_s, int | float)
                or not math.isfinite(self.process_time_s)):
            raise ValueError(f"process_time_s: expected a finite number or None, got "
                             f"{self.process_time_s!r}")
        if not isinstance(self.kind, str) or len(self.kind) > 64 or not _KIND.match(self.kind):
            raise ValueError(f"kind: expected a dotted lower-case name, got {self.kind!r}")
        _check_detail(self.detail)
        if not isinstance(self.identity, str) or not 0 < len(self.identity) <= 128:
            raise ValueError(f"identity: expected 1..128 characters, got {self.identity!r}")

    def view(self) -> dict[str, Any]:
        """The REST shape: ``{"id", "time" (ISO UTC), "process_time_h", "kind", "detail",
        "identity"}``."""
        return {"id": self.id, "time": iso_utc(self.time_us),
                "process_time_h": (None if self.process_time_s is None
                                   else self.process_time_s / 3600.0),
                "kind": self.kind, "detail": self.detail, "identity": self.identity}


def transition_event(record: dict, state: str, process_time_s: float | None,
                     time_us: int | None = None) -> Event:
    """The event of a transition (its record, :meth:`Transition.as_dict`) reaching
    ``state``; id ``transition-<id>-<state>``."""
    return Event(id=f"transition-{record['id']}-{state}",
                 time_us=now_us() if time_us is None else time_us,
                 process_time_s=process_time_s, kind=f"transition.{state}",
                 detail={"transition": record["id"], "grade": record.get("grade"),
                         "from_grade": record.get("from_grade"), "state": state,
                         "note": str(record.get("detail") or "")})


def action_event(what: str, detail: dict, identity: str, process_time_s: float | None,
                 *, event_id: str | None = None, time_us: int | None = None) -> Event:
    """An operator action ``action.<what>`` (e.g. ``what="mode"`` with
    ``{"mode": "on"}``) made by ``identity``. ``event_id``: a stable id when the action
    can be replayed (default: a new random one, the action happens once)."""
    return Event(id=event_id or f"action-{uuid.uuid4().hex}",
                 time_us=now_us() if time_us is None else time_us,
                 process_time_s=process_time_s, kind=f"action.{what}", detail=dict(detail),
                 identity=identity)


class AlarmTracker:
    """``alarm.raised`` / ``alarm.cleared`` events from the alarms of successive samples.

    Parameters
    ----------
    active : dict of str to str, optional
        Alarms raised and not cleared (key to the text it was raised with), as the
        store has them at start.
    """

    def __init__(self, active: dict[str, str] | None = None) -> None:
        self.active: dict[str, str] = dict(active or {})

    def update(self, alarms: Sequence[str], sample: int, process_time_s: float,
               scope: str = "") -> list[Event]:
        """The events of one sample whose controller reports ``alarms`` (texts);
        ``scope`` (e.g. the plant incarnation) makes ids of a replayed sample number
        distinct. Cheap when nothing is or was in alarm."""
        if not alarms and not self.active:
            return []
        now = keyed_alarms(alarms)
        if now.keys() == self.active.keys():
            return []
        out = []
        t_us = now_us()
        for key, text in now.items():
            if key not in self.active:
                out.append(self._event(ALARM_RAISED, key, text, sample, process_time_s,
                                       scope, t_us))
        for key, text in self.active.items():
            if key not in now:
                out.append(self._event(ALARM_CLEARED, key, text, sample, process_time_s,
                                       scope, t_us))
        self.active = now
        return out

    @staticmethod
    def _event(kind, key, text, sample, t, scope, t_us) -> Event:
        digest = hashlib.sha1(key.encode("utf-8", "backslashreplace")).hexdigest()[:12]
        verb = kind.rsplit(".", 1)[1]
        return Event(id=f"alarm-{digest}-{verb}-{scope}{sample}", time_us=t_us,
                     process_time_s=float(t), kind=kind,
                     detail={"alarm": text, "key": key, "sample": int(sample)})


def fold_alarms(kinds_details: Iterable[tuple[str, dict]]) -> dict[str, str]:
    """Alarms raised and not cleared, from ``(kind, detail)`` pairs in time order."""
    active: dict[str, str] = {}
    for kind, detail in kinds_details:
        key = detail.get("key")
        if not isinstance(key, str):
            continue
        if kind == ALARM_RAISED:
            active[key] = str(detail.get("alarm", key))
        elif kind == ALARM_CLEARED:
            active.pop(key, None)
    return active


def describe(view: dict) -> str:
    """One readable phrase for an event's REST view (what happened)."""
    kind, d = view.get("kind", ""), view.get("detail") or {}
    if kind.startswith("transition."):
        text = (f"transition {d.get('transition')} {d.get('from_grade') or '-'} -> "
                f"{d.get('grade')}: {d.get('state')}")
        return text + (f" ({d['note']})" if d.get("note") else "")
    if kind in ("action.transition.create", "action.transition.queue"):
        how = " (queued)" if kind.endswith("queue") else ""
        return f"requested transition {d.get('transition')} to {d.get('grade')}{how}"
    if kind == "action.transition.abort":
        return f"aborted transition {d.get('transition')} to {d.get('grade')}"
    if kind == ALARM_RAISED:
        return f"alarm: {d.get('alarm')}"
    if kind == ALARM_CLEARED:
        return f"alarm cleared: {d.get('alarm')}"
    rest = ", ".join(f"{k}={json.dumps(v)}" for k, v in d.items())
    return f"{kind} {rest}".strip()
