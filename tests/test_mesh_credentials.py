"""Mesh credentials: made owner-only, reused, rotated; anything else refused clearly.

The library (:mod:`services.io.mesh_auth`) and the commands that take credentials
(``ssmpc credentials``, the node commands' ``--credentials``, ``ssmpc router``,
``ssmpc up``): a credentials directory or file open to others, missing, or not a
regular file is ``error: ...`` with exit 2 and nothing started, never a traceback.
"""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from services.io import mesh_auth
from services.io.acl import RULES_BY_ROLE, access_control

REPO = Path(__file__).resolve().parents[1]


def _mode(path: Path) -> int:
    return path.stat().st_mode & 0o777


def _run(argv, timeout=60):
    env = {k: v for k, v in os.environ.items() if k != "SSMPC_API_TOKEN"}
    env["PYTHONPATH"] = str(REPO)
    return subprocess.run([sys.executable, "-m", "services.cli", *argv], capture_output=True,
                          text=True, timeout=timeout, env=env, cwd=REPO)


def _is_config_error(proc, *words):
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: "), proc.stderr[-2000:]
    assert "ready" not in proc.stdout and "starting" not in proc.stdout
    for w in words:
        assert w in proc.stderr, proc.stderr


def test_credentials_are_made_owner_only_and_reused(tmp_path):
    d = tmp_path / "state" / "mesh"
    old_umask = os.umask(0o022)  # a usual umask would leave files world-readable
    try:
        assert mesh_auth.make_credentials(d) == list(mesh_auth.ROLES)
    finally:
        os.umask(old_umask)
    assert _mode(d) == 0o700
    assert sorted(p.name for p in d.iterdir()) == sorted(
        [f"{r}.key" for r in mesh_auth.ROLES] + ["passwords"])
    assert all(_mode(p) == 0o600 for p in d.iterdir())
    first = {r: mesh_auth.node_credentials(d, r).password for r in mesh_auth.ROLES}
    assert len(set(first.values())) == len(first)  # one password per identity
    assert mesh_auth.make_credentials(d) == []  # a later start reuses them
    assert {r: mesh_auth.node_credentials(d, r).password for r in mesh_auth.ROLES} == first
    lines = mesh_auth.router_dictionary(d).read_text().splitlines()
    assert sorted(lines) == sorted(f"ssmpc-{r}:{first[r]}" for r in first)


def test_rotation_draws_new_passwords_for_every_identity(tmp_path):
    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    before = {r: mesh_auth.node_credentials(d, r).password for r in mesh_auth.ROLES}
    assert mesh_auth.make_credentials(d, rotate=True) == list(mesh_auth.ROLES)
    after = {r: mesh_auth.node_credentials(d, r).password for r in mesh_auth.ROLES}
    assert all(before[r] != after[r] for r in mesh_auth.ROLES)
    assert mesh_auth.router_dictionary(d).read_text().count(after["controller"]) == 1
    assert before["controller"] not in mesh_auth.router_dictionary(d).read_text()
    assert all(_mode(p) == 0o600 for p in d.iterdir())


def test_a_lost_key_file_is_made_again_and_the_dictionary_follows(tmp_path):
    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    (d / "api.key").unlink()
    assert mesh_auth.make_credentials(d) == ["api"]
    new = mesh_auth.node_credentials(d, "api").password
    assert f"ssmpc-api:{new}" in mesh_auth.router_dictionary(d).read_text().splitlines()


@pytest.mark.parametrize("target, mode", [("plant.key", 0o640), ("plant.key", 0o604),
                                          ("passwords", 0o644), (".", 0o750), (".", 0o755)])
def test_credentials_open_to_others_are_refused(tmp_path, target, mode):
    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    os.chmod(d / target, mode)
    with pytest.raises(ValueError, match=r"credentials: .*open to others .*chmod 0[67]00"):
        if target == "passwords":
            mesh_auth.router_dictionary(d)
        else:
            mesh_auth.node_credentials(d, "plant")
    with pytest.raises(ValueError, match="open to others"):  # nor made over: the user decides
        mesh_auth.make_credentials(d)


def test_missing_or_odd_credentials_are_refused(tmp_path):
    with pytest.raises(ValueError, match="does not exist.*ssmpc credentials"):
        mesh_auth.node_credentials(tmp_path / "nowhere", "plant")
    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    with pytest.raises(ValueError, match="role: expected one of"):
        mesh_auth.node_credentials(d, "intruder")
    (d / "cli.key").unlink()
    (d / "cli.key").symlink_to(d / "api.key")
    with pytest.raises(ValueError, match="not a regular file"):
        mesh_auth.node_credentials(d, "cli")
    (d / "api.key").write_text("")
    with pytest.raises(ValueError, match="empty"):
        mesh_auth.node_credentials(d, "api")
    (d / "passwords").write_text("no separator here\n")
    with pytest.raises(ValueError, match="user:password"):
        mesh_auth.router_dictionary(d)


def test_the_acl_denies_by_default_and_names_every_identity():
    acl = access_control()
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert all(r["permission"] == "allow" for r in acl["rules"])
    users = {s["id"]: s["usernames"] for s in acl["subjects"]}
    assert users == {r: [f"ssmpc-{r}"] for r in mesh_auth.ROLES}
    rules = {r["id"]: r for r in acl["rules"]}

    def allowed(role, flow, message, key):
        return [rid for rid in RULES_BY_ROLE[role] if flow in rules[rid]["flows"]
                and message in rules[rid]["messages"] and key in rules[rid]["key_exprs"]]

    # the moves: only the controller puts them, only the plant receives them
    assert [r for r in mesh_auth.ROLES if allowed(r, "ingress", "put", "ssmpc/*/mv")] == [
        "controller"]
    assert [r for r in mesh_auth.ROLES if allowed(r, "egress", "put", "ssmpc/*/mv")] == [
        "plant"]
    assert [r for r in mesh_auth.ROLES if allowed(r, "ingress", "put", "ssmpc/*/meas")] == [
        "plant"]
    assert [r for r in mesh_auth.ROLES
            if allowed(r, "ingress", "query", "ssmpc/*/cmd/**")] == ["api", "cli"]


def test_ssmpc_credentials_makes_checks_and_rotates(tmp_path):
    proc = _run(["credentials", "--state-dir", str(tmp_path), "--json"])
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout.strip().splitlines()[-1])
    assert doc["made"] == list(mesh_auth.ROLES)
    assert doc["directory"] == str(tmp_path / "mesh")
    password = mesh_auth.node_credentials(tmp_path / "mesh", "api").password
    assert password not in proc.stdout + proc.stderr  # never printed
    proc = _run(["credentials", "--state-dir", str(tmp_path), "--json"])
    assert json.loads(proc.stdout.strip().splitlines()[-1])["made"] == []
    proc = _run(["credentials", "--state-dir", str(tmp_path), "--rotate", "--json"])
    assert json.loads(proc.stdout.strip().splitlines()[-1])["made"] == list(mesh_auth.ROLES)
    assert mesh_auth.node_credentials(tmp_path / "mesh", "api").password != password
    os.chmod(tmp_path / "mesh" / "api.key", 0o644)
    _is_config_error(_run(["credentials", "--state-dir", str(tmp_path)]), "chmod 0600")


@pytest.mark.integration
@pytest.mark.parametrize("argv", [
    ["plant", "--unit", "cstr", "--duration", "5"],
    ["controller", "--unit", "cstr", "--duration", "5", "--no-telemetry"],
    ["api", "--port", "1", "--duration", "5"],
    ["router", "--listen", "tcp/127.0.0.1:0", "--duration", "5"],
])
def test_node_commands_refuse_wrong_mode_or_missing_credentials(tmp_path, argv):
    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    os.chmod(d / "plant.key", 0o644)
    os.chmod(d / "controller.key", 0o644)
    os.chmod(d / "api.key", 0o644)
    os.chmod(d / "passwords", 0o644)
    extra = ["--state-dir", str(tmp_path)] if argv[0] == "controller" else []
    _is_config_error(_run([*argv, *extra, "--credentials", str(d)]), "credentials",
                     "open to others")
    _is_config_error(_run([*argv, *extra, "--credentials", str(tmp_path / "none")]),
                     "credentials", "does not exist")


@pytest.mark.integration
def test_ssmpc_up_refuses_credentials_open_to_others_before_anything_moves(tmp_path):
    mesh_auth.make_credentials(tmp_path / "mesh")
    os.chmod(tmp_path / "mesh", 0o755)
    (tmp_path / "ssmpc-cstr.sqlite").write_text("a previous run's store")
    proc = _run(["up", "--unit", "cstr", "--state-dir", str(tmp_path), "--duration", "5"])
    _is_config_error(proc, "credentials", "chmod 0700")
    assert (tmp_path / "ssmpc-cstr.sqlite").read_text() == "a previous run's store"


@pytest.mark.integration
def test_a_bad_zenoh_config_with_credentials_is_an_error(tmp_path):
    mesh_auth.make_credentials(tmp_path / "mesh")
    conf = tmp_path / "z.json5"
    conf.write_text('{mode: "client", transport: {auth: {usrpwd: {bogus: 1}}}}\n')
    proc = _run(["api", "--port", "1", "--zenoh-config", str(conf), "--credentials",
                 str(tmp_path / "mesh"), "--duration", "5"])
    _is_config_error(proc, "zenoh_config")


@pytest.mark.parametrize("command, role", [("plant", "plant"), ("opcua", "plant"),
                                           ("controller", "controller"), ("api", "api")])
def test_each_node_command_authenticates_as_its_own_identity(tmp_path, command, role):
    from services.cli.entry import build_parser
    from services.nodes.run import session_settings

    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    args = build_parser().parse_args([command, "--mode", "client", "--credentials", str(d)])
    settings = session_settings(args)
    assert settings.user == f"ssmpc-{role}"
    assert settings.password == mesh_auth.node_credentials(d, role).password
    assert settings.password not in repr(settings)
    assert session_settings(build_parser().parse_args([command])).user is None


@pytest.mark.parametrize("mode_args", [[], ["--mode", "peer"], ["--zenoh-config", "PEER"]])
def test_a_node_with_credentials_refuses_to_be_a_peer(tmp_path, mode_args):
    """A peer would listen for sessions nobody authenticates: with credentials a node
    joins the router as a client, or does not start."""
    from services.cli.entry import build_parser
    from services.nodes.run import session_settings
    from services.output import CLIError

    d = tmp_path / "mesh"
    mesh_auth.make_credentials(d)
    peer = tmp_path / "peer.json5"
    peer.write_text('{mode: "peer", scouting: {multicast: {enabled: false}}}\n')
    argv = [str(peer) if a == "PEER" else a for a in mode_args]
    args = build_parser().parse_args(["controller", *argv, "--credentials", str(d)])
    with pytest.raises(CLIError, match="credentials: .*client.*not as a peer"):
        session_settings(args)
    client = tmp_path / "client.json5"
    client.write_text('{mode: "client", connect: {endpoints: ["tcp/127.0.0.1:7447"]}}\n')
    args = build_parser().parse_args(["controller", "--zenoh-config", str(client),
                                      "--credentials", str(d)])
    assert session_settings(args).user == "ssmpc-controller"
