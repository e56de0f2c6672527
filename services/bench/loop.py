"""``ssmpc bench loop``: the closed loop over Zenoh, as separate processes on loopback.

Cases
-----
speed
    Plant (real-time mode) and controller nodes at a ladder of speeds; each
    rung runs ``--rung-seconds`` wall seconds after a warm-up. A rung passes
    with zero deadline misses (controller) and zero held samples (no MV in
    time at the plant). ``median`` is the highest passing speed (process s per
    wall s); the case also reports the wall period of that rung and the
    equivalent speed for the TE sample period (36 s). Each rung also carries the
    phase records of its latest missed samples and ``miss_causes``, their count by
    largest part (:func:`services.timing.miss_cause`): "queued" (before processing),
    "computing" (the thread's CPU time: the step itself, or the host taking the
    vCPU away, which a VM without steal time counts as CPU time), "waiting" (for the
    interpreter lock or a CPU; ``waiting_misses`` counts those that were preempted,
    i.e. another thread took the CPU, and those that blocked on a lock). Likewise the
    plant's latest held samples and
    ``held_causes`` (:func:`services.nodes.plant.held_cause`): "published_late" (the
    plant's own wake-up at the boundary), "answered_late", "no_answer". Each kept
    held sample is set beside the controller's record of it (the ``sample_times``
    query): ``split`` gives the round trip's parts, ms (:func:`held_split`), and
    ``held_split`` counts which part was the longest.
latency
    Lock-step loop: wall time from the plant publishing measurement k to it
    receiving the MV answering k (Zenoh both ways + decode + controller step +
    encode), µs, p50/p99 from the plant node's record.
mesh
    The ``latency`` case on the deployment of ``ssmpc up``: plant and controller as
    Zenoh clients of an authenticated router (user/password per identity, access
    control; :mod:`services.io.mesh_router`) in this process, instead of direct peers.
jitter
    The machine's own scheduling noise, side by side: one thread that sleeps to
    1 ms boundaries for ``--jitter-seconds`` (before and after the speed ladder),
    µs of oversleep, p50/p99/max and the count above 1 and 2 ms. A rung's misses
    are not the loop's when a plain sleeper on the idle machine stalls as long.
opcua
    The ``latency`` case with the controller linked by OPC UA (``ssmpc opcua`` and
    ``ssmpc controller --plant-io opcua``, Basic256Sha256 / SignAndEncrypt on
    loopback): per sample the server updates the measurements, the client is
    notified of the new sample, reads it in one Read, the controller steps and the
    moves and heartbeat go back in one Write; µs, p50/p99 from the plant node's
    record, beside the Zenoh ``latency`` case of the same run.
rest
    ``GET /api/v1/units/<unit>/status`` on the api node (uvicorn → Zenoh query
    → controller → back), µs, over a kept-alive HTTP connection, with the loop
    running in real time (speed 1).

With ``--stall-probe`` each rung also runs a :class:`StallProbe` in this process and
reports its stalls (``probe_stalls``) and how many of the kept missed and held samples
overlap one (``with_probe_stall``); off by default, as its ~1000 wake-ups a second
disturb what they observe on a 2-CPU machine.

``--rt-priority N`` runs the plant and controller nodes under SCHED_FIFO;
``--busy-poll`` runs the controller node with ``--busy-poll``, ``--plant-busy-poll``
the plant node (every case reports both). The controller node
runs without Rerun telemetry unless ``--telemetry`` is given (then it records to an
``.rrd`` file in the run's temporary state directory, as ``ssmpc up`` does); every
case reports which (``telemetry``).
"""

from __future__ import annotations

import tempfile
import time

from services.bench._common import latency_case
from services.machine import cpu_idle_settings
from services.nodes.plant import HELD_CAUSES, held_cause
from services.timing import MISS_CAUSES, miss_cause

NAME = "loop"
DESCRIPTION = ("closed loop over Zenoh: highest speed at zero misses, loop latency (Zenoh and "
               "OPC UA links), REST latency")

TE_SAMPLE_PERIOD_S = 36.0


def add_arguments(parser) -> None:
    parser.add_argument("--unit", default="te", help="unit to run (default te)")
    parser.add_argument("--speeds", default=None,
                        help="comma-separated speed ladder (default: from the unit's period)")
    parser.add_argument("--rung-seconds", type=float, default=3.0,
                        help="wall seconds measured per speed rung")
    parser.add_argument("--latency-seconds", type=float, default=5.0,
                        help="wall seconds of the lock-step latency run")
    parser.add_argument("--rest-requests", type=int, default=500, help="REST requests")
    parser.add_argument("--unit-config", default=None, metavar="FILE",
                        help="JSON overrides of the unit config (e.g. {\"strategy\": \"pi\"})")
    parser.add_argument("--rt-priority", type=int, default=None,
                        help="run plant and controller under SCHED_FIFO with this priority")
    parser.add_argument("--stall-probe", action="store_true",
                        help="run a 1 ms sleeping probe thread beside every rung and match "
                             "missed and held samples to its stalls (adds ~1000 wake-ups/s)")
    parser.add_argument("--busy-poll", action="store_true",
                        help="run the controller node with --busy-poll (one CPU polling)")
    parser.add_argument("--plant-busy-poll", action="store_true",
                        help="run the plant node with --busy-poll (one more CPU polling)")
    parser.add_argument("--telemetry", action="store_true",
                        help="record Rerun telemetry in the controller node (to an .rrd file), "
                             "as ssmpc up does; default: off")
    parser.add_argument("--jitter-seconds", type=float, default=5.0,
                        help="wall seconds of each scheduling-jitter probe")
    parser.add_argument("--cases", default="jitter,speed,latency,mesh,opcua,rest",
                        help="comma-separated subset of jitter, speed, latency, mesh, opcua, "
                             "rest")


class _Nodes:
    """Controller, plant and (optionally) api nodes as child processes.

    Each node's listen ports are picked (free at that moment) just before it starts.
    Another process may still bind one first (the nodes' own outgoing connections
    draw from the same ephemeral range); a node that exits for that reason is
    started again on fresh ports
    (:func:`services.nodes.supervisor.start_on_free_ports`)."""

    def __init__(self, unit: str, speed: float, lockstep: bool, api: bool, state_dir: str,
                 rt_priority: int | None = None, unit_config: str | None = None,
                 busy_poll: bool = False, telemetry: bool = False,
                 plant_busy_poll: bool = False, io: str = "zenoh", mesh: bool = False):
        from services.io.zenoh_session import free_port, free_tcp_endpoint

        self.procs = []
        self.router = None
        state_dir = tempfile.mkdtemp(dir=state_dir)  # a fresh store: no restored checkpoint
        join = []
        if mesh:  # as ssmpc up: the nodes are clients of an authenticated router
            from services.io.mesh_router import node_arguments, open_router

            self.router = open_router(state_dir, lease_ms=1000)
            join = node_arguments(self.router.plan)
        self.ep_c = self.ep_p = None
        self.port = None
        common = ["--unit", unit, "--speed", repr(float(speed)), "--lease-ms", "1000"]
        if rt_priority is not None:
            common += ["--rt-priority", str(rt_priority)]
        if unit_config is not None:
            common += ["--unit-config", unit_config]
        deadline = time.monotonic() + 120

        def ctrl(*extra: str) -> list[str]:
            self.ep_c = free_tcp_endpoint()
            return (["controller", *common, *(join or ["--listen", self.ep_c]),
                     "--state-dir", state_dir, *extra]
                    + ([] if telemetry else ["--no-telemetry"])
                    + (["--busy-poll"] if busy_poll else []))

        def plant(role: str = "plant", *extra: str) -> list[str]:
            self.ep_p = free_tcp_endpoint()
            return ([role, *common, *(join or ["--listen", self.ep_p]), *extra]
                    + (["--lockstep"] if lockstep else [])
                    + (["--busy-poll"] if plant_busy_poll else []))

        try:
            if io == "opcua":  # the plant serves, the controller connects: plant first
                cert = ["--opcua-cert-dir", f"{state_dir}/opcua"]
                link = []

                def opcua_plant() -> list[str]:
                    link[:] = ["--opcua-endpoint",
                               f"opc.tcp://127.0.0.1:{free_port()}/ssmpc", *cert]
                    return plant("opcua", *link)

                self._start("plant", opcua_plant, deadline)
                self._start("controller", lambda: ctrl("--connect", self.ep_p, "--plant-io",
                                                       "opcua", *link), deadline)
            else:
                self._start("controller", ctrl, deadline)
                self._start("plant", lambda: plant() if mesh
                            else plant("plant", "--connect", self.ep_c), deadline)
            if api:
                def api_node() -> list[str]:
                    self.port = free_port()
                    return ["api", "--listen", free_tcp_endpoint(), "--connect", self.ep_c,
                            "--connect", self.ep_p, "--port", str(self.port)]

                self._start("api", api_node, deadline)
        except BaseException:
            self.close()
            raise

    def _start(self, role: str, argv, deadline: float) -> None:
        """Start the node ``argv()`` gives (it picks its ports): see
        :func:`services.nodes.supervisor.start_on_free_ports`."""
        from services.nodes.supervisor import start_on_free_ports

        self.procs.append(start_on_free_ports(argv, role, deadline))

    def close(self) -> None:
        from services.nodes.supervisor import stop_children

        stop_children(self.procs)
        if self.router is not None:
            self.router.close()


#: The parts of a held sample's round trip (:func:`held_split`).
HELD_PARTS = ("to_controller", "controller", "back")


def held_split(held: dict, ctrl: dict | None) -> dict | None:
    """Where a held sample's round trip went, from the plant's record of it and the
    controller's (``sample_times``), ms: ``to_controller`` (the plant's publication
    to the controller taking the measurement in), ``controller`` (to its move going
    out), ``back`` (to the plant receiving it), and the ``largest`` part. Both records
    are on CLOCK_MONOTONIC, so this holds for nodes on one host. None when either
    record or the answer is missing."""
    if ctrl is None or held.get("published_s") is None or held.get("answered_s") is None:
        return None
    parts = {"to_controller": (ctrl["arrived_s"] - held["published_s"]) * 1e3,
             "controller": (ctrl["published_s"] - ctrl["arrived_s"]) * 1e3,
             "back": (held["answered_s"] - ctrl["published_s"]) * 1e3}
    return {**parts, "largest": max(parts, key=parts.get)}


def _query(session, key, action, args=None):
    from services.io.messages import Reply, Request

    for r in session.get(key, payload=Request(action, args or {}).to_bytes(), timeout=5.0):
        if r.ok is not None:
            return Reply.from_bytes(r.ok.payload.to_bytes()).data
    raise RuntimeError(f"no answer from {key}")


def _client_session(nodes: _Nodes):
    from services.io.zenoh_session import SessionSettings, open_session

    if nodes.router is not None:  # the operator's identity on the authenticated mesh
        from services.io.mesh_auth import node_credentials

        cred = node_credentials(nodes.router.plan.credentials_dir, "cli")
        s = open_session(SessionSettings(mode="client", connect=(nodes.router.plan.endpoint,),
                                         user=cred.user, password=cred.password))
    else:
        s = open_session(SessionSettings(connect=(nodes.ep_c, nodes.ep_p)))
    time.sleep(0.5)
    return s


def _wait_running(session, unit: str, samples: int = 50, timeout_s: float = 300.0) -> None:
    """Wait until the loop has run ``samples`` samples (first-use JIT compiles may take a while)."""
    from services.io import keys

    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        if _query(session, keys.plant_cmd(unit, "status"), "status")["samples"] >= samples:
            return
        time.sleep(0.2)
    raise RuntimeError(f"the {unit} loop did not start within {timeout_s:g} s")


def _rung(unit: str, speed: float, seconds: float, state_dir: str,
          rt_priority: int | None = None, unit_config: str | None = None,
          busy_poll: bool = False, stall_probe: bool = False, telemetry: bool = False,
          plant_busy_poll: bool = False) -> dict:
    from services.io import keys

    nodes = _Nodes(unit, speed, lockstep=False, api=False, state_dir=state_dir,
                   rt_priority=rt_priority, unit_config=unit_config, busy_poll=busy_poll,
                   telemetry=telemetry, plant_busy_poll=plant_busy_poll)
    s = _client_session(nodes)
    try:
        _wait_running(s, unit)
        time.sleep(0.5)  # warm-up: caches, connections
        with StallProbe(enabled=stall_probe) as probe:
            _query(s, keys.cmd(unit, "reset_stats"), "reset_stats")
            _query(s, keys.plant_cmd(unit, "reset_stats"), "reset_stats")
            time.sleep(seconds)
            cs = _query(s, keys.cmd(unit, "status"), "status")
            ps = _query(s, keys.plant_cmd(unit, "status"), "status")
        held = ps.get("held_samples") or []
        times = _query(s, keys.cmd(unit, "sample_times"), "sample_times",
                       {"seqs": [h["sample"] for h in held]})["samples"] if held else {}
    finally:
        s.close()
        nodes.close()
    missed = cs.get("missed_samples") or []
    causes = {c: 0 for c in MISS_CAUSES}
    waits = {"preempted": 0, "blocked": 0}
    for m in missed:  # the latest ones the controller kept (a bounded number)
        cause = miss_cause(m)
        causes[cause] += 1
        if cause == "waiting":  # was its CPU taken, or did it wait for a lock?
            for kind in waits:
                waits[kind] += m.get(kind, 0) > 0
    held_causes = {c: 0 for c in HELD_CAUSES}
    split_counts = {p: 0 for p in HELD_PARTS}
    for h in held:
        held_causes[held_cause(h)] += 1
        h["split"] = held_split(h, times.get(str(h["sample"])))
        if h["split"] is not None:
            split_counts[h["split"]["largest"]] += 1
    w_missed, w_held = _sample_windows(missed, held)
    return {"speed": speed, "samples": cs["samples"], "deadline_misses": cs["deadline_misses"],
            "held": ps["mv_held"], "plant_samples": ps["samples"],
            "sample_ms": cs.get("sample_ms"), "slowest_sample": cs.get("slowest_sample"),
            "plant_loop_latency_us": ps.get("loop_latency"),
            "controller_gc_pauses": cs.get("gc_pauses"),
            "plant_gc_pauses": ps.get("gc_pauses"),
            "plant_advance_max_ms": ps.get("advance_max_ms"),
            "plant_publish_lag_us": ps.get("publish_lag"),
            "telemetry_samples": cs.get("telemetry_samples"),
            # how each node waited, as the nodes report it
            "plant_busy_poll": ps.get("busy_poll"),
            "missed_samples": missed, "miss_causes": causes,
            # of the "waiting" ones: how many were preempted, how many blocked (or both)
            "waiting_misses": waits,
            "held_samples": held, "held_causes": held_causes,
            # of the held samples with both nodes' records: which part of the round trip
            # was the longest (see held_split)
            "held_split": split_counts,
            # a thread of a third process (this one) that only sleeps to 1 ms boundaries:
            # its stalls during the rung, and how many of the kept missed and held
            # samples overlap one (then the machine, not the loop, lost the time)
            "probe_stalls": probe.summary(),
            "with_probe_stall": None if not probe.enabled else {
                "missed": coincident(w_missed, probe.stalls), "of_missed": len(w_missed),
                "held": coincident(w_held, probe.stalls), "of_held": len(w_held)}}


def speed_case(args, state_dir: str) -> dict:
    from services.registry import load_unit_config

    cfg = load_unit_config(args.unit, args.unit_config)
    if args.speeds:
        ladder = [float(x) for x in args.speeds.split(",")]
    else:  # wall periods from 20 ms down to 0.5 ms
        ladder = [cfg.sample_period_s / w
                  for w in (20e-3, 10e-3, 5e-3, 3.6e-3, 2.5e-3, 2e-3, 1.5e-3, 1e-3, 0.5e-3)]
    best = None
    rungs = []
    for speed in ladder:
        r = _rung(args.unit, speed, args.rung_seconds, state_dir, args.rt_priority,
                  args.unit_config, busy_poll=args.busy_poll, stall_probe=args.stall_probe,
                  telemetry=args.telemetry, plant_busy_poll=args.plant_busy_poll)
        rungs.append(r)
        ok = r["deadline_misses"] == 0 and r["held"] == 0 and r["samples"] > 0
        if ok:
            best = r
        else:
            break
    common = {"case": "speed", "unit": "x real time", "plant_unit": args.unit, "rungs": rungs,
              "rt_priority": args.rt_priority, "busy_poll": args.busy_poll,
              "plant_busy_poll": args.plant_busy_poll,
              "telemetry": args.telemetry, "cpu_idle": cpu_idle_settings(),
              "controller": cfg.controller,
              "strategy": cfg.strategy if cfg.plant == "te" else None}
    if best is None:  # a result, not an error: every rung missed
        return {**common, "median": 0.0, "p99": 0.0, "max": 0.0, "n": 0,
                "note": f"no speed of {ladder} ran without deadline misses and held moves"}
    wall_period = cfg.sample_period_s / best["speed"]
    return {**common, "median": best["speed"], "p99": best["speed"], "max": best["speed"],
            "n": best["samples"], "wall_period_ms": wall_period * 1e3,
            "te_equivalent_speed": TE_SAMPLE_PERIOD_S / wall_period}


def latency_case_run(args, state_dir: str, io: str = "zenoh", mesh: bool = False) -> dict:
    """Lock-step loop (as fast as it goes): the plant's record of meas -> MV times, with
    the controller linked by Zenoh (case ``latency``; through the authenticated router of
    ``ssmpc up``: case ``mesh``) or OPC UA (case ``opcua``)."""
    from services.io import keys
    from services.registry import load_unit_config

    cfg = load_unit_config(args.unit, args.unit_config)
    nodes = _Nodes(args.unit, 1.0, lockstep=True, api=False, state_dir=state_dir,
                   rt_priority=args.rt_priority, unit_config=args.unit_config,
                   busy_poll=args.busy_poll and io == "zenoh", telemetry=args.telemetry,
                   plant_busy_poll=args.plant_busy_poll, io=io, mesh=mesh)
    s = _client_session(nodes)
    try:
        _wait_running(s, args.unit)
        _query(s, keys.plant_cmd(args.unit, "reset_stats"), "reset_stats")
        time.sleep(args.latency_seconds)
        ps = _query(s, keys.plant_cmd(args.unit, "status"), "status")
    finally:
        s.close()
        nodes.close()
    lat = ps["loop_latency"]
    if lat is None:
        raise RuntimeError(f"the {io} loop answered no sample in {args.latency_seconds:g} s")
    rate = ps["samples"] / args.latency_seconds
    case = io if io != "zenoh" else "mesh" if mesh else "latency"
    if case == "opcua":
        extra = {"link": "OPC UA Basic256Sha256/SignAndEncrypt, loopback",
                 "lockstep_timeouts": ps["lockstep_timeouts"], "sheds": ps["link"]["sheds"]}
    elif case == "mesh":
        extra = {"link": "Zenoh clients of the ssmpc up router (user/password, ACL), loopback"}
    else:
        extra = {"link": "Zenoh peers, loopback"}
    return {"case": case, "unit": "us", **extra,
            "median": lat["p50_us"], "p99": lat["p99_us"], "max": lat["max_us"], "n": lat["n"],
            "plant_unit": args.unit, "mode": "lockstep",
            "samples_per_wall_s": rate, "lockstep_speed": rate * cfg.sample_period_s,
            "te_equivalent_speed": rate * TE_SAMPLE_PERIOD_S,
            "sample_period_s": cfg.sample_period_s, "rt_priority": args.rt_priority,
            "busy_poll": args.busy_poll, "plant_busy_poll": args.plant_busy_poll,
            "telemetry": args.telemetry}


def rest_case_run(args, state_dir: str) -> dict:
    """REST GET status against a loop running in real time (speed 1), as an operator sees it."""
    import httpx

    nodes = _Nodes(args.unit, 1.0, lockstep=False, api=True, state_dir=state_dir,
                   unit_config=args.unit_config)
    s = _client_session(nodes)
    try:
        _wait_running(s, args.unit, samples=1)
        url = f"http://127.0.0.1:{nodes.port}/api/v1/units/{args.unit}/status"
        times = []
        with httpx.Client(timeout=10) as c:
            for _ in range(20):
                c.get(url).raise_for_status()
            for _ in range(args.rest_requests):
                t0 = time.perf_counter()
                c.get(url).raise_for_status()
                times.append((time.perf_counter() - t0) * 1e6)
    finally:
        s.close()
        nodes.close()
    return latency_case("rest", times, "us", endpoint="GET status", plant_unit=args.unit,
                        loop="real time, speed 1")


class StallProbe:
    """A thread that sleeps to 1 ms boundaries beside a rung and keeps its stalls.

    A stall is a wake-up later than ``threshold_s``; it is kept as ``(end, length)``
    (wall clock, s). After a stall the probe re-anchors, so one long stall counts once.
    It tells whether a rung's missed and held samples coincide with moments when a
    plain sleeping thread in a third process could not run either
    (:func:`coincident`).
    """

    def __init__(self, period_s: float = 1e-3, threshold_s: float = 1e-3,
                 enabled: bool = True) -> None:
        import threading

        self.enabled = bool(enabled)
        self.period_s = float(period_s)
        self.threshold_s = float(threshold_s)
        self.stalls: list[tuple[float, float]] = []
        self.wakeups = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ssmpc-stall-probe",
                                        daemon=True)

    def _run(self) -> None:
        nxt = time.perf_counter()
        while not self._stop.is_set():
            nxt += self.period_s
            delay = nxt - time.perf_counter()
            if delay > 0:
                time.sleep(delay)
            late = time.perf_counter() - nxt
            self.wakeups += 1
            if late > self.threshold_s:
                self.stalls.append((time.time(), late))
                nxt = time.perf_counter()

    def __enter__(self) -> StallProbe:
        if self.enabled:
            self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        if self.enabled:
            self._stop.set()
            self._thread.join(5)

    def summary(self) -> dict | None:
        """Wake-ups, stalls over 1 and 2 ms, the longest one (ms); None when disabled."""
        if not self.enabled:
            return None
        lengths = [n for _, n in self.stalls]
        return {"wakeups": self.wakeups, "over_1ms": sum(n > 1e-3 for n in lengths),
                "over_2ms": sum(n > 2e-3 for n in lengths),
                "max_ms": max(lengths) * 1e3 if lengths else 0.0}


def coincident(windows, stalls, margin_s: float = 1e-3) -> int:
    """How many of ``windows`` ((start, end) wall-clock s) overlap a stall
    (``(end, length)`` of :class:`StallProbe`), each widened by ``margin_s``."""
    spans = [(end - length, end) for end, length in stalls]
    return sum(any(a - margin_s <= s_end and s_start <= b + margin_s
                   for s_start, s_end in spans) for a, b in windows)


def _sample_windows(missed: list[dict], held: list[dict]) -> tuple[list, list]:
    """Wall-clock spans of the kept missed samples (start of processing to the move) and
    held samples (the sample's period, ending when the plant noted the hold)."""
    m = [(r["at_unix_s"], r["at_unix_s"] + r["total_ms"] * 1e-3) for r in missed
         if "at_unix_s" in r]
    h = [(r["at_unix_s"] - r["period_ms"] * 1e-3, r["at_unix_s"]) for r in held
         if "at_unix_s" in r]
    return m, h


def scheduling_jitter(seconds: float, period_s: float = 1e-3, rt_priority: int | None = None
                      ) -> list[float]:
    """Oversleep (µs) of a thread sleeping to ``period_s`` boundaries for ``seconds``.

    With ``rt_priority`` the probing thread runs under SCHED_FIFO, as the nodes do.
    """
    import os
    import threading

    out: list[float] = []
    err: list[BaseException] = []

    def probe():
        try:
            if rt_priority is not None:
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(rt_priority))
            t_end = time.perf_counter() + seconds
            nxt = time.perf_counter()
            while nxt < t_end:
                nxt += period_s
                delay = nxt - time.perf_counter()
                if delay > 0:
                    time.sleep(delay)
                out.append((time.perf_counter() - nxt) * 1e6)
        except BaseException as exc:  # reported by the caller
            err.append(exc)

    th = threading.Thread(target=probe, name="ssmpc-jitter-probe")
    th.start()
    th.join()
    if err:
        raise RuntimeError(f"jitter probe failed: {err[0]}")
    return out


def jitter_case(args, when: str) -> dict:
    import numpy as np

    us = scheduling_jitter(args.jitter_seconds, rt_priority=args.rt_priority)
    a = np.asarray(us)
    return latency_case("jitter", us, "us", when=when, period_us=1000.0,
                        over_1ms=int(np.sum(a > 1000)), over_2ms=int(np.sum(a > 2000)),
                        rt_priority=args.rt_priority, cpu_idle=cpu_idle_settings())


def run(args) -> list[dict]:
    cases = {c.strip() for c in args.cases.split(",") if c.strip()}
    unknown = cases - {"jitter", "speed", "latency", "mesh", "opcua", "rest"}
    if unknown:
        raise ValueError(f"cases: unknown case(s) {', '.join(sorted(unknown))}")
    if "jitter" in cases and not (args.jitter_seconds > 0):
        raise ValueError(f"jitter_seconds: must be positive, got {args.jitter_seconds}")
    out = []
    with tempfile.TemporaryDirectory(prefix="ssmpc-bench-loop-") as state_dir:
        if "jitter" in cases:
            out.append(jitter_case(args, "before the speed ladder"))
        if "speed" in cases:
            out.append(speed_case(args, state_dir))
            if "jitter" in cases:
                out.append(jitter_case(args, "after the speed ladder"))
        if "latency" in cases:
            out.append(latency_case_run(args, state_dir))
        if "mesh" in cases:
            out.append(latency_case_run(args, state_dir, mesh=True))
        if "opcua" in cases:
            out.append(latency_case_run(args, state_dir, io="opcua"))
        if "rest" in cases:
            out.append(rest_case_run(args, state_dir))
    return out
