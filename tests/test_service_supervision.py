"""``ssmpc up`` supervises its nodes: a controller killed with SIGKILL is restarted
(alarm line, backoff) while the plant keeps running; beyond the restart limit ``up``
stops with an error. A lost plant is an alarm in the controller's status."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import httpx
import pytest

from services.io.zenoh_session import free_port

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]
REPO = Path(__file__).resolve().parents[1]


def _role_pids(pid: int) -> dict[str, int]:
    out = {}
    for task in Path(f"/proc/{pid}/task").iterdir():
        for child in (task / "children").read_text().split():
            argv = Path(f"/proc/{child}/cmdline").read_bytes().split(b"\0")
            for role in (b"controller", b"plant", b"api", b"router"):
                if role in argv[3:5]:
                    out[role.decode()] = int(child)
    return out


class _Up:
    def __init__(self, tmp_path, *extra):
        self.port = free_port()
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "services.cli", "up", "--unit", "cstr", "--speed", "20",
             "--port", str(self.port), "--state-dir", str(tmp_path), "--lease-ms", "500",
             *extra], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.lines: list[str] = []
        self._t = threading.Thread(target=self._read, daemon=True)
        self._t.start()

    def _read(self):
        for line in self.proc.stdout:
            self.lines.append(line)

    def wait_line(self, prefix: str, n: int = 1, timeout: float = 120.0) -> None:
        t_end = time.monotonic() + timeout
        while sum(ln.startswith(prefix) for ln in self.lines) < n:
            assert self.proc.poll() is None or time.monotonic() < t_end, (
                f"no {prefix!r}: {''.join(self.lines)}")
            assert time.monotonic() < t_end, f"no {prefix!r}: {''.join(self.lines)}"
            time.sleep(0.05)

    def close(self):
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()


def _status(c: httpx.Client, until, timeout: float = 60.0) -> dict:
    """The controller's status through the API, polled until ``until(status)``."""
    t_end = time.monotonic() + timeout
    while True:
        r = c.get("/api/v1/units/cstr/status")
        if r.status_code == 200 and until(r.json()):
            return r.json()
        assert time.monotonic() < t_end, f"status never as awaited: {r.status_code} {r.text}"
        time.sleep(0.2)


def _router_endpoint(line: str) -> str:
    """The endpoint of a router's ``ready router ... listen=<endpoint> ...`` line."""
    return line.split("listen=")[1].split()[0]


def test_a_killed_controller_is_restarted_and_the_plant_keeps_running(tmp_path):
    up = _Up(tmp_path)
    try:
        up.wait_line("ssmpc up:")
        pids = _role_pids(up.proc.pid)
        assert set(pids) == {"controller", "plant", "api", "router"}
        os.kill(pids["controller"], signal.SIGKILL)
        up.wait_line("alarm: the controller node exited", timeout=30)
        up.wait_line("ready controller", n=2, timeout=120)
        after = _role_pids(up.proc.pid)
        assert all(after[r] == pids[r] for r in ("plant", "api", "router"))
        assert after["controller"] != pids["controller"]
        with httpx.Client(base_url=f"http://127.0.0.1:{up.port}", timeout=10) as c:
            first = _status(c, lambda st: st["sample"] > 0)["sample"]
            time.sleep(1.0)
            assert c.get("/api/v1/units/cstr/status").json()["sample"] > first
        # the controller's restart said so; the plant was never restarted
        assert not any(ln.startswith("alarm: the plant") for ln in up.lines)
        # a lost plant: an alarm in the controller's status within the lease
        os.kill(after["plant"], signal.SIGSTOP)
        try:
            with httpx.Client(base_url=f"http://127.0.0.1:{up.port}", timeout=10) as c:
                st = _status(c, lambda st: st.get("plant_alive") is False, timeout=20)
                assert st["plant_alive"] is False
                assert any("plant node lost" in a for a in st["alarms"])
        finally:
            os.kill(after["plant"], signal.SIGCONT)
    finally:
        up.close()


def test_a_killed_router_is_restarted_and_the_nodes_reconnect(tmp_path):
    """The router is a child of its own: its crash is an alarm and a restart on the same
    endpoint, not the end of ``up``; the nodes are not restarted, their sessions
    reconnect, and the loop runs on (the controller counts new samples, the plant is
    seen alive again) and carries a grade change acknowledged before the crash to its
    grade."""
    up = _Up(tmp_path)
    try:
        up.wait_line("ssmpc up:")
        pids = _role_pids(up.proc.pid)
        endpoint = _router_endpoint(next(ln for ln in up.lines
                                         if ln.startswith("ready router")))
        with httpx.Client(base_url=f"http://127.0.0.1:{up.port}", timeout=10) as c:
            before = _status(c, lambda st: st["sample"] > 0 and st["plant_alive"])["sample"]
            # a grade change acknowledged before the crash is carried through it: over
            # 180 process s (9 wall s at 20x), so the cut (about 2 wall s, 40 process s)
            # stays well inside the 3 x duration it is given to settle (over the default
            # 20 s, a cut of 60 process s once ended it "not settled within 3 x duration")
            r = c.post("/api/v1/units/cstr/transitions",
                       json={"grade": "OPII", "duration_h": 0.05})
            assert r.status_code == 202
            loc = r.headers["location"]
            os.kill(pids["router"], signal.SIGKILL)
            up.wait_line("alarm: the router node exited", timeout=30)
            up.wait_line("ready router", n=2, timeout=60)
            again = next(ln for ln in reversed(up.lines) if ln.startswith("ready router"))
            assert _router_endpoint(again) == endpoint
            st = _status(c, lambda st: st["plant_alive"] and st["sample"] > before + 20)
            t_end = time.monotonic() + 90
            while (v := c.get(loc).json())["state"] in ("pending", "running"):
                assert time.monotonic() < t_end, f"the grade change never ended: {v}"
                time.sleep(0.2)
            assert v["state"] == "settled", json.dumps(v)
            st = c.get("/api/v1/units/cstr/status").json()
            assert abs(st["cv"]["y"] - 5.0) < 0.05  # OPII's y (tests/test_service_up.py)
            assert any("plant node lost" in a for a in st["alarms"])  # the cut was seen
        after = _role_pids(up.proc.pid)
        assert after["router"] != pids["router"]
        assert all(after[r] == pids[r] for r in ("controller", "plant", "api"))
        assert up.proc.poll() is None and st["plant_alive"] is True
        assert not any(ln.startswith(("alarm: the controller", "alarm: the plant",
                                      "alarm: the api")) for ln in up.lines)
    finally:
        up.close()


def test_a_router_whose_port_was_taken_meanwhile_stops_up_with_an_error(tmp_path):
    """Another process binds the router's port while the crashed router waits for its
    restart: the nodes' endpoint is gone, so ``up`` stops everything with an error
    line naming the router, never a traceback."""
    import socket

    up = _Up(tmp_path)
    try:
        up.wait_line("ssmpc up:")
        line = next(ln for ln in up.lines if ln.startswith("ready router"))
        port = int(_router_endpoint(line).rsplit(":", 1)[1])
        pid = _role_pids(up.proc.pid)["router"]
        os.kill(pid, signal.SIGKILL)
        with socket.socket() as squatter:
            # SO_REUSEADDR, as the router's own listener has: the links the killed
            # router closed keep its port in TIME_WAIT
            squatter.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            t_end = time.monotonic() + 5
            while True:
                try:
                    squatter.bind(("127.0.0.1", port))
                    break
                except OSError:
                    assert time.monotonic() < t_end, "the dead router's port stayed bound"
                    time.sleep(0.01)
            squatter.listen()
            assert up.proc.wait(60) != 0
        err = up.proc.stderr.read()
        assert err.splitlines()[-1].startswith("error: router: node exited with code")
        assert "Traceback" not in err
        assert any(ln.startswith("alarm: the router node exited") for ln in up.lines)
    finally:
        up.close()


def test_up_gives_up_beyond_its_restart_limit(tmp_path):
    up = _Up(tmp_path, "--restart-limit", "1")
    try:
        up.wait_line("ssmpc up:")
        os.kill(_role_pids(up.proc.pid)["controller"], signal.SIGKILL)
        up.wait_line("ready controller", n=2, timeout=120)
        os.kill(_role_pids(up.proc.pid)["controller"], signal.SIGKILL)
        assert up.proc.wait(60) == 1
        err = up.proc.stderr.read()  # the nodes' log lines, then up's own error line
        assert err.splitlines()[-1].startswith("error: the controller node exited 2 times")
        assert "Traceback" not in err
    finally:
        up.close()
