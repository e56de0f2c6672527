"""The plant node: a plant of :mod:`plant_sim` in scaled real time on Zenoh.

Each sample k (period ``Ts`` process seconds, ``Ts / speed`` wall seconds):

1. publish :class:`~services.io.messages.Measurement` ``k`` (outputs at ``t_k``)
   on ``ssmpc/<unit>/meas``;
2. wait for the boundary ``k + 1`` (real-time mode), or for the MV answering
   sample ``k`` (lock-step mode, bounded by a timeout);
3. take the newest accepted MV message (zero-order hold: none new → keep the
   last, as a DCS does) and integrate the plant over ``[t_k, t_k+1]``.

An MV message is accepted only if it decodes strictly, names this unit, comes
from the expected sender and has a ``seq`` newer than the last accepted one, but
not further ahead of it than the wall time since then allows (the controller
numbers its moves by the wall clock in µs, see ``ControllerNode._publish_mv``; the
first one may be at most that far ahead of this node's clock): a forged move with a
huge ``seq`` would otherwise make every genuine move look stale. Everything else is
counted by reason (``decode``, ``sender``, ``tuning``, ``stale``, ``jump``) and ignored.
A move of the expected sender refused as stale although it answers a sample as new as the
applied one's raises the alarm that the applied move is not the controller's latest.
The move applied is then held inside the instrument ranges and rate limits of
:mod:`services.nodes.plant_guard` (counted as ``moves_limited``, with an alarm).

A move may name the tuning set of the plant's own loops for its interval (TE:
:data:`controller.units.te.loops.LOOP_TUNING_SETS`); a move naming a set this plant
does not know is refused whole (``tuning``, with an alarm), one naming none runs the
default set. The set switches with the move it came with, before the interval is
integrated; a held sample keeps the set in force. When the controller's liveliness is
lost (over OPC UA: its heartbeat) the loops shed to their default set, as a DCS sheds
its APC, and the last move holds; moves applied before the controller is back (one
still on its way included) run the default set. ``status`` reports the set in force
(``tuning``).

Every measurement carries this run's ``incarnation`` (random at start), so the
controller can tell a restarted plant from a forged or replayed sample. A controller move computed
from ``y(k)`` and received before boundary ``k+1`` acts over ``[t_k, t_k+1]``,
the usual discrete-time convention (computation delay within the budget).

**Lock-step mode** (``lockstep=True``) is for tests and benchmarks: the plant
waits for the MV of sample ``k`` (or ``lockstep_timeout_s``, then holds)
instead of the wall clock, so a run is deterministic and as fast as the loop
allows. The controller still measures its compute time against the budget of
the configured speed.

**Busy polling** (``busy_poll=True``, ``ssmpc plant --busy-poll``): the loop thread
never sleeps. It polls a channel for MV messages (Zenoh's thread only queues them)
and the clock for the boundary, calling ``os.sched_yield`` between polls, so that a
sample boundary is kept to a few microseconds instead of a wake-up: on a virtual
machine a sleeping thread's wake-up came 2-4 ms late several times a minute, a whole
sample at 10,000x for TE (``docs/realtime.md``). It costs one CPU at 100 %.

The node holds the liveliness token ``ssmpc/<unit>/alive/plant`` and answers
queries on ``ssmpc/<unit>/plant/cmd/**``: ``status``, ``disturbance``
(``{"name": ..., "value": ...}``: a disturbance variable of an ODE plant, or
``IDV1``…``IDV20`` on/off for TE), ``noise`` (``{"on": bool}``, TE), ``reset_stats``.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from controller.blas import single_threaded_blas
from controller.units.config import UnitConfig, build_plant, cv_indices, mv_indices, time_scale_s
from services.io import keys
from services.io.messages import Measurement, MessageError, MVMessage, Reply, Request
from services.io.zenoh_session import (
    PayloadSample,
    declare_loop_publisher,
    declare_loop_subscriber,
)
from services.nodes.plant_guard import InstrumentLimits, te_limits
from services.timing import GC_PAUSES, SampleClock, TimingBudget, percentile_summary

__all__ = ["ODERunner", "PlantNode", "PlantCounters"]

log = logging.getLogger("ssmpc.plant")


class ODERunner:
    """Integrates a :class:`~plant_sim.base.PlantModel` sample by sample.

    The MVs are the unit's selected inputs; the other inputs stay at the
    initial grade's values. Time is kept in process seconds.
    """

    def __init__(self, cfg: UnitConfig, plant=None) -> None:
        from plant_sim.integrate import step

        self._step = step
        self.plant = plant if plant is not None else build_plant(cfg)
        op = self.plant.operating_point(cfg.initial_grade)
        self.x = np.asarray(op.x, float).copy()
        self.u_full = np.asarray(op.u, float).copy()
        self.d = (np.asarray(op.d, float).copy() if op.d.size == self.plant.nd
                  else self.plant.default_disturbance())
        self.cvi = cv_indices(cfg, self.plant)
        self.mvi = mv_indices(cfg, self.plant)
        self.scale = time_scale_s(self.plant)
        self.substeps = cfg.substeps
        self.t = 0.0
        self.shutdown = False
        #: the plant side's tuning sets (an ODE plant has no loops: none) and the one in force
        self.tunings: tuple[str, ...] = ()
        self.tuning: str | None = None
        self.default_tuning: str | None = None
        lo = np.array([self.plant.input_vars[i].lower for i in self.mvi])
        hi = np.array([self.plant.input_vars[i].upper for i in self.mvi])
        self.u_lower, self.u_upper = lo, hi
        self.mv_names = tuple(self.plant.input_vars[i].name for i in self.mvi)
        #: the inputs' physical bounds, no rate limit (plant_guard)
        self.limits = InstrumentLimits(self.mv_names, tuple(lo), tuple(hi),
                                       (math.inf,) * len(lo))

    @property
    def u(self) -> np.ndarray:
        return self.u_full[self.mvi].copy()

    def y(self) -> np.ndarray:
        return np.asarray(self.plant.outputs(self.x, self.u_full), float)[self.cvi]

    def advance(self, u, dt_s: float) -> None:
        """Apply ``u`` (clipped to the actuator limits) and integrate ``dt_s`` process seconds."""
        self.u_full[self.mvi] = np.clip(np.asarray(u, float), self.u_lower, self.u_upper)
        h = dt_s / self.scale / self.substeps
        for _ in range(self.substeps):
            self.x = self._step(self.plant, self.x, self.u_full, h, self.d, t=self.t / self.scale)
        self.t += dt_s

    def set_disturbance(self, name: str, value: float) -> None:
        i = self.plant.index("disturbance", name)
        v = float(value)
        if not np.isfinite(v):
            raise ValueError(f"value: disturbance {name} must be finite")
        self.d[i] = v

    def disturbances(self) -> dict[str, float]:
        return dict(zip(self.plant.names("disturbance"), self.d.tolist()))


class TERunner:
    """The Tennessee Eastman plant: Euler at 1.8 s with the Table 7.10 PI loops closed.

    The inner loops of the cascade (:func:`controller.units.te.structure.te_structure`)
    run at every integration step, as a DCS runs them; the unit's MVs are XMVs not
    driven by a loop and the loops' set points
    (:func:`controller.units.te.structure.te_mv_names`). Everything else holds its start value.
    Disturbances: ``set_idv(k, on)``; measurement noise: ``set_noise(on)``.
    """

    def __init__(self, cfg: UnitConfig, *, noise: bool = False, seed: float | None = None
                 ) -> None:
        from controller.units.te.loops import DEFAULT_TUNING, LOOP_TUNING_SETS
        from controller.units.te.structure import (
            TE_EULER_STEP_S,
            te_mv_names,
            te_setpoint_name,
            te_structure,
        )
        from plant_sim.tennessee_eastman import SimSettings, TESimulator
        from plant_sim.tennessee_eastman.regulatory import RegulatoryLayer

        kw = {"mode": cfg.initial_grade, "noise": noise, "dt_s": TE_EULER_STEP_S}
        if seed is not None:
            kw["seed"] = seed
        self.sim = TESimulator(SimSettings(**kw))
        loops, _ = te_structure(cfg.strategy)
        self.reg = RegulatoryLayer(self.sim, loops=loops)
        self._loops = loops
        #: the loops' named tuning sets (:data:`controller.units.te.loops.LOOP_TUNING_SETS`;
        #: the decentralized structure's loops have their published tuning only) and the
        #: one in force, the default until a move selects another
        self.tunings = ((DEFAULT_TUNING,) if cfg.strategy == "decentralized"
                        else tuple(LOOP_TUNING_SETS))
        self.tuning = self.default_tuning = DEFAULT_TUNING
        self.steps = int(round(cfg.sample_period_s / TE_EULER_STEP_S))
        self.cvi = [int(n[5:]) - 1 for n in cfg.cvs]
        sp_names = [te_setpoint_name(lp) for lp in loops]
        mvs = te_mv_names(cfg)
        self._sp_index = {i: sp_names.index(n) for i, n in enumerate(mvs) if n in sp_names}
        self._xmv_index = {i: int(n[3:]) - 1 for i, n in enumerate(mvs) if n not in sp_names}
        self.t = 0.0
        self.mv_names = tuple(mvs)
        #: instrument ranges and rate limits of the set points and valves (plant_guard)
        self.limits = te_limits(mvs)
        self.u_lower = np.array(self.limits.lower)
        self.u_upper = np.array(self.limits.upper)

    @property
    def shutdown(self) -> bool:
        return self.sim.shutdown is not None

    @property
    def u(self) -> np.ndarray:
        sp = self.reg.setpoints
        xmv = self.sim.xmv
        out = np.empty(len(self._sp_index) + len(self._xmv_index))
        for i, j in self._sp_index.items():
            out[i] = sp[j]
        for i, j in self._xmv_index.items():
            out[i] = xmv[j]
        return out

    def y(self) -> np.ndarray:
        return self.sim.xmeas[self.cvi]

    def advance(self, u, dt_s: float) -> None:
        u = np.clip(np.asarray(u, float), self.u_lower, self.u_upper)
        if self._sp_index:
            sp = self.reg.setpoints
            for i, j in self._sp_index.items():
                sp[j] = u[i]
            self.reg.set_setpoints(sp)
        if self._xmv_index:
            xmv = self.sim.xmv
            for i, j in self._xmv_index.items():
                xmv[j] = u[i]
            self.sim.set_xmv(xmv)
        self.reg.run_steps(self.steps)
        self.t += dt_s

    def set_tuning(self, name: str) -> None:
        """Switch the loops to tuning set ``name`` (one of :attr:`tunings`; each retuned
        loop re-based onto its new gain,
        :meth:`plant_sim.tennessee_eastman.regulatory.RegulatoryLayer.set_gains`)."""
        from controller.units.te.loops import tuning_gains

        if name not in self.tunings:
            raise ValueError(f"tuning: unknown tuning set {name!r}; known: "
                             f"{', '.join(self.tunings)}")
        if name != self.tuning:
            self.reg.set_gains(tuning_gains(self._loops, name))
            self.tuning = name

    def set_idv(self, k: int, on: bool) -> None:
        self.sim.set_idv(int(k), bool(on))

    def set_noise(self, on: bool) -> None:
        from dataclasses import replace

        self.sim.settings = replace(self.sim.settings, noise=bool(on))

    def set_disturbance(self, name: str, value: float) -> None:
        k = int(name[3:]) if name.upper().startswith("IDV") and name[3:].isdigit() else 0
        if not 1 <= k <= 20:
            raise ValueError(f"name: unknown TE disturbance {name!r}; known: IDV1..IDV20")
        if value not in (0, 1):
            raise ValueError(f"value: IDV{k} is switched on (1) or off (0), got {value!r}")
        self.set_idv(k, bool(value))

    def disturbances(self) -> dict[str, float]:
        return {f"IDV{i + 1}": float(v) for i, v in enumerate(self.sim.idv)}


def make_runner(cfg: UnitConfig, **kw):
    """The plant runner of a unit: :class:`TERunner` for TE, else :class:`ODERunner`."""
    if cfg.plant == "te":
        return TERunner(cfg, **kw)
    return ODERunner(cfg)


#: Why a sample was held, from its record (see :func:`held_cause`).
HELD_CAUSES = ("published_late", "answered_late", "no_answer")


def held_cause(record: dict) -> str:
    """Why a held sample's move missed its boundary, from the plant's record of it.

    ``"no_answer"``: no MV answering it has come (controller gone, a lost message);
    ``"published_late"``: the plant itself put the measurement out more than half a
    period after its boundary (its own wake-up); ``"answered_late"``: otherwise, the
    answer took too long (the controller, or delivery either way).
    """
    if record["answered_after_ms"] is None:
        return "no_answer"
    if record["publish_lag_ms"] > 0.5 * record["period_ms"]:
        return "published_late"
    return "answered_late"


def _percentiles_us(values_s) -> dict | None:
    """p50/p99/max (µs) and count of a series of durations in s; None when empty."""
    s = percentile_summary(values_s, 1e6)
    if s is None:
        return None
    return {"p50_us": s["p50"], "p99_us": s["p99"], "max_us": s["max"], "n": s["n"]}


@dataclass
class PlantCounters:
    samples: int = 0
    mv_accepted: int = 0
    mv_held: int = 0
    rejected: dict = field(default_factory=lambda: {"decode": 0, "sender": 0, "stale": 0,
                                                    "jump": 0, "tuning": 0})
    lockstep_timeouts: int = 0
    #: samples whose move was clamped or rate-limited (plant_guard)
    moves_limited: int = 0


class PlantNode:
    """Runs one unit's plant; see the module docstring.

    Parameters
    ----------
    cfg : UnitConfig
    session : zenoh.Session
        An open session (the caller closes it).
    speed : float
        Process seconds per wall second.
    expected_sender : str
        The only ``sender`` whose MV messages are applied.
    lockstep : bool
        Wait for the MV of each sample instead of the wall clock.
    lockstep_timeout_s : float
        Longest wait for an MV in lock-step mode (then the last MV holds).
    runner : optional
        A prepared plant runner (default :class:`ODERunner` of the unit's plant).
    link : optional
        A second plant link beside Zenoh (the OPC UA server of
        :class:`services.io.opcua.server.PlantOPCUAServer`): ``attach(node)`` at start,
        ``publish(measurement)`` every sample, ``status()``, ``close()``; it hands moves
        in through :meth:`submit_mv`.
    """

    #: How many of the latest held samples keep their record (see ``_note_held``).
    KEEP_HELD = 32

    #: MV messages the busy-poll channel holds (more than one only when the loop is
    #: behind; all are taken in order, the newest acts).
    POLL_QUEUE = 16
    #: Longest sleep between two looks at the stop event while waiting for a move, s.
    STOP_CHECK_S = 0.1
    #: How far an MV's ``seq`` (wall µs) may run ahead of the time elapsed since the
    #: last accepted one (or of this node's clock for the first), s; at least two
    #: wall periods. Clock skew between hosts of a mesh must stay below it.
    MV_SEQ_SLACK_S = 1.0
    #: Shortest wall time between two alarms of one kind (the rest are counted), s.
    ALARM_MIN_WALL_S = 1.0

    def __init__(self, cfg: UnitConfig, session, *, speed: float = 1.0,
                 expected_sender: str | None = None, lockstep: bool = False,
                 lockstep_timeout_s: float = 2.0, runner=None,
                 busy_poll: bool = False, link=None) -> None:
        self.cfg = cfg
        self.session = session
        self.budget = TimingBudget(cfg.sample_period_s, speed, cfg.budget_fraction)
        self.expected_sender = expected_sender or f"{cfg.unit}-controller"
        self.lockstep = lockstep
        self.lockstep_timeout_s = float(lockstep_timeout_s)
        self.runner = runner if runner is not None else make_runner(cfg)
        self.nu = len(self.runner.u)
        #: this run of the plant node, in every measurement
        self.incarnation = uuid.uuid4().hex
        self.limits: InstrumentLimits = self.runner.limits
        self.alarms: deque[str] = deque(maxlen=20)
        self._alarm_wall: dict[str, float] = {}
        self._seq_slack_us = 1e6 * max(self.MV_SEQ_SLACK_S, 2 * self.budget.wall_period_s)
        self._last_mv_wall_us = 0
        self._last_mv_meas_seq = -1
        self.counters = PlantCounters()
        self.k = 0
        self.last_mv_seq = -1
        self._applied_mv_seq = -1
        self._pending: MVMessage | None = None
        #: the loops shed to their default tuning set: the moves' sets are not taken
        #: (the controller lost, until it is back)
        self._tuning_shed = False
        self._cond = threading.Condition()
        self._lock = threading.Lock()
        self._published_at = 0.0
        #: wall time from publishing measurement k to receiving the MV answering it, s
        self.loop_latency_s: deque[float] = deque(maxlen=20_000)
        #: real-time mode: wall time from a sample boundary to its measurement going out, s
        self.publish_lag_s: deque[float] = deque(maxlen=20_000)
        self.worst_lag: tuple[float, float, int] = (0.0, 0.0, -1)  # (s, at unix s, sample)
        self.advance_max_s = 0.0  # longest integration of one sample interval, s
        self._lag_now = 0.0  # publish lag of the current sample, s
        #: real-time mode: the latest held samples, where their time went (ms)
        self.held_samples: deque[dict] = deque(maxlen=self.KEEP_HELD)
        self._held_open: dict[int, dict] = {}  # sample -> its record, awaiting the answer
        self._pub = declare_loop_publisher(session, keys.meas(cfg.unit))
        self.busy_poll = bool(busy_poll)
        self._sub = declare_loop_subscriber(  # busy polling: run() polls the channel
            session, keys.mv(cfg.unit), self._on_mv,
            poll_queue=self.POLL_QUEUE if self.busy_poll else None)
        self._qry = session.declare_queryable(keys.plant_cmd_all(cfg.unit), self._on_query)
        self._token = session.liveliness().declare_token(keys.alive(cfg.unit, "plant"))
        self.controller_alive = False
        self._live = session.liveliness().declare_subscriber(
            keys.alive(cfg.unit, "controller"), self._on_controller_liveliness, history=True)
        self.link = link
        if link is not None:
            link.attach(self)

    # -- Zenoh callbacks ---------------------------------------------------------------
    def _on_mv(self, sample) -> None:
        try:
            msg = MVMessage.from_bytes(sample.payload.to_bytes(), unit=self.cfg.unit, nu=self.nu)
        except MessageError as exc:
            with self._cond:
                self.counters.rejected["decode"] += 1
            log.warning("MV rejected: %s", exc)
            return
        now_us = time.time_ns() // 1000
        with self._cond:
            if msg.sender != self.expected_sender:
                self.counters.rejected["sender"] += 1
                log.warning("MV rejected: sender %r is not %r", msg.sender, self.expected_sender)
                return
            if msg.tuning is not None and msg.tuning not in self.runner.tunings:
                self.counters.rejected["tuning"] += 1
                known = ", ".join(self.runner.tunings) or "none"
                self._alarm("tuning", f"move for sample {msg.meas_seq} refused: unknown "
                            f"tuning set {msg.tuning!r} (this plant knows: {known})")
                return
            if msg.seq <= self.last_mv_seq:
                self.counters.rejected["stale"] += 1
                # a repeat of the applied move is the network's doing; an older move
                # for a sample no older than the applied one's is another publisher's
                if msg.seq < self.last_mv_seq and msg.meas_seq >= self._last_mv_meas_seq:
                    self._alarm("stale", f"move for sample {msg.meas_seq} refused as older "
                                "than the applied one: the applied move is not the "
                                "controller's latest (another publisher uses its name?)")
                return
            base = now_us if self.last_mv_seq < 0 else (
                self.last_mv_seq + now_us - self._last_mv_wall_us)
            if msg.seq > base + self._seq_slack_us:
                self.counters.rejected["jump"] += 1
                self._alarm("jump", f"move for sample {msg.meas_seq} refused: sequence jump "
                            f"of {(msg.seq - base) / 1e6:.3g} s beyond the time elapsed")
                return
            self.last_mv_seq = msg.seq
            self._last_mv_wall_us = now_us
            self._last_mv_meas_seq = msg.meas_seq
            if msg.meas_seq == self.k and not msg.fallback:
                self.loop_latency_s.append(time.perf_counter() - self._published_at)
            elif msg.meas_seq in self._held_open:  # the answer to a held sample, late
                record = self._held_open.pop(msg.meas_seq)
                now = time.perf_counter()
                record["answered_after_ms"] = (now - record["published_s"]) * 1e3
                record["answered_s"] = now
            self._pending = msg
            self._cond.notify_all()

    def submit_mv(self, payload: bytes) -> None:
        """An MV message from the plant link (OPC UA): the same checks as over Zenoh."""
        self._on_mv(PayloadSample(payload))

    def _alarm(self, kind: str, text: str) -> None:
        """Raise an alarm (caller holds ``_cond``), at most one of a kind per
        :attr:`ALARM_MIN_WALL_S`."""
        now = time.monotonic()
        if now - self._alarm_wall.get(kind, -math.inf) < self.ALARM_MIN_WALL_S:
            return
        self._alarm_wall[kind] = now
        self.alarms.append(f"sample {self.k}: {text}")
        log.warning("%s", text)

    def _on_query(self, query) -> None:
        try:
            req = Request.from_bytes(query.payload.to_bytes()) if query.payload is not None \
                else Request(action=str(query.key_expr).rsplit("/", 1)[-1])
            reply = self._handle(req)
        except MessageError as exc:
            reply = Reply(400, error=str(exc))
        except ValueError as exc:
            reply = Reply(422, error=str(exc))
        except Exception as exc:  # never let a query kill the node
            reply = Reply(500, error=f"internal error: {exc}")
        query.reply(query.key_expr, reply.to_bytes())

    def _on_controller_liveliness(self, sample) -> None:
        import zenoh

        alive = sample.kind == zenoh.SampleKind.PUT
        if self.controller_alive and not alive:
            # Documented safe action: keep applying the last move (as a DCS holds its
            # outputs) and say so; a restarted controller resumes from its checkpoint.
            # The loops shed to their default tuning set, as a DCS sheds its APC's.
            log.warning("controller of %s lost: holding the last MVs", self.cfg.unit)
            self.shed_tuning()
        elif alive:
            self.resume_tuning()
        self.controller_alive = alive

    def shed_tuning(self) -> None:
        """The loops back on their default tuning set until :meth:`resume_tuning`: moves
        applied meanwhile (one still on its way from the lost controller included) keep
        their valves but not their tuning set."""
        if not self.runner.tunings:
            return
        self._tuning_shed = True
        with self._lock:
            if self.runner.tuning == self.runner.default_tuning:
                return
            self.runner.set_tuning(self.runner.default_tuning)
            log.warning("%s: loops back on their %r tuning", self.cfg.unit,
                        self.runner.tuning)

    def resume_tuning(self) -> None:
        """The controller is back: its moves select the tuning set again."""
        self._tuning_shed = False

    def _handle(self, req: Request) -> Reply:
        if req.action == "status":
            return Reply(200, self.status())
        if req.action == "disturbance":
            name, value = req.args.get("name"), req.args.get("value")
            if not isinstance(name, str):
                return Reply(422, error="name: expected the disturbance name")
            if isinstance(value, bool) or not isinstance(value, int | float):
                return Reply(422, error="value: expected a number")
            with self._lock:
                try:
                    self.runner.set_disturbance(name, value)
                except ValueError as exc:  # PlantInputError: unknown name
                    return Reply(404 if "unknown" in str(exc) else 422, error=str(exc))
            return Reply(200, {"disturbances": self.runner.disturbances()})
        if req.action == "disturbance_list":
            return Reply(200, self.runner.disturbances())
        if req.action == "noise":
            on = req.args.get("on")
            if not isinstance(on, bool) or not hasattr(self.runner, "set_noise"):
                return Reply(422, error="on: expected a boolean (TE plants only)")
            with self._lock:
                self.runner.set_noise(on)
            return Reply(200, {"noise": on})
        if req.action == "reset_stats":
            with self._cond:
                self.loop_latency_s.clear()
                self.publish_lag_s.clear()
                self.worst_lag = (0.0, 0.0, -1)
                self.advance_max_s = 0.0
                self.held_samples.clear()
                self._held_open.clear()
                self.counters = PlantCounters()
            GC_PAUSES.reset()
            return Reply(200, self.status())
        return Reply(404, error=f"action: unknown plant action {req.action!r}")

    def status(self) -> dict:
        with self._cond:
            c = self.counters
            latency = _percentiles_us(self.loop_latency_s)
            lag = _percentiles_us(self.publish_lag_s)
            if lag is not None:  # when the worst one happened (to match other nodes' records)
                lag.update(worst_at_unix_s=self.worst_lag[1], worst_sample=self.worst_lag[2])
            return {"loop_latency": latency, "publish_lag": lag,
                    "advance_max_ms": self.advance_max_s * 1e3,
                    "held_samples": [dict(r) for r in self.held_samples],
                    "gc_pauses": GC_PAUSES.as_dict(),
                    "unit": self.cfg.unit, "sample": self.k,
                    "t": self.runner.t,
                    "u": self.runner.u.tolist(), "mv_seq_applied": self._applied_mv_seq,
                    "samples": c.samples, "mv_accepted": c.mv_accepted, "mv_held": c.mv_held,
                    "mv_rejected": dict(c.rejected), "lockstep": self.lockstep,
                    "lockstep_timeouts": c.lockstep_timeouts, "speed": self.budget.speed,
                    "moves_limited": c.moves_limited, "alarms": list(self.alarms),
                    "incarnation": self.incarnation,
                    "busy_poll": self.busy_poll,
                    "shutdown": bool(self.runner.shutdown),
                    "tuning": self.runner.tuning,
                    "controller_alive": self.controller_alive,
                    "link": None if self.link is None else self.link.status()}

    # -- loop ------------------------------------------------------------------------------
    def _publish(self) -> None:
        y = self.runner.y()
        msg = Measurement(unit=self.cfg.unit, seq=self.k, t=self.runner.t, y=tuple(y),
                          u=tuple(self.runner.u), mv_seq=self._applied_mv_seq,
                          shutdown=bool(self.runner.shutdown), incarnation=self.incarnation)
        with self._cond:
            self._published_at = time.perf_counter()
        self._pub.put(msg.to_bytes())
        if self.link is not None:
            self.link.publish(msg)
        self.counters.samples += 1

    def _poll_mv(self) -> None:
        """Busy polling: take the queued MV messages in, then yield the CPU (and with
        it the interpreter lock) to any thread that is ready to run."""
        try_recv = self._sub.try_recv
        while (sample := try_recv()) is not None:
            self._on_mv(sample)
        os.sched_yield()

    def _answered(self) -> bool:
        return self._pending is not None and self._pending.meas_seq >= self.k

    def _take_mv(self, timeout_s: float,
                 stop: threading.Event | None = None) -> MVMessage | None:
        """The newest accepted MV; waits up to ``timeout_s`` for the one answering sample k,
        or until ``stop`` is set (seen within :attr:`STOP_CHECK_S` when sleeping)."""
        end = time.perf_counter() + max(0.0, timeout_s)
        if self.busy_poll:
            while True:
                self._poll_mv()
                if (self._answered() or time.perf_counter() >= end
                        or (stop is not None and stop.is_set())):
                    break
        with self._cond:
            if self.busy_poll:
                ok = self._answered()
            else:  # in slices, so that a stop is not kept waiting for a whole period
                while not (ok := self._answered()):
                    left = end - time.perf_counter()
                    if left <= 0 or (stop is not None and stop.is_set()):
                        break
                    self._cond.wait(min(left, self.STOP_CHECK_S))
            if not ok and self.lockstep:
                self.counters.lockstep_timeouts += 1
            msg, self._pending = self._pending, None
            if msg is None:
                self.counters.mv_held += 1
                if not self.lockstep:
                    self._note_held()
            else:
                self.counters.mv_accepted += 1
            return msg

    def _note_held(self) -> None:
        """Record where the time of held sample k went (caller holds ``_cond``).

        ``publish_lag_ms``: how late measurement k went out after its boundary;
        ``answered_after_ms``: wall time from its publication to the arrival of the MV
        answering it (filled in when that MV comes; None if it never does). The sample
        was held because the two add up to more than ``period_ms``.
        """
        record = {"sample": self.k, "at_unix_s": time.time(),
                  "period_ms": self.budget.wall_period_s * 1e3,
                  "publish_lag_ms": self._lag_now * 1e3, "answered_after_ms": None,
                  # time.perf_counter (CLOCK_MONOTONIC: comparable with the controller's
                  # sample_times on the same host)
                  "published_s": self._published_at, "answered_s": None}
        self.held_samples.append(record)
        self._held_open = {k: v for k, v in self._held_open.items() if k >= self.k - 4}
        self._held_open[self.k] = record

    def _guarded(self, msg: MVMessage) -> np.ndarray:
        """The move of ``msg`` inside the instrument ranges and rate limits."""
        u, limited = self.limits.apply(self.runner.u, msg.u)
        if limited:
            with self._cond:
                self.counters.moves_limited += 1
                self._alarm("limited", f"move for sample {msg.meas_seq} clamped or "
                            f"rate-limited: {', '.join(limited)}")
        return u

    def run(self, stop: threading.Event, max_samples: int | None = None) -> None:
        """Run until ``stop`` is set (or ``max_samples`` samples have been integrated),
        with BLAS single-threaded meanwhile (:mod:`controller.blas`); see :meth:`_run`."""
        with single_threaded_blas():
            self._run(stop, max_samples)

    def _run(self, stop: threading.Event, max_samples: int | None = None) -> None:
        """Run until ``stop`` is set (or ``max_samples`` samples have been integrated).

        Real-time mode integrates the interval ``[t_k, t_k+1]`` as soon as the MV
        answering sample k arrives (or at boundary k+1 with the held MV if it has
        not), then publishes ``y(k+1)`` exactly at boundary k+1: the integration
        stays off the critical path.
        """
        clock = SampleClock(self.budget.wall_period_s)
        self._publish()
        n = 0
        while not stop.is_set() and (max_samples is None or n < max_samples):
            if self.lockstep:
                msg = self._take_mv(self.lockstep_timeout_s, stop)
            else:
                msg = self._take_mv(clock.deadline(clock.k + 1) - time.perf_counter(), stop)
            u = self.runner.u if msg is None else self._guarded(msg)
            if msg is not None:
                self._applied_mv_seq = msg.seq
            t_adv = time.perf_counter()
            with self._lock:
                if msg is not None and self.runner.tunings:  # checked known on receipt
                    self.runner.set_tuning(msg.tuning if msg.tuning and not self._tuning_shed
                                           else self.runner.default_tuning)
                self.runner.advance(u, self.cfg.sample_period_s)
            self.advance_max_s = max(self.advance_max_s, time.perf_counter() - t_adv)
            if not self.lockstep:
                clock.wait_next(stop, poll=self._poll_mv if self.busy_poll else None)
                if stop.is_set():
                    break
                lag = time.perf_counter() - clock.deadline()
                self._lag_now = lag
                self.publish_lag_s.append(lag)
                if lag > self.worst_lag[0]:
                    self.worst_lag = (lag, time.time() - lag, self.k + 1)
            with self._cond:
                self.k += 1
            n += 1
            self._publish()

    def close(self) -> None:
        if self.link is not None:
            self.link.close()
        for ent in (self._live, self._token, self._qry, self._sub, self._pub):
            try:
                ent.undeclare()
            except Exception:
                pass
