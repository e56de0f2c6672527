"""The controller node's answer to an ``events`` query: its event log read back.

``args``: ``since_us`` (µs since the Unix epoch, UTC; events at or after it; absent:
from the first) and ``limit`` (1..:data:`services.events.MAX_LIMIT`, default
:data:`DEFAULT_LIMIT`; the oldest that many). Reply 200 with the events' REST views
(:meth:`services.events.Event.view`), oldest first; 422 for bad arguments; 503 with
a message when the store cannot be read.
"""

from __future__ import annotations

import sqlite3

from services.events import MAX_LIMIT
from services.io.messages import Reply
from services.store import StoreError, UnitStore

__all__ = ["DEFAULT_LIMIT", "events_reply"]

#: Events one read returns unless it asks for another number.
DEFAULT_LIMIT = 1000


def _integer(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def events_reply(store: UnitStore, args: dict) -> Reply:
    """The unit's events as the ``events`` query asks for them (see the module notes)."""
    since = args.get("since_us")
    if since is not None and not (_integer(since) and abs(since) < 2**62):
        return Reply(422, error="since_us: expected an integer (µs since the epoch)")
    limit = args.get("limit", DEFAULT_LIMIT)
    if not (_integer(limit) and 1 <= limit <= MAX_LIMIT):
        return Reply(422, error=f"limit: expected an integer 1..{MAX_LIMIT}")
    try:
        events = store.unit_events(since, limit)
    except (sqlite3.Error, StoreError, ValueError) as exc:
        return Reply(503, error=f"store: cannot read the event log ({type(exc).__name__}: "
                                f"{exc})")
    return Reply(200, [e.view() for e in events])
