"""REST v1 contract on the real uvicorn server, talking to real nodes over Zenoh."""

import threading
import time

import httpx
import pytest
import uvicorn

from api.app import create_app
from api.mesh import Mesh
from services.io import keys
from services.io.zenoh_session import SessionSettings, free_port, open_session

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

TOKEN = "s3cret-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}


class ApiServer:
    def __init__(self, harness, timeout_s=2.0):
        self.session = open_session(SessionSettings(connect=(harness.ep,), lease_ms=1000))
        self.mesh = Mesh(self.session, timeout_s=timeout_s)
        self.port = free_port()
        app = create_app(self.mesh, token=TOKEN)
        self.server = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=self.port,
                                                    log_level="warning", lifespan="off"))
        self.thread = threading.Thread(target=self.server.run, daemon=True)
        self.thread.start()
        t_end = time.monotonic() + 10
        while not self.server.started and time.monotonic() < t_end:
            time.sleep(0.02)
        assert self.server.started
        self.client = httpx.Client(base_url=f"http://127.0.0.1:{self.port}", timeout=10)
        t_end = time.monotonic() + 5
        while not self.mesh.alive(harness.cfg.unit, "controller") and time.monotonic() < t_end:
            time.sleep(0.02)

    def close(self):
        self.client.close()
        self.server.should_exit = True
        self.thread.join(10)
        self.mesh.close()
        self.session.close()


def test_health_units_openapi(stack):
    h, api = stack
    c = api.client
    assert c.get("/health").json()["status"] == "ok"
    units = c.get("/api/v1/units").json()["units"]
    assert {"unit": "cstr", "plant": True, "controller": True} in units
    doc = c.get("/openapi.json").json()
    for path in ("/api/v1/units/{unit}/transitions", "/api/v1/units/{unit}/status",
                 "/api/v1/units/{unit}/transitions/{tid}", "/api/v1/units/{unit}/grades"):
        assert path in doc["paths"]


def test_transition_lifecycle_over_rest(stack):
    h, api = stack
    c = api.client
    grades = c.get("/api/v1/units/cstr/grades").json()
    assert grades["grades"]["OPII"]["setpoints"]["y"] == pytest.approx(5.0, rel=1e-6)
    r = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"}, headers=AUTH)
    assert r.status_code == 202
    tid = r.json()["id"]
    assert r.headers["location"] == f"/api/v1/units/cstr/transitions/{tid}"
    assert c.post("/api/v1/units/cstr/transitions", json={"grade": "OPIII"},
                  headers=AUTH).status_code == 409
    t_end = time.monotonic() + 30
    while time.monotonic() < t_end:
        v = c.get(r.headers["location"]).json()
        if v["state"] == "settled":
            break
        time.sleep(0.05)
    assert v["state"] == "settled" and v["progress"] == 1.0 and v["ise"] > 0
    st = c.get("/api/v1/units/cstr/status").json()
    for key in ("process_time_s", "sample", "cv", "ref", "mv", "active_model", "J", "solve_ms",
                "deadline_misses", "alarms"):
        assert key in st
    hist = c.get("/api/v1/units/cstr/transitions").json()
    assert [x["id"] for x in hist] == [tid]


def test_queued_transition_is_202_and_runs_after(stack):
    h, api = stack
    c = api.client
    first = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"}, headers=AUTH)
    second = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPI", "queue": True},
                    headers=AUTH)
    assert first.status_code == 202 and second.status_code == 202
    assert second.json()["state"] == "pending"
    t_end = time.monotonic() + 60
    while time.monotonic() < t_end:
        v = c.get(second.headers["location"]).json()
        if v["state"] in ("settled", "failed", "aborted"):
            break
        time.sleep(0.1)
    assert v["state"] == "settled" and v["from_grade"] == "OPII"
    assert c.get(first.headers["location"]).json()["state"] == "settled"


def test_abort_holds(stack):
    h, api = stack
    c = api.client
    tid = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII", "duration_h": 0.01},
                 headers=AUTH).json()["id"]
    time.sleep(0.2)
    r = c.delete(f"/api/v1/units/cstr/transitions/{tid}", headers=AUTH)
    assert r.status_code == 200 and r.json()["state"] == "aborted"
    st = c.get("/api/v1/units/cstr/status").json()
    assert st["grade"] is None
    ref = st["ref"]["y"]
    time.sleep(0.3)
    assert c.get("/api/v1/units/cstr/status").json()["ref"]["y"] == ref


@pytest.mark.parametrize("body", [{}, {"grade": ""}, {"grade": "OPII", "duration_h": -1},
                                  {"grade": "OPII", "extra": 1}, {"grade": 5}, "notjson"])
def test_malformed_bodies_are_422(stack, body):
    h, api = stack
    kw = {"content": body} if isinstance(body, str) else {"json": body}
    r = api.client.post("/api/v1/units/cstr/transitions", headers=AUTH, **kw)
    assert r.status_code == 422


def test_not_found_and_auth(stack):
    h, api = stack
    c = api.client
    assert c.get("/api/v1/units/nosuch/status").status_code == 404
    assert c.post("/api/v1/units/cstr/transitions", json={"grade": "mode9"},
                  headers=AUTH).status_code == 404
    assert c.get("/api/v1/units/cstr/transitions/abc").status_code == 404
    assert c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"}).status_code == 401
    r = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
               headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 401 and TOKEN not in r.text
    assert c.delete("/api/v1/units/cstr/transitions/abc").status_code == 401


def test_controller_gone_is_503(stack):
    h, api = stack
    h.stop_controller()
    t_end = time.monotonic() + 5
    while api.mesh.alive("cstr", "controller") and time.monotonic() < t_end:
        time.sleep(0.02)
    r = api.client.get("/api/v1/units/cstr/status")
    assert r.status_code == 503
    units = api.client.get("/api/v1/units").json()["units"]
    assert {"unit": "cstr", "plant": True, "controller": False} in units


def test_silent_controller_is_504_not_a_hang(stack):
    h, api = stack
    s = h.s_client
    q = s.declare_queryable(keys.cmd_all("mute"), lambda query: time.sleep(3.0))
    token = s.liveliness().declare_token(keys.alive("mute", "controller"))
    t_end = time.monotonic() + 5
    while not api.mesh.alive("mute", "controller") and time.monotonic() < t_end:
        time.sleep(0.02)
    t0 = time.monotonic()
    r = api.client.get("/api/v1/units/mute/status")
    assert r.status_code == 504
    assert time.monotonic() - t0 < 5
    q.undeclare()
    token.undeclare()


def test_disturbances_by_command(stack):
    h, api = stack
    c = api.client
    assert c.get("/api/v1/units/cstr/disturbances").json()["disturbances"] == {"x1f": 1.0}
    body = {"name": "x1f", "value": 1.1}  # the seed's Fig. 5.15: feed concentration +10 %
    assert c.post("/api/v1/units/cstr/disturbances", json=body).status_code == 401
    r = c.post("/api/v1/units/cstr/disturbances", json=body, headers=AUTH)
    assert r.status_code == 200 and r.json()["disturbances"] == {"x1f": 1.1}
    assert h.plant.runner.d[0] == 1.1
    assert c.post("/api/v1/units/cstr/disturbances", json={"name": "nope", "value": 1},
                  headers=AUTH).status_code == 404
    assert c.post("/api/v1/units/cstr/disturbances", json={"name": "x1f", "value": "x"},
                  headers=AUTH).status_code == 422
    assert c.get("/api/v1/units/nosuch/disturbances").status_code == 404
    # the operator client, as a user runs it
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "disturbance", "cstr", "x1f", "1.0", "--api",
         f"http://127.0.0.1:{api.port}", "--token", TOKEN, "--json"],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert h.plant.runner.d[0] == 1.0
    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "status", "cstr", "--api",
         f"http://127.0.0.1:{api.port}"], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "active model" in proc.stdout and "deadline misses" in \
        proc.stdout
