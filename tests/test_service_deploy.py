"""deploy/: every Zenoh config parses with the installed Zenoh (which validates keys and
enum values), and the router config opens a real router session."""

from pathlib import Path

import pytest
import zenoh

DEPLOY = Path(__file__).resolve().parents[1] / "deploy"
CONFIGS = sorted((DEPLOY / "zenoh").glob("*.json5"))


def test_there_are_configs_for_each_mode():
    names = {p.name for p in CONFIGS}
    assert {"router.json5", "client.json5", "peer-loopback.json5", "router-tls.json5",
            "router-acl.json5", "router-usrpwd-acl.json5"} <= names


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: p.name)
def test_config_is_valid_for_zenoh(path):
    zenoh.Config.from_file(str(path))


def test_a_typo_in_a_config_is_caught(tmp_path):
    bad = tmp_path / "bad.json5"
    bad.write_text((DEPLOY / "zenoh" / "router-acl.json5").read_text()
                   .replace('"reply"', '"replyy"', 1))
    with pytest.raises(zenoh.ZError):
        zenoh.Config.from_file(str(bad))


def test_router_config_opens_a_router(tmp_path):
    from services.io.zenoh_session import free_port

    text = (DEPLOY / "zenoh" / "router.json5").read_text().replace(
        "tcp/0.0.0.0:7447", f"tcp/127.0.0.1:{free_port()}")
    path = tmp_path / "router.json5"
    path.write_text(text)
    s = zenoh.open(zenoh.Config.from_file(str(path)))
    try:
        assert str(s.zid())
    finally:
        s.close()


def test_systemd_units_start_ssmpc_subcommands():
    for unit in (DEPLOY / "systemd").glob("*.service"):
        text = unit.read_text()
        exec_line = [ln for ln in text.splitlines() if ln.startswith("ExecStart=")][0]
        sub = exec_line.split()[1]
        assert sub in ("router", "plant", "controller", "api"), unit.name
        assert "--zenoh-config" in exec_line
        assert "--credentials /etc/ssmpc/mesh" in exec_line, unit.name


def test_the_usrpwd_router_template_has_the_acl_of_ssmpc_router():
    import json

    from services.io.acl import access_control

    template = zenoh.Config.from_file(str(DEPLOY / "zenoh" / "router-usrpwd-acl.json5"))
    built = zenoh.Config()
    built.insert_json5("access_control", json.dumps(access_control()))
    assert json.loads(template.get_json("access_control")) == json.loads(
        built.get_json("access_control"))
    assert json.loads(template.get_json("transport/auth/usrpwd/dictionary_file")) == \
        "/etc/ssmpc/mesh/passwords"


def test_loop_units_run_under_sched_fifo_with_only_that_privilege():
    for role in ("plant", "controller"):
        text = (DEPLOY / "systemd" / f"ssmpc-{role}@.service").read_text()
        exec_line = [ln for ln in text.splitlines() if ln.startswith("ExecStart=")][0]
        prio = int(exec_line.split("--rt-priority", 1)[1].split()[0])
        assert 1 <= prio <= 99
        assert "AmbientCapabilities=CAP_SYS_NICE" in text
        assert "CapabilityBoundingSet=CAP_SYS_NICE" in text
        assert f"LimitRTPRIO={prio}" in text
        assert "NoNewPrivileges=true" in text
