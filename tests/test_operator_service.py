"""Operator control over the real nodes and the REST API (TE, the state-shared MPC):
an MV in manual held by the plant, back to auto, the controller mode warm and on,
validation, and the settings surviving a controller restart."""

from __future__ import annotations

import time

import pytest
from test_api import TOKEN, ApiServer

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]

AUTH = {"Authorization": f"Bearer {TOKEN}"}


def _wait(pred, timeout=60.0, what="condition"):
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def _variable(api, name):
    st = api.client.get("/api/v1/units/te/status").json()
    return next(v for v in st["variables"] if v["name"] == name), st


@pytest.fixture
def te(te_api):
    return te_api


def test_an_mv_in_manual_is_held_by_the_plant_and_released(te):
    h, api = te
    h.wait_samples(20, timeout=120)
    j = h.ctrl.info.mv_names.index("XMV3")
    value = round(float(h.plant.status()["u"][j]) + 1.0, 3)
    r = api.client.patch("/api/v1/units/te/variables/XMV3", headers=AUTH,
                         json={"mode": "manual", "value": value})
    assert r.status_code == 200, r.text
    assert (r.json()["mode"], r.json()["target"]) == ("manual", value)
    # the plant applies the held value (after its rate limit lets it get there) and keeps it
    _wait(lambda: h.plant.status()["u"][j] == value, what="the plant at the held value")
    h.wait_samples(10, timeout=60)
    assert h.plant.status()["u"][j] == value
    v, st = _variable(api, "XMV3")
    assert (v["mode"], v["value"], v["target"]) == ("manual", value, value)
    # back to auto: the controller moves it again, starting from the held value
    r = api.client.patch("/api/v1/units/te/variables/XMV3", headers=AUTH, json={"mode": "auto"})
    assert r.status_code == 200 and r.json()["mode"] == "auto"
    _wait(lambda: h.plant.status()["u"][j] != value, what="XMV3 moved by the controller")
    assert abs(h.plant.status()["u"][j] - value) < 5.0


def test_controller_mode_warm_writes_nothing_and_on_writes_again(te):
    h, api = te
    h.wait_samples(20, timeout=120)
    r = api.client.put("/api/v1/units/te/mode", headers=AUTH, json={"mode": "warm"})
    assert r.status_code == 200, r.text
    assert r.json() == {"unit": "te", "mode": "warm", "previous": "on"}
    h.wait_samples(3, timeout=60)
    accepted = h.plant.status()["mv_accepted"]
    h.wait_samples(10, timeout=60)
    assert h.plant.status()["mv_accepted"] == accepted  # no move written
    st = api.client.get("/api/v1/units/te/status").json()
    assert st["controller_mode"] == "warm" and st["computed_mv"] is not None
    assert st["mv"] == pytest.approx(dict(zip(h.ctrl.info.mv_names, h.plant.status()["u"])),
                                     abs=1e-9)  # the status shows what the plant holds
    r = api.client.put("/api/v1/units/te/mode", headers=AUTH, json={"mode": "on"})
    assert r.status_code == 200 and r.json()["previous"] == "warm"
    _wait(lambda: h.plant.status()["mv_accepted"] > accepted + 3, what="moves written again")
    assert api.client.get("/api/v1/units/te/status").json()["controller_mode"] == "on"


def test_operator_commands_are_validated(te):
    h, api = te
    h.wait_samples(5, timeout=120)
    c = api.client
    cases = [
        ("XMV99", {"mode": "auto"}, 404, "no variable"),
        ("XMV3", {"lo": 60.0, "hi": 40.0}, 422, "lo"),
        ("XMV3", {"hi": 120.0}, 422, "engineering range"),
        ("XMEAS7", {"mode": "manual"}, 422, "cannot be 'manual'"),
        ("XMEAS1", {"mode": "off"}, 422, "measured only"),
        ("XMEAS11", {"hi": 80.0}, 422, "no operator limits"),
        ("XMV3", {"mode": "auto", "speed": 1}, 422, "speed"),
        ("XMV3", {"value": True}, 422, "value"),
        ("XMV3", {}, 422, "nothing to change"),
    ]
    for name, body, code, text in cases:
        r = c.patch(f"/api/v1/units/te/variables/{name}", headers=AUTH, json=body)
        assert r.status_code == code, (name, body, r.text)
        assert text in r.json()["detail"], (name, body, r.text)
    # the reactor pressure takes limits: they go to the steady-state targets
    r = c.patch("/api/v1/units/te/variables/XMEAS7", headers=AUTH, json={"hi": 2800.0})
    assert r.status_code == 200, r.text
    v, _ = _variable(api, "XMEAS7")
    assert v["hi"] == 2800.0
    h.wait_samples(2, timeout=60)
    st = c.get("/api/v1/units/te/status").json()  # the targets the MPC steers to
    assert st["targets"]["status"] in ("optimal", "relaxed")
    assert set(st["targets"]["mv"]) == {"XMV3", "XMV4", "Pr_sp", "Tr_sp", "XMV11"}
    assert st["targets"]["cv"]["XMEAS7"] <= 2800.0 + 1e-6
    r = c.patch("/api/v1/units/te/variables/XMV3", headers=AUTH,
                content=b'{"lo": NaN}', )
    assert r.status_code == 422
    assert c.put("/api/v1/units/te/mode", headers=AUTH, json={"mode": "auto"}).status_code == 422
    assert c.put("/api/v1/units/te/mode", json={"mode": "off"}).status_code == 401
    assert c.patch("/api/v1/units/te/variables/XMV3", json={"mode": "auto"}).status_code == 401
    doc = c.get("/openapi.json").json()
    assert "patch" in doc["paths"]["/api/v1/units/{unit}/variables/{name}"]
    assert "put" in doc["paths"]["/api/v1/units/{unit}/mode"]


def test_operator_settings_survive_a_controller_restart(te):
    h, api = te
    h.wait_samples(10, timeout=120)
    c = api.client
    assert c.patch("/api/v1/units/te/variables/reactor_pressure_sp", headers=AUTH,
                   json={"hi": 2800.0, "ramp_per_h": 50.0}).status_code == 200
    assert c.patch("/api/v1/units/te/variables/XMEAS18", headers=AUTH,
                   json={"mode": "off"}).status_code == 200
    assert c.put("/api/v1/units/te/mode", headers=AUTH, json={"mode": "warm"}).status_code == 200
    h.stop_controller()
    h.start_controller()
    _wait(lambda: api.mesh.alive("te", "controller"), what="the controller back")
    h.wait_samples(3, timeout=120)
    v, st = _variable(api, "XMEAS18")
    assert st["controller_mode"] == "warm" and v["mode"] == "off"
    p, _ = _variable(api, "reactor_pressure_sp")
    # the high limit ramps from 2950 toward 2800 at 50 kPa/h: between the two
    assert 2800.0 <= p["hi"] < 2950.0


def _cli(api, *argv):
    import subprocess
    import sys

    extra = ["--api", f"http://127.0.0.1:{api.port}", "--token", TOKEN]
    return subprocess.run([sys.executable, "-m", "services.cli", *argv, *extra],
                          capture_output=True, text=True, timeout=60)


def test_mode_and_variable_from_the_command_line(te, capsys):
    import json

    from services.cli.entry import main

    h, api = te
    h.wait_samples(5, timeout=120)
    ok = _cli(api, "variable", "te", "XMV11", "--mode", "manual", "--value", "20", "--json")
    assert ok.returncode == 0, ok.stderr
    v = json.loads(ok.stdout.strip().splitlines()[-1])
    assert (v["name"], v["mode"], v["target"]) == ("XMV11", "manual", 20.0)
    extra = ["--api", f"http://127.0.0.1:{api.port}", "--token", TOKEN]
    assert main(["mode", "te", "warm", *extra]) == 0  # in-process: no interpreter start
    assert "on -> warm" in capsys.readouterr().out
    for argv, text in ((("variable", "te", "XMV11", "--lo", "60", "--hi", "40"), "422"),
                       (("variable", "te", "XMV11"), "nothing to change"),
                       (("variable", "te", "XMV11", "--hi", "nan"), "finite"),
                       (("variable", "te", "NOPE", "--mode", "auto"), "404")):
        assert main([*argv, *extra]) == 2, argv
        err = capsys.readouterr().err
        assert err.startswith("error:") and text in err, (argv, err)
    with pytest.raises(SystemExit) as exc:  # argparse's own refusal, exit 2
        main(["mode", "te", "standby", *extra])
    assert exc.value.code == 2 and "invalid choice" in capsys.readouterr().err


def test_an_operator_action_the_store_cannot_commit_is_503_and_not_applied(harness):

    # the CSTR unit (MV u, CV y). A command's checkpoint waits behind the loop's own
    # writes, each failing after the 1 s busy timeout while the store is locked: the loop
    # checkpoints here only on its wall-clock period (5 s), and the api waits longer
    # than its default 2 s to hear the 503
    h = harness(telemetry=False, checkpoint_every=10**9)
    api = ApiServer(h, timeout_s=8.0)
    try:
        _store_locked_then_free(h, api)
    finally:
        api.close()


def _store_locked_then_free(h, api):
    import sqlite3

    c = api.client
    h.wait_samples(3)
    other = sqlite3.connect(str(h.store_path), isolation_level=None)
    other.execute("BEGIN IMMEDIATE")  # another process holds the write lock
    try:
        r = c.patch("/api/v1/units/cstr/variables/u", headers=AUTH,
                    json={"mode": "manual", "value": 1.0})
        assert r.status_code == 503 and "store" in r.json()["detail"], r.text
        v, _ = _variable_of(api, "cstr", "u")
        assert v["mode"] == "auto"  # not applied
    finally:
        other.execute("ROLLBACK")
        other.close()
    r = c.patch("/api/v1/units/cstr/variables/u", headers=AUTH,
                json={"mode": "manual", "value": 1.0})
    assert r.status_code == 200 and r.json()["mode"] == "manual"
    # the CSTR's controller offers no CV modes: refused with the reason
    r = c.patch("/api/v1/units/cstr/variables/y", headers=AUTH, json={"mode": "off"})
    assert r.status_code == 422 and "no CV modes" in r.json()["detail"]
    _wait(lambda: h.plant.status()["u"][0] == 1.0, what="the CSTR's u held at 1.0")


def _variable_of(api, unit, name):
    st = api.client.get(f"/api/v1/units/{unit}/status").json()
    return next(v for v in st["variables"] if v["name"] == name), st


def test_no_transition_without_the_controller_on_and_no_warm_during_one(stack):
    h, api = stack
    c = api.client
    h.wait_samples(3)
    post = "/api/v1/units/cstr/transitions"
    tid = c.post(post, headers=AUTH, json={"grade": "OPII", "duration_h": 1.0}).json()["id"]
    r = c.put("/api/v1/units/cstr/mode", headers=AUTH, json={"mode": "warm"})
    assert r.status_code == 409 and tid in r.json()["detail"], r.text
    assert c.delete(f"{post}/{tid}", headers=AUTH).status_code == 200
    assert c.put("/api/v1/units/cstr/mode", headers=AUTH, json={"mode": "off"}).status_code == 200
    r = c.post(post, headers=AUTH, json={"grade": "OPIII"})
    assert r.status_code == 409 and "off" in r.json()["detail"], r.text
    assert c.put("/api/v1/units/cstr/mode", headers=AUTH, json={"mode": "on"}).status_code == 200
    assert c.post(post, headers=AUTH, json={"grade": "OPIII"}).status_code == 202
