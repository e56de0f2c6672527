"""Certificates of the OPC UA link: a CA and one application certificate per identity.

OPC 10000-6 §6.2.2 application instance certificates (RSA 2048, SHA-256, for the
Basic256Sha256 policy): the application URI in the subjectAltName (with
``localhost``, the host's name and ``127.0.0.1``), key usage digitalSignature, nonRepudiation,
keyEncipherment and dataEncipherment, extended key usage serverAuth (the plant)
or clientAuth (the clients). Made with ``cryptography`` on first start, signed by a
CA made alongside, written owner-only (files 0600, directory 0700); later starts
load them. Identities: ``plant`` (the server a DCS would run), ``controller`` (may
write set points and the heartbeat) and ``operator`` (reads).
"""

from __future__ import annotations

import datetime
import ipaddress
import os
import socket
from dataclasses import dataclass
from pathlib import Path

__all__ = ["IDENTITIES", "CertPaths", "application_uri", "ensure_certificates",
           "load_certificates"]

#: The identities a certificate is made for; ``plant`` is the server.
IDENTITIES = ("plant", "controller", "operator")

#: Validity of the certificates made here, days.
VALID_DAYS = 3650


def application_uri(identity: str) -> str:
    """The OPC UA application URI of an identity (in its certificate's SAN)."""
    return f"urn:ssmpc:{identity}"


@dataclass(frozen=True)
class CertPaths:
    """The PEM files of a certificate directory (``<name>.pem``, ``<name>-key.pem``)."""

    directory: Path

    @property
    def ca(self) -> Path:
        return self.directory / "ca.pem"

    def cert(self, identity: str) -> Path:
        return self.directory / f"{identity}.pem"

    def key(self, identity: str) -> Path:
        return self.directory / f"{identity}-key.pem"


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _name(cn: str):
    from cryptography import x509
    from cryptography.x509.oid import NameOID

    return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn),
                      x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ssmpc")])


def _make(directory: Path) -> None:
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import rsa
    from cryptography.x509.oid import ExtendedKeyUsageOID

    now = datetime.datetime.now(datetime.UTC) - datetime.timedelta(minutes=5)
    until = now + datetime.timedelta(days=VALID_DAYS)
    pem = serialization.Encoding.PEM
    pkcs8 = serialization.PrivateFormat.PKCS8
    none = serialization.NoEncryption()
    paths = CertPaths(directory)

    ca_key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
    ca_name = _name("ssmpc OPC UA CA")
    ca = (x509.CertificateBuilder().subject_name(ca_name).issuer_name(ca_name)
          .public_key(ca_key.public_key()).serial_number(x509.random_serial_number())
          .not_valid_before(now).not_valid_after(until)
          .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
          .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=False,
                                       key_encipherment=False, data_encipherment=False,
                                       key_agreement=False, key_cert_sign=True, crl_sign=True,
                                       encipher_only=False, decipher_only=False), critical=True)
          .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()),
                         critical=False)
          .sign(ca_key, hashes.SHA256()))
    for identity in IDENTITIES:
        key = rsa.generate_private_key(public_exponent=65537, key_size=2048)
        eku = ExtendedKeyUsageOID.SERVER_AUTH if identity == "plant" \
            else ExtendedKeyUsageOID.CLIENT_AUTH
        san = x509.SubjectAlternativeName([
            x509.UniformResourceIdentifier(application_uri(identity)),
            *(x509.DNSName(h) for h in dict.fromkeys(("localhost", socket.gethostname()))),
            x509.IPAddress(ipaddress.ip_address("127.0.0.1"))])
        cert = (x509.CertificateBuilder().subject_name(_name(identity)).issuer_name(ca_name)
                .public_key(key.public_key()).serial_number(x509.random_serial_number())
                .not_valid_before(now).not_valid_after(until)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, content_commitment=True,
                                             key_encipherment=True, data_encipherment=True,
                                             key_agreement=False, key_cert_sign=False,
                                             crl_sign=False, encipher_only=False,
                                             decipher_only=False), critical=True)
                .add_extension(x509.ExtendedKeyUsage([eku]), critical=False)
                .add_extension(san, critical=False)
                .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()),
                               critical=False)
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                    ca_key.public_key()), critical=False)
                .sign(ca_key, hashes.SHA256()))
        _write_private(paths.key(identity), key.private_bytes(pem, pkcs8, none))
        _write_private(paths.cert(identity), cert.public_bytes(pem))
    _write_private(directory / "ca-key.pem", ca_key.private_bytes(pem, pkcs8, none))
    _write_private(paths.ca, ca.public_bytes(pem))  # last: its presence means "complete"


def ensure_certificates(directory: str | Path) -> CertPaths:
    """The certificates in ``directory``, made there first if it has none.

    The directory is created owner-only (0700). A directory with some but not all
    of the files is an error (never silently replaced: a client may hold the old ones).

    Raises
    ------
    ValueError
        The directory cannot be written, or holds an incomplete set.
    """
    directory = Path(directory)
    paths = CertPaths(directory)
    try:
        directory.mkdir(parents=True, exist_ok=True, mode=0o700)
        os.chmod(directory, 0o700)
    except OSError as exc:
        raise ValueError(f"cert_dir: cannot create {directory} ({exc.strerror})") from exc
    if not paths.ca.exists():
        if any(paths.cert(i).exists() for i in IDENTITIES):
            raise ValueError(f"cert_dir: {directory} holds certificates but no ca.pem; "
                             "remove them to make a new set")
        try:
            _make(directory)
        except OSError as exc:
            raise ValueError(f"cert_dir: cannot write certificates in {directory} "
                             f"({exc.strerror})") from exc
    return load_certificates(directory)


def load_certificates(directory: str | Path) -> CertPaths:
    """The certificates already in ``directory`` (a controller never makes them).

    Raises
    ------
    ValueError
        A file is missing, or readable by others than the owner.
    """
    paths = CertPaths(Path(directory))
    files = [paths.ca] + [f for i in IDENTITIES for f in (paths.cert(i), paths.key(i))]
    for f in files:
        if not f.exists():
            raise ValueError(f"cert_dir: {f} is missing (the plant's OPC UA server makes the "
                             f"certificates on its first start: run it first, or point "
                             f"--state-dir at its directory)")
        if f.stat().st_mode & 0o077:
            raise ValueError(f"cert_dir: {f} is readable by others (chmod 600 it)")
    return paths
