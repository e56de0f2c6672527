"""Fault injection for the soak: a chaos relay on Zenoh, bad measurements, a stalled solver.

Nothing here changes how a node behaves; faults are injected from outside:

- :class:`ChaosRelay` stands between the plant side and the controller side of a
  unit. The plant node's session and the controller node's session are not
  linked to each other; the relay holds one session on each side and forwards
  ``ssmpc/<unit>/meas`` (plant → controller) and ``ssmpc/<unit>/mv``
  (controller → plant), applying the active :class:`FaultWindow` rules on the
  way: **drop**, **delay** (by a number of sample periods), **duplicate**,
  **reorder** (swap with the next message), and, on measurements, **nan** /
  **inf** (the ``NaN``/``Infinity`` literals a careless encoder writes) and
  **range** (one finite but physically impossible value). The plant's
  liveliness token is mirrored on the controller side, so the api node still
  sees the plant.
- :class:`StallingController` wraps a unit's controller and sleeps beyond the
  timing budget inside ``step`` during the windows it is given (a stalled
  solver); ``python -m services.soak.faults controller ...`` runs a controller node
  with it, like ``ssmpc controller``.
- Node kills are done by the soak orchestrator (:mod:`services.soak.run`).

Fault specification (``--faults SPEC``)
---------------------------------------
A comma-separated list of items ``kind[:target][:amount]@start[-end]``:

=================================  ===============================================
``kill:plant@1h``                  plant node killed at 1 process hour, restarted
``kill:controller@30m``            controller process SIGKILLed, restarted
``kill:api@1.5h``                  api process SIGKILLed, restarted
``drop:meas:20%@1h-1.2h``          drop 20 % of the measurements in the window
``drop:mv:50%@...``                drop MV messages
``delay:mv:3@...``                 delay every MV by 3 sample periods (wall time)
``duplicate:meas:30%@...``         send 30 % of the measurements twice
``reorder:mv:30%@...``             swap 30 % of the MVs with the message after them
``nan:meas:10%@...``               a NaN literal in one output of 10 % of the samples
``inf:meas:10%@...``               an Infinity literal instead
``range:meas:10%@...``             one output set to an impossible finite value
``stall:controller:4@2h-2.1h``     each step sleeps 4 x the timing budget
=================================  ===============================================

Times are process time with a unit ``h``, ``m`` or ``s``; ``start`` alone means
the fault happens once (kills) or lasts one sample period (message faults). The
amount is a percentage (probability per message; default 100 %), a number of
sample periods (``delay``) or a multiple of the budget (``stall``; default 4).
"""

from __future__ import annotations

import heapq
import itertools
import json
import logging
import math
import random
import re
import threading
import time
from collections import Counter
from dataclasses import dataclass

from services.io import keys
from services.io.zenoh_session import declare_loop_publisher

__all__ = [
    "KINDS",
    "MESSAGE_KINDS",
    "FaultSpecError",
    "FaultWindow",
    "parse_faults",
    "default_faults",
    "report_kind",
    "ChaosRelay",
    "corrupt_measurement",
    "StallingController",
]

log = logging.getLogger("ssmpc.faults")

#: Every fault kind the soak can inject.
KINDS = ("kill", "drop", "delay", "duplicate", "reorder", "nan", "inf", "range", "stall")
#: Kinds applied by the relay to messages.
MESSAGE_KINDS = ("drop", "delay", "duplicate", "reorder", "nan", "inf", "range")
_TARGETS = {
    "kill": ("plant", "controller", "api"),
    "drop": ("meas", "mv"),
    "delay": ("meas", "mv"),
    "duplicate": ("meas", "mv"),
    "reorder": ("meas", "mv"),
    "nan": ("meas",),
    "inf": ("meas",),
    "range": ("meas",),
    "stall": ("controller",),
}
_UNITS_S = {"h": 3600.0, "m": 60.0, "s": 1.0}
_TIME = r"(\d+(?:\.\d+)?)([hms])"
_ITEM = re.compile(
    rf"^(?P<kind>[a-z_]+)(?::(?P<target>[a-z]+))?(?::(?P<amount>\d+(?:\.\d+)?)(?P<pct>%)?)?"
    rf"@(?P<start>{_TIME})(?:-(?P<end>{_TIME}))?$")

#: Value written by a ``range`` fault: finite, but no instrument of a process plant reads it.
OUT_OF_RANGE_VALUE = -1.0e9


class FaultSpecError(ValueError):
    """A ``--faults`` specification that does not parse; the message names the item."""


@dataclass(frozen=True)
class FaultWindow:
    """One fault of the schedule.

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    target : str
        ``plant``/``controller``/``api`` (kill), ``meas``/``mv`` (message faults),
        ``controller`` (stall).
    start_s, end_s : float
        Process-time window, s (``end_s == start_s`` for a kill).
    probability : float
        Share of the messages in the window that are hit, in (0, 1] (the relay
        always hits the first message of a window, so every window injects).
    amount : float
        ``delay``: sample periods; ``stall``: multiple of the timing budget.
    """

    kind: str
    target: str
    start_s: float
    end_s: float
    probability: float = 1.0
    amount: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise FaultSpecError(f"kind: unknown fault kind {self.kind!r}; known: "
                                 f"{', '.join(KINDS)}")
        if self.target not in _TARGETS[self.kind]:
            raise FaultSpecError(f"target: {self.kind} applies to "
                                 f"{' or '.join(_TARGETS[self.kind])}, not {self.target!r}")
        if not (math.isfinite(self.start_s) and self.start_s >= 0):
            raise FaultSpecError(f"start: must be a process time >= 0, got {self.start_s}")
        if not (math.isfinite(self.end_s) and self.end_s >= self.start_s):
            raise FaultSpecError(f"end: must not be before start ({self.start_s} s), "
                                 f"got {self.end_s}")
        if not (0 < self.probability <= 1):
            raise FaultSpecError(f"probability: must be in (0, 100] %, got "
                                 f"{100 * self.probability:g} %")
        if not (math.isfinite(self.amount) and self.amount >= 0):
            raise FaultSpecError(f"amount: must be a finite number >= 0, got {self.amount}")

    @property
    def name(self) -> str:
        """Report key: ``kill_controller``, ``drop_meas``, ``stall`` ..."""
        return report_kind(self.kind, self.target)

    def active(self, t_s: float) -> bool:
        return self.start_s <= t_s <= self.end_s


def report_kind(kind: str, target: str) -> str:
    """The key under which a fault is counted in the soak report."""
    return "stall" if kind == "stall" else f"{kind}_{target}"


def _seconds(text: str) -> float:
    m = re.fullmatch(_TIME, text)
    return float(m.group(1)) * _UNITS_S[m.group(2)]


def parse_faults(spec: str, sample_period_s: float) -> list[FaultWindow]:
    """Parse a ``--faults`` specification (grammar in the module docstring).

    An empty string or ``none`` gives no faults.
    """
    out: list[FaultWindow] = []
    spec = (spec or "").strip()
    if spec.lower() in ("", "none"):
        return out
    for item in spec.split(","):
        item = item.strip()
        m = _ITEM.match(item)
        if m is None:
            raise FaultSpecError(f"faults: cannot parse {item!r}; expected "
                                 "kind[:target][:amount[%]]@start[-end], e.g. drop:meas:5%@1h-1.2h")
        kind = m.group("kind")
        if kind not in KINDS:
            raise FaultSpecError(f"faults: unknown kind {kind!r} in {item!r}; known: "
                                 f"{', '.join(KINDS)}")
        target = m.group("target") or _TARGETS[kind][0]
        start = _seconds(m.group("start"))
        end = _seconds(m.group("end")) if m.group("end") else (
            start if kind == "kill" else start + sample_period_s)
        amount_text, pct = m.group("amount"), m.group("pct")
        probability, amount = 1.0, 0.0
        if kind == "kill" and amount_text is not None:
            raise FaultSpecError(f"faults: kill takes no amount ({item!r})")
        if kind in ("delay", "stall"):
            if pct:
                raise FaultSpecError(f"faults: {kind} takes a number, not a percentage "
                                     f"({item!r})")
            amount = float(amount_text) if amount_text else (2.0 if kind == "delay" else 4.0)
        elif amount_text is not None:
            if not pct:
                raise FaultSpecError(f"faults: {kind} takes a percentage, e.g. 20% ({item!r})")
            probability = float(amount_text) / 100.0
        if kind == "kill" and m.group("end"):
            raise FaultSpecError(f"faults: kill happens at one time, not a window ({item!r})")
        try:
            out.append(FaultWindow(kind, target, start, end, probability, amount))
        except FaultSpecError as exc:
            raise FaultSpecError(f"faults: {item!r}: {exc}") from exc
    return sorted(out, key=lambda w: (w.start_s, w.kind, w.target))


def default_faults(hours: float, sample_period_s: float) -> list[FaultWindow]:
    """Every fault kind once (each message kind on each channel it applies to).

    Message faults and the stall first, spread over 10-70 % of the run, each window
    ~2 % of the run (at least three sample periods) long; then the kills, at 75 %
    (api), 80 % (plant) and 85 % (controller), because a restarted node process
    needs about a wall second, which is a process hour at 3600x.
    """
    total = hours * 3600.0
    items: list[tuple[str, str, float, float]] = [("stall", "controller", 1.0, 4.0)]
    for kind in MESSAGE_KINDS:
        for target in _TARGETS[kind]:
            p = {"drop": 0.5, "duplicate": 0.5, "reorder": 0.5}.get(kind, 0.3)
            items.append((kind, target, p, 2.0 if kind == "delay" else 0.0))
    width = max(3 * sample_period_s, 0.02 * total)
    span = 0.6 * total
    out = []
    for i, (kind, target, p, amount) in enumerate(items):
        start = 0.1 * total + span * i / len(items)
        out.append(FaultWindow(kind, target, start, start + width, p, amount))
    for frac, target in ((0.75, "api"), (0.8, "plant"), (0.85, "controller")):
        out.append(FaultWindow("kill", target, frac * total, frac * total))
    return out


def corrupt_measurement(payload: bytes, kind: str, rng: random.Random) -> bytes:
    """A measurement with one output made NaN, infinite or impossible.

    ``nan`` and ``inf`` write the ``NaN``/``Infinity`` literals Python's ``json``
    emits with ``allow_nan=True`` (which a strict decoder must refuse); ``range``
    writes :data:`OUT_OF_RANGE_VALUE`, a valid JSON number.
    """
    obj = json.loads(payload)
    y = obj["y"]
    i = rng.randrange(len(y))
    y[i] = {"nan": math.nan, "inf": math.inf if rng.random() < 0.5 else -math.inf,
            "range": OUT_OF_RANGE_VALUE}[kind]
    return json.dumps(obj, separators=(",", ":"), allow_nan=True).encode()


class _Scheduler:
    """One thread that runs callables at wall-clock times (delayed forwarding)."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._heap: list = []
        self._count = itertools.count()
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="ssmpc-chaos", daemon=True)
        self._thread.start()

    def at(self, when: float, fn) -> None:
        with self._cond:
            heapq.heappush(self._heap, (when, next(self._count), fn))
            self._cond.notify()

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(2.0)

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (
                        not self._heap or self._heap[0][0] > time.perf_counter()):
                    timeout = None if not self._heap else self._heap[0][0] - time.perf_counter()
                    self._cond.wait(timeout)
                if self._closed:
                    return
                _, _, fn = heapq.heappop(self._heap)
            try:
                fn()
            except Exception:  # a closed session during shutdown: nothing to deliver to
                log.debug("delayed delivery failed", exc_info=True)


class ChaosRelay:
    """Forward one unit's measurements and MVs between two sessions, injecting faults.

    Parameters
    ----------
    unit : str
    plant_side, controller_side : zenoh.Session
        Sessions on the plant's and on the controller's side (not linked to each other).
    sample_period_s : float
        Process seconds per sample.
    speed : float
        Process seconds per wall second (converts ``delay`` to wall time).
    windows : list of FaultWindow
        The schedule; only message kinds are applied here. The current process
        time is the ``t`` of the newest measurement seen.
    seed : int
        Seed of the relay's own random generator.
    on_mv, on_meas : callable, optional
        Observers called with ``(payload, wall_time)`` of every message that
        arrived (before faults), e.g. to check a bumpless restart.
    """

    def __init__(self, unit: str, plant_side, controller_side, *, sample_period_s: float,
                 speed: float, windows=(), seed: int = 0, on_mv=None, on_meas=None) -> None:
        self.unit = keys.check_unit_name(unit)
        self.plant_side = plant_side
        self.controller_side = controller_side
        self.sample_period_s = float(sample_period_s)
        self.speed = float(speed)
        self.windows = [w for w in windows if w.kind in MESSAGE_KINDS]
        self.rng = random.Random(seed)
        self.injected: Counter[str] = Counter()
        self.forwarded: Counter[str] = Counter()
        self.process_time_s = 0.0
        self.on_mv, self.on_meas = on_mv, on_meas
        self._lock = threading.Lock()
        self._held: dict[str, bytes | None] = {"meas": None, "mv": None}
        self._seen_windows: set[int] = set()
        self._sched = _Scheduler()
        self._pub = {"meas": declare_loop_publisher(controller_side, keys.meas(unit)),
                     "mv": declare_loop_publisher(plant_side, keys.mv(unit))}
        self._subs = [
            plant_side.declare_subscriber(keys.meas(unit), lambda s: self._on("meas", s)),
            controller_side.declare_subscriber(keys.mv(unit), lambda s: self._on("mv", s)),
        ]
        self._mirror_token = None
        self._live = plant_side.liveliness().declare_subscriber(
            keys.alive(unit, "plant"), self._on_plant_alive, history=True)

    # -- liveliness mirror -------------------------------------------------------------
    def _on_plant_alive(self, sample) -> None:
        import zenoh

        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT and self._mirror_token is None:
                self._mirror_token = self.controller_side.liveliness().declare_token(
                    keys.alive(self.unit, "plant"))
            elif sample.kind == zenoh.SampleKind.DELETE and self._mirror_token is not None:
                self._mirror_token.undeclare()
                self._mirror_token = None

    # -- forwarding --------------------------------------------------------------------
    def _send(self, channel: str, payload: bytes) -> None:
        self._pub[channel].put(payload)
        with self._lock:
            self.forwarded[channel] += 1

    def _count(self, kind: str, channel: str) -> None:
        with self._lock:
            self.injected[report_kind(kind, channel)] += 1

    def _hit(self, channel: str) -> list[FaultWindow]:
        """Windows that hit this message: the first message in a window always, then
        each with the window's probability."""
        t = self.process_time_s
        out = []
        for i, w in enumerate(self.windows):
            if w.target != channel or not w.active(t):
                continue
            if i not in self._seen_windows:
                self._seen_windows.add(i)
                out.append(w)
            elif self.rng.random() < w.probability:
                out.append(w)
        return out

    def _on(self, channel: str, sample) -> None:
        try:
            self._forward(channel, sample.payload.to_bytes())
        except Exception:  # counted by the soak as an unhandled error (ERROR log record)
            log.exception("relay failed on %s", channel)

    def _forward(self, channel: str, payload: bytes) -> None:
        now = time.perf_counter()
        if channel == "meas":
            try:
                self.process_time_s = float(json.loads(payload)["t"])
            except Exception:  # a malformed payload is forwarded as is; the node judges it
                pass
        observer = self.on_meas if channel == "meas" else self.on_mv
        if observer is not None:
            observer(payload, now)
        with self._lock:
            hits = self._hit(channel)
        kinds = {w.kind: w for w in hits}
        if "drop" in kinds:
            self._count("drop", channel)
            return
        for bad in ("nan", "inf", "range"):
            if bad in kinds:
                payload = corrupt_measurement(payload, bad, self.rng)
                self._count(bad, channel)
                break
        copies = 1
        if "duplicate" in kinds:
            copies = 2
            self._count("duplicate", channel)
        if "delay" in kinds:
            self._count("delay", channel)
            wall = kinds["delay"].amount * self.sample_period_s / self.speed
            for _ in range(copies):
                self._sched.at(now + wall, lambda p=payload: self._send(channel, p))
            return
        with self._lock:
            held, self._held[channel] = self._held[channel], None
            if "reorder" in kinds and held is None:
                # hold this one; it goes out right after the next message (or after a period)
                self._held[channel] = payload
                self.injected[report_kind("reorder", channel)] += 1
                flush_at = now + 1.5 * self.sample_period_s / self.speed
                self._sched.at(flush_at, lambda: self._flush(channel, payload))
                return
        for _ in range(copies):
            self._send(channel, payload)
        if held is not None:
            self._send(channel, held)

    def _flush(self, channel: str, payload: bytes) -> None:
        with self._lock:
            if self._held[channel] is not payload:
                return
            self._held[channel] = None
        self._send(channel, payload)

    def close(self) -> None:
        self._sched.close()
        for ent in (*self._subs, self._live, *self._pub.values()):
            try:
                ent.undeclare()
            except Exception:
                pass
        with self._lock:
            if self._mirror_token is not None:
                try:
                    self._mirror_token.undeclare()
                except Exception:
                    pass
                self._mirror_token = None


class StallingController:
    """A unit's controller whose ``step`` stalls during given process-time windows.

    Parameters
    ----------
    inner : SampleController
        The real controller; everything else is delegated to it.
    windows : sequence of (start_s, end_s)
        Process-time windows in which every step sleeps ``stall_s`` first.
    stall_s : float
        Wall seconds each stalled step sleeps (choose it beyond the timing budget).
    """

    def __init__(self, inner, windows, stall_s: float) -> None:
        if not (math.isfinite(stall_s) and stall_s > 0):
            raise ValueError(f"stall_s: must be positive wall seconds, got {stall_s}")
        self.inner = inner
        self.windows = [(float(a), float(b)) for a, b in windows]
        self.stall_s = float(stall_s)
        self.stalls = 0

    def step(self, k, t, y, reference):
        if any(a <= t <= b for a, b in self.windows):
            self.stalls += 1
            time.sleep(self.stall_s)
        return self.inner.step(k, t, y, reference)

    def __getattr__(self, name):  # checkpoint, restore, on_transition, ...
        return getattr(self.inner, name)


# -- a controller node with a stalling solver, as a process (used by the soak) -------------
def _controller_main(argv: list[str] | None = None) -> int:
    """``python -m services.soak.faults controller``: ``ssmpc controller`` with stall windows."""
    import argparse

    from controller.units.config import build_plant
    from services.nodes.controller import ControllerNode
    from services.nodes.run import add_mesh_arguments, session_settings
    from services.registry import build_controller, load_unit_config
    from services.store import UnitStore, default_store_path
    from services.timing import TimingBudget

    p = argparse.ArgumentParser(prog="python -m services.soak.faults controller")
    p.add_argument("role", choices=["controller"])
    p.add_argument("--unit", default="te")
    p.add_argument("--unit-config", default=None)
    p.add_argument("--speed", type=float, default=1.0)
    p.add_argument("--state-dir", default=".")
    p.add_argument("--stall", action="append", default=[], metavar="T0:T1",
                   help="process-time window (s) in which every step stalls")
    p.add_argument("--stall-factor", type=float, default=4.0,
                   help="stall length as a multiple of the timing budget")
    add_mesh_arguments(p)
    args = p.parse_args(argv)
    logging.basicConfig(level=logging.WARNING,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    cfg = load_unit_config(args.unit, args.unit_config)
    windows = [tuple(float(v) for v in w.split(":")) for w in args.stall]
    budget = TimingBudget(cfg.sample_period_s, args.speed, cfg.budget_fraction)
    plant = build_plant(cfg)
    inner = build_controller(cfg, plant)
    ctl = StallingController(inner, windows, args.stall_factor * budget.budget_s)
    stop = threading.Event()

    import faulthandler
    import signal

    faulthandler.register(signal.SIGUSR1)  # stacks to the log on demand (a hung node)
    signal.signal(signal.SIGTERM, lambda *a: stop.set())
    signal.signal(signal.SIGINT, lambda *a: stop.set())
    from services.io.zenoh_session import open_session

    store = UnitStore(default_store_path(cfg.unit, args.state_dir), cfg.unit)
    session = open_session(session_settings(args, role="controller"))
    node = None
    try:
        node = ControllerNode(cfg, session, store, None, speed=args.speed, controller=ctl)
        print(f"ready controller {cfg.unit} zid={session.zid()}", flush=True)
        node.run(stop)
    finally:
        if node is not None:
            node.close()
        session.close()
        store.close()
    return 0


if __name__ == "__main__":  # pragma: no cover - a subprocess of the soak
    import sys

    sys.exit(_controller_main())
