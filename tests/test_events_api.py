"""The event log over the real stack (CSTR plant and controller nodes on Zenoh, the api
on uvicorn): every operator action and state change once, with its identity, also
after a controller restart; alarms raised and cleared once; ``since``; errors; and the
``ssmpc events`` command (``--json``, ``--follow`` interrupted by Ctrl-C)."""

from __future__ import annotations

import json
import queue
import signal
import sqlite3
import subprocess
import sys
import threading
import time
from collections import Counter

import pytest
from test_api import AUTH, TOKEN, ApiServer
from test_service_loop import Harness

from services.registry import build_controller

pytestmark = [pytest.mark.integration, pytest.mark.timeout(240)]

EVENTS = "/api/v1/units/cstr/events"
ALARM_TEXT = "y = {:.4f} above the test's alarm limit"


class _Alarming:
    """The unit's own controller; while :attr:`on` is set, every decision also carries
    an alarm whose text has the measured value in it (as the TE alarms do)."""

    on = threading.Event()

    def __init__(self, cfg):
        self._inner = build_controller(cfg)

    def step(self, k, t, y, reference):
        d = self._inner.step(k, t, y, reference)
        if self.on.is_set():
            from dataclasses import replace

            d = replace(d, alarms=(*d.alarms, ALARM_TEXT.format(float(y[0]))))
        return d

    def __getattr__(self, name):  # checkpoint, restore, align, horizon, ...
        return getattr(self._inner, name)


@pytest.fixture
def alarming_stack(tmp_path):
    _Alarming.on.clear()
    h = Harness(tmp_path, controller_factory=_Alarming, telemetry=False)
    api = ApiServer(h)
    yield h, api
    _Alarming.on.clear()
    api.close()
    h.close()


def _wait_state(c, tid, states, timeout=30.0):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        v = c.get(f"/api/v1/units/cstr/transitions/{tid}").json()
        if v["state"] in states:
            return v
        time.sleep(0.05)
    raise AssertionError(f"transition {tid} still {v['state']}")


def _events(c, **params):
    r = c.get(EVENTS, params=params)
    assert r.status_code == 200, r.text
    return r.json()


def _wait_kinds(c, kinds: Counter, timeout=20.0):
    """The events once ``kinds`` (kind -> count) are all there."""
    t_end = time.monotonic() + timeout
    while True:
        events = _events(c)
        have = Counter(e["kind"] for e in events)
        if all(have[k] >= n for k, n in kinds.items()) or time.monotonic() > t_end:
            return events
        time.sleep(0.1)


def _restart(h, api):
    h.stop_controller()
    h.start_controller()
    t_end = time.monotonic() + 10
    while not api.mesh.alive("cstr", "controller") and time.monotonic() < t_end:
        time.sleep(0.02)
    h.wait_samples(3, timeout=30)


def _once(events):
    ids = [e["id"] for e in events]
    assert len(ids) == len(set(ids)), Counter(ids).most_common(3)
    times = [e["time"] for e in events]
    assert times == sorted(times)


def test_every_action_and_state_change_once_with_its_identity_across_a_restart(
        alarming_stack):
    h, api = alarming_stack
    c = api.client
    h.wait_samples(3)
    first = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"}, headers=AUTH)
    assert first.status_code == 202
    a = first.json()["id"]
    second = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPIII", "queue": True},
                    headers=AUTH)
    assert second.status_code == 202 and second.json()["state"] == "pending"
    b = second.json()["id"]
    _wait_state(c, a, ("running",))
    assert c.delete(f"/api/v1/units/cstr/transitions/{a}", headers=AUTH).status_code == 200
    # an abort of a transition that has ended changes nothing and records nothing
    assert c.delete(f"/api/v1/units/cstr/transitions/{a}", headers=AUTH).status_code == 200
    _wait_state(c, b, ("running", "settled"))
    events = _wait_kinds(c, Counter({"transition.running": 2}))
    _once(events)
    def of(tid):
        return [(e["kind"], e["identity"]) for e in events
                if e["detail"].get("transition") == tid]

    assert of(a) == [("action.transition.create", "operator"),
                     ("transition.pending", "controller"), ("transition.running", "controller"),
                     ("action.transition.abort", "operator"),
                     ("transition.aborted", "controller")]
    assert of(b)[:3] == [("action.transition.queue", "operator"),
                         ("transition.pending", "controller"),
                         ("transition.running", "controller")]
    assert all(e["process_time_h"] is not None and e["process_time_h"] >= 0 for e in events)

    # a restart of the controller loses nothing and repeats nothing
    _restart(h, api)
    events_after = _events(c)
    assert events_after[:len(events)] == events
    _once(events_after)
    assert Counter(e["kind"] for e in events_after)["action.transition.abort"] == 1

    # since: the events at or after that time, in order
    abort = next(e for e in events if e["kind"] == "action.transition.abort")
    cut = abort["time"]
    later = _events(c, since=cut)
    assert later == [e for e in events_after if e["time"] >= cut]
    assert later[0] == abort
    assert _events(c, since=cut, limit=1) == later[:1]


def test_an_alarm_is_raised_once_while_it_holds_also_across_a_restart(alarming_stack):
    h, api = alarming_stack
    c = api.client
    h.wait_samples(3)
    _Alarming.on.set()
    h.wait_samples(10)
    events = _wait_kinds(c, Counter({"alarm.raised": 1}))
    _restart(h, api)  # the alarm holds across the restart
    h.wait_samples(10)
    _Alarming.on.clear()
    h.wait_samples(5)
    events = _wait_kinds(c, Counter({"alarm.cleared": 1}))
    alarms = [e for e in events if e["kind"].startswith("alarm.")]
    assert [e["kind"] for e in alarms] == ["alarm.raised", "alarm.cleared"]
    assert all(e["identity"] == "controller" for e in alarms)
    assert alarms[0]["detail"]["alarm"].startswith("y = ")


def test_bad_since_unknown_unit_and_an_unreadable_store(alarming_stack):
    h, api = alarming_stack
    c = api.client
    for bad in ("yesterday", "2026-13-01T00:00:00Z", "1" * 80):
        r = c.get(EVENTS, params={"since": bad})
        assert r.status_code == 422 and "since" in r.json()["detail"]
    assert c.get(EVENTS, params={"limit": 0}).status_code == 422
    assert c.get("/api/v1/units/nosuch/events").status_code == 404
    assert c.get(EVENTS, params={"since": "2026-12-01T00:00:00+02:00"}).status_code == 200

    def unreadable(*args, **kw):
        raise sqlite3.DatabaseError("database disk image is malformed")

    h.store.unit_events = unreadable
    r = c.get(EVENTS)
    assert r.status_code == 503
    assert "event log" in r.json()["detail"] and "malformed" in r.json()["detail"]


def _cli(api, *argv):
    return [sys.executable, "-m", "services.cli", *argv, "--api",
            f"http://127.0.0.1:{api.port}", "--token", TOKEN]


def test_ssmpc_events_json_and_follow_until_ctrl_c(stack):
    h, api = stack
    c = api.client
    h.wait_samples(3)
    tid = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
                 headers=AUTH).json()["id"]
    _wait_state(c, tid, ("running", "settled"))
    done = subprocess.run(_cli(api, "events", "cstr", "--json"), capture_output=True,
                          text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    doc = json.loads(done.stdout.strip().splitlines()[-1])
    assert doc["unit"] == "cstr"
    assert [e["kind"] for e in doc["events"]][:3] == [
        "action.transition.create", "transition.pending", "transition.running"]
    assert doc["events"] == _events(c)[:len(doc["events"])]
    text = subprocess.run(_cli(api, "events", "cstr"), capture_output=True, text=True,
                          timeout=60)
    assert text.returncode == 0, text.stderr
    line = text.stdout.splitlines()[0]
    assert f"requested transition {tid} to OPII" in line and line.endswith("[operator]")

    follow = subprocess.Popen(_cli(api, "events", "cstr", "--follow", "--json",
                                   "--poll-s", "0.2"),
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue = queue.Queue()
    threading.Thread(target=lambda: [lines.put(x) for x in follow.stdout], daemon=True).start()
    try:
        seen = []

        def until(pred, timeout=30.0):
            t_end = time.monotonic() + timeout
            while time.monotonic() < t_end:
                try:
                    seen.append(json.loads(lines.get(timeout=0.5)))
                except queue.Empty:
                    continue
                if pred():
                    return
            raise AssertionError(f"not printed: {[e['kind'] for e in seen]}")

        until(lambda: len(seen) >= len(doc["events"]))
        _wait_state(c, tid, ("settled",))
        assert c.delete(f"/api/v1/units/cstr/transitions/{tid}",
                        headers=AUTH).json()["state"] == "settled"
        new = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPI"},
                     headers=AUTH).json()["id"]
        until(lambda: any(e["detail"].get("transition") == new
                          and e["kind"] == "transition.pending" for e in seen))
    finally:
        follow.send_signal(signal.SIGINT)
        try:
            code = follow.wait(timeout=20)
        finally:
            follow.kill()
    err = follow.stderr.read()
    assert code == 0, err
    assert "Traceback" not in err
    ids = [e["id"] for e in seen]
    assert len(ids) == len(set(ids))  # nothing printed twice while polling
    assert ids == [e["id"] for e in _events(c)][:len(ids)]


def test_ssmpc_events_errors_are_exit_2(stack):
    h, api = stack
    bad = subprocess.run(_cli(api, "events", "cstr", "--since", "noon"), capture_output=True,
                         text=True, timeout=60)
    assert bad.returncode == 2 and bad.stderr.startswith("error: since")
    unknown = subprocess.run(_cli(api, "events", "nosuch"), capture_output=True, text=True,
                             timeout=60)
    assert unknown.returncode == 2 and "404" in unknown.stderr
    assert "Traceback" not in bad.stderr + unknown.stderr


def test_operator_actions_go_to_the_recordings_event_log_too(stack):
    from test_telemetry import _read

    h, api = stack
    c = api.client
    h.wait_samples(3)
    tid = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
                 headers=AUTH).json()["id"]
    _wait_state(c, tid, ("running", "settled"))
    c.delete(f"/api/v1/units/cstr/transitions/{tid}", headers=AUTH)
    h.stop_controller()  # closes the recording
    _, _, text, _ = _read(h.tmp / "cstr.rrd")
    lines = [t for _, t in text.get("/cstr/events", [])]
    assert f"requested transition {tid} to OPII [operator]" in lines
    aborted = [e for e in _events_from_store(h) if e.kind == "action.transition.abort"]
    if aborted:  # it was still running when the DELETE came
        assert f"aborted transition {tid} to OPII [operator]" in lines


def _events_from_store(h):
    from services.store import UnitStore

    with UnitStore(h.store_path, "cstr") as s:
        return s.unit_events()


def test_a_state_change_replayed_from_an_older_checkpoint_is_stored_once(harness):
    """A controller that restarts from a checkpoint older than its last state change
    (a crash between the two writes) goes through that change again: the event log
    keeps the first one."""
    h = harness(start_plant=False)
    rep = h.query("transition", {"op": "create", "grade": "OPII", "identity": "alice"})
    assert rep.code == 202 and rep.data["state"] == "pending"
    tid = rep.data["id"]
    h.ctrl.flush()
    db = sqlite3.connect(h.store_path)
    older = db.execute("SELECT sample, process_time, wall, state FROM checkpoint").fetchone()
    db.close()
    assert json.loads(older[3])["transitions"]["active"]["state"] == "pending"
    h.start_plant()
    t_end = time.monotonic() + 30
    while h.query("transition", {"op": "get", "id": tid}).data["state"] == "pending":
        assert time.monotonic() < t_end
        time.sleep(0.05)
    h.stop_controller()
    db = sqlite3.connect(h.store_path)  # the crash: the newer checkpoint never made it
    db.execute("UPDATE checkpoint SET sample=?, process_time=?, wall=?, state=?", older)
    db.commit()
    db.close()
    h.start_controller()
    t_end = time.monotonic() + 30
    while _answer(h, "transition", {"op": "get", "id": tid})["state"] == "pending":
        assert time.monotonic() < t_end, "the restored transition did not run again"
        time.sleep(0.05)
    events = _answer(h, "events")
    mine = Counter((e["kind"], e["identity"]) for e in events
                   if e["detail"].get("transition") == tid)
    assert mine[("transition.running", "controller")] == 1
    assert mine[("transition.pending", "controller")] == 1
    assert mine[("action.transition.create", "alice")] == 1
    assert len({e["id"] for e in events}) == len(events)


def _answer(h, action, args=None, timeout=20.0):
    """The data of the node's reply, asking again while a restarted node's queryable is
    not yet known on the mesh."""
    t_end = time.monotonic() + timeout
    while True:
        try:
            return h.query(action, args).data
        except AssertionError:
            if time.monotonic() > t_end:
                raise
            time.sleep(0.1)
