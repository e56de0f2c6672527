"""The event log in the store: stable ids (a replay is stored once), ``since`` and
``limit``, alarms raised once until cleared (also across a reopen), times in ISO UTC."""

import sqlite3

import pytest

from services.events import (
    AlarmTracker,
    Event,
    action_event,
    describe,
    iso_utc,
    parse_since_us,
    transition_event,
)
from services.events_query import events_reply
from services.store import StoreError, UnitStore


def _rec(tid, state, grade="OPII"):
    return {"id": tid, "grade": grade, "from_grade": "OPI", "state": state, "detail": ""}


def test_time_format_is_iso_utc_with_microseconds():
    # 1_700_000_000 s after the epoch is 2023-11-14 22:13:20 UTC
    assert iso_utc(1_700_000_000_123_456) == "2023-11-14T22:13:20.123456Z"
    assert iso_utc(0) == "1970-01-01T00:00:00.000000Z"
    assert parse_since_us("2023-11-14T22:13:20.123456Z") == 1_700_000_000_123_456
    assert parse_since_us("2023-11-14T23:13:20+01:00") == 1_700_000_000_000_000
    assert parse_since_us("2023-11-14T22:13:20") == 1_700_000_000_000_000  # no zone: UTC
    for bad in ("yesterday", "", "2023-13-01T00:00:00Z", "x" * 100):
        with pytest.raises(ValueError, match="since"):
            parse_since_us(bad)


def test_a_replayed_state_change_is_stored_once_and_survives_reopen(tmp_path):
    path = tmp_path / "u.sqlite"
    s = UnitStore(path, "cstr")
    act = action_event("transition.create", {"transition": "a", "grade": "OPII"}, "operator",
                       1.0, event_id="action-a-create")
    s.save_transition(_rec("a", "pending"), event="pending", process_time=1.0,
                      events=(act, transition_event(_rec("a", "pending"), "pending", 1.0)))
    s.save_transition(_rec("a", "running"), event="running", process_time=2.0,
                      events=(transition_event(_rec("a", "running"), "running", 2.0),))
    s.close()
    s = UnitStore(path, "cstr")  # a restart from an older checkpoint runs it again
    s.save_transition(_rec("a", "running"), event="running", process_time=2.5,
                      events=(transition_event(_rec("a", "running"), "running", 2.5),))
    s.save_transition(_rec("a", "settled"), event="settled", process_time=9.0,
                      events=(transition_event(_rec("a", "settled"), "settled", 9.0),))
    events = s.unit_events()
    assert [e.kind for e in events] == ["action.transition.create", "transition.pending",
                                        "transition.running", "transition.settled"]
    assert [e.identity for e in events] == ["operator", "controller", "controller",
                                            "controller"]
    running = events[2]
    assert running.process_time_s == 2.0  # the first one stays
    view = running.view()
    assert set(view) == {"id", "time", "process_time_h", "kind", "detail", "identity"}
    assert view["process_time_h"] == pytest.approx(2.0 / 3600)
    assert parse_since_us(view["time"]) == running.time_us
    assert describe(view) == "transition a OPI -> OPII: running"
    s.close()


def test_since_is_inclusive_and_limit_takes_the_oldest(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    base = 1_700_000_000_000_000
    s.add_events([Event(id=f"e{i}", time_us=base + i * 1000, process_time_s=float(i),
                        kind="action.test", detail={"i": i}) for i in range(5)])
    other = UnitStore(tmp_path / "u.sqlite", "te")  # another unit's log is its own
    other.add_events([Event(id="e9", time_us=base, process_time_s=None, kind="action.test")])
    assert [e.id for e in s.unit_events(since_us=base + 2000)] == ["e2", "e3", "e4"]
    assert [e.id for e in s.unit_events(limit=2)] == ["e0", "e1"]
    assert s.unit_events(since_us=base + 10_000) == []
    rep = events_reply(s, {"since_us": base + 3000})
    assert rep.code == 200 and [v["id"] for v in rep.data] == ["e3", "e4"]
    for bad in ({"since_us": "x"}, {"since_us": True}, {"limit": 0}, {"limit": 10**6}):
        assert events_reply(s, bad).code == 422
    s.close()
    other.close()


def test_alarm_raised_once_while_it_holds_and_not_again_after_reopen(tmp_path):
    tracker = AlarmTracker()
    hi = "XMEAS7 = {:.1f} above its alarm limit 2950 (interlock ahead)"
    assert tracker.update([], 1, 1.0) == []
    raised = tracker.update([hi.format(2951.2)], 2, 2.0, "abcd")
    assert [e.kind for e in raised] == ["alarm.raised"]
    assert raised[0].detail["alarm"] == hi.format(2951.2)
    # the value moves, the alarm is the same one
    assert tracker.update([hi.format(2960.7)], 3, 3.0, "abcd") == []
    path = tmp_path / "u.sqlite"
    s = UnitStore(path, "te")
    s.add_events(raised)
    s.close()
    s = UnitStore(path, "te")
    again = AlarmTracker(s.active_alarms())  # a restarted controller
    assert again.update([hi.format(2955.0)], 10, 10.0, "abcd") == []
    cleared = again.update([], 11, 11.0, "abcd")
    assert [e.kind for e in cleared] == ["alarm.cleared"]
    s.add_events(cleared)
    assert s.active_alarms() == {}
    assert [describe(e.view()) for e in s.unit_events()] == [
        f"alarm: {hi.format(2951.2)}", f"alarm cleared: {hi.format(2951.2)}"]
    s.close()


def test_event_fields_are_checked():
    for bad in (dict(id=""), dict(kind="Bad Kind"), dict(detail={"x": float("nan")}),
                dict(detail=[1]), dict(identity=""), dict(time_us=1.5),
                dict(process_time_s=float("inf"))):
        kw = dict(id="e", time_us=1, process_time_s=0.0, kind="action.test", detail={})
        kw.update(bad)
        with pytest.raises(ValueError):
            Event(**kw)


def test_a_store_with_an_undecodable_event_is_refused(tmp_path):
    path = tmp_path / "u.sqlite"
    UnitStore(path, "cstr").close()
    db = sqlite3.connect(path)
    db.execute("INSERT INTO events (id, unit, time_us, process_time, kind, detail, identity)"
               " VALUES ('x', 'cstr', 1, NULL, 'action.test', '{\"v\": 1e999}', 'operator')")
    db.commit()
    db.close()
    with pytest.raises(StoreError, match="event 'x'"):
        UnitStore(path, "cstr")
