"""The KPIs over the real nodes and the real HTTP server: ``GET .../kpis`` and
``ssmpc kpis`` on a CSTR unit (service factor ON, lowered by a WARM period, fallbacks as
the status counts them, the counts going on over a controller restart) and on TE (the
Downs & Vogel cost against the base case, every CV and MV, the models' errors)."""

from __future__ import annotations

import subprocess
import sys
import time

import pytest
from test_api import TOKEN, ApiServer

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]

AUTH = {"Authorization": f"Bearer {TOKEN}"}
# docs/facts/te.md section 9: Downs & Vogel's base case, about 170.6 $/h
TE_BASE_CASE_USD_H = 170.6


def _since_start(doc):
    return next(w for w in doc["windows"] if w["window"] == "since start")


def _samples_in(w, period_s):
    """The window's time in samples of the unit's period, by state."""
    n = w["hours"] * 3600.0 / period_s
    return {k: v * n for k, v in w["time_share"].items()}


def _wait(pred, timeout=60.0, what="condition"):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out waiting for {what}")


def _stop_plant(h):
    h.stop_plant.set()
    h.plant_thread.join(5)
    h.plant.close()
    h.plant = None


def _cli(api, *argv):
    return subprocess.run([sys.executable, "-m", "services.cli", *argv,
                           "--api", f"http://127.0.0.1:{api.port}"],
                          capture_output=True, text=True, timeout=60)


@pytest.fixture
def cstr(harness):
    # 1x, in real time (20 samples a second; lock step would wait for moves in WARM): a
    # 25 ms budget, so that a loaded machine rarely makes a held move
    h = harness(unit="cstr", speed=1.0, lockstep=False, telemetry=False)
    api = ApiServer(h)
    yield h, api
    api.close()


def test_service_factor_on_warm_and_over_a_restart(cstr):
    h, api = cstr
    c = api.client
    period = h.cfg.sample_period_s
    h.wait_samples(30)
    with h.ctrl._lock:  # a sample's counts and the status' go in under this lock together
        on_only = _since_start(h.ctrl.kpis.report())
        fallbacks, samples = h.ctrl.stats.fallbacks, h.ctrl.stats.samples
    # ON: 1.0 but for the held moves (on a loaded machine, a missed deadline)
    assert on_only["service_factor"] == pytest.approx(1.0 - fallbacks / samples)
    assert c.put("/api/v1/units/cstr/mode", headers=AUTH, json={"mode": "warm"}).status_code \
        == 200
    k_warm = h.ctrl.k
    h.wait_samples(40)
    assert c.put("/api/v1/units/cstr/mode", headers=AUTH, json={"mode": "on"}).status_code == 200
    k_on = h.ctrl.k
    h.wait_samples(30)
    _stop_plant(h)  # no more samples: the KPIs and the status hold still
    r = c.get("/api/v1/units/cstr/kpis")  # a GET, without the token the api has
    assert r.status_code == 200, r.text
    doc, st = r.json(), c.get("/api/v1/units/cstr/status").json()
    w = _since_start(doc)
    assert doc["samples"] == st["samples"] and doc["sample"] == st["sample"]
    share = _samples_in(w, period)
    # every sample is one period of ON, ON in fallback (held, as the status counts) or WARM
    assert share["off"] == 0.0 and share["down"] == 0.0
    assert share["fallback"] == pytest.approx(st["fallback_moves"], abs=1e-6)
    assert abs(share["warm"] - (k_on - k_warm)) <= 2
    assert share["on"] + share["fallback"] + share["warm"] == pytest.approx(doc["samples"])
    assert w["service_factor"] == pytest.approx(share["on"] / doc["samples"])
    assert w["service_factor"] < 1.0 - 35 / doc["samples"]  # the WARM period counts against
    assert w["samples_on"] == doc["samples"] - round(share["warm"])
    # the process hour holds all of it; no cost for the CSTR
    one = next(x for x in doc["windows"] if x["window"] == "1 h")
    assert one["time_share"] == pytest.approx(w["time_share"])
    assert w["cost"]["mean_usd_h"] is None and doc["base_cost_usd_h"] is None
    assert set(w["prediction_rms"]) == set(st["J"])
    activity = {a["name"]: a for a in w["constraint_activity"]}
    assert set(activity) == {"y", "u"} and activity["u"]["kind"] == "mv"

    # a controller restart goes on counting from the checkpoint
    h.stop_controller()
    h.start_controller()
    _wait(lambda: api.mesh.alive("cstr", "controller"), what="the controller back")
    again = c.get("/api/v1/units/cstr/kpis").json()
    assert again["windows"] == doc["windows"] and again["samples"] == doc["samples"]
    h.stop_plant.clear()
    h.start_plant()  # a fresh plant counts its samples and time from 0: one period each
    _wait(lambda: h.ctrl.kpi_report()["samples"] >= doc["samples"] + 20,
          what="20 samples of the new plant")
    _stop_plant(h)
    later = c.get("/api/v1/units/cstr/kpis").json()
    w2 = _since_start(later)
    share2 = _samples_in(w2, period)
    assert later["samples"] > doc["samples"] + 15
    assert share2["warm"] == pytest.approx(share["warm"])  # no more WARM: the same time
    assert share2["down"] == 0.0
    assert sum(share2.values()) == pytest.approx(later["samples"])

    # the controller away for a second while the plant runs on (20 samples a second): the
    # samples it missed are time without a controller, against the service factor
    h.stop_plant.clear()
    h.start_plant()
    _wait(lambda: h.ctrl.kpi_report()["samples"] >= later["samples"] + 10, what="samples")
    h.stop_controller()
    time.sleep(1.0)
    h.start_controller()
    n_back = h.ctrl.kpi_report()["samples"]
    _wait(lambda: h.ctrl.kpi_report()["samples"] >= n_back + 10, what="samples after")
    _stop_plant(h)
    last = _since_start(c.get("/api/v1/units/cstr/kpis").json())
    down = _samples_in(last, period)["down"]
    assert down >= 10  # 20 a second, less the start of the node and its first period
    assert last["service_factor"] < w2["service_factor"]


def test_kpis_cli_and_errors(cstr):
    h, api = cstr
    h.wait_samples(10)
    out = _cli(api, "kpis", "cstr")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("cstr  sample ")
    assert any(ln.startswith("since start") for ln in lines)
    assert any(ln.startswith("M2 ") for ln in lines)  # a model's prediction error
    assert max(len(ln) for ln in lines) <= 100
    js = _cli(api, "kpis", "cstr", "--json")
    assert js.returncode == 0 and '"windows"' in js.stdout.splitlines()[-1]
    bad = _cli(api, "kpis", "nope")
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and "404" in bad.stderr
    assert "Traceback" not in bad.stderr
    c = api.client
    assert c.get("/api/v1/units/nope/kpis").status_code == 404
    assert c.get("/api/v1/units/c%20c/kpis").status_code in (404, 422)
    doc = c.get("/openapi.json").json()
    op = doc["paths"]["/api/v1/units/{unit}/kpis"]["get"]
    assert op["summary"] and op["description"]
    ref = op["responses"]["200"]["content"]["application/json"]["schema"]["$ref"]
    assert ref.endswith("/KPIsView")
    assert "service_factor" in doc["components"]["schemas"]["KPIWindowView"]["properties"]


@pytest.fixture
def te(te_api):
    return te_api


def test_te_kpis_cost_against_the_base_case(te):
    h, api = te
    h.wait_samples(20, timeout=120)
    r = api.client.get("/api/v1/units/te/kpis")
    assert r.status_code == 200, r.text
    doc = r.json()
    st = api.client.get("/api/v1/units/te/status").json()
    assert doc["base_cost_usd_h"] == TE_BASE_CASE_USD_H
    assert "Downs & Vogel" in doc["base_cost_origin"]
    w = _since_start(doc)
    # held at mode 0, the base case: its cost, within the noise of a few samples
    assert abs(doc["cost_now_usd_h"] - TE_BASE_CASE_USD_H) < 15.0
    assert abs(w["cost"]["vs_base_usd_h"]) < 10.0
    assert w["cost"]["vs_base_usd_h"] == pytest.approx(
        w["cost"]["mean_usd_h"] - TE_BASE_CASE_USD_H)
    names = {a["name"] for a in w["constraint_activity"]}
    assert names == {v["name"] for v in st["variables"] if v["kind"] in ("cv", "mv")}
    assert len(names) == 53  # 41 XMEAS, 12 MVs
    assert set(w["prediction_rms"]) == set(st["prediction_rms"])
    assert all(v is None or v >= 0 for v in w["prediction_rms"].values())
    assert w["service_factor"] is not None and w["service_factor"] > 0.5


def _edit_checkpoint(path, edit):
    import json
    import sqlite3

    db = sqlite3.connect(str(path))
    state = json.loads(db.execute("SELECT state FROM checkpoint").fetchone()[0])
    edit(state)
    db.execute("UPDATE checkpoint SET state=?", (json.dumps(state),))
    db.commit()
    db.close()


def test_kpis_of_a_checkpoint_that_do_not_fit_are_refused_and_old_ones_start_afresh(tmp_path):
    from test_service_loop import Harness

    h = Harness(tmp_path, telemetry=False)
    h.wait_samples(10)
    h.close()
    target = tmp_path / "ssmpc-cstr.sqlite"
    h.store_path.rename(target)

    def wrong(state):  # counts of another unit's variables
        state["kpis"]["variables"] = [["XMEAS7", "cv"]]

    _edit_checkpoint(target, wrong)
    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "controller", "--unit", "cstr", "--state-dir",
         str(tmp_path), "--no-telemetry", "--duration", "3"],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: ") and "kpis" in proc.stderr
    assert "Traceback" not in proc.stderr

    _edit_checkpoint(target, lambda state: state.pop("kpis"))  # a checkpoint from before
    target.rename(h.store_path)
    h2 = Harness(tmp_path, telemetry=False)
    try:
        h2.wait_samples(5)
        assert h2.ctrl.restored_from is not None  # the rest of the checkpoint was taken
        with h2.ctrl._lock:  # the KPIs count this start's samples, as the status does
            assert h2.ctrl.kpis.acc.samples == h2.ctrl.stats.samples >= 5
    finally:
        h2.close()
