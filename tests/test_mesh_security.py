"""The default deployment's mesh, attacked: ``ssmpc up`` with its router, real nodes.

One ``ssmpc up --unit cstr`` (router with user/password and ACL in the ``up``
process, plant, controller and api as Zenoh clients). Other sessions join its
router: without credentials, with a wrong password, and with the credentials of
each identity. What a session may not do, it must not achieve: the plant's
counters of moves that reached it (accepted or rejected) and the controller's of
measurements and transitions must not change, and no unit may appear alive. The
same attempt with the right identity changes them (each check can fail).
"""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from services.io import keys
from services.io.mesh_auth import node_credentials
from services.io.messages import MVMessage, Reply, Request
from services.io.zenoh_session import SessionSettings, free_port, open_session

pytestmark = [pytest.mark.integration, pytest.mark.timeout(300)]

REPO = Path(__file__).resolve().parents[1]
UNIT = "cstr"
DENIED_WAIT_S = 1.0  # a denied query gets no answer: wait this long for one


class UpMesh:
    def __init__(self, state_dir: Path) -> None:
        self.state_dir = state_dir
        self.port = free_port()
        env = {k: v for k, v in os.environ.items() if k != "SSMPC_API_TOKEN"}
        env["PYTHONPATH"] = str(REPO)
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "services.cli", "up", "--unit", UNIT, "--speed", "5",
             "--port", str(self.port), "--state-dir", str(state_dir), "--duration", "280"],
            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        self.endpoint = None
        t_end = time.monotonic() + 200
        while time.monotonic() < t_end:
            line = self.proc.stdout.readline()
            assert line, "ssmpc up exited before it was ready"
            if line.startswith("mesh: Zenoh router on "):
                self.endpoint = line.split()[4].rstrip(",")
            if line.startswith("ssmpc up:"):
                break
        assert self.endpoint and self.endpoint.startswith("tcp/127.0.0.1:")
        self.sessions = []

    @property
    def credentials(self) -> Path:
        return self.state_dir / "mesh"

    def session(self, role=None, *, password=None, mode="client"):
        """A session on the router as ``role`` (None: no credentials)."""
        auth = {}
        if role is not None:
            cred = node_credentials(self.credentials, role)
            auth = {"user": cred.user, "password": password or cred.password}
        s = open_session(SessionSettings(mode=mode, connect=(self.endpoint,), **auth))
        self.sessions.append(s)
        return s

    def close(self) -> None:
        for s in self.sessions:
            s.close()
        self.proc.send_signal(signal.SIGTERM)
        try:
            self.proc.wait(60)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture(scope="module")
def mesh(tmp_path_factory):
    m = UpMesh(tmp_path_factory.mktemp("up"))
    yield m
    m.close()


def query(session, key: str, action: str, args=None, timeout=DENIED_WAIT_S) -> list[Reply]:
    return [Reply.from_bytes(r.ok.payload.to_bytes())
            for r in session.get(key, payload=Request(action, args or {}).to_bytes(),
                                 timeout=timeout) if r.ok is not None]


class Operator:
    """The operator's own identity (``cli``): reads the nodes' status."""

    def __init__(self, session) -> None:
        self.session = session

    def plant(self) -> dict:
        return query(self.session, keys.plant_cmd(UNIT, "status"), "status", timeout=5)[0].data

    def controller(self) -> dict:
        return query(self.session, keys.cmd(UNIT, "status"), "status", timeout=5)[0].data

    def transitions(self) -> list:
        return query(self.session, keys.cmd(UNIT, "transition"), "transition", {"op": "list"},
                     timeout=5)[0].data

    def liveliness(self):
        return self.session.liveliness()


@pytest.fixture(scope="module")
def operator(mesh):
    return Operator(mesh.session("cli"))


def _wait_until(pred, timeout=5.0) -> bool:
    t_end = time.monotonic() + timeout
    while time.monotonic() < t_end:
        if pred():
            return True
        time.sleep(0.05)
    return pred()


def test_credentials_are_owner_only(mesh):
    d = mesh.credentials
    assert d.stat().st_mode & 0o777 == 0o700
    files = sorted(p.name for p in d.iterdir())
    assert files == ["api.key", "cli.key", "controller.key", "passwords", "plant.key"]
    assert all((d / f).stat().st_mode & 0o777 == 0o600 for f in files)


def test_a_session_without_credentials_cannot_join(mesh, operator):
    with pytest.raises(ValueError, match="cannot open the session"):
        mesh.session(None)
    with pytest.raises(ValueError, match="cannot open the session"):
        mesh.session("controller", password="not-the-password")
    # a peer may open without its link; what it sends must not arrive
    before = operator.plant()["mv_rejected"]["decode"]
    bad_before = operator.controller()["bad_measurements"]
    peer = mesh.session(None, mode="peer")
    peer.put(keys.mv(UNIT), b"not a move")
    peer.put(keys.meas(UNIT), b"not a measurement")
    peer.liveliness().declare_token(keys.alive("ghost", "controller"))
    time.sleep(0.5)
    assert operator.plant()["mv_rejected"]["decode"] == before
    assert operator.controller()["bad_measurements"] == bad_before


def test_only_the_controller_identity_moves_the_plant(mesh, operator):
    st = operator.plant()
    assert _wait_until(lambda: operator.plant()["mv_accepted"] > st["mv_accepted"])
    for role in ("api", "plant", "cli"):
        s = mesh.session(role)
        time.sleep(0.3)
        before = operator.plant()
        # a move that passes the plant's own checks if delivered: the controller's
        # sender, the next sequence number, a value no controller here computes
        forged = MVMessage(unit=UNIT, seq=before["mv_seq_applied"] + 1,
                           meas_seq=before["sample"], u=(2.75,),
                           sender=f"{UNIT}-controller").to_bytes()
        for _ in range(5):
            s.put(keys.mv(UNIT), forged)
            s.put(keys.mv(UNIT), b"not a move")
            time.sleep(0.02)
        time.sleep(0.5)
        after = operator.plant()
        real = after["mv_accepted"] - before["mv_accepted"]
        assert after["mv_rejected"] == before["mv_rejected"], role
        assert abs(after["u"][0] - 2.75) > 1e-9, role
        assert real > 0  # the controller still moves it
    # the controller's identity gets through: its garbage reaches the plant (and is refused)
    s = mesh.session("controller")
    time.sleep(0.3)
    before = operator.plant()["mv_rejected"]["decode"]
    s.put(keys.mv(UNIT), b"not a move")
    assert _wait_until(lambda: operator.plant()["mv_rejected"]["decode"] > before)


def test_only_the_plant_identity_feeds_the_controller(mesh, operator):
    for role in ("api", "controller", "cli"):
        s = mesh.session(role)
        time.sleep(0.3)
        before = operator.controller()["bad_measurements"]
        s.put(keys.meas(UNIT), b"not a measurement")
        time.sleep(0.5)
        assert operator.controller()["bad_measurements"] == before, role
    s = mesh.session("plant")
    time.sleep(0.3)
    before = operator.controller()["bad_measurements"]
    s.put(keys.meas(UNIT), b"not a measurement")
    assert _wait_until(lambda: operator.controller()["bad_measurements"] > before)


def test_only_the_api_and_cli_identities_command(mesh, operator):
    create = {"op": "create", "grade": "OPII"}
    for role in ("plant", "controller"):
        s = mesh.session(role)
        time.sleep(0.3)
        assert query(s, keys.cmd(UNIT, "status"), "status") == [], role
        assert query(s, keys.cmd(UNIT, "transition"), "transition", create) == [], role
        assert query(s, keys.plant_cmd(UNIT, "status"), "status") == [], role
        assert query(s, keys.plant_cmd(UNIT, "disturbance"), "disturbance",
                     {"name": "x1f", "value": 1.1}) == [], role
    assert operator.transitions() == []
    # the api identity may (the operator's cli identity read the status above)
    s = mesh.session("api")
    time.sleep(0.3)
    [reply] = query(s, keys.cmd(UNIT, "transition"), "transition", create, timeout=5)
    assert reply.code == 202, reply.error
    assert [t["grade"] for t in operator.transitions()] == ["OPII"]


def test_no_identity_but_its_own_holds_a_liveliness_token(mesh, operator):
    held = []
    for role, unit, as_role in (("api", "ghost", "controller"), ("cli", "ghost", "plant"),
                                ("plant", "ghost", "controller"),
                                ("controller", "ghost", "plant")):
        held.append(mesh.session(role).liveliness().declare_token(keys.alive(unit, as_role)))
    time.sleep(0.5)
    seen = {str(r.ok.key_expr) for r in operator.liveliness().get(keys.alive_all(), timeout=2)
            if r.ok is not None}
    assert keys.alive(UNIT, "plant") in seen and keys.alive(UNIT, "controller") in seen
    assert not [k for k in seen if "/ghost/" in k]
    with httpx.Client(base_url=f"http://127.0.0.1:{mesh.port}", timeout=10) as c:
        units = c.get("/api/v1/units").json()["units"]
    assert [u["unit"] for u in units] == [UNIT]
    # the controller's identity may declare a controller's token (the check can fail)
    token = mesh.session("controller").liveliness().declare_token(
        keys.alive("ghost", "controller"))
    assert _wait_until(lambda: "ghost" in json.dumps(
        httpx.get(f"http://127.0.0.1:{mesh.port}/api/v1/units", timeout=10).json()))
    token.undeclare()


def test_ssmpc_router_with_credentials_authenticates_and_filters(tmp_path):
    """The router of a mesh across hosts (``ssmpc router --credentials``), alone."""
    from services.io.mesh_auth import make_credentials

    make_credentials(tmp_path / "mesh")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", "router", "--listen", endpoint,
                             "--credentials", str(tmp_path / "mesh"), "--duration", "120"],
                            cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True)
    sessions = []

    def join(role):
        cred = node_credentials(tmp_path / "mesh", role)
        s = open_session(SessionSettings(mode="client", connect=(endpoint,), user=cred.user,
                                         password=cred.password))
        sessions.append(s)
        return s

    try:
        assert "auth=usrpwd+acl" in proc.stdout.readline()
        with pytest.raises(ValueError, match="cannot open the session"):
            open_session(SessionSettings(mode="client", connect=(endpoint,)))
        got = []
        join("plant").declare_subscriber(keys.mv(UNIT), lambda s: got.append(
            s.payload.to_bytes()))
        api, controller = join("api"), join("controller")
        time.sleep(0.5)
        api.put(keys.mv(UNIT), b"from the api")
        controller.put(keys.mv(UNIT), b"from the controller")
        assert _wait_until(lambda: got)
        time.sleep(0.3)
        assert got == [b"from the controller"]
    finally:
        for s in sessions:
            s.close()
        proc.send_signal(signal.SIGTERM)
        proc.wait(30)
