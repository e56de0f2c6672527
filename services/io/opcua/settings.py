"""Settings of the OPC UA link between a plant (the DCS side) and its controller.

One frozen, self-validating dataclass shared by the server (:mod:`.server`) and the
controller's client (:mod:`.client`): the endpoint, where the certificates live, and
the two times of the heartbeat handshake (OPC 10000-4 leaves these to the
application; the values follow DCS practice, a link time-out of a few seconds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlparse

__all__ = ["DEFAULT_ENDPOINT", "NAMESPACE_URI", "OPCUASettings", "parse_endpoint"]

#: Endpoint of ``ssmpc up --io opcua`` when none is given.
DEFAULT_ENDPOINT = "opc.tcp://127.0.0.1:4840/ssmpc"
#: The namespace of every ssmpc node.
NAMESPACE_URI = "urn:ssmpc"


def parse_endpoint(endpoint: str) -> tuple[str, int]:
    """``(host, port)`` of an ``opc.tcp://HOST:PORT[/path]`` endpoint.

    Raises
    ------
    ValueError
        Not an ``opc.tcp`` URL, no host, or a port outside 1..65535.
    """
    if not isinstance(endpoint, str):
        raise ValueError("endpoint: expected opc.tcp://HOST:PORT[/path]")
    u = urlparse(endpoint)
    if u.scheme != "opc.tcp" or not u.hostname:
        raise ValueError(f"endpoint: expected opc.tcp://HOST:PORT[/path], got {endpoint!r}")
    try:
        port = u.port
    except ValueError as exc:
        raise ValueError(f"endpoint: bad port in {endpoint!r}") from exc
    if port is None or not 0 < port < 65536:
        raise ValueError(f"endpoint: port must be 1..65535 in {endpoint!r}")
    return u.hostname, port


@dataclass(frozen=True)
class OPCUASettings:
    """How a plant serves, and a controller reaches, the unit over OPC UA.

    Attributes
    ----------
    endpoint : str
        ``opc.tcp://HOST:PORT[/path]`` the server binds to and the client connects to.
    cert_dir : str
        Directory of the CA, server and client certificates (made on first start by
        :func:`services.io.opcua.certs.ensure_certificates`; owner-only files).
    watchdog_s : float
        Wall seconds without a controller heartbeat after which the plant sheds
        (holds the valves, ``Status/WatchdogState`` = ``shed``).
    heartbeat_s : float
        Longest wall time between two heartbeats the controller writes (it also
        writes one with every move); must be below ``watchdog_s``.
    allow_anonymous : bool
        Offer the anonymous identity token (read-only); off by default.
    timeout_s : float
        Client request timeout, s.
    retry_s : float
        Wall seconds between the client's reconnection attempts.
    """

    endpoint: str = DEFAULT_ENDPOINT
    cert_dir: str = "opcua"
    watchdog_s: float = 5.0
    heartbeat_s: float = 1.0
    allow_anonymous: bool = False
    timeout_s: float = 4.0
    retry_s: float = 1.0

    def __post_init__(self) -> None:
        parse_endpoint(self.endpoint)
        if not isinstance(self.cert_dir, str | Path) or not str(self.cert_dir):
            raise ValueError("cert_dir: expected a directory path")
        for name in ("watchdog_s", "heartbeat_s", "timeout_s", "retry_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) \
                    or v <= 0:
                raise ValueError(f"{name}: must be a positive number of seconds, got {v!r}")
        if self.heartbeat_s >= self.watchdog_s:
            raise ValueError(f"heartbeat_s: must be below watchdog_s ({self.watchdog_s:g} s), "
                             f"got {self.heartbeat_s:g}")
        if not isinstance(self.allow_anonymous, bool):
            raise ValueError("allow_anonymous: expected a boolean")

    @property
    def host_port(self) -> tuple[str, int]:
        return parse_endpoint(self.endpoint)
