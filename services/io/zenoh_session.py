"""Open a Zenoh session: from a config file, or the embedded default.

The embedded default is what ``ssmpc up`` needs on one machine and nothing
more: peer mode, listening on loopback only, multicast scouting off (peers
find each other through the endpoints they are told to connect to, then
gossip), and an optional short lease so that a frozen peer is noticed quickly
(the default lease is 10 s; a 1 s lease notices a frozen peer in ~0.75 s).
A client of the embedded default retries a lost router on a short period
(:data:`CLIENT_RETRY`), so the nodes of ``ssmpc up`` are back on a restarted router
within half a second of its return.

A config file (``--zenoh-config FILE``, JSON5 as read by
``zenoh.Config.from_file``) replaces the embedded default entirely; command
line ``--listen``/``--connect`` endpoints and the authentication below are then
added on top of it. The file is read when the settings are made: invalid JSON5,
an unknown field or a wrong value is a ``ValueError`` naming ``zenoh_config`` with
Zenoh's reason and the line (the CLI prints it as ``error: ...`` and exits 2),
never a traceback.

Authentication (:mod:`services.io.mesh_auth`, Zenoh's ``transport.auth.usrpwd``): a
node opens its session with its role's user name and password; a router checks the
sessions it accepts against a dictionary file and filters their messages with an
access-control list (:mod:`services.io.acl`).
"""

from __future__ import annotations

import json
import re
import socket
from dataclasses import dataclass, field
from pathlib import Path

__all__ = ["SessionSettings", "CLIENT_RETRY", "build_config", "open_session",
           "declare_loop_publisher", "declare_loop_subscriber", "free_port",
           "free_tcp_endpoint", "zenoh_reason", "PayloadSample"]

MODES = ("peer", "client", "router")

#: ``connect/retry`` of a client session of the embedded default: how often it tries
#: its router again once the link is lost. Zenoh's default (1 s, doubling to 4 s)
#: kept the nodes of ``ssmpc up`` cut off for 1.2 s after a router restarted 1.8 s
#: after its crash (they reconnected 3.0 s after it, the retry after 1 s and 2 s);
#: with these they reconnected as it came back (zenoh 1.10.2, loopback, three trials;
#: a failed try on loopback is one refused TCP connect).
CLIENT_RETRY = {"period_init_ms": 100, "period_max_ms": 500, "period_increase_factor": 2}


class PayloadSample:
    """A payload from another link (OPC UA), shaped as a Zenoh sample
    (``sample.payload.to_bytes()``), so that it takes the Zenoh path's checks."""

    __slots__ = ("payload", "_data")

    def __init__(self, data: bytes) -> None:
        self._data = data
        self.payload = self

    def to_bytes(self) -> bytes:
        return self._data


@dataclass(frozen=True)
class SessionSettings:
    """How a node joins the Zenoh mesh.

    Parameters
    ----------
    config_file : str or None
        A Zenoh JSON5 configuration; None for the embedded default.
    mode : str
        ``peer``, ``client`` or ``router`` (embedded default only).
    listen, connect : tuple of str
        Endpoints such as ``tcp/127.0.0.1:7447``.
    lease_ms : int or None
        Transport lease in ms; None keeps Zenoh's default.
    multicast_scouting : bool
        Embedded default keeps it off.
    user, password : str or None
        Zenoh user/password authentication of this session (both or neither).
    dictionary_file : str or None
        Accept only sessions that authenticate against this ``user:password`` file.
    access_control : dict or None
        A Zenoh ``access_control`` block for the sessions this one accepts.
    """

    config_file: str | None = None
    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    lease_ms: int | None = None
    multicast_scouting: bool = False
    extra: dict = field(default_factory=dict)
    user: str | None = None
    password: str | None = field(default=None, repr=False)
    dictionary_file: str | None = None
    access_control: dict | None = None

    def __post_init__(self) -> None:
        if (self.user is None) != (self.password is None):
            raise ValueError("credentials: a user name needs a password and a password a user")
        if self.dictionary_file is not None and not Path(self.dictionary_file).is_file():
            raise ValueError(f"credentials: dictionary {self.dictionary_file!r} does not exist")
        if self.access_control is not None and not isinstance(self.access_control, dict):
            raise ValueError("access_control: must be a mapping (Zenoh's access_control block)")
        if self.mode not in MODES:
            raise ValueError(f"mode: expected one of {MODES}, got {self.mode!r}")
        if self.lease_ms is not None and not (100 <= int(self.lease_ms) <= 600_000):
            raise ValueError(f"lease_ms: must be in [100, 600000] ms, got {self.lease_ms}")
        for name in ("listen", "connect"):
            for ep in getattr(self, name):
                if "/" not in ep:
                    raise ValueError(f"{name}: endpoint {ep!r} is not of the form proto/addr:port")
        if self.config_file is not None:
            if not Path(self.config_file).is_file():
                raise ValueError(f"zenoh_config: file {self.config_file!r} does not exist")
            _read_config_file(self.config_file)


_JSON_REASON = re.compile(r'msg: "(?P<msg>.*?)", location: Some\(Location \{ line: '
                          r'(?P<line>\d+), column: (?P<col>\d+)', re.S)
_PARSE_REASON = re.compile(r"-->\s*(?P<line>\d+):(?P<col>\d+).*=\s*(?P<msg>[^\n]+)", re.S)
_SOURCE_PATH = re.compile(r"\s+at /\S+?\.rs:\d+\.?")


def zenoh_reason(exc: BaseException) -> str:
    """Zenoh's error text in one line: the reason and where, without its source path."""
    text = str(exc)
    m = _JSON_REASON.search(text)
    if m:
        return f"{m['msg']} (line {m['line']}, column {m['col']})"
    m = _PARSE_REASON.search(_SOURCE_PATH.sub("", text))
    if m:  # the JSON5 parser's report
        return f"not JSON5: {m['msg'].strip()} (line {m['line']}, column {m['col']})"
    return " ".join(_SOURCE_PATH.sub("", text).split()) or type(exc).__name__


def _read_config_file(path: str):
    import zenoh

    try:
        return zenoh.Config.from_file(str(path))
    except Exception as exc:  # zenoh.ZError: not JSON5, unknown field, wrong value
        raise ValueError(f"zenoh_config: {path}: {zenoh_reason(exc)}") from None


def build_config(settings: SessionSettings):
    """A ``zenoh.Config`` for ``settings``."""
    import zenoh

    if settings.config_file is not None:
        conf = _read_config_file(settings.config_file)
        try:
            if settings.listen:
                conf.insert_json5("listen/endpoints", json.dumps(list(settings.listen)))
            if settings.connect:
                conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
        except Exception as exc:
            raise ValueError(f"listen/connect: {zenoh_reason(exc)}") from None
        _insert_auth(conf, settings)
        return conf
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(settings.mode))
    listen = list(settings.listen)
    if not listen and settings.mode != "client":
        listen = ["tcp/127.0.0.1:0"]
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    conf.insert_json5("connect/endpoints", json.dumps(list(settings.connect)))
    if settings.mode == "client":
        conf.insert_json5("connect/retry", json.dumps(CLIENT_RETRY))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(settings.multicast_scouting)))
    if settings.lease_ms is not None:
        conf.insert_json5("transport/link/tx/lease", str(int(settings.lease_ms)))
    for key, value in settings.extra.items():
        conf.insert_json5(key, json.dumps(value))
    _insert_auth(conf, settings)
    return conf


def _insert_auth(conf, settings: SessionSettings) -> None:
    """User/password, dictionary and access control of ``settings`` into ``conf``."""
    entries = []
    if settings.user is not None:
        entries += [("transport/auth/usrpwd/user", settings.user),
                    ("transport/auth/usrpwd/password", settings.password)]
    if settings.dictionary_file is not None:
        entries.append(("transport/auth/usrpwd/dictionary_file",
                        str(Path(settings.dictionary_file).resolve())))
    if settings.access_control is not None:
        entries.append(("access_control", settings.access_control))
    for key, value in entries:
        try:
            conf.insert_json5(key, json.dumps(value))
        except Exception as exc:  # zenoh.ZError: a field Zenoh refuses
            raise ValueError(f"{key.split('/')[0]}: {zenoh_reason(exc)}") from None


def open_session(settings: SessionSettings | None = None):
    """Open and return a ``zenoh.Session``; the caller must ``close()`` it.

    Raises
    ------
    ValueError
        The session cannot be opened (an endpoint in use or unreachable, a config
        Zenoh refuses): the message names Zenoh's reason.
    """
    import zenoh

    conf = build_config(settings or SessionSettings())
    try:
        return zenoh.open(conf)
    except Exception as exc:  # zenoh.ZError
        reason = zenoh_reason(exc)
        if "shm" in reason.lower():  # its shared-memory segments live in /dev/shm
            reason += (" (/dev/shm is full or not writable: free room there, or set "
                       "transport/shared_memory/enabled to false in the Zenoh config)")
        raise ValueError(f"zenoh: cannot open the session: {reason}") from None


def declare_loop_publisher(session, key_expr):
    """A publisher for the control loop's own messages (measurements, moves).

    Express (sent at once, not held back for batching), real-time priority (ahead
    of status and telemetry on a shared link) and drop on congestion (a newer
    sample replaces a message a congested link cannot take; the plant holds the
    last move, as a DCS does).
    """
    import zenoh

    return session.declare_publisher(key_expr, express=True,
                                     priority=zenoh.Priority.REAL_TIME,
                                     congestion_control=zenoh.CongestionControl.DROP)


def declare_loop_subscriber(session, key_expr, callback, *, poll_queue: int | None = None):
    """A subscriber for the control loop's own messages.

    ``callback`` runs on Zenoh's thread for each sample; with ``poll_queue`` Zenoh's
    thread only queues the samples in a FIFO channel of that depth, and the loop's
    own thread takes them with ``try_recv`` (busy polling).
    """
    if poll_queue is None:
        return session.declare_subscriber(key_expr, callback)
    import zenoh

    return session.declare_subscriber(key_expr,
                                      handler=zenoh.handlers.FifoChannel(int(poll_queue)))


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that was free a moment ago (for tests and ``ssmpc up``)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return s.getsockname()[1]


def free_tcp_endpoint(host: str = "127.0.0.1") -> str:
    return f"tcp/{host}:{free_port(host)}"
