"""REST security: writes need the token, the token never shows up in logs or answers, the
api binds to loopback unless told otherwise, and the plant applies moves only from its
controller's sender id.
"""

import os
import subprocess
import sys
import time

import httpx
import pytest
from test_api import AUTH, TOKEN
from test_service_loop import Harness

from services.io import keys
from services.io.messages import MVMessage
from services.io.zenoh_session import free_port

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


BAD_AUTH = [
    {},
    {"Authorization": ""},
    {"Authorization": "Bearer"},
    {"Authorization": "Bearer wrong-token"},
    {"Authorization": f"Basic {TOKEN}"},
    {"Authorization": f"Bearer {TOKEN}x"},
    {"Authorization": f"Bearer {TOKEN[:-1]}"},
]


@pytest.mark.parametrize("headers", BAD_AUTH, ids=range(len(BAD_AUTH)))
def test_writes_without_the_token_are_refused_and_change_nothing(stack, headers):
    h, api = stack
    c = api.client
    before = c.get("/api/v1/units/cstr/transitions").json()
    r = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"}, headers=headers)
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert r.json()["detail"]
    assert c.get("/api/v1/units/cstr/transitions").json() == before
    # an abort of a real transition is refused as well
    tid = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
                 headers=AUTH).json()["id"]
    r = c.delete(f"/api/v1/units/cstr/transitions/{tid}", headers=headers)
    assert r.status_code == 401
    assert c.get(f"/api/v1/units/cstr/transitions/{tid}").json()["state"] in (
        "pending", "running", "settled")
    assert TOKEN not in r.text
    # reads stay open
    assert c.get("/api/v1/units/cstr/status").status_code == 200


def test_the_token_never_reaches_the_logs(tmp_path):
    """``ssmpc api`` with the token in its environment, every kind of request, then its
    whole output searched for the token."""
    token = "tok-" + os.urandom(12).hex()
    port = free_port()
    env = {**os.environ, "SSMPC_API_TOKEN": token}
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "api", "--port", str(port),
                             "--duration", "60"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().startswith("ready api")
        base = f"http://127.0.0.1:{port}"
        with httpx.Client(base_url=base, timeout=10) as c:
            good = {"Authorization": f"Bearer {token}"}
            bad = {"Authorization": f"Bearer {token}-not"}
            for headers in (good, bad, {}):
                c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
                       headers=headers)
                c.post("/api/v1/units/cstr/transitions", content=b"{not json",
                       headers=headers)
                c.delete("/api/v1/units/nope/transitions/x", headers=headers)
                r = c.get("/api/v1/units/cstr/status", headers=headers)
                assert token not in r.text
            assert token not in c.get("/openapi.json").text
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=30)
    assert token not in out and token not in err


def _listening(port: int) -> set[str]:
    """Local addresses (hex, as in /proc/net/tcp) listening on ``port``."""
    out = set()
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        try:
            lines = open(table).read().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            local, state = line.split()[1], line.split()[3]
            addr, p = local.rsplit(":", 1)
            if state == "0A" and int(p, 16) == port:
                out.add(addr)
    return out


@pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="needs Linux /proc/net/tcp")
@pytest.mark.parametrize("host, expected", [(None, {"0100007F"}), ("0.0.0.0", {"00000000"})])
def test_api_binds_to_loopback_unless_told(host, expected):
    port = free_port()
    argv = [sys.executable, "-m", "services.cli", "api", "--port", str(port), "--duration", "30"]
    env = {k: v for k, v in os.environ.items() if k != "SSMPC_API_TOKEN"}
    if host:  # beyond loopback only with a token (tests/test_config_errors.py)
        argv += ["--host", host]
        env["SSMPC_API_TOKEN"] = TOKEN
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            env=env)
    try:
        assert proc.stdout.readline().startswith("ready api")
        assert _listening(port) == expected  # 127.0.0.1 in /proc's byte order
    finally:
        proc.terminate()
        proc.wait(30)


@pytest.mark.skipif(not os.path.exists("/proc/net/tcp"), reason="needs Linux /proc/net/tcp")
def test_ssmpc_up_serves_the_api_on_loopback(tmp_path):
    port = free_port()
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "up", "--unit", "cstr",
                             "--port", str(port), "--duration", "60", "--state-dir",
                             str(tmp_path)], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True)
    try:
        t_end = time.monotonic() + 90
        line = ""
        while not line.startswith("ssmpc up:") and time.monotonic() < t_end:
            line = proc.stdout.readline()
            assert line, "ssmpc up exited before it was ready"
        assert _listening(port) == {"0100007F"}
    finally:
        proc.terminate()
        proc.wait(60)


def test_moves_from_another_sender_are_not_applied(tmp_path):
    h = Harness(tmp_path, lockstep=False, speed=10.0, telemetry=False)
    try:
        h.wait_samples(5)
        forged = MVMessage(unit="cstr", seq=2**62, meas_seq=0, u=(0.123,), sender="intruder")
        h.s_client.put(keys.mv("cstr"), forged.to_bytes())
        t_end = time.monotonic() + 5
        while h.plant.counters.rejected["sender"] == 0 and time.monotonic() < t_end:
            time.sleep(0.01)
        assert h.plant.counters.rejected["sender"] == 1
        assert h.plant.last_mv_seq < 2**62
        accepted = h.plant.counters.mv_accepted
        h.wait_samples(5)
        assert h.plant.counters.mv_accepted > accepted
    finally:
        h.close()
