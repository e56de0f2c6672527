"""The OPC UA link on loopback: a real asyncua server (the plant, as a DCS serves it),
the controller linked through it, and a third-party client that is plain ``asyncua``.

One CSTR loop for the module (lock-step: the plant waits for each move, so the loop
runs as fast as the link allows): the namespace is browsed and read as any OPC UA
client would, the roles are tried, bad writes are answered per item, a grade change
over REST completes with the controller on OPC UA, and the controller's death makes
the plant shed and hold within the watchdog time; a new controller takes over
bumplessly. Then the TE unit: its loops' tuning set travels with the moves
(``Status/Tuning``), an unknown one is refused, and a shed puts the loops back on
their default set.
"""

import asyncio
import math
import threading
import time

import pytest
from asyncua import Client, ua
from asyncua.crypto.security_policies import SecurityPolicyBasic256Sha256
from test_plant_guard import _until
from test_service_te import SteadyTuning

from services.io.opcua.client import ControllerOPCUALink
from services.io.opcua.server import PlantOPCUAServer
from services.io.opcua.settings import NAMESPACE_URI, OPCUASettings
from services.io.zenoh_session import SessionSettings, free_port, free_tcp_endpoint, open_session
from services.nodes.controller import ControllerNode
from services.nodes.plant import PlantNode
from services.registry import get_unit
from services.store import UnitStore

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

WATCHDOG_S = 1.0


class Loop:
    """Plant node with its OPC UA server, controller node over OPC UA, both on Zenoh."""

    def __init__(self, tmp):
        self.cfg = get_unit("cstr")
        self.tmp = tmp
        self.ep = free_tcp_endpoint()
        self.settings = OPCUASettings(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/ssmpc",
                                      cert_dir=str(tmp / "opcua"), watchdog_s=WATCHDOG_S,
                                      heartbeat_s=0.2)
        self.s_ctrl = open_session(SessionSettings(listen=(self.ep,), lease_ms=1000))
        self.s_plant = open_session(SessionSettings(connect=(self.ep,), lease_ms=1000))
        self.start_plant()
        self.ctrl = None
        self.start_controller()

    def start_plant(self):
        """The plant node with its OPC UA server, lock-step, on its own thread."""
        self.server = PlantOPCUAServer(self.cfg, self.settings)
        self.plant = PlantNode(self.cfg, self.s_plant, speed=1.0, lockstep=True,
                               lockstep_timeout_s=0.5, link=self.server)
        self.stop_plant = threading.Event()
        self.plant_thread = threading.Thread(target=self.plant.run, args=(self.stop_plant,),
                                             daemon=True)
        self.plant_thread.start()

    def start_controller(self):
        self.store = UnitStore(self.tmp / "cstr.sqlite", "cstr")
        self.link = ControllerOPCUALink(self.cfg, self.settings)
        self.ctrl = ControllerNode(self.cfg, self.s_ctrl, self.store, None, speed=1.0,
                                   plant_link=self.link)
        assert self.link.wait_connected(30), self.link.last_error

    def stop_controller(self):
        self.ctrl.close()
        self.store.close()
        self.ctrl = None

    def close(self):
        if self.ctrl is not None:
            self.stop_controller()
        self.stop_plant.set()
        self.plant_thread.join(5)
        self.plant.close()
        for s in (self.s_plant, self.s_ctrl):
            s.close()


@pytest.fixture(scope="module")
def loop(tmp_path_factory):
    lp = Loop(tmp_path_factory.mktemp("opcua"))
    yield lp
    lp.close()


async def _client(lp, identity, *, token=True, app_uri=None):
    """A plain asyncua client with one of the link's certificates."""
    d = lp.settings.cert_dir
    c = Client(lp.settings.endpoint, timeout=10)
    c.application_uri = app_uri or f"urn:ssmpc:{identity}"
    await c.set_security(SecurityPolicyBasic256Sha256, f"{d}/{identity}.pem",
                         f"{d}/{identity}-key.pem", server_certificate=f"{d}/plant.pem",
                         mode=ua.MessageSecurityMode.SignAndEncrypt)
    if token:
        await c.load_client_certificate(f"{d}/{identity}.pem")
        await c.load_private_key(f"{d}/{identity}-key.pem")
    return c


def _run(coro):
    return asyncio.run(asyncio.wait_for(coro, 60))


def test_third_party_client_browses_and_reads(loop):
    async def main():
        c = await _client(loop, "operator")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            units = {(await n.read_browse_name()).Name: n
                     for n in await c.nodes.objects.get_children()}
            unit = units["cstr"]
            folders = {(await n.read_browse_name()).Name: n for n in await unit.get_children()}
            assert {"Measurements", "Setpoints", "Status"} <= set(folders)
            y = await folders["Measurements"].get_child(f"{ns}:y")
            eu = await (await y.get_child("0:EngineeringUnits")).read_value()
            desc = await y.read_description()
            assert await y.read_data_type_as_variant_type() == ua.VariantType.Double
            u = await folders["Setpoints"].get_child(f"{ns}:u")
            rng = await (await u.get_child("0:EURange")).read_value()
            sample = await folders["Status"].get_child(f"{ns}:Sample")
            state = await folders["Status"].get_child(f"{ns}:WatchdogState")
            tunings = [await (await folders["Status"].get_child(f"{ns}:{n}")).read_value()
                       for n in ("Tuning", "AppliedTuning")]
            first = [await sample.read_value(), await y.read_data_value()]
            await asyncio.sleep(0.5)
            second = [await sample.read_value(), await y.read_data_value()]
            return eu, desc, rng, first, second, await state.read_value(), tunings

    eu, desc, rng, first, second, state, tunings = _run(main())
    # CSTR (plant_sim.cstr): the output is the dimensionless reactor temperature
    assert eu.DisplayName.Text == "-"
    assert "reactor temperature" in desc.Text
    assert (rng.Low, rng.High) == (-3.0, 3.0)  # the chapter-5 input range of the jacket
    assert second[0] > first[0] + 5  # lock-step: many samples in half a second
    assert second[1].SourceTimestamp > first[1].SourceTimestamp
    assert math.isfinite(second[1].Value.Value)
    assert state == "ok"
    assert tunings == ["", ""]  # the CSTR plant has no loops of its own to tune


def test_operator_and_anonymous_cannot_write_setpoints(loop):
    async def operator_write():
        c = await _client(loop, "operator")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            node = c.get_node(ua.NodeId("cstr.Setpoints.u", ns))
            before = await node.read_value()
            with pytest.raises(ua.UaStatusCodeError) as err:
                await node.write_value(ua.DataValue(ua.Variant(1.0, ua.VariantType.Double)))
            return err.value, before

    err, before = _run(operator_write())
    assert "BadUserAccessDenied" in type(err).__name__
    assert math.isfinite(before)

    async def anonymous():  # a trusted channel certificate, but no identity token
        c = await _client(loop, "operator", token=False)
        await c.connect()
        await c.disconnect()

    with pytest.raises(ua.UaStatusCodeError) as err:
        _run(anonymous())
    assert "BadIdentityTokenRejected" in type(err.value).__name__

    async def no_certificate():
        c = Client(loop.settings.endpoint, timeout=5)
        await c.connect()
        await c.disconnect()

    with pytest.raises(Exception):  # noqa: B017 - any refusal: no endpoint without security
        _run(no_certificate())


def test_foreign_certificate_is_refused(loop, tmp_path):
    """A controller certificate of another CA (a PKI made the same way elsewhere)."""
    from services.io.opcua.certs import ensure_certificates

    other = ensure_certificates(tmp_path / "other")

    async def main():
        c = Client(loop.settings.endpoint, timeout=5)
        c.application_uri = "urn:ssmpc:controller"
        await c.set_security(SecurityPolicyBasic256Sha256, str(other.cert("controller")),
                             str(other.key("controller")),
                             server_certificate=f"{loop.settings.cert_dir}/plant.pem")
        await c.load_client_certificate(str(other.cert("controller")))
        await c.load_private_key(other.key("controller"))
        await c.connect()
        await c.disconnect()

    with pytest.raises(ua.UaStatusCodeError) as err:
        _run(main())
    assert "BadCertificateUntrusted" in type(err.value).__name__


def test_bad_writes_are_answered_per_item(loop):
    async def main():
        c = await _client(loop, "controller")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            ids = [ua.NodeId("cstr.Setpoints.nope", ns), ua.NodeId("cstr.Setpoints.u", ns),
                   ua.NodeId("cstr.Setpoints.u", ns), ua.NodeId("cstr.Setpoints.u", ns),
                   ua.NodeId("cstr.Measurements.y", ns),
                   ua.NodeId("cstr.Status.ControllerMode", ns)]
            dvs = [ua.DataValue(ua.Variant(0.5, ua.VariantType.Double)),
                   ua.DataValue(ua.Variant(1, ua.VariantType.Int32)),
                   ua.DataValue(ua.Variant(math.nan, ua.VariantType.Double)),
                   ua.DataValue(ua.Variant(10.0, ua.VariantType.Double)),
                   ua.DataValue(ua.Variant(0.5, ua.VariantType.Double)),
                   ua.DataValue(ua.Variant("turbo", ua.VariantType.String))]
            return await c.uaclient.write_attributes(ids, dvs)

    moves = loop.server.moves
    results = [r.name for r in _run(main())]
    assert results == ["BadNodeIdUnknown", "BadTypeMismatch", "BadOutOfRange",
                       "BadOutOfRange", "BadUserAccessDenied", "BadOutOfRange"]
    assert loop.server.moves - moves <= 20  # only the controller's own moves meanwhile
    assert loop.plant.status()["mv_rejected"]["decode"] == 0


def test_link_to_a_missing_server_says_so(loop, tmp_path):
    settings = OPCUASettings(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/ssmpc",
                             cert_dir=loop.settings.cert_dir, retry_s=0.2)
    link = ControllerOPCUALink(loop.cfg, settings).subscribe(lambda sample: None)
    try:
        t_end = time.monotonic() + 10
        while link.last_error is None and time.monotonic() < t_end:
            time.sleep(0.05)
        assert not link.connected.is_set()
        assert "cannot reach the server" in link.last_error
        link.put(b"{}")  # a move while unconnected: dropped, no exception
    finally:
        link.undeclare()


def test_grade_change_over_rest_with_the_controller_on_opcua(loop):
    from test_api import AUTH, ApiServer

    api = ApiServer(loop)
    try:
        r = api.client.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"},
                            headers=AUTH)
        assert r.status_code == 202
        t_end = time.monotonic() + 90
        while time.monotonic() < t_end:
            v = api.client.get(r.headers["location"]).json()
            if v["state"] in ("settled", "aborted", "failed"):
                break
            time.sleep(0.1)
        assert v["state"] == "settled"
        st = api.client.get("/api/v1/units/cstr/status").json()
        assert st["cv"]["y"] == pytest.approx(5.0, abs=0.5)  # OPII: y = 5 (seed ch. 5)
    finally:
        api.close()
    assert loop.plant.status()["mv_rejected"] == {"decode": 0, "sender": 0, "stale": 0,
                                                  "jump": 0, "tuning": 0}


def test_controller_death_sheds_and_holds_then_returns_bumpless(loop):
    """Last in the module: it stops the controller."""
    assert loop.server.state == "ok"
    loop.stop_controller()
    t_dead = time.monotonic()
    while loop.server.state != "shed" and time.monotonic() - t_dead < 10:
        time.sleep(0.02)
    shed_after = time.monotonic() - t_dead
    assert loop.server.state == "shed"
    assert shed_after < WATCHDOG_S + 1.0  # the watchdog time, with a loaded machine's slack
    held = loop.plant.status()
    time.sleep(1.2)  # lock-step timeout 0.5 s: the plant samples on, on held moves
    later = loop.plant.status()
    assert later["sample"] > held["sample"]
    assert later["u"] == held["u"]

    async def read_state():
        c = await _client(loop, "operator")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            return await c.read_values([c.get_node(ua.NodeId(f"cstr.{n}", ns)) for n in (
                "Status.WatchdogState", "Status.AppliedMoves", "Setpoints.u")])

    state, applied, setpoint = _run(read_state())
    assert state == "shed"
    assert applied == held["u"] and setpoint == held["u"][0]  # set points track the hold
    # a new controller: the heartbeat returns, it starts from the held move
    loop.start_controller()
    t_end = time.monotonic() + 20
    while loop.server.state != "ok" and time.monotonic() < t_end:
        time.sleep(0.02)
    assert loop.server.state == "ok"
    seq = loop.plant.status()["mv_seq_applied"]
    while loop.plant.status()["mv_seq_applied"] == seq and time.monotonic() < t_end:
        time.sleep(0.01)
    first = loop.plant.status()["u"]
    # it took the held move over (AppliedMoves and AppliedMoveSeq came through) and
    # moved on from it: its first move corrects what the plant drifted meanwhile (up to
    # 0.013 seen), far from another grade's move (OPIII's is 0.47, OPII's 0.41)
    assert any("from the plant's move" in a for a in loop.ctrl.status()["alarms"])
    assert abs(first[0] - held["u"][0]) < 0.03


def test_server_going_away_is_reported_by_the_link(loop):
    """After the take-over: the plant's server stops; the link says so, the node lives."""
    assert loop.link.wait_connected(10)
    loop.stop_plant.set()
    loop.plant_thread.join(5)
    loop.server.close()
    t_end = time.monotonic() + 15
    while loop.link.connected.is_set() and time.monotonic() < t_end:
        time.sleep(0.05)
    assert not loop.link.connected.is_set()
    while loop.link.last_error is None and time.monotonic() < t_end:
        time.sleep(0.05)
    assert loop.link.last_error is not None
    assert loop.ctrl.status()["unit"] == "cstr"  # the controller node itself goes on


def test_te_serves_its_valves_and_loop_setpoints(tmp_path):
    """TE: the 41 XMEAS with Downs & Vogel's units, the free valves and the inner loops'
    set points as Setpoints (no controller: the plant holds its start values)."""
    cfg = get_unit("te")
    settings = OPCUASettings(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/ssmpc",
                             cert_dir=str(tmp_path / "opcua"))
    session = open_session(SessionSettings(lease_ms=1000))
    server = PlantOPCUAServer(cfg, settings)
    plant = PlantNode(cfg, session, speed=1.0, link=server)
    stop = threading.Event()
    th = threading.Thread(target=plant.run, args=(stop,), daemon=True)
    th.start()

    async def main():
        d = settings.cert_dir
        c = Client(settings.endpoint, timeout=10)
        c.application_uri = "urn:ssmpc:operator"
        await c.set_security(SecurityPolicyBasic256Sha256, f"{d}/operator.pem",
                             f"{d}/operator-key.pem", server_certificate=f"{d}/plant.pem")
        await c.load_client_certificate(f"{d}/operator.pem")
        await c.load_private_key(f"{d}/operator-key.pem")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            meas = c.get_node(ua.NodeId("te.Measurements", ns))
            sps = c.get_node(ua.NodeId("te.Setpoints", ns))
            names = [(await n.read_browse_name()).Name for n in await meas.get_children()]
            sp_names = [(await n.read_browse_name()).Name for n in await sps.get_children()]
            p = await meas.get_child(f"{ns}:XMEAS7")
            eu = await (await p.get_child("0:EngineeringUnits")).read_value()
            value = await p.read_value()
            state = await c.get_node(ua.NodeId("te.Status.WatchdogState", ns)).read_value()
            return names, sp_names, eu, value, state

    try:
        names, sp_names, eu, value, state = _run(main())
    finally:
        stop.set()
        th.join(10)
        plant.close()
        session.close()
    assert names == [f"XMEAS{i}" for i in range(1, 42)]
    assert eu.DisplayName.Text == "kPa gauge"  # Downs & Vogel Table 4: reactor pressure
    assert 2600 < value < 2800  # base case ~2705 kPa gauge
    assert {"reactor_pressure_sp", "reactor_level_sp"} <= set(sp_names)
    assert any(n.startswith("XMV") for n in sp_names)
    assert state == "shed"  # no controller has ever written a heartbeat


class TELoop(Loop):
    """TE plant node with its OPC UA server, a holding controller node over OPC UA.

    Their Zenoh sessions are not connected: the plant knows the controller through the
    link alone (no liveliness), so a lost controller is the watchdog's to notice."""

    def __init__(self, tmp):
        self.cfg = get_unit("te")
        self.settings = OPCUASettings(endpoint=f"opc.tcp://127.0.0.1:{free_port()}/ssmpc",
                                      cert_dir=str(tmp / "opcua"), watchdog_s=WATCHDOG_S,
                                      heartbeat_s=0.2)
        self.s_plant = open_session(SessionSettings(lease_ms=1000))
        self.s_ctrl = open_session(SessionSettings(lease_ms=1000))
        self.start_plant()
        self.store = UnitStore(tmp / "te.sqlite", "te")
        self.link = ControllerOPCUALink(self.cfg, self.settings)
        self.ctrl = ControllerNode(self.cfg, self.s_ctrl, self.store, None, speed=1.0,
                                   controller=SteadyTuning(self.cfg), plant_link=self.link)
        assert self.link.wait_connected(30), self.link.last_error

    def wait(self, cond, timeout=20.0):
        return _until(cond, timeout)

    def read(self, *names, identity="operator"):
        """``Status/<name>`` values, read by a plain asyncua client."""
        async def main():
            c = await _client(self, identity)
            async with c:
                ns = await c.get_namespace_index(NAMESPACE_URI)
                return await c.read_values([c.get_node(ua.NodeId(f"te.Status.{n}", ns))
                                            for n in names])

        return _run(main())


@pytest.fixture(scope="module")
def te_loop(tmp_path_factory):
    lp = TELoop(tmp_path_factory.mktemp("opcua-te"))
    yield lp
    lp.close()


def test_te_tuning_set_the_controller_selects_reaches_the_plant(te_loop):
    plant, ctl = te_loop.plant, te_loop.ctrl.controller
    assert te_loop.wait(lambda: plant.runner.tuning == "steady")
    assert te_loop.wait(lambda: te_loop.read("AppliedTuning") == ["steady"])
    assert te_loop.read("Tuning") == ["steady"]
    assert plant.status()["tuning"] == "steady"
    # the controller selects the grade changes' set: the plant and the DCS follow
    ctl.tuning = "grade_change"
    assert te_loop.wait(lambda: plant.runner.tuning == "grade_change")
    assert te_loop.wait(lambda: te_loop.read("Tuning", "AppliedTuning")
                        == ["grade_change", "grade_change"])
    ctl.tuning = "steady"
    assert te_loop.wait(lambda: plant.runner.tuning == "steady")
    assert te_loop.server.state == "ok"
    assert plant.status()["mv_rejected"]["tuning"] == 0


def test_te_unknown_or_malformed_tuning_is_refused(te_loop):
    plant, server = te_loop.plant, te_loop.server
    assert te_loop.wait(lambda: plant.runner.tuning == "steady")
    refused = dict(server.refused)

    async def main():
        c = await _client(te_loop, "controller")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)

            def nid(name):
                return ua.NodeId(f"te.{name}", ns)

            u = await c.get_node(nid("Status.AppliedMoves")).read_value()
            sps = [nid(f"Setpoints.{n}") for n in te_loop.link.mv_names]
            S, D = ua.VariantType.String, ua.VariantType.Double
            # set points with a set this plant does not know: written, the move refused
            unknown = await c.uaclient.write_attributes(
                sps + [nid("Status.Tuning")],
                [ua.DataValue(ua.Variant(float(x), D)) for x in u]
                + [ua.DataValue(ua.Variant("aggressive", S))])
            bad = await c.uaclient.write_attributes(
                [nid("Status.Tuning"), nid("Status.Tuning"), nid("Status.AppliedTuning")],
                [ua.DataValue(ua.Variant("x" * 65, S)), ua.DataValue(ua.Variant(1.0, D)),
                 ua.DataValue(ua.Variant("steady", S))])
            return [r.name for r in unknown], [r.name for r in bad]

    unknown, bad = _run(main())
    assert set(unknown) == {"Good"}
    assert bad == ["BadOutOfRange", "BadTypeMismatch", "BadUserAccessDenied"]
    assert server.refused["range"] == refused["range"] + 1
    assert server.refused["type"] == refused["type"] + 1
    assert te_loop.wait(lambda: plant.status()["mv_rejected"]["tuning"] == 1)
    st = plant.status()
    assert any("unknown tuning set 'aggressive'" in a for a in st["alarms"])

    async def operator_write():  # only the controller's identity writes it
        c = await _client(te_loop, "operator")
        async with c:
            ns = await c.get_namespace_index(NAMESPACE_URI)
            with pytest.raises(ua.UaStatusCodeError) as err:
                await c.get_node(ua.NodeId("te.Status.Tuning", ns)).write_value(
                    ua.DataValue(ua.Variant("grade_change", ua.VariantType.String)))
            return type(err.value).__name__

    assert "BadUserAccessDenied" in _run(operator_write())
    # the plant runs on with the controller's set: its next moves name it again
    sample = plant.status()["sample"]
    assert te_loop.wait(lambda: plant.status()["sample"] > sample + 5)
    assert plant.runner.tuning == "steady" and server.state == "ok"
    assert te_loop.read("Tuning", "AppliedTuning") == ["steady", "steady"]


def test_te_heartbeat_loss_sheds_the_tuning_to_the_default(te_loop):
    """Last of the TE tests: it stops the controller."""
    plant, server = te_loop.plant, te_loop.server
    assert te_loop.wait(lambda: plant.runner.tuning == "steady")
    sheds = server.sheds
    te_loop.stop_controller()
    assert te_loop.wait(lambda: server.state == "shed", timeout=WATCHDOG_S + 5)
    assert te_loop.wait(lambda: plant.runner.tuning == "grade_change", timeout=5)
    assert server.sheds == sheds + 1
    assert plant.controller_alive is False  # no liveliness here: the watchdog did it
    # the DCS sees the default set in force; a returning controller must name its own
    assert te_loop.wait(lambda: te_loop.read("WatchdogState", "Tuning", "AppliedTuning")
                        == ["shed", "", "grade_change"])
    sample = plant.status()["sample"]
    assert te_loop.wait(lambda: plant.status()["sample"] > sample)  # held, running on
    assert plant.status()["tuning"] == "grade_change"
