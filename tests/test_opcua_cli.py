"""The OPC UA commands' bad input (exit 2, one ``error:`` line) and the link settings."""

import os
import stat

import pytest

from services.cli import main
from services.io.opcua.certs import IDENTITIES, ensure_certificates, load_certificates
from services.io.opcua.settings import OPCUASettings


@pytest.mark.parametrize("endpoint", ["http://127.0.0.1:4840", "opc.tcp://:4840",
                                      "opc.tcp://127.0.0.1:0/x", "opc.tcp://127.0.0.1:99999"])
def test_bad_endpoints_are_config_errors(endpoint, capsys, tmp_path):
    assert main(["opcua", "--unit", "cstr", "--endpoint", endpoint,
                 "--state-dir", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: endpoint:") and "Traceback" not in err


def test_watchdog_must_exceed_the_heartbeat(capsys, tmp_path):
    assert main(["controller", "--unit", "cstr", "--plant-io", "opcua", "--watchdog", "0.5",
                 "--heartbeat", "1", "--state-dir", str(tmp_path)]) == 2
    assert "heartbeat_s: must be below watchdog_s" in capsys.readouterr().err
    with pytest.raises(ValueError, match="watchdog_s"):
        OPCUASettings(watchdog_s=float("nan"))


def test_controller_without_certificates_says_where_they_come_from(capsys, tmp_path):
    assert main(["controller", "--unit", "cstr", "--plant-io", "opcua",
                 "--state-dir", str(tmp_path), "--no-telemetry"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: cert_dir:") and "is missing" in err


def test_busy_poll_is_for_the_zenoh_link(capsys, tmp_path):
    ensure_certificates(tmp_path / "opcua")
    assert main(["controller", "--unit", "cstr", "--plant-io", "opcua", "--busy-poll",
                 "--state-dir", str(tmp_path), "--no-telemetry"]) == 2
    assert "busy_poll" in capsys.readouterr().err


def test_certificates_are_owner_only_and_made_once(tmp_path):
    d = tmp_path / "opcua"
    paths = ensure_certificates(d)
    assert stat.S_IMODE(os.stat(d).st_mode) == 0o700
    files = sorted(d.iterdir())
    assert len(files) == 2 + 2 * len(IDENTITIES)  # CA and its key, a pair per identity
    assert all(stat.S_IMODE(f.stat().st_mode) == 0o600 for f in files)
    before = {f.name: f.read_bytes() for f in files}
    ensure_certificates(d)
    assert {f.name: f.read_bytes() for f in sorted(d.iterdir())} == before
    os.chmod(paths.key("controller"), 0o644)
    with pytest.raises(ValueError, match="readable by others"):
        load_certificates(d)
    os.remove(paths.ca)
    with pytest.raises(ValueError, match="no ca.pem"):
        ensure_certificates(d)


def test_certificates_carry_the_application_uri(tmp_path):
    from cryptography import x509

    paths = ensure_certificates(tmp_path / "opcua")
    ca = x509.load_pem_x509_certificate(paths.ca.read_bytes())
    for identity in IDENTITIES:
        cert = x509.load_pem_x509_certificate(paths.cert(identity).read_bytes())
        cert.verify_directly_issued_by(ca)
        san = cert.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
        assert f"urn:ssmpc:{identity}" in san.get_values_for_type(x509.UniformResourceIdentifier)
        ku = cert.extensions.get_extension_for_class(x509.KeyUsage).value
        assert ku.digital_signature and ku.key_encipherment and ku.data_encipherment


def test_an_endpoint_in_use_is_a_clear_error(capsys, tmp_path):
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        assert main(["opcua", "--unit", "cstr", "--endpoint", f"opc.tcp://127.0.0.1:{port}",
                     "--state-dir", str(tmp_path), "--duration", "5"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: endpoint: cannot serve") and "in use" in err
