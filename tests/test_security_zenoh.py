"""deploy/: Zenoh mutual TLS and access control, run for real.

A router with ``deploy/zenoh/router-acl.json5`` and nodes with
``deploy/zenoh/tls-client.json5`` (certificate paths, address and port rewritten to a
PKI made here with ``cryptography``: a CA and one certificate per identity). The CSTR
loop runs through the router (plant ``plant.ssmpc``, controller ``controller.ssmpc``)
and the api identity can query the controller; a session with another certificate of
the same CA, and the api identity, publish forged moves — with the controller's sender
name and the newest sequence number — which the router must not deliver.
"""

import datetime
import json
import threading
import time
from pathlib import Path

import pytest
import zenoh

from services.io import keys
from services.io.messages import MVMessage, Reply, Request
from services.io.zenoh_session import free_port
from services.nodes.controller import ControllerNode
from services.nodes.plant import PlantNode
from services.registry import get_unit
from services.store import UnitStore

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]

DEPLOY = Path(__file__).resolve().parents[1] / "deploy" / "zenoh"
FORGED_U = 0.123456789  # a move no controller of this test computes
FORGED_SEQ = 2**62  # newer than any genuine seq (counters or microsecond clocks)


def _make_pki(d: Path, names):
    """A CA and one certificate per name (CN ``<name>.ssmpc``, SAN localhost/127.0.0.1)."""
    try:
        import cryptography  # noqa: F401 - not a declared dependency of ssmpc
    except ImportError:
        return _make_pki_openssl(d, names)
    return _make_pki_cryptography(d, names)


def _make_pki_openssl(d: Path, names):
    import shutil
    import subprocess

    if shutil.which("openssl") is None:
        pytest.skip("neither the cryptography package nor the openssl CLI is available")

    def run(*argv):
        subprocess.run(["openssl", *argv], cwd=d, check=True, capture_output=True)

    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    run("req", "-x509", *ec, "-keyout", "ca-key.pem", "-out", "ca.pem", "-days", "1",
        "-subj", "/CN=ssmpc test CA")
    for name in names:
        (d / f"{name}.ext").write_text(
            "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=critical,CA:FALSE\n"
            "extendedKeyUsage=serverAuth,clientAuth\n")
        run("req", *ec, "-keyout", f"{name}-key.pem", "-out", f"{name}.csr",
            "-subj", f"/CN={name}.ssmpc")
        run("x509", "-req", "-in", f"{name}.csr", "-CA", "ca.pem", "-CAkey", "ca-key.pem",
            "-CAcreateserial", "-out", f"{name}.pem", "-days", "1", "-extfile", f"{name}.ext")


def _make_pki_cryptography(d: Path, names):
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)

    def write(name, key, cert):
        (d / f"{name}-key.pem").write_bytes(key.private_bytes(
            serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
            serialization.NoEncryption()))
        (d / f"{name}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))

    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "ssmpc test CA")])
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now - datetime.timedelta(hours=1))
          .not_valid_after(now + datetime.timedelta(days=1))
          .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
          .add_extension(x509.KeyUsage(False, False, False, False, False, True, True, False,
                                       False), critical=True)
          .sign(ca_key, hashes.SHA256()))
    write("ca", ca_key, ca)
    import ipaddress

    for name in names:
        key = ec.generate_private_key(ec.SECP256R1())
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME,
                                                            f"{name}.ssmpc")]))
                .issuer_name(ca_name).public_key(key.public_key())
                .serial_number(x509.random_serial_number())
                .not_valid_before(now - datetime.timedelta(hours=1))
                .not_valid_after(now + datetime.timedelta(days=1))
                .add_extension(x509.SubjectAlternativeName(
                    [x509.DNSName("localhost"),
                     x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), critical=False)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None),
                               critical=True)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]),
                               critical=False)
                .sign(ca_key, hashes.SHA256()))
        write(name, key, cert)


@pytest.fixture
def acl_mesh(tmp_path):
    _make_pki(tmp_path, ["router", "plant", "controller", "api", "rogue"])
    port = free_port()
    router_text = (DEPLOY / "router-acl.json5").read_text()
    assert "/etc/ssmpc/tls/" in router_text and "tls/0.0.0.0:7448" in router_text
    router_text = (router_text.replace("/etc/ssmpc/tls/", f"{tmp_path}/")
                   .replace("tls/0.0.0.0:7448", f"tls/127.0.0.1:{port}"))
    (tmp_path / "router.json5").write_text(router_text)
    client_text = (DEPLOY / "tls-client.json5").read_text()
    assert "tls/router.plant.local:7448" in client_text

    def client(name):
        text = (client_text.replace("tls/router.plant.local:7448", f"tls/localhost:{port}")
                .replace("/etc/ssmpc/tls/node", f"{tmp_path}/{name}")
                .replace("/etc/ssmpc/tls/", f"{tmp_path}/"))
        path = tmp_path / f"{name}.json5"
        path.write_text(text)
        return zenoh.open(zenoh.Config.from_file(str(path)))

    router = zenoh.open(zenoh.Config.from_file(str(tmp_path / "router.json5")))
    sessions = {}
    try:
        for name in ("controller", "plant", "api", "rogue"):
            sessions[name] = client(name)
        yield sessions
    finally:
        for s in sessions.values():
            s.close()
        router.close()


def test_only_the_controller_identity_can_move_the_plant(acl_mesh, tmp_path):
    cfg = get_unit("cstr")
    s = acl_mesh
    store = UnitStore(tmp_path / "cstr.sqlite", "cstr")
    ctrl = ControllerNode(cfg, s["controller"], store, None, speed=10.0)
    seen: list[MVMessage] = []
    spy = s["plant"].declare_subscriber(
        keys.mv("cstr"), lambda smp: seen.append(MVMessage.from_bytes(smp.payload.to_bytes())))
    time.sleep(0.5)
    plant = PlantNode(cfg, s["plant"], speed=10.0)
    stop = threading.Event()
    threads = [threading.Thread(target=n.run, args=(stop,), daemon=True) for n in (ctrl, plant)]
    for th in threads:
        th.start()
    try:
        t_end = time.monotonic() + 20
        while ctrl.k < 20 and time.monotonic() < t_end:
            time.sleep(0.02)
        assert ctrl.k >= 20, "the loop does not run through the ACL router"
        # the api identity may query the controller
        rs = list(s["api"].get(keys.cmd("cstr", "status"),
                               payload=Request("status").to_bytes(), timeout=5))
        assert Reply.from_bytes(rs[0].ok.payload.to_bytes()).data["unit"] == "cstr"
        # others cannot publish moves, not even forged as the controller with the newest seq
        forged = MVMessage(unit="cstr", seq=FORGED_SEQ, meas_seq=0, u=(FORGED_U,),
                           sender=ctrl.sender).to_bytes()
        for _ in range(5):
            for name in ("rogue", "api"):
                s[name].put(keys.mv("cstr"), forged)
            time.sleep(0.05)
        accepted = plant.counters.mv_accepted
        t_end = time.monotonic() + 10  # a loaded machine may hold a few moves in a row
        while plant.counters.mv_accepted <= accepted and time.monotonic() < t_end:
            time.sleep(0.05)
        assert plant.counters.mv_accepted > accepted  # the real controller still moves it
        assert seen and all(m.seq != FORGED_SEQ for m in seen)
        assert plant.last_mv_seq < FORGED_SEQ
        assert all(abs(m.u[0] - FORGED_U) > 1e-12 for m in seen)
    finally:
        stop.set()
        for th in threads:
            th.join(5)
        spy.undeclare()
        plant.close()
        ctrl.close()
        store.close()


def test_a_session_without_a_site_certificate_cannot_join(acl_mesh, tmp_path):
    # a client that offers no certificate: the mutual-TLS handshake fails, nothing flows
    text = json.dumps({"mode": "client",
                       "connect": {"endpoints": [_router_endpoint(tmp_path)]},
                       "scouting": {"multicast": {"enabled": False}},
                       "transport": {"link": {"tls": {
                           "root_ca_certificate": str(tmp_path / "ca.pem")}}}})
    conf = zenoh.Config.from_json5(text)
    seen = []
    sub = acl_mesh["plant"].declare_subscriber(keys.mv("cstr"), lambda smp: seen.append(1))
    try:
        try:
            outsider = zenoh.open(conf)
        except zenoh.ZError:
            return  # refused outright
        try:
            time.sleep(0.3)
            outsider.put(keys.mv("cstr"), b"{}")
            time.sleep(0.5)
            assert not seen
        finally:
            outsider.close()
    finally:
        sub.undeclare()


def _router_endpoint(tmp_path):
    text = (tmp_path / "router.json5").read_text()
    start = text.index("tls/127.0.0.1:")
    return text[start:text.index('"', start)].replace("127.0.0.1", "localhost")
