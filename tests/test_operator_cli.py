"""The operator's command line against a real api server and real nodes: transition
(--queue), abort, and the status text view (fits 100 columns, marks limits)."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import pytest

from services.cli.operator import STATUS_WIDTH, status_lines

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

TOKEN = "s3cret-token"  # the token tests/test_api.py's server is started with


def _cli(api, *argv, token=True):
    extra = ["--api", f"http://127.0.0.1:{api.port}"] + (["--token", TOKEN] if token else [])
    return subprocess.run([sys.executable, "-m", "services.cli", *argv, *extra],
                          capture_output=True, text=True, timeout=60)


def _last_json(proc):
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def test_transition_queue_and_abort_from_the_command_line(stack):
    h, api = stack
    first = _last_json(_cli(api, "transition", "cstr", "OPII", "--duration-h", "1", "--json"))
    assert first["state"] in ("pending", "running")
    # a second one without --queue is refused (409), with --queue it waits
    refused = _cli(api, "transition", "cstr", "OPIII")
    assert refused.returncode == 2 and refused.stderr.startswith("error:")
    assert "409" in refused.stderr and "Traceback" not in refused.stderr
    queued = _last_json(_cli(api, "transition", "cstr", "OPI", "--queue", "--json"))
    assert queued["state"] == "pending"
    t_end = time.monotonic() + 30
    while h.query("transition", {"op": "get", "id": first["id"]}).data["state"] != "running":
        assert time.monotonic() < t_end
        time.sleep(0.05)
    aborted = _last_json(_cli(api, "abort", "cstr", "--json"))
    assert aborted["id"] == first["id"] and aborted["state"] == "aborted"
    # then the queued one runs; abort it by id
    t_end = time.monotonic() + 30
    while h.query("transition", {"op": "get", "id": queued["id"]}).data["state"] == "pending":
        assert time.monotonic() < t_end
        time.sleep(0.05)
    by_id = _last_json(_cli(api, "abort", "cstr", queued["id"], "--json"))
    assert by_id["id"] == queued["id"] and by_id["state"] in ("aborted", "settled")
    nothing = _cli(api, "abort", "cstr")
    assert nothing.returncode == 2 and "no transition under way" in nothing.stderr


def test_status_text_view_fits_and_marks_limits(stack):
    h, api = stack
    h.wait_samples(5)
    proc = _cli(api, "status", "cstr", "--all", token=False)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert all(len(ln) <= STATUS_WIDTH for ln in lines), max(lines, key=len)
    assert any(ln.startswith("y ") for ln in lines) and any(ln.startswith("u ") for ln in lines)
    # the models' index read as prediction errors, the active model by name
    model_line = next(ln for ln in lines if ln.startswith("active model "))
    assert "prediction error (RMS, CV scales)" in model_line
    # a status with an MV at its upper limit and an alarm naming a CV: both are marked
    st = json.loads(_cli(api, "status", "cstr", "--json", token=False).stdout.splitlines()[-1])
    for v in st["variables"]:
        if v["name"] == "u":
            v["value"], v["at_limit"] = v["hi"], "hi"
    st["alarms"] = ["y above its alarm limit"]
    view = status_lines(st)
    row_u = next(ln for ln in view if ln.startswith("u "))
    row_y = next(ln for ln in view if ln.startswith("y "))
    assert row_u.rstrip().endswith("HI") and row_y.rstrip().endswith("!")
