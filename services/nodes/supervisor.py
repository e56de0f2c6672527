"""``ssmpc up``: plant + controller + api of one unit on the embedded default.

Three child processes (``ssmpc plant|controller|api``) joined by an authenticated
Zenoh router, a fourth child (``ssmpc router``) on a fresh loopback port
(:mod:`services.io.mesh_router`): on first start ``up`` makes one password per node
identity in ``<state-dir>/mesh`` (owner-only; reused later), the nodes join as Zenoh
clients with their identity's credentials and listen on nothing, and the router's
access-control list lets only the controller move the plant, only the plant publish
measurements, only the api (or an operator's ``cli`` identity) command the nodes, and
each node hold only its own liveliness token (:mod:`services.io.acl`); multicast
scouting off, Rerun to
``<state-dir>/ssmpc-<unit>.rrd``, API on 127.0.0.1:``--port``. The simulated
plant starts afresh, so by default a previous run's store and recording are
renamed with a time stamp (``--resume`` keeps the store, e.g. to continue). ``up`` waits
until each child prints ``ready``, then runs until Ctrl-C/SIGTERM or
``--duration`` wall seconds, and stops the children with SIGTERM (SIGKILL after
a grace period; the router last). It supervises them: a node that dies is restarted
with a growing pause (:data:`RESTART_BACKOFF_S`, doubling), with an ``alarm:`` line,
while the others keep running (the controller resumes from its store, bumplessly); a
node that dies more than :data:`RESTART_LIMIT` times within :data:`RESTART_WINDOW_S`
stops ``up``. The router is supervised the same way, and on the same endpoint, so
the supervisor outlives a crash of the Zenoh library in the router (one was seen
with eclipse-zenoh 1.10.2: a general-protection fault in the router's receive thread
as a SIGKILLed client's link closed, which took down ``up`` while it hosted the
router); while it is down the nodes are cut off from each other, the plant holds its
last moves and the controller reports the plant lost, and once it is back the nodes'
sessions reconnect by themselves (a grade change under way goes on; it fails as "not
settled" when the cut leaves it too little of the time it was given to settle).
Measured (``up --unit cstr --speed 20 --lease-ms 500``, 2-vCPU AMD EPYC, three runs):
the router SIGKILLed was ready again 1.8-1.9 s later (the 1 s pause and its 0.75 s
start), and the controller counted new samples, the plant alive again, 0.03-0.06 s
after that (the clients retry their router every 100-500 ms,
:data:`services.io.zenoh_session.CLIENT_RETRY`).
Children get the parent-death signal, so no orphan survives
even if ``up`` itself is killed.

``--io opcua``: the plant runs as ``ssmpc opcua`` (its OPC UA server on
``--opcua-endpoint``, a simulated DCS) and the controller as ``ssmpc controller
--plant-io opcua``; the certificates are made in ``<state-dir>/opcua`` before either
starts, and the plant starts first (the controller connects to it).
"""

from __future__ import annotations

import collections
import os
import queue
import signal
import subprocess
import sys
import threading
import time

from services.output import CLIError

__all__ = ["register", "run_up"]

DEFAULT_UNIT = "te"
#: Supervision: a node that dies is restarted after RESTART_BACKOFF_S, doubling with
#: each restart; more than RESTART_LIMIT restarts of one node within RESTART_WINDOW_S
#: stops ``up`` (exit 1).
RESTART_BACKOFF_S = 1.0
RESTART_LIMIT = 5
RESTART_WINDOW_S = 600.0


def register(sub) -> None:
    p = sub.add_parser("up", help="plant + controller + api for one unit on the embedded default")
    p.add_argument("--unit", default=DEFAULT_UNIT, help=f"unit (default {DEFAULT_UNIT})")
    p.add_argument("--speed", type=float, default=1.0,
                   help="process seconds per wall second (default 1)")
    p.add_argument("--port", type=int, default=8000, help="API port on 127.0.0.1 (default 8000)")
    p.add_argument("--state-dir", default=".",
                   help="SQLite store, .rrd and mesh credentials (<dir>/mesh) (default .)")
    p.add_argument("--unit-config", metavar="FILE", help="JSON overrides of the unit config")
    p.add_argument("--duration", type=float, default=None,
                   help="stop by itself after this many wall seconds")
    p.add_argument("--lockstep", action="store_true",
                   help="plant waits for each MV instead of the wall clock")
    p.add_argument("--lease-ms", type=int, default=1000, help="Zenoh lease, ms (default 1000)")
    p.add_argument("--busy-poll", action="store_true",
                   help="controller polls for measurements (warm caches; one CPU at 100%%)")
    p.add_argument("--ready-timeout", type=float, default=120.0,
                   help="longest wait for the nodes to start, s")
    p.add_argument("--resume", action="store_true",
                   help="keep the controller's store of a previous run (default: the simulated "
                        "plant starts afresh, so the previous store and recording are moved "
                        "aside with a time stamp)")
    p.add_argument("--restart-limit", type=int, default=RESTART_LIMIT,
                   help=f"restarts of a node that dies, within {RESTART_WINDOW_S / 60:.0f} min, "
                        f"before up gives up (default {RESTART_LIMIT}; 0: never restart)")
    p.add_argument("--io", choices=["zenoh", "opcua"], default="zenoh",
                   help="plant link of the controller (default zenoh; opcua: the plant "
                        "serves OPC UA as a DCS would)")
    from services.io.opcua.settings import DEFAULT_ENDPOINT

    p.add_argument("--opcua-endpoint", default=DEFAULT_ENDPOINT, metavar="URL",
                   help=f"with --io opcua: the plant's endpoint (default {DEFAULT_ENDPOINT})")
    p.add_argument("--watchdog", type=float, default=5.0, metavar="S",
                   help="with --io opcua: the plant sheds after S s without a heartbeat")
    p.set_defaults(func=run_up)


def _pdeathsig():  # pragma: no cover - runs in the child
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except Exception:
        pass


#: Lines of a node's standard error kept by :func:`_spawn` with ``tee_stderr``.
STDERR_TAIL_LINES = 40


def _spawn(argv: list[str], tee_stderr: bool = False) -> subprocess.Popen:
    """Start ``ssmpc <argv>`` as a child node, its stdout piped for :func:`_wait_ready`.

    Its standard error goes to this process's; with ``tee_stderr`` it is also kept
    (the last :data:`STDERR_TAIL_LINES` lines, :func:`stderr_tail`), so that a caller
    can tell why a node exited before it was ready."""
    proc = subprocess.Popen([sys.executable, "-m", "services.cli", *argv],
                            stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE if tee_stderr else None, text=True,
                            bufsize=1,
                            preexec_fn=_pdeathsig if sys.platform.startswith("linux") else None)
    if tee_stderr:
        tail: collections.deque = collections.deque(maxlen=STDERR_TAIL_LINES)

        def echo() -> None:
            try:
                for line in proc.stderr:
                    tail.append(line)
                    sys.stderr.write(line)
            except (OSError, ValueError):
                pass

        reader = threading.Thread(target=echo, name="ssmpc-node-stderr", daemon=True)
        reader.start()
        proc._ssmpc_stderr = (tail, reader)
    return proc


def stderr_tail(proc: subprocess.Popen, wait_s: float = 2.0) -> str:
    """The kept end of a node's standard error (``""`` unless started with
    ``tee_stderr``); waits up to ``wait_s`` for an exited node's last lines."""
    kept = getattr(proc, "_ssmpc_stderr", None)
    if kept is None:
        return ""
    tail, reader = kept
    if proc.poll() is not None:
        reader.join(wait_s)
    return "".join(tail)


#: Wall seconds between "still starting" lines while a node gets ready.
PROGRESS_EVERY_S = 10.0


def _lines(proc: subprocess.Popen) -> queue.SimpleQueue:
    """The node's stdout, line by line (None at its end), read on a thread of its own.

    A thread rather than ``select`` on the pipe: a node that printed several lines at
    once leaves them in the reader's buffer, where ``select`` does not see them, and a
    node whose output nobody reads would block once the pipe is full."""
    q = getattr(proc, "_ssmpc_lines", None)
    if q is None:
        q = queue.SimpleQueue()
        proc._ssmpc_lines = q

        def read() -> None:
            try:
                for line in proc.stdout:
                    q.put(line)
            except (OSError, ValueError):
                pass
            q.put(None)

        threading.Thread(target=read, name="ssmpc-node-output", daemon=True).start()
    return q


def _wait_ready(proc: subprocess.Popen, role: str, deadline: float,
                progress=None) -> str:
    """Wait for the node's ``ready`` line; ``progress(elapsed_s)`` is called every
    :data:`PROGRESS_EVERY_S` meanwhile (a first start compiles for a minute)."""
    lines = _lines(proc)
    t0 = time.monotonic()
    next_note = t0 + PROGRESS_EVERY_S
    while time.monotonic() < deadline:
        if progress is not None and time.monotonic() >= next_note:
            progress(time.monotonic() - t0)
            next_note += PROGRESS_EVERY_S
        try:
            line = lines.get(timeout=0.2)
        except queue.Empty:
            continue
        if line is None:  # its output ended: it exited (or is about to)
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                pass
            raise CLIError(f"{role}: node exited with code {proc.returncode} before it was ready")
        if line.startswith("ready"):
            return line.strip()
    raise CLIError(f"{role}: not ready within the timeout")


#: Starts of a node whose listen port was taken between picking and binding it.
PORT_TRIES = 3


def port_taken(stderr: str) -> bool:
    """Whether a node's standard error says its listen address was in use."""
    return "in use" in stderr.lower()


def start_on_free_ports(argv, role: str, deadline: float, tries: int = PORT_TRIES
                        ) -> subprocess.Popen:
    """Start the node ``argv()`` gives and wait for its ``ready`` line; ``argv`` picks the
    node's listen ports (free at that moment) each time it is called.

    Another process may bind a picked port before the node does (outgoing connections
    draw from the same ephemeral range). A node that exits before it is ready because
    an address was in use is started again with a fresh ``argv()``, up to ``tries``
    times; any other failure raises :class:`CLIError` at once, as does the last try.
    The node's standard error is echoed to this process's as it comes."""
    for attempt in range(1, tries + 1):
        proc = _spawn(argv(), tee_stderr=True)
        try:
            _wait_ready(proc, role, deadline)
            return proc
        except CLIError:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            if attempt == tries or not port_taken(stderr_tail(proc)):
                raise
    raise AssertionError("unreachable")  # pragma: no cover


def _drain(proc: subprocess.Popen) -> None:
    """Echo the node's output after its ``ready`` line to this process's stdout."""
    lines = _lines(proc)
    while (line := lines.get()) is not None:
        sys.stdout.write(line)


def stop_children(procs: list[subprocess.Popen], grace_s: float = 10.0) -> None:
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    for p in procs:
        try:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _move_aside(state_dir: str, unit: str) -> list[str]:
    """Rename a previous run's store and recording to ``*.<UTC time>.*`` (nothing is lost)."""
    from pathlib import Path

    stamp = time.strftime("%Y%m%dT%H%M%SZ", time.gmtime())
    moved = []
    for suffix in (".sqlite", ".sqlite-wal", ".sqlite-shm", ".rrd"):
        src = Path(state_dir) / f"ssmpc-{unit}{suffix}"
        if src.exists():
            dst = src.with_name(f"ssmpc-{unit}.{stamp}{suffix}")
            os.replace(src, dst)
            moved.append(str(dst))
    return moved


def run_up(args) -> int:
    from api.auth import token_from_env
    from services.registry import load_unit_config

    load_unit_config(args.unit, args.unit_config)  # fail early on a bad unit/config
    token_from_env()  # set but empty: a config error before any node starts
    if not 0 < args.port < 65536:
        raise CLIError(f"port: must be 1..65535, got {args.port}")
    if args.restart_limit < 0:
        raise CLIError(f"restart_limit: must be >= 0, got {args.restart_limit}")
    os.makedirs(args.state_dir, exist_ok=True)
    from services.io.mesh_router import node_arguments, plan_mesh, router_arguments

    # credentials not owner-only: exit 2 before anything moves
    mesh = plan_mesh(args.state_dir)
    if mesh.made:
        print(f"mesh credentials made in {mesh.credentials_dir} (owner-only)", flush=True)
    print(f"mesh: Zenoh router on {mesh.endpoint}, user/password per node and access "
          f"control by identity (credentials in {mesh.credentials_dir})", flush=True)
    join = node_arguments(mesh)
    opcua = []
    if args.io == "opcua":
        from services.io.opcua.certs import ensure_certificates
        from services.io.opcua.settings import OPCUASettings

        cert_dir = os.path.join(args.state_dir, "opcua")
        try:
            OPCUASettings(endpoint=args.opcua_endpoint, cert_dir=cert_dir,
                          watchdog_s=args.watchdog)
            ensure_certificates(cert_dir)
        except ValueError as exc:
            raise CLIError(str(exc)) from exc
        opcua = ["--opcua-endpoint", args.opcua_endpoint, "--opcua-cert-dir", cert_dir,
                 "--watchdog", repr(float(args.watchdog))]
    if not args.resume:
        for path in _move_aside(args.state_dir, args.unit):
            print(f"previous run kept as {path}", flush=True)
    common = ["--unit", args.unit, "--speed", str(args.speed), "--lease-ms", str(args.lease_ms),
              *join]
    if args.unit_config:
        common += ["--unit-config", args.unit_config]
    stop = threading.Event()

    def handler(signum, frame):
        stop.set()

    signal.signal(signal.SIGINT, handler)
    signal.signal(signal.SIGTERM, handler)
    procs: list[subprocess.Popen] = []
    routers: list[subprocess.Popen] = []
    nodes: dict[str, dict] = {}

    def spawn(role: str, argv: list[str], doing: str) -> None:
        print(f"starting the {role} node: {doing}", flush=True)
        proc = _spawn(argv)
        (routers if role == "router" else procs).append(proc)
        nodes.setdefault(role, {"argv": argv, "doing": doing, "restarts": []})["proc"] = proc

    def ready(role: str) -> None:
        def progress(elapsed: float) -> None:
            print(f"  still starting the {role} node ({elapsed:.0f} s): the first start "
                  f"compiles the numerical kernels with numba (about 45 s on 2 cores); "
                  f"later starts load them from the cache", flush=True)

        proc = nodes[role]["proc"]
        print(_wait_ready(proc, role, deadline, progress), flush=True)
        threading.Thread(target=_drain, args=(proc,), daemon=True).start()

    def start(role: str, argv: list[str], doing: str) -> None:
        spawn(role, argv, doing)
        ready(role)

    try:
        deadline = time.monotonic() + args.ready_timeout
        # a router that cannot listen (the port taken meanwhile): exit before anything moves
        start("router", router_arguments(mesh, lease_ms=args.lease_ms),
              f"the Zenoh router on {mesh.endpoint}")
        controller = (["controller", *common, "--state-dir", args.state_dir]
                      + (["--busy-poll"] if args.busy_poll else []))
        plant = (["opcua" if opcua else "plant", *common]
                 + (["--lockstep"] if args.lockstep else []) + opcua)
        api = ["api", *join, "--lease-ms", str(args.lease_ms), "--port", str(args.port)]
        # The plant starts after the node it follows is ready (the controller; with
        # OPC UA the controller connects to the plant's server, so the plant first). The
        # API needs neither to start: it starts alongside the first node.
        if opcua:
            spawn("plant", plant, f"the {args.unit} simulation, OPC UA on "
                                  f"{args.opcua_endpoint}")
            spawn("api", api, f"REST on 127.0.0.1:{args.port}")
            ready("plant")
            start("controller", [*controller, "--plant-io", "opcua", *opcua],
                  f"models, controller and store in {args.state_dir}, linked by OPC UA")
        else:
            spawn("controller", controller, f"models, controller and store in {args.state_dir}")
            spawn("api", api, f"REST on 127.0.0.1:{args.port}")
            ready("controller")
            start("plant", plant, f"the {args.unit} simulation")
        ready("api")
        print(f"ssmpc up: unit {args.unit} at {args.speed:g}x, API http://127.0.0.1:{args.port}"
              f" (Ctrl-C to stop)", flush=True)
        t_end = None if args.duration is None else time.monotonic() + args.duration
        while not stop.is_set():
            if t_end is not None and time.monotonic() >= t_end:
                break
            for role, node in nodes.items():
                code = node["proc"].poll()
                if code is None or stop.is_set():
                    continue
                # the others keep running (the plant keeps its regulatory layer and holds
                # its valves); the dead node is restarted after a growing pause
                now = time.monotonic()
                node["restarts"] = [t for t in node["restarts"] if now - t < RESTART_WINDOW_S]
                if len(node["restarts"]) >= args.restart_limit:
                    raise CLIError(f"the {role} node exited {len(node['restarts']) + 1} times "
                                   f"within "
                                   f"{RESTART_WINDOW_S / 60:.0f} min (last code {code}); "
                                   "stopping the others", code=1)
                pause = RESTART_BACKOFF_S * 2 ** len(node["restarts"])
                node["restarts"].append(now)
                cut_off = (" (the nodes are cut off from each other until it is back; the "
                           "plant holds its last moves)" if role == "router" else "")
                print(f"alarm: the {role} node exited (code {code}){cut_off}; restarting it in "
                      f"{pause:g} s (restart {len(node['restarts'])} of at most "
                      f"{args.restart_limit} in {RESTART_WINDOW_S / 60:.0f} min)", flush=True)
                if stop.wait(pause):
                    break
                deadline = time.monotonic() + args.ready_timeout
                start(role, node["argv"], node["doing"])
            stop.wait(0.2)
    finally:
        stop_children(procs)
        stop_children(routers)  # last: the nodes' goodbyes still travel
    return 0
