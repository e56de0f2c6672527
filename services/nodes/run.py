"""``ssmpc plant|controller|api|opcua``: one node alone, on the embedded default or a Zenoh mesh.

``ssmpc opcua`` is the plant node serving its unit over OPC UA as well
(:mod:`services.io.opcua.server`, a simulated DCS); ``ssmpc controller --plant-io
opcua`` reads measurements and writes moves over OPC UA instead of Zenoh
(:mod:`services.io.opcua.client`). Commands, status and liveliness stay on Zenoh.

Each node opens its own Zenoh session (``--zenoh-config FILE`` or the embedded
default: peer mode, loopback, multicast scouting off; ``--listen`` and
``--connect`` add endpoints; ``--credentials DIR`` authenticates it as its
identity, :mod:`services.io.mesh_auth`), prints ``ready <role> <unit>`` on stdout when it
serves, and stops cleanly on SIGINT/SIGTERM or after ``--duration`` wall
seconds: telemetry flushed, checkpoint written, session closed.
"""

from __future__ import annotations

import logging
import signal
import sys
import threading
import time

from services.output import CLIError

__all__ = ["register", "add_mesh_arguments", "add_opcua_arguments", "opcua_settings",
           "session_settings"]


def add_mesh_arguments(p) -> None:
    g = p.add_argument_group("Zenoh mesh")
    g.add_argument("--zenoh-config", metavar="FILE",
                   help="Zenoh JSON5 config (default: embedded peer on loopback, no multicast)")
    g.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)")
    g.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="endpoint to connect to (repeatable)")
    g.add_argument("--mode", choices=["peer", "client"], default="peer",
                   help="Zenoh mode of the embedded default (default peer)")
    g.add_argument("--lease-ms", type=int, default=None,
                   help="transport lease in ms (shorter: a dead peer is noticed sooner)")
    g.add_argument("--credentials", metavar="DIR", default=None,
                   help="mesh credentials directory (ssmpc credentials; <state-dir>/mesh of "
                        "ssmpc up): the session authenticates as this command's identity")


#: The mesh identity of each node command (services.io.mesh_auth); any other is ``cli``.
ROLE_OF_COMMAND = {"plant": "plant", "opcua": "plant", "controller": "controller", "api": "api"}


def session_settings(args, role: str | None = None):
    """The node's :class:`~services.io.zenoh_session.SessionSettings`; with
    ``--credentials`` it authenticates as ``role`` (default: its command's identity)."""
    from services.io.zenoh_session import SessionSettings

    auth = {}
    cred_dir = getattr(args, "credentials", None)
    if cred_dir is not None:
        from services.io.mesh_auth import node_credentials

        role = role or ROLE_OF_COMMAND.get(getattr(args, "command", None), "cli")
        cred = node_credentials(cred_dir, role)
        auth = {"user": cred.user, "password": cred.password}
    settings = SessionSettings(config_file=args.zenoh_config, mode=args.mode,
                               listen=tuple(args.listen), connect=tuple(args.connect),
                               lease_ms=args.lease_ms, **auth)
    if auth and _mode_of(settings) != "client":
        # a peer listens, and what it accepts is not authenticated: a session there could
        # answer this node's queries or feed it samples past the router's ACL
        raise CLIError("credentials: a node with credentials joins the mesh's router as a "
                       "Zenoh client (--mode client --connect ROUTER, or a client config "
                       f"such as deploy/zenoh/client.json5), not as a {_mode_of(settings)}")
    return settings


def _mode_of(settings) -> str:
    """The Zenoh mode a node's session will open in."""
    import json

    if settings.config_file is None:
        return settings.mode
    from services.io.zenoh_session import build_config

    return json.loads(build_config(settings).get_json("mode"))


def add_opcua_arguments(p, *, server: bool) -> None:
    from services.io.opcua.settings import DEFAULT_ENDPOINT

    g = p.add_argument_group("OPC UA link")
    g.add_argument("--opcua-endpoint", "--endpoint", dest="opcua_endpoint",
                   default=DEFAULT_ENDPOINT, metavar="URL",
                   help=f"opc.tcp://HOST:PORT[/path] (default {DEFAULT_ENDPOINT})")
    g.add_argument("--opcua-cert-dir", default=None, metavar="DIR",
                   help="CA and certificates (default <state-dir>/opcua; the server makes "
                        "them on its first start, owner-only)")
    g.add_argument("--watchdog", type=float, default=5.0, metavar="S",
                   help="plant sheds (holds the valves) after S wall seconds without a "
                        "controller heartbeat (default 5)")
    if server:
        g.add_argument("--allow-anonymous", action="store_true",
                       help="offer the anonymous identity (read-only; default off)")
    else:
        g.add_argument("--heartbeat", type=float, default=1.0, metavar="S",
                       help="longest wall time between heartbeats (default 1; also one per "
                            "move)")


def opcua_settings(args):
    """:class:`~services.io.opcua.settings.OPCUASettings` of the parsed arguments."""
    from pathlib import Path

    from services.io.opcua.settings import OPCUASettings

    cert_dir = args.opcua_cert_dir or str(Path(getattr(args, "state_dir", ".")) / "opcua")
    kw = {"endpoint": args.opcua_endpoint, "cert_dir": cert_dir, "watchdog_s": args.watchdog}
    if hasattr(args, "heartbeat"):
        kw["heartbeat_s"] = args.heartbeat
    if hasattr(args, "allow_anonymous"):
        kw["allow_anonymous"] = args.allow_anonymous
    try:
        return OPCUASettings(**kw)
    except ValueError as exc:
        raise CLIError(str(exc)) from exc


def _quiet_asyncua() -> None:
    # asyncua logs expected events (revised parameters, a peer gone) as warnings and
    # errors; the link logs what matters itself
    logging.getLogger("asyncua").setLevel(logging.CRITICAL)


def _add_unit_arguments(p) -> None:
    p.add_argument("--unit", default="te", help="unit name (see services.registry; default te)")
    p.add_argument("--unit-config", metavar="FILE", help="JSON overrides of the unit config")
    p.add_argument("--speed", type=float, default=1.0,
                   help="process seconds per wall second (default 1 = real time)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop by itself after this many wall seconds")
    p.add_argument("--rt-priority", type=int, default=None,
                   help="run the node under SCHED_FIFO with this priority 1..99 (Linux)")


def _add_plant_arguments(p) -> None:
    _add_unit_arguments(p)
    add_mesh_arguments(p)
    p.add_argument("--lockstep", action="store_true",
                   help="wait for each sample's MV instead of the wall clock (tests, benches)")
    p.add_argument("--lockstep-timeout", type=float, default=2.0,
                   help="longest wait for an MV in lock-step mode, wall s")
    p.add_argument("--sender", default=None, help="expected controller sender id")
    p.add_argument("--noise", action="store_true", help="TE: measurement noise on")
    p.add_argument("--idv", action="append", type=int, default=[], metavar="K",
                   help="TE: switch disturbance IDV(K) on from the start (repeatable)")
    p.add_argument("--busy-poll", action="store_true",
                   help="keep the sample boundaries by polling instead of sleeping (a "
                        "wake-up can come ms late on a VM), at the cost of one CPU at "
                        "100%% (docs/realtime.md)")


def register(sub) -> None:
    p = sub.add_parser("plant", help="run a unit's plant node (scaled real time on Zenoh)")
    _add_plant_arguments(p)
    p.set_defaults(func=run_plant)

    p = sub.add_parser("opcua", help="run a unit's plant as an OPC UA server (a simulated "
                                     "DCS), its commands on Zenoh")
    _add_plant_arguments(p)
    p.add_argument("--state-dir", default=".",
                   help="directory of the OPC UA certificates (<dir>/opcua; default .)")
    add_opcua_arguments(p, server=True)
    p.set_defaults(func=run_opcua)

    p = sub.add_parser("controller", help="run a unit's controller node")
    _add_unit_arguments(p)
    add_mesh_arguments(p)
    p.add_argument("--state-dir", default=".", help="directory of the SQLite store (default .)")
    p.add_argument("--rrd", default=None,
                   help="Rerun recording file (default <state-dir>/ssmpc-<unit>.rrd)")
    p.add_argument("--rerun-addr", default=None,
                   help="send telemetry to a Rerun viewer (rerun+http://host:9876/proxy) "
                        "instead of a file")
    p.add_argument("--no-telemetry", action="store_true", help="do not record telemetry")
    p.add_argument("--sender", default=None, help="sender id written into MV messages")
    p.add_argument("--busy-poll", action="store_true",
                   help="poll for measurements without sleeping: the step starts from warm "
                        "caches, at the cost of one CPU at 100%% (docs/realtime.md)")
    p.add_argument("--plant-io", choices=["zenoh", "opcua"], default="zenoh",
                   help="how measurements and moves travel (default zenoh); commands, "
                        "status and the api stay on Zenoh")
    add_opcua_arguments(p, server=False)
    p.set_defaults(func=run_controller)

    p = sub.add_parser("api", help="run the REST api node (FastAPI on uvicorn)")
    add_mesh_arguments(p)
    p.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000)")
    p.add_argument("--query-timeout", type=float, default=2.0,
                   help="Zenoh query timeout, s (then 504)")
    p.add_argument("--duration", type=float, default=None,
                   help="stop by itself after this many wall seconds")
    p.set_defaults(func=run_api)


def _realtime_tuning(rt_priority: int | None = None) -> None:
    """Fewer, shorter pauses in a node's sample loop, once set-up is done.

    The process settings of a sample loop (:func:`services.realtime_process.
    settle_for_samples`: the set-up's objects frozen out of the collector's way, rarer
    young collections, BLAS on the calling thread, a 0.5 ms interpreter switch
    interval). With ``rt_priority`` every thread of the process (including Zenoh's)
    runs under ``SCHED_FIFO`` (Linux, needs CAP_SYS_NICE), as a control loop on a
    shared machine should.
    """
    import os

    from services.realtime_process import settle_for_samples

    settle_for_samples()
    if rt_priority is not None:
        if not 1 <= rt_priority <= 99:
            raise CLIError(f"rt_priority: must be 1..99, got {rt_priority}")
        try:
            param = os.sched_param(rt_priority)
            for tid in os.listdir("/proc/self/task"):
                os.sched_setscheduler(int(tid), os.SCHED_FIFO, param)
        except (OSError, AttributeError) as exc:
            raise CLIError(f"rt_priority: cannot switch to SCHED_FIFO ({exc})") from exc


def _warn_busy_poll_under_fifo(role: str, args) -> None:
    if args.busy_poll and args.rt_priority is not None:
        # a SCHED_FIFO thread that never sleeps keeps its CPU from every thread of
        # lower or equal priority (Zenoh's, the kernel's) but for the RT throttling
        logging.getLogger(f"ssmpc.{role}").warning(
            "--busy-poll with --rt-priority: the polling thread holds one CPU under "
            "SCHED_FIFO; give the node a CPU of its own (isolcpus, taskset)")


def _logging() -> None:
    import faulthandler

    logging.basicConfig(level=logging.WARNING, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    # a fatal signal (SIGSEGV, SIGBUS from a mapped file that cannot be backed) leaves
    # the Python stacks of every thread in the log instead of an empty one
    # (a stderr without a file descriptor, e.g. captured in a test, has nowhere to
    # write them from a signal handler: the process's own stderr then)
    try:
        faulthandler.enable(file=sys.stderr, all_threads=True)
    except (AttributeError, OSError, ValueError):  # io.UnsupportedOperation: fileno
        if sys.__stderr__ is not None:
            faulthandler.enable(file=sys.__stderr__, all_threads=True)


def _stop_event(duration: float | None) -> threading.Event:
    stop = threading.Event()

    def handler(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    if duration is not None:
        if duration <= 0:
            raise CLIError("duration: must be positive wall seconds")
        timer = threading.Timer(duration, stop.set)
        timer.daemon = True
        timer.start()
    return stop


def _ready(role: str, unit: str, **extra) -> None:
    tail = " ".join(f"{k}={v}" for k, v in extra.items())
    print(f"ready {role} {unit} {tail}".rstrip(), flush=True)


def _config(args):
    """The unit's validated config (exit 2 on a bad speed, unit or override file)."""
    from services.registry import load_unit_config

    if args.speed is None or not args.speed > 0:
        raise CLIError("speed: must be positive (process seconds per wall second)")
    return load_unit_config(args.unit, args.unit_config)


def _is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    import ipaddress

    if host.strip().lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip().strip("[]")).is_loopback
    except ValueError:
        return False  # a name: it may resolve beyond loopback


def run_opcua(args) -> int:
    """``ssmpc opcua``: the plant node with its OPC UA server."""
    from services.io.opcua.server import PlantOPCUAServer

    _logging()
    _quiet_asyncua()
    cfg = _config(args)
    settings = opcua_settings(args)
    try:
        link = PlantOPCUAServer(cfg, settings)
    except ValueError as exc:
        raise CLIError(str(exc)) from exc
    return run_plant(args, link=link)


def run_plant(args, link=None) -> int:
    from services.io.zenoh_session import open_session
    from services.nodes.plant import PlantNode, make_runner

    if link is None:
        _logging()
    settings = session_settings(args)  # a bad Zenoh config fails before anything starts
    cfg = _config(args)
    if (args.noise or args.idv) and cfg.plant != "te":
        raise CLIError("noise/idv: only the TE plant has them; use the plant's "
                       "'disturbance' command for the others")
    runner = make_runner(cfg, noise=args.noise) if cfg.plant == "te" else make_runner(cfg)
    for k in args.idv:
        if not 1 <= k <= 20:
            raise CLIError(f"idv: IDV number must be 1..20, got {k}")
        runner.set_idv(k, True)
    stop = _stop_event(args.duration)
    session = open_session(settings)
    node = None
    try:
        try:
            node = PlantNode(cfg, session, speed=args.speed, expected_sender=args.sender,
                             lockstep=args.lockstep, lockstep_timeout_s=args.lockstep_timeout,
                             runner=runner, busy_poll=args.busy_poll, link=link)
        except ValueError as exc:  # the link could not serve (endpoint in use ...)
            raise CLIError(str(exc)) from exc
        _realtime_tuning(args.rt_priority)
        _warn_busy_poll_under_fifo("plant", args)
        extra = {} if link is None else {"opcua": link.settings.endpoint}
        _ready("plant", cfg.unit, zid=session.zid(), **extra)
        node.run(stop)
    finally:
        if node is not None:
            node.close()
        session.close()
    return 0


def _unused_path(path) -> str:
    """``path`` if free, else ``<stem>.<n><suffix>``: a restart never overwrites a recording."""
    if not path.exists():
        return str(path)
    n = 1
    while True:
        candidate = path.with_name(f"{path.stem}.{n}{path.suffix}")
        if not candidate.exists():
            return str(candidate)
        n += 1


def run_controller(args) -> int:
    from pathlib import Path

    from controller.units.config import build_plant, unit_info
    from controller.units.variables import unit_variables
    from services.io.zenoh_session import open_session
    from services.nodes.controller import ControllerNode
    from services.store import UnitStore, default_store_path
    from services.telemetry import TelemetryLogger

    _logging()
    settings = session_settings(args)  # a bad Zenoh config fails before anything starts
    cfg = _config(args)
    link = None
    if args.plant_io == "opcua":
        from services.io.opcua.client import ControllerOPCUALink

        if args.busy_poll:
            raise CLIError("busy_poll: polls the Zenoh channel; not with --plant-io opcua")
        _quiet_asyncua()
        try:
            link = ControllerOPCUALink(cfg, opcua_settings(args))
        except ValueError as exc:
            raise CLIError(str(exc)) from exc
    plant = build_plant(cfg)
    info = unit_info(cfg, plant)
    stop = _stop_event(args.duration)
    store = UnitStore(default_store_path(cfg.unit, args.state_dir), cfg.unit)
    sink = None
    if not args.no_telemetry:
        sink = args.rerun_addr or args.rrd or str(Path(args.state_dir) / f"ssmpc-{cfg.unit}.rrd")
        if not args.rerun_addr:
            sink = _unused_path(Path(sink))
    # A restarted node continues its recording: same recording id, next file.
    cp = store.load_checkpoint()
    recording_id = None if cp is None else cp["state"].get("recording_id")
    telemetry = TelemetryLogger(cfg.unit, info.cv_names, info.mv_names, sink,
                                batch=cfg.telemetry_every, ref_names=cfg.track or None,
                                recording_id=recording_id,
                                variables=unit_variables(cfg, plant))
    try:
        session = open_session(settings)
    except BaseException:
        telemetry.close()
        store.close()
        raise
    node = None
    try:
        node = ControllerNode(cfg, session, store, telemetry, speed=args.speed,
                              sender=args.sender, busy_poll=args.busy_poll, plant_link=link)
        _realtime_tuning(args.rt_priority)
        _warn_busy_poll_under_fifo("controller", args)
        _ready("controller", cfg.unit, zid=session.zid(), store=store.path)
        node.run(stop)
    finally:
        if node is not None:
            node.close()
        else:
            telemetry.close()
        session.close()
        store.close()
    return 0


def run_api(args) -> int:
    import uvicorn

    from api.app import create_app
    from api.auth import ENV, token_from_env
    from api.mesh import Mesh
    from services.io.zenoh_session import open_session

    _logging()
    if not 0 < args.port < 65536:
        raise CLIError(f"port: must be 1..65535, got {args.port}")
    settings = session_settings(args)
    token = token_from_env()  # set but empty: a config error
    if token is None and not _is_loopback(args.host):
        raise CLIError(f"host: serving on {args.host} (beyond loopback) needs a write token; "
                       f"set {ENV}")
    session = open_session(settings)
    mesh = Mesh(session, timeout_s=args.query_timeout)
    try:
        app = create_app(mesh, token=token, token_from_environment=False)
        config = uvicorn.Config(app, host=args.host, port=args.port, log_level="warning",
                                access_log=False, lifespan="off")
        server = uvicorn.Server(config)
        stop = _stop_event(args.duration)
        # uvicorn runs in a worker thread (so it installs no signal handlers); the main
        # thread owns SIGINT/SIGTERM and tells it to exit.
        thread = threading.Thread(target=server.run, name="uvicorn", daemon=True)
        thread.start()
        while not server.started and thread.is_alive() and not stop.is_set():
            time.sleep(0.02)
        if not thread.is_alive() and not server.started:
            raise CLIError(f"port: cannot serve on {args.host}:{args.port} (in use?)")
        if server.started:
            _ready("api", "-", url=f"http://{args.host}:{args.port}")
        while not stop.is_set() and thread.is_alive():
            stop.wait(0.2)
        server.should_exit = True
        thread.join(timeout=10)
    finally:
        mesh.close()
        session.close()
    return 0
