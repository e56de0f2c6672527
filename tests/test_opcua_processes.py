"""The OPC UA link between processes, as a user runs it: ``ssmpc up --io opcua`` with a
grade change over REST, and a controller process killed (SIGKILL) under a running
``ssmpc opcua`` plant, seen by a plain asyncua client: shed and hold within the
watchdog time."""

import asyncio
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256

from services.io.opcua.settings import NAMESPACE_URI
from services.io.zenoh_session import free_port, free_tcp_endpoint

pytestmark = [pytest.mark.integration, pytest.mark.slow, pytest.mark.timeout(300)]

REPO = Path(__file__).resolve().parents[1]
WATCHDOG_S = 1.5


def _spawn(argv):
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    return subprocess.Popen([sys.executable, "-m", "services.cli", *argv], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _ready(proc, prefix="ready", timeout=150):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        line = proc.stdout.readline()
        assert line, f"exited early: {proc.stderr.read()}"
        if line.startswith(prefix):
            return line
    raise AssertionError("not ready in time")


def _stop(*procs):
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    for p in procs:
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def test_up_io_opcua_grade_change_over_rest(tmp_path):
    port = free_port()
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/ssmpc"
    proc = _spawn(["up", "--unit", "cstr", "--io", "opcua", "--opcua-endpoint", endpoint,
                   "--speed", "2", "--port", str(port), "--state-dir", str(tmp_path),
                   "--duration", "200"])
    try:
        _ready(proc, "ssmpc up:")
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as c:
            r = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"})
            assert r.status_code == 202
            t_end = time.monotonic() + 90
            while time.monotonic() < t_end:
                v = c.get(r.headers["location"]).json()
                if v["state"] not in ("pending", "running"):
                    break
                time.sleep(0.2)
            assert v["state"] == "settled"
            assert abs(c.get("/api/v1/units/cstr/status").json()["cv"]["y"] - 5.0) < 0.1
    finally:
        _stop(proc)
    assert proc.returncode == 0
    assert (tmp_path / "opcua" / "ca.pem").exists()


async def _watch(endpoint, cert_dir, seconds):
    """(wall s, WatchdogState, Sample, AppliedMoves) every 50 ms for ``seconds``."""
    c = Client(endpoint, timeout=10)
    c.application_uri = "urn:ssmpc:operator"
    await c.set_security(SecurityPolicyBasic256Sha256, f"{cert_dir}/operator.pem",
                         f"{cert_dir}/operator-key.pem", server_certificate=f"{cert_dir}/plant.pem",
                         mode=ua.MessageSecurityMode.SignAndEncrypt)
    await c.load_client_certificate(f"{cert_dir}/operator.pem")
    await c.load_private_key(f"{cert_dir}/operator-key.pem")
    out = []
    async with c:
        ns = await c.get_namespace_index(NAMESPACE_URI)
        nodes = [c.get_node(ua.NodeId(f"cstr.Status.{n}", ns))
                 for n in ("WatchdogState", "Sample", "AppliedMoves")]
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            out.append((time.monotonic(), *await c.read_values(nodes)))
            await asyncio.sleep(0.05)
    return out


def test_killed_controller_process_sheds_and_holds(tmp_path):
    endpoint = f"opc.tcp://127.0.0.1:{free_port()}/ssmpc"
    ep = free_tcp_endpoint()
    link = ["--opcua-endpoint", endpoint, "--opcua-cert-dir", str(tmp_path / "opcua"),
            "--watchdog", str(WATCHDOG_S)]
    plant = _spawn(["opcua", "--unit", "cstr", "--listen", ep, *link])
    ctrl = None
    try:
        _ready(plant)
        ctrl = _spawn(["controller", "--unit", "cstr", "--connect", ep, "--plant-io", "opcua",
                       "--heartbeat", "0.3", "--state-dir", str(tmp_path), "--no-telemetry",
                       *link])
        _ready(ctrl)
        cert_dir = str(tmp_path / "opcua")
        before = asyncio.run(_watch(endpoint, cert_dir, 1.0))
        assert before[-1][1] == "ok"
        ctrl.send_signal(signal.SIGKILL)
        t_kill = time.monotonic()
        after = asyncio.run(_watch(endpoint, cert_dir, WATCHDOG_S + 3.0))
    finally:
        _stop(*(p for p in (ctrl, plant) if p is not None))
    shed = [row for row in after if row[1] == "shed"]
    assert shed, "the plant never shed"
    assert shed[0][0] - t_kill < WATCHDOG_S + 1.0
    # held: the plant samples on (its regulatory layer, if any, keeps running), moves fixed
    assert shed[-1][2] > shed[0][2]
    assert all(row[3] == shed[0][3] for row in shed)


def test_bench_loop_reports_the_opcua_case(capsys):
    import json

    from services.cli import main

    assert main(["bench", "loop", "--json", "--unit", "cstr", "--cases", "opcua",
                 "--latency-seconds", "2"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (case,) = doc["cases"]
    assert case["case"] == "opcua" and case["unit"] == "us" and case["n"] > 0
    assert 0 < case["median"] <= case["p99"] <= case["max"]
    assert case["sheds"] == 0 and "SignAndEncrypt" in case["link"]
