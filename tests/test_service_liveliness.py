"""A controller process killed with SIGKILL: its liveliness token expires with the lease,
the api answers 503 (never hangs), the plant holds its last move and says so."""

import signal
import subprocess
import time

import httpx
import pytest

from services.io import keys
from services.io.messages import Reply, Request
from services.io.zenoh_session import (
    SessionSettings,
    free_port,
    free_tcp_endpoint,
    open_session,
)
from services.nodes.supervisor import start_on_free_ports

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

LEASE_MS = 1000


def test_killed_controller_gives_503_and_plant_holds(tmp_path):
    # each node's ports are picked as it starts, and picked again if one was taken
    ep = {}
    common = ["--unit", "cstr", "--speed", "20", "--lease-ms", str(LEASE_MS)]

    def fresh(*names):
        for name in names:
            ep[name] = free_port() if name == "http" else free_tcp_endpoint()

    def controller():
        fresh("c")
        return ["controller", *common, "--listen", ep["c"], "--state-dir", str(tmp_path),
                "--no-telemetry"]

    def plant():
        fresh("p")
        return ["plant", *common, "--listen", ep["p"], "--connect", ep["c"]]

    def api():
        fresh("a", "http")
        return ["api", "--listen", ep["a"], "--connect", ep["c"], "--connect", ep["p"],
                "--lease-ms", str(LEASE_MS), "--port", str(ep["http"]),
                "--query-timeout", "1.0"]

    procs = []
    try:
        deadline = time.monotonic() + 120
        for role, argv in (("controller", controller), ("plant", plant), ("api", api)):
            procs.append(start_on_free_ports(argv, role, deadline))
        ep_p, port = ep["p"], ep["http"]
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as c:
            t_end = time.monotonic() + 10
            while c.get("/api/v1/units/cstr/status").status_code != 200:
                assert time.monotonic() < t_end
                time.sleep(0.1)
            procs[0].send_signal(signal.SIGKILL)
            procs[0].wait()
            t0 = time.monotonic()
            codes = []
            while time.monotonic() - t0 < 15:
                t_req = time.monotonic()
                r = c.get("/api/v1/units/cstr/status")
                assert time.monotonic() - t_req < 5.0  # answered, never a hang
                codes.append(r.status_code)
                if r.status_code == 503:
                    break
                time.sleep(0.1)
            assert codes[-1] == 503, codes
            assert set(codes) <= {504, 503}
            units = c.get("/api/v1/units").json()["units"]
            assert {"unit": "cstr", "plant": True, "controller": False} in units
        # the plant keeps running on its last move and reports the lost controller
        session = open_session(SessionSettings(connect=(ep_p,)))
        try:
            time.sleep(0.5)

            def plant_status():
                rs = list(session.get(keys.plant_cmd("cstr", "status"),
                                      payload=Request("status").to_bytes(), timeout=5))
                return Reply.from_bytes(rs[0].ok.payload.to_bytes()).data

            first = plant_status()
            time.sleep(0.5)
            second = plant_status()
            assert first["controller_alive"] is False
            assert second["sample"] > first["sample"]
            assert second["mv_held"] > first["mv_held"]
            assert second["u"] == first["u"]
        finally:
            session.close()
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
