"""Configuration errors of the node commands, run as a user runs them: ``error: ...`` on
stderr and exit 2, never a traceback, and nothing started.

An invalid or unknown-field Zenoh config, an empty ``SSMPC_API_TOKEN`` (it would
silently switch the write check off), a bind beyond loopback without a token, and a
unit configuration file with a value of the wrong JSON type in any field (and, for
every unit, each field checked in-process before any node starts).
"""

import dataclasses
import json
import os
import subprocess
import sys

import pytest

from services.io.zenoh_session import free_port

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

BAD_CONFIGS = {
    "not_json5": '{mode: "peer",\n',
    "unknown_field": '{mode: "peer", bogus_field: 1}\n',
    "unknown_nested_field": '{scouting: {multicast: {enabled: false, nonsense: 3}}}\n',
    "wrong_type": '{mode: 7}\n',
}


def _run(argv, env_over=None, timeout=120):
    env = {k: v for k, v in os.environ.items() if k != "SSMPC_API_TOKEN"}
    env.update(env_over or {})
    return subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True,
                          text=True, timeout=timeout, env=env)


def _is_config_error(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: "), proc.stderr[-2000:]
    assert "ready" not in proc.stdout
    for w in words:
        assert w in proc.stderr, proc.stderr


@pytest.mark.parametrize("role, kind", [("api", k) for k in sorted(BAD_CONFIGS)]
                         + [("plant", "not_json5"), ("controller", "unknown_field")])
def test_a_bad_zenoh_config_is_an_error_not_a_traceback(tmp_path, role, kind):
    conf = tmp_path / "zenoh.json5"
    conf.write_text(BAD_CONFIGS[kind])
    argv = [role, "--zenoh-config", str(conf), "--duration", "5"]
    if role == "api":
        argv += ["--port", str(free_port())]
    else:
        argv += ["--unit", "cstr"]
    if role == "controller":
        argv += ["--state-dir", str(tmp_path), "--no-telemetry"]
    proc = _run(argv)
    _is_config_error(proc, "zenoh_config")
    assert "/root/.cargo" not in proc.stderr  # the library's source path is no message


def test_a_missing_zenoh_config_is_an_error(tmp_path):
    proc = _run(["api", "--zenoh-config", str(tmp_path / "nope.json5"), "--port",
                 str(free_port()), "--duration", "5"])
    _is_config_error(proc, "zenoh_config")


@pytest.mark.parametrize("value", ["", "   "])
def test_an_empty_api_token_is_an_error(value):
    proc = _run(["api", "--port", str(free_port()), "--duration", "5"],
                {"SSMPC_API_TOKEN": value})
    _is_config_error(proc, "SSMPC_API_TOKEN")


def test_ssmpc_up_refuses_an_empty_api_token(tmp_path):
    proc = _run(["up", "--unit", "cstr", "--state-dir", str(tmp_path), "--port",
                 str(free_port()), "--duration", "5"], {"SSMPC_API_TOKEN": ""})
    _is_config_error(proc, "SSMPC_API_TOKEN")
    assert "starting" not in proc.stdout


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.0.2.10", "example.org"])
def test_a_bind_beyond_loopback_without_a_token_is_refused(host):
    proc = _run(["api", "--host", host, "--port", str(free_port()), "--duration", "5"])
    _is_config_error(proc, "host", "SSMPC_API_TOKEN")


def _serve_on_a_free_port(host: str, env: dict, tries: int = 3) -> tuple[str, str]:
    """Start the API on a port that was free a moment ago: (its first stdout line, its
    stderr if it stopped). Another process may take the port in between (the API then
    says "in use" and stops); that, and only that, is tried again on another port."""
    for _ in range(tries):
        argv = [sys.executable, "-m", "services.cli", "api", "--host", host, "--port",
                str(free_port()), "--duration", "20"]
        proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env=env)
        try:
            line = proc.stdout.readline()
            err = ""
            if not line:  # stdout closed: the process stopped; say why
                proc.wait(30)
                err = proc.stderr.read()
        finally:
            proc.terminate()
            proc.wait(30)
        if "in use" not in err:
            return line, err
    return line, err


@pytest.mark.parametrize("host", ["127.0.0.1", "localhost", "::1"])
def test_a_loopback_bind_needs_no_token(host):
    env = {k: v for k, v in os.environ.items() if k != "SSMPC_API_TOKEN"}
    line, err = _serve_on_a_free_port(host, env)
    assert line.startswith("ready api"), err or line


#: Values of each JSON type but the field's own (a name list, a number, text, ...).
WRONG_TYPES = ("x", ["a", 1], {"a": 1}, None, True, 5, -1.5, [])


def _unit_fields(unit):
    from services.registry import get_unit

    return json.loads(json.dumps(dataclasses.asdict(get_unit(unit))))


@pytest.mark.parametrize("unit", ["cstr", "bioreactor", "two_phase_reactor", "te"])
def test_every_unit_config_field_of_the_wrong_type_is_a_value_error(unit):
    """A field of a unit configuration file given a value of another JSON type: the
    configuration is refused with a ``ValueError`` naming the field (the commands' clear
    ``error:``), or it is taken and the unit's plant, grades and controller build from
    it; never another exception."""
    from controller.units.config import UnitConfig
    from services.registry import build_controller, build_plant, grade_setpoints

    good = _unit_fields(unit)
    failures, refused = [], 0
    for name in good:
        for value in WRONG_TYPES:
            data = {**good, name: value}
            try:
                cfg = UnitConfig.from_dict(data)
                plant = build_plant(cfg)
                grade_setpoints(cfg, plant)
                build_controller(cfg, plant)
            except ValueError:
                refused += 1
            except Exception as exc:
                failures.append((name, value, repr(exc)))
    assert not failures, failures[:10]
    assert refused >= len(good)  # every field refuses at least one wrong type


@pytest.mark.parametrize("field, value", [("budget_fraction", "x"), ("cvs", 5),
                                          ("initial_grade", "mode9"), ("cv_scales", ["a"])])
def test_a_unit_config_file_with_a_wrong_value_is_an_error(tmp_path, field, value):
    conf = tmp_path / "te.json"
    conf.write_text(json.dumps({field: value}))
    proc = _run(["controller", "--unit", "te", "--unit-config", str(conf), "--state-dir",
                 str(tmp_path), "--no-telemetry", "--duration", "5"])
    _is_config_error(proc, field)
