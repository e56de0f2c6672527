"""REST hardening on the real server and real nodes: malformed numbers and text are 422,
types are strict, the transition queue is bounded, ``Idempotency-Key`` is honoured (also
across a controller restart), a controller that never answers does not slow ``/health``,
and a malformed reply from the mesh is a 502 with a message.
"""

import json
import threading
import time

import httpx
import pytest
from test_api import AUTH, ApiServer
from test_service_loop import Harness

from services.io import keys
from services.io.messages import SCHEMA_VERSION, Reply

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

POST = "/api/v1/units/cstr/transitions"
DIST = "/api/v1/units/cstr/disturbances"
JSON = {**AUTH, "content-type": "application/json"}


def _is_422_with_message(r):
    assert r.status_code == 422, (r.status_code, r.text)
    body = r.json()  # valid JSON, valid UTF-8
    assert body["detail"], body
    return body


@pytest.mark.parametrize("raw", [
    '{"grade": "OPII", "duration_h": NaN}',
    '{"grade": "OPII", "duration_h": Infinity}',
    '{"grade": "OPII", "duration_h": -Infinity}',
    '{"grade": "OPII", "duration_h": 1e400}',
    '{"grade": "OPII", "duration_h": 1' + "0" * 400 + "}",
    '{"grade": "\\ud800"}',
    '{"grade": "OP\\udfffII"}',
    '{"grade": "OPII", "\\ud800": 1}',
    b'{"grade": "OP\xffII"}',  # not UTF-8
    b'{"grade": "OPII", "duration_h": 1' + b"0" * 5000 + b"}",  # beyond int conversion
    '{"grade": "OPII"',
], ids=lambda raw: repr(raw[:48]))
def test_non_finite_out_of_range_and_bad_unicode_transition_bodies_are_422(stack, raw):
    h, api = stack
    _is_422_with_message(api.client.post(POST, content=raw, headers=JSON))


@pytest.mark.parametrize("raw", [
    '{"name": "x1f", "value": NaN}',
    '{"name": "x1f", "value": Infinity}',
    '{"name": "x1f", "value": 1e400}',
    '{"name": "x1f", "value": -1e999}',
    '{"name": "\\ud83d", "value": 1.0}',
])
def test_non_finite_and_bad_unicode_disturbance_bodies_are_422(stack, raw):
    h, api = stack
    _is_422_with_message(api.client.post(DIST, content=raw, headers=JSON))
    assert h.plant.runner.d[0] == 1.0


@pytest.mark.parametrize("path, body", [
    (POST, {"grade": "OPII", "duration_h": True}),
    (POST, {"grade": "OPII", "duration_h": "0.5"}),
    (POST, {"grade": "OPII", "queue": 1}),
    (POST, {"grade": "OPII", "queue": "true"}),
    (POST, {"grade": ["OPII"]}),
    (DIST, {"name": "x1f", "value": True}),
    (DIST, {"name": "x1f", "value": "1.1"}),
    (DIST, {"name": 1, "value": 1.1}),
])
def test_types_are_strict(stack, path, body):
    h, api = stack
    _is_422_with_message(api.client.post(path, json=body, headers=AUTH))
    assert h.plant.runner.d[0] == 1.0
    assert api.client.get(POST).json() == []


def test_an_integer_duration_is_still_a_number(stack):
    h, api = stack
    r = api.client.post(POST, json={"grade": "OPII", "duration_h": 1}, headers=AUTH)
    assert r.status_code == 202 and r.json()["duration_s"] == 3600.0


@pytest.fixture
def small_queue(tmp_path):
    h = Harness(tmp_path, transition_queue_limit=2)
    api = ApiServer(h)
    yield h, api
    api.close()
    h.close()


def test_a_full_transition_queue_is_429(small_queue):
    h, api = small_queue
    c = api.client
    slow = {"grade": "OPII", "duration_h": 1.0}  # 36 wall s at 100x: stays running
    assert c.post(POST, json=slow, headers=AUTH).status_code == 202
    for grade in ("OPIII", "OPI"):
        assert c.post(POST, json={"grade": grade, "queue": True},
                      headers=AUTH).status_code == 202
    r = c.post(POST, json={"grade": "OPII", "queue": True}, headers=AUTH)
    assert r.status_code == 429 and "queue" in r.json()["detail"]
    assert len(c.get(POST).json()) == 3  # the refused one was not stored


def test_idempotency_key_gives_the_same_transition_even_after_a_restart(stack):
    h, api = stack
    c = api.client
    key = {**AUTH, "Idempotency-Key": "a1b2c3-order-17"}
    first = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=key)
    again = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=key)
    assert first.status_code == 202 and again.status_code == 202
    assert again.json()["id"] == first.json()["id"]
    assert again.headers["location"] == first.headers["location"]
    # the same key with another body is refused, not a second transition
    other = c.post(POST, json={"grade": "OPIII", "queue": True}, headers=key)
    assert other.status_code == 422 and "Idempotency-Key" in other.json()["detail"]
    assert len(c.get(POST).json()) == 1
    # durable: a restarted controller still knows the key
    h.stop_controller()
    h.start_controller()
    t_end = time.monotonic() + 10
    while not api.mesh.alive("cstr", "controller") and time.monotonic() < t_end:
        time.sleep(0.02)
    after = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=key)
    assert after.status_code == 202 and after.json()["id"] == first.json()["id"]
    assert len(c.get(POST).json()) == 1
    # a queued request with a new key is a new transition
    fresh = c.post(POST, json={"grade": "OPIII", "queue": True},
                   headers={**AUTH, "Idempotency-Key": "another"})
    assert fresh.status_code == 202 and fresh.json()["id"] != first.json()["id"]


@pytest.mark.parametrize("bad", ["", "x" * 300, b"k\xffey"])
def test_a_malformed_idempotency_key_is_422(stack, bad):
    h, api = stack
    r = api.client.post(POST, json={"grade": "OPII"}, headers={**AUTH, "Idempotency-Key": bad})
    assert r.status_code == 422 and "Idempotency-Key" in r.json()["detail"]


def _fake_controller(session, unit, answer):
    """A liveliness token and a queryable that answers every query with ``answer(query)``
    (bytes), or keeps the query unanswered when that is None."""
    held = []

    def on_query(query):
        payload = answer(query)
        if payload is None:
            held.append(query)  # never answered, never finalized
        else:
            query.reply(query.key_expr, payload)

    # the queryable before the token, as the controller node declares them: a client that
    # sees the token alive then finds the queryable (declarations arrive in order)
    q = session.declare_queryable(keys.cmd_all(unit), on_query)
    token = session.liveliness().declare_token(keys.alive(unit, "controller"))
    return token, q, held


def _wait_alive(api, unit):
    t_end = time.monotonic() + 5
    while not api.mesh.alive(unit, "controller") and time.monotonic() < t_end:
        time.sleep(0.02)
    assert api.mesh.alive(unit, "controller")


def test_health_stays_fast_while_a_controller_never_answers(stack):
    h, api = stack
    token, q, held = _fake_controller(h.s_client, "mute", lambda query: None)
    _wait_alive(api, "mute")
    codes, lock = [], threading.Lock()
    base = f"http://127.0.0.1:{api.port}"
    # one client per request: a pool shared by 200 threads races in httpcore (seen once:
    # ReadError "Bad file descriptor" on the client side)

    def get():
        with httpx.Client(base_url=base, timeout=60) as c:
            r = c.get("/api/v1/units/mute/status")
        with lock:
            codes.append(r.status_code)

    threads = [threading.Thread(target=get) for _ in range(200)]
    for t in threads:
        t.start()
    time.sleep(0.5)  # the flood is in
    health_s = []
    for _ in range(5):
        t0 = time.monotonic()
        assert api.client.get("/health").status_code == 200
        health_s.append(time.monotonic() - t0)
    units = api.client.get("/api/v1/units")
    for t in threads:
        t.join(60)
    q.undeclare()
    token.undeclare()
    print(f"/health under a 200-query flood: {max(health_s) * 1e3:.1f} ms at most")
    assert max(health_s) < 2.0
    assert units.status_code == 200
    assert len(codes) == 200 and set(codes) <= {503, 504}, sorted(set(codes))


def _reply(data, code=200):
    return Reply(code, data).to_bytes()


@pytest.mark.parametrize("answer, method, path", [
    (lambda q: _reply({"state": "running"}, 202), "post", "/api/v1/units/fake/transitions"),
    (lambda q: _reply({"id": 5, "state": "running"}, 202), "post",
     "/api/v1/units/fake/transitions"),
    (lambda q: _reply([1, 2], 200), "get", "/api/v1/units/fake/transitions/abc"),
    (lambda q: _reply({"id": "abc"}, 200), "delete", "/api/v1/units/fake/transitions/abc"),
    (lambda q: _reply({"x": 1}, 200), "get", "/api/v1/units/fake/transitions"),
    (lambda q: _reply([1, 2], 200), "get", "/api/v1/units/fake/status"),
    (lambda q: _reply("grades", 200), "get", "/api/v1/units/fake/grades"),
    (lambda q: b"not a reply at all", "get", "/api/v1/units/fake/status"),
    (lambda q: json.dumps({"schema": SCHEMA_VERSION, "kind": "reply"}).encode(), "get",
     "/api/v1/units/fake/status"),
])
def test_a_malformed_reply_is_a_502_with_a_message(stack, answer, method, path):
    h, api = stack
    token, q, _ = _fake_controller(h.s_client, "fake", answer)
    try:
        _wait_alive(api, "fake")
        kw = {"json": {"grade": "OPII"}} if method == "post" else {}
        r = getattr(api.client, method)(path, headers=AUTH, **kw)
        assert r.status_code == 502, (r.status_code, r.text)
        assert "malformed" in r.json()["detail"]
    finally:
        q.undeclare()
        token.undeclare()
