"""The controller node: one unit's controller on Zenoh, inside a timing budget.

Per measurement (sample k):

1. decode and validate it strictly (a bad payload is counted, raises an alarm
   and is skipped: the plant keeps the last move); a measurement of another plant
   incarnation than the one followed is refused (``foreign_measurements``, an
   alarm) unless the plant's liveliness token appeared again since and the one
   followed has gone silent (:attr:`ControllerNode.PLANT_SILENT_PERIODS`): only
   then did the plant restart, and its samples are followed from its new numbering;
2. advance the transition (:class:`~services.transitions.TransitionManager`)
   and take the reference over the horizon;
3. step the unit's :class:`~controller.interfaces.SampleController` (shared
   state, adaptation, switching, MPC — whatever the configured controller does);
4. publish the move on ``ssmpc/<unit>/mv``.

Budget: ``budget_fraction * Ts / speed`` wall seconds from the measurement's
arrival (when this node's thread takes it in: time it waited in Zenoh for a thread
still busy with the previous sample is not in it; the plant counts that sample as held
if its move comes after the next boundary). A :class:`~services.timing.Watchdog`
publishes the fallback move (the last move, held) at the deadline if the step has
not returned, so an overrun never stalls the plant; the late result is not published
and the miss is counted (also where the watchdog's thread had not run by the deadline
on a loaded machine: the step's end then sends the fallback). The controller's own
fallback (``ControlDecision.fallback``: next move of the previous plan for the MPC) is
counted too.

Threads: a measurement is processed on the Zenoh thread that delivers it (no
hand-over to another thread: waking one cost up to milliseconds on a loaded
machine); one sample at a time, and a measurement that arrives while one is
being processed replaces any older waiting one (only the newest is acted on, the
others are counted as dropped) and is processed right after it.

Status goes to ``ssmpc/<unit>/status`` every ``status_every`` samples, but no
more often than every :attr:`ControllerNode.STATUS_MIN_WALL_S` of wall time (TE at
10,000x: every 10 samples is ~28 messages a second at ~1.3 ms of the loop thread
each), on a sample with the slack for it before the next measurement, at the latest
after :attr:`ControllerNode.STATUS_MAX_WALL_S`; queries answer with a fresh status at
any time;
telemetry to Rerun in batches; a checkpoint (controller state, last move,
transition state) to SQLite every ``checkpoint_every`` samples or 5 wall
seconds — on the first such sample with time for the snapshot before the next
measurement, at the latest after 10 s — and at every transition state change. On start the node
restores the checkpoint and, on a running plant, takes over the move the plant holds
(:meth:`ControllerNode._align`); its moves then ramp in at no more than the largest
recent step of each MV (:mod:`services.nodes.ramp_in`). Whenever the plant keeps
another move than the one computed (a missed deadline, the ramp-in), the controller
is told (``applied``) and goes on from what the plant got.

Queries on ``ssmpc/<unit>/cmd/<action>`` with a :class:`~services.io.messages.Request`:
``status``, ``grades``, ``transition`` (``args.op``: ``create`` with ``grade``
and optional ``duration_s``; ``get`` / ``abort`` with ``id``; ``list``), ``events``
(:mod:`services.events_query`), ``kpis`` (service factor, constraint activity, cost
against the base case, prediction error per model: :mod:`controller.kpis`, counted
every sample after the move is out and kept in the checkpoint), and the operator's
``mode`` and ``variable`` (:mod:`services.nodes.operator_commands`).

Operator control (:class:`controller.units.operator.OperatedController`): in mode
``off`` nothing is computed and in ``warm`` the move is computed and reported
(``computed_mv``) but neither writes a move (no watchdog either: the plant holds its
move and regulatory layer); per-variable modes and limits apply from the next sample.

Events (:mod:`services.events`): every transition state change, every operator
action (with the ``identity`` the api node puts in the request's args) and every
alarm of the controller raised or cleared go to the store's event log; an operator
action is committed with the change it makes, before the reply
(:meth:`ControllerNode.record_action` for actions that change no transition).
"""

from __future__ import annotations

import copy
import logging
import math
import operator
import os
import queue
import sqlite3
import threading
import time
from collections import deque

import numpy as np

from controller.blas import single_threaded_blas
from controller.interfaces import ControlDecision
from controller.units.config import UnitConfig, build_plant, cv_scales, plausible_ranges, unit_info
from controller.units.kpis import UnitKPIs
from controller.units.operator import operate
from controller.units.takeover import align_multimodel, continue_from_applied
from controller.units.variables import at_limit, unit_variables
from services.events import (
    AlarmTracker,
    action_event,
    alarm_key,
    describe,
    identity_of,
    transition_event,
)
from services.events_query import events_reply
from services.io import keys
from services.io.messages import Measurement, MessageError, MVMessage, Reply, Request
from services.io.zenoh_session import declare_loop_publisher, declare_loop_subscriber
from services.nodes import operator_commands
from services.nodes.ramp_in import STEP_WINDOW, MoveHistory, RampIn
from services.registry import build_controller
from services.store import StoreError, UnitStore
from services.telemetry import TelemetryLogger
from services.timing import (
    GC_PAUSES,
    DeadlineStats,
    SampleTimes,
    TimingBudget,
    Watchdog,
    thread_switches,
)
from services.transitions import (
    TERMINAL,
    ConflictError,
    QueueFullError,
    Transition,
    TransitionError,
    TransitionManager,
    UnknownTransition,
)

__all__ = ["CHECKPOINT_MISFIT", "ControllerNode", "FailureLog"]

log = logging.getLogger("ssmpc.controller")

#: What a controller's ``restore`` raises for a checkpoint entry that does not fit: a key
#: missing, a value of the wrong type or shape (``AttributeError``: a mapping's method
#: asked of an entry that is not one). The node refuses such a checkpoint with a
#: :class:`~services.store.StoreError`.
CHECKPOINT_MISFIT = (KeyError, TypeError, ValueError, IndexError, AttributeError)


def _qp_work(extra: dict) -> dict:
    """``qp_solve_ms`` and ``qp_iterations`` of a decision's extras, those reported
    (:data:`controller.interfaces.QP_WORK_KEYS`)."""
    out = {}
    if isinstance(extra.get("qp_solve_ms"), int | float):
        out["qp_solve_ms"] = extra["qp_solve_ms"]
    if isinstance(extra.get("iterations"), int):
        out["qp_iterations"] = extra["iterations"]
    return out


def _json_targets(report) -> dict | None:
    """A decision's ``extra["targets"]`` as the status carries it: its status, the MV and
    CV targets by name, the relaxed limits; None without one."""
    if not isinstance(report, dict) or "status" not in report:
        return None

    def numbers(d):
        return {str(k): float(v) for k, v in d.items()} if isinstance(d, dict) else {}

    relaxed = [{"cv": str(r["cv"]), "kind": str(r["kind"]), "rank": int(r["rank"]),
                "limit": float(r["limit"]), "amount": float(r["amount"])}
               for r in report.get("relaxed") or () if isinstance(r, dict)]
    return {"status": str(report["status"]), "mv": numbers(report.get("mv")),
            "cv": numbers(report.get("cv")), "relaxed": relaxed}


class _Worker:
    """One background thread for slow chores of a sample, in submission order, so that
    they never delay the next move. The node keeps one for the store (SQLite) and one
    for telemetry (Rerun): a slow telemetry sink never holds up a write that a request
    is answered on.

    ``on_error(exc)`` is told of every task that raised (after it is logged)."""

    def __init__(self, on_error=None) -> None:
        self._on_error = on_error
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._latest: dict[str, tuple] = {}
        self._latest_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name="ssmpc-worker", daemon=True)
        self._thread.start()

    def submit(self, fn, *args) -> None:
        self._q.put((fn, args, None))

    def submit_latest(self, key: str, fn, *args) -> None:
        """Like :meth:`submit` for a write only whose newest value matters and whose
        order no other record depends on (the recent steps): while one of ``key`` waits
        in the queue, a new one replaces its arguments instead of queueing again. A store
        that cannot commit (each try waits out the busy timeout) then holds one such write,
        not one per sample, and a write someone waits for is not stuck behind them."""
        with self._latest_lock:
            queued = key in self._latest
            self._latest[key] = (fn, args)
        if not queued:
            self._q.put((self._run_latest, (key,), None))

    def _run_latest(self, key: str) -> None:
        with self._latest_lock:
            fn, args = self._latest.pop(key)
        fn(*args)

    def call(self, fn, *args, timeout: float = 30.0):
        """Run ``fn(*args)`` in order after everything submitted so far; its result, or
        its exception raised here.

        TimeoutError if it has not *started* within ``timeout``: it is then withdrawn
        and never runs, so a write answered as not committed does not commit later (a
        store held locked by another process makes every write ahead of it wait out
        the busy timeout). One that has started is waited for to the end (at most the
        store's busy timeout) and answers as it ends."""
        done = threading.Event()
        out: dict = {}
        state = {"started": False, "withdrawn": False}
        gate = threading.Lock()

        def task():
            with gate:
                if state["withdrawn"]:
                    return
                state["started"] = True
            try:
                out["value"] = fn(*args)
            except BaseException as exc:  # handed to the caller, not to on_error
                out["error"] = exc
            finally:
                done.set()

        self._q.put((task, (), None))
        if not done.wait(timeout):
            with gate:
                if not state["started"]:
                    state["withdrawn"] = True
                    raise TimeoutError(f"store: the write did not start within {timeout:g} s "
                                       "(withdrawn, not committed)")
            done.wait()  # it runs now: its own outcome is the answer
        if "error" in out:
            raise out["error"]
        return out.get("value")

    def wait(self, timeout: float = 30.0) -> None:
        """Block until everything submitted so far is done."""
        done = threading.Event()
        self._q.put((done.set, (), None))
        done.wait(timeout)

    def close(self, timeout: float = 30.0) -> None:
        self._q.put(None)
        self._thread.join(timeout)

    def _run(self) -> None:
        while True:
            item = self._q.get()
            if item is None:
                return
            fn, args, _ = item
            try:
                fn(*args)
            except Exception as exc:
                log.exception("background task failed")
                if self._on_error is not None:
                    try:
                        self._on_error(exc)
                    except Exception:
                        log.exception("background error handler failed")


class FailureLog:
    """Logs a failure's traceback once per kind (exception type and message), then
    only counts it: a fault that repeats every sample must not flood the log.

    Every :attr:`every` repeats a one-line summary with the count is logged.
    """

    every = 1000

    def __init__(self, logger: logging.Logger) -> None:
        self.logger = logger
        self.counts: dict[tuple[str, str, str], int] = {}

    def note(self, what: str, exc: BaseException) -> int:
        """Record one failure; returns how many times it happened before."""
        key = (what, type(exc).__name__, str(exc))
        n = self.counts.get(key, 0)
        self.counts[key] = n + 1
        if n == 0:
            self.logger.error("%s: %s", what, exc, exc_info=exc)
        elif (n + 1) % self.every == 0:
            self.logger.error("%s: %s (%d times so far)", what, exc, n + 1)
        return n


class ControllerNode:
    """Runs one unit's controller; see the module docstring.

    Parameters
    ----------
    cfg : UnitConfig
    session : zenoh.Session
    store : UnitStore
    telemetry : TelemetryLogger or None
    speed : float
        Process seconds per wall second (sets the wall-clock budget).
    sender : str
        Identity written into every MV message.
    controller : SampleController, optional
        Default: built from ``cfg``.
    horizon : int
        Reference rows passed to the controller (its prediction horizon P).
    plant_link : optional
        The plant link when it is not Zenoh (the OPC UA client of
        :class:`services.io.opcua.client.ControllerOPCUALink`): ``subscribe(callback)``
        delivers measurements as Zenoh samples, ``put(bytes)`` takes the moves,
        ``undeclare()``. Commands, status and liveliness stay on Zenoh.
    """

    def __init__(self, cfg: UnitConfig, session, store: UnitStore,
                 telemetry: TelemetryLogger | None = None, *, speed: float = 1.0,
                 sender: str | None = None, controller=None, horizon: int = 1,
                 busy_poll: bool = False, plant_link=None) -> None:
        if plant_link is not None and busy_poll:
            raise ValueError("busy_poll: polls a Zenoh channel; not with another plant link")
        self.cfg = cfg
        self.session = session
        self.store = store
        self.telemetry = telemetry
        self.sender = sender or f"{cfg.unit}-controller"
        self.budget = TimingBudget(cfg.sample_period_s, speed, cfg.budget_fraction)
        self.horizon = int(horizon)
        plant = build_plant(cfg)
        self.info = unit_info(cfg, plant)
        self.variables = unit_variables(cfg, plant)
        self.ny, self.nu = len(self.info.cv_names), len(self.info.mv_names)
        grades = self.info.grades
        self.u_last = np.asarray(grades[cfg.initial_grade]["mv"], float)
        self.controller = controller if controller is not None else build_controller(
            cfg, plant, self.u_last, grades)
        self.horizon = int(getattr(self.controller, "horizon", self.horizon))
        #: the controller under the operator's mode and per-variable settings
        self.operated = operate(cfg, plant, self.controller, grades)
        # Transitions follow the tracked CVs (cfg.track; all CVs when empty).
        self.track_names = cfg.track or self.info.cv_names
        self.track_idx = [self.info.cv_names.index(n) for n in self.track_names]
        tracked = {k: {**g, "setpoints": [g["setpoints"][i] for i in self.track_idx]}
                   for k, g in grades.items()}
        self.tm = TransitionManager(
            cfg.unit, {k: g["setpoints"] for k, g in tracked.items()}, cv_scales(cfg, tracked),
            cfg.initial_grade, cfg.sample_period_s, cfg.transition_duration_s,
            cfg.settle_tolerance, cfg.settle_samples, max_queued=cfg.transition_queue_limit)
        self.stats = DeadlineStats(self.budget.budget_s)
        self.sample_times = SampleTimes()  # arrival and move of the latest samples
        self.mv_seq = 0
        #: the plant side's tuning set sent with each move (the controller's selection,
        #: ``ControlDecision.extra["tuning"]``; None: the plant's default)
        self.tuning: str | None = None
        self.k = -1
        self.t = 0.0
        self.y = np.full(self.ny, np.nan)
        self.r = np.asarray(self.tm.hold, float)
        self.last_decision = None
        self.bad_measurements = 0
        self.stale_measurements = 0
        self.implausible_measurements = 0
        #: samples whose controller step raised (the move was held); tracebacks are
        #: logged once per kind of failure, then counted (:class:`FailureLog`)
        self.failed_samples = 0
        self._alarms_logged: set[str] = set()
        #: liveliness of the plant node (None until it is first seen)
        self.plant_alive: bool | None = None
        self._failures = FailureLog(log)
        self._last_meas_seq = -1
        #: the plant run followed (Measurement.incarnation); another one is taken only
        #: after the plant's liveliness token appeared again
        self._plant_incarnation: str | None = None
        self._plant_restarted = False
        self._followed_at = -math.inf  # arrival of its latest accepted sample, perf s
        self.foreign_measurements = 0
        self._foreign_moves = 0  # samples whose applied move this node did not send
        self.y_lower, self.y_upper = plausible_ranges(cfg, plant, grades)
        self._plausible_bounds: tuple | None = None  # the ranges as lists (_plausible)
        self.plant_shutdown = False
        self.alarms: deque[str] = deque(maxlen=20)
        self.restored_from: int | None = None
        self._lock = threading.RLock()
        self._create_lock = threading.RLock()  # one create at a time (idempotency keys)
        self._cond = threading.Condition()
        self._latest: tuple[float, Measurement] | None = None
        self._busy = threading.Lock()  # held by whichever thread processes a sample
        self._closing = False
        self._dropped = 0
        #: why the store last failed to commit (None: it commits); writes answer 503
        self.store_error: str | None = None
        self._worker = _Worker(on_error=self._background_failed)  # the store's writes
        #: telemetry's flushes (Rerun) apart from the store's writes
        self._telemetry_worker = _Worker(on_error=self._telemetry_failed) \
            if telemetry is not None else None
        self._checkpoint_due = False
        self._busy_until = 0.0
        self._last_flush = time.perf_counter()
        self._last_status_wall = -math.inf
        self._status_due = False
        self._status_cost_s = 0.0  # wall time of the latest status, decayed (s)
        self._checkpoint_cost_s = 0.0
        self._last_checkpoint_wall = time.perf_counter()
        # Bumpless (re)start: the first measurement from a plant that already runs on a
        # controller's moves (mv_seq >= 0) tells which move it holds; the first move is
        # computed from there (see _align). Set before the subscriber is declared: on a
        # running plant a measurement can be processed before __init__ returns.
        self._align_pending = True
        # the moves sent lately (their largest steps go into the checkpoint) and, after a
        # resume on a running plant, the ramp-in that limits the moves to those steps
        self._moves = MoveHistory(self.nu, STEP_WINDOW)
        self._restored_steps: np.ndarray | None = None
        self._last_steps_wall = -math.inf
        self._ramp_in: RampIn | None = None
        self._mv_span = np.array([v.hi - v.lo for v in self.variables if v.kind == "mv"],
                                 float)
        #: service factor, constraint activity, cost, prediction errors (in the checkpoint)
        self.kpis = UnitKPIs(cfg, self.info.cv_names, self.info.mv_names, self.variables)
        self._restore()
        #: alarms raised and not cleared, as the event log has them (no second raise)
        self.alarm_events = AlarmTracker(self.store.active_alarms())
        self._watchdog = Watchdog(period_hint_s=self.budget.wall_period_s)
        self._mv_pub = plant_link if plant_link is not None else declare_loop_publisher(
            session, keys.mv(cfg.unit))
        self.plant_link = plant_link
        operator_commands.publish_mode(self)  # a restored mode to the DCS too
        self._status_pub = session.declare_publisher(keys.status(cfg.unit))
        self.busy_poll = bool(busy_poll)
        self._sub = plant_link.subscribe(self._on_meas) if plant_link is not None \
            else declare_loop_subscriber(  # busy polling: run() polls the channel
                session, keys.meas(cfg.unit), self._on_meas,
                poll_queue=self.POLL_QUEUE if self.busy_poll else None)
        self._qry = session.declare_queryable(keys.cmd_all(cfg.unit), self._on_query)
        self._token = session.liveliness().declare_token(keys.alive(cfg.unit, "controller"))
        self._plant_live = session.liveliness().declare_subscriber(
            keys.alive(cfg.unit, "plant"), self._on_plant_liveliness, history=True)

    # -- KPIs ---------------------------------------------------------------------------
    def _count_kpis(self, t: float, mode: str, fallback: bool, decision) -> None:
        """One sample into the KPIs (call with the lock held, after the move is out)."""
        try:
            self.kpis.count(t, mode, fallback, self.y, self.u_last, self.operated.state,
                            decision.extra.get("prediction_rms"), decision.model_names)
        except Exception as exc:  # counting must never stall the loop
            self._failures.note("KPIs not counted", exc)

    def kpi_report(self) -> dict:
        """The KPIs (:meth:`controller.units.kpis.UnitKPIs.report`) with the unit and the
        latest sample."""
        with self._lock:
            return {"unit": self.cfg.unit, "sample": self.k, **self.kpis.report()}

    # -- persistence -------------------------------------------------------------------
    def _restore(self) -> None:
        """Start from the checkpoint, reconciled with the transition records.

        A checkpoint that does not decode or does not fit this controller is refused:
        :class:`~services.store.StoreError` (the CLI: ``error:``, exit 2; the operator
        moves the store aside), never a start from half of it. The records win over
        the checkpoint: a transition the store has as ended stays ended, and one the
        store has as pending but the checkpoint does not know (a crash between the
        two writes) is queued again, so nothing acknowledged is lost or revived.
        """
        cp = self.store.load_checkpoint()  # StoreError when it does not decode
        if cp is not None:
            st = cp["state"]
            try:
                self.tm.restore(st["transitions"])
                self.controller.restore(st["controller"])
                u_last = np.asarray(st["u_last"], float)
                if u_last.shape != (self.nu,) or not np.all(np.isfinite(u_last)):
                    raise ValueError(f"u_last: expected {self.nu} finite numbers")
                self.u_last = u_last
                self.mv_seq = int(st["mv_seq"])
                self.stats.misses = int(st.get("deadline_misses", 0))
                self.stats.fallbacks = int(st.get("fallback_moves", 0))
                steps = st.get("recent_steps")
                if steps is not None:
                    steps = np.asarray(steps, float)
                    if steps.shape != (self.nu,) or not np.all(np.isfinite(steps)) \
                            or np.any(steps < 0):
                        raise ValueError(f"recent_steps: expected {self.nu} finite values "
                                         ">= 0")
                    self._restored_steps = steps
                self.k = int(cp["sample"])
                self.t = float(cp["process_time"])
                if st.get("operator") is not None:
                    self.operated.operator_restore(st["operator"])
                if st.get("kpis") is not None:  # older checkpoints: counted from now on
                    self.kpis.restore(st["kpis"])
            except CHECKPOINT_MISFIT as exc:
                raise StoreError(f"store: {self.store.path}: the checkpoint does not fit "
                                 f"this controller ({type(exc).__name__}: {exc}); move the "
                                 "store aside to start afresh") from None
            self.restored_from = self.k
            log.info("restored checkpoint at sample %d", self.k)
        stored = self.store.load_recent_steps()  # newer than the checkpoint's, if any
        if stored is not None and len(stored) == self.nu:
            self._restored_steps = np.asarray(stored, float)
        self._reconcile()

    def _reconcile(self) -> None:
        """Make the transitions in memory agree with the committed records.

        A record this unit cannot run (:meth:`TransitionManager.checked_record
        <services.transitions.TransitionManager.checked_record>`: a target of the wrong
        length, an unknown grade, ...) refuses the start with a
        :class:`~services.store.StoreError`, as a checkpoint that does not fit does. Only
        the reading of a record is judged so; an error elsewhere is not a misfit.
        """
        tm = self.tm
        known = {tr.id for tr in ([tm.active] if tm.active is not None else []) + tm.queued}
        for tr in ([tm.active] if tm.active is not None else []) + list(tm.queued):
            rec = self.store.transition(tr.id)
            if rec is None or self._stored(rec, "state") not in TERMINAL or tr.terminal:
                continue
            ended = self._stored_transition(rec)
            if tr is tm.active:
                # hold the set points of the moment it ended (settled: its target)
                t_end = ended.ended_t if ended.ended_t is not None else self.t
                tm.hold = (np.asarray(ended.target, float) if ended.state == "settled"
                           else tm.reference_at(t_end)[0].copy())
                tm.grade = ended.grade if ended.state == "settled" else None
                tm.active = ended
            else:
                tm.queued.remove(tr)
            self.alarms.append(f"transition {tr.id}: the store has it {ended.state}; "
                               "the older checkpoint's state was dropped")
        for rec in self.store.transitions():
            tid, state = self._stored(rec, "id"), self._stored(rec, "state")
            if tid in known or state in TERMINAL:
                continue
            tr = self._stored_transition(rec)
            if state == "pending":
                tr.detail = "queued"
                tm.queued.append(tr)  # acknowledged, never started: it runs
                self.alarms.append(f"transition {tr.id}: pending in the store, not in the "
                                   "checkpoint; queued again")
            else:  # running, but the checkpoint never knew it: its start is lost
                tr.state, tr.ended_t = "failed", self.t
                tr.detail = "interrupted by a restart before its start was checkpointed"
                self.store.save_transition(tr.as_dict(), event="failed", process_time=self.t,
                                           detail=tr.detail, events=(transition_event(
                                               tr.as_dict(), "failed", self.t),))
                self.alarms.append(f"transition {tr.id}: {tr.detail}")

    def _misfit(self, exc: BaseException) -> StoreError:
        return StoreError(f"store: {self.store.path}: a transition record does not fit "
                          f"this controller ({type(exc).__name__}: {exc}); move the store "
                          "aside to start afresh")

    def _stored(self, rec, name: str):
        """Field ``name`` of a committed record (a damaged record: StoreError)."""
        try:
            value = rec[name]
            hash(value)  # what set membership will ask of it
        except CHECKPOINT_MISFIT as exc:
            raise self._misfit(exc) from None
        return value

    def _stored_transition(self, rec) -> Transition:
        """A committed record as a transition of this unit (one it cannot run: StoreError)."""
        try:
            return self.tm.checked_record(rec)
        except CHECKPOINT_MISFIT as exc:
            raise self._misfit(exc) from None

    # -- the store's health --------------------------------------------------------------
    def _store_failed(self, what: str, exc: BaseException) -> None:
        """The store did not commit ``what``: degraded, with an alarm (writes answer 503)."""
        reason = f"{what} not stored ({type(exc).__name__}: {exc})"
        with self._lock:
            first = self.store_error is None
            self.store_error = reason
            self.alarms.append(f"store degraded: {reason}")
        if first:
            log.error("store degraded: %s", reason)

    def _store_ok(self) -> None:
        if self.store_error is not None:
            with self._lock:
                self.store_error = None
                self.alarms.append("store commits again")

    def _background_failed(self, exc: BaseException) -> None:
        self._store_failed("a background write", exc)

    def _telemetry_failed(self, exc: BaseException) -> None:
        """A telemetry flush raised: an alarm; the store and the loop are not concerned."""
        with self._lock:
            self.alarms.append(f"telemetry not written: {type(exc).__name__}: {exc}")

    def checkpoint(self, wait: bool = True) -> None:
        """Snapshot the node's state now and write it (in order with transition records);
        ``wait`` blocks until it is on disk."""
        with self._lock:
            state = {"controller": self.controller.checkpoint(),
                     "transitions": self.tm.checkpoint(), "u_last": self.u_last.tolist(),
                     "mv_seq": self.mv_seq, "deadline_misses": self.stats.misses,
                     "fallback_moves": self.stats.fallbacks,
                     "operator": self.operated.operator_checkpoint(),
                     "kpis": self.kpis.checkpoint(),
                     "recording_id": getattr(self.telemetry, "recording_id", None)}
            steps = self._moves.steps()
            if steps is None:
                steps = self._restored_steps
            if steps is not None:
                state["recent_steps"] = steps.tolist()
            k, t = max(self.k, 0), self.t
        # encoded here (the loop thread calls this only when the slack allows): in the
        # worker, json.dumps would hold the interpreter lock against the next step
        try:
            payload = self.store.encode_checkpoint(state)
        except (TypeError, ValueError) as exc:  # NaN/inf or a foreign object: keep the old one
            log.error("checkpoint not written (kept the previous one): %s", exc)
            with self._lock:
                self.alarms.append(f"checkpoint not written at sample {k}: {exc}")
            return
        if not wait:
            # a newer snapshot replaces one still queued: a store that cannot commit
            # holds one checkpoint write, not one per period
            self._worker.submit_latest("checkpoint", self.store.save_checkpoint, k, t,
                                       payload)
            return
        try:
            self._worker.call(self.store.save_checkpoint, k, t, payload)
        except (sqlite3.Error, TimeoutError) as exc:
            self._store_failed(f"checkpoint at sample {k}", exc)

    #: A new plant incarnation is followed only when the one followed has been silent
    #: this many wall periods (and the plant's liveliness token appeared again): a live
    #: plant publishes every period, so a sample of another incarnation meanwhile is
    #: forged or replayed.
    PLANT_SILENT_PERIODS = 1.5
    #: Shortest wall time between two published status messages, s.
    STATUS_MIN_WALL_S = 0.2
    #: A checkpoint is also due after this wall time (slow speeds: samples are far apart), s.
    CHECKPOINT_WALL_S = 5.0
    #: Shortest wall time between two writes of the recent MV steps (the ramp-in's), s.
    STEPS_WALL_S = 0.05
    #: Longest wall time between checkpoints however little slack the loop has, s.
    CHECKPOINT_MAX_WALL_S = 10.0

    def _maybe_checkpoint(self, arrived: float, forced: bool) -> None:
        """Checkpoint when the snapshot fits before the next measurement is due.

        Snapshotting a large controller (TE: 1-2 ms of CPU with its JSON at load 4-8) on
        the loop thread must not push the next sample past its deadline at high speed, so
        a due checkpoint waits for a sample with enough slack; it is forced by a
        transition state change or after :attr:`CHECKPOINT_MAX_WALL_S`.
        """
        now = time.perf_counter()
        slack = arrived + self.budget.wall_period_s - now
        overdue = now - self._last_checkpoint_wall > self.CHECKPOINT_MAX_WALL_S
        if not (forced or overdue or self._checkpoint_cost_s < slack):
            return
        self.checkpoint(wait=False)
        cost = time.perf_counter() - now
        self._checkpoint_cost_s = max(cost, 0.5 * self._checkpoint_cost_s)
        self._last_checkpoint_wall = time.perf_counter()
        self._checkpoint_due = False

    #: Longest wall time between status messages however little slack the loop has, s.
    STATUS_MAX_WALL_S = 1.0

    def _maybe_publish_status(self, arrived: float) -> None:
        """Publish a due status when it fits before the next measurement is due.

        On this thread, after the move (Python that, run by the worker, would contend
        with the next step for the interpreter lock). The TE status costs 1.4-2.2 ms
        (building and encoding it); at 10,000x that is more than a sample's slack after
        the step and the bookkeeping, and publishing it anyway ran into the next
        measurement, which then waited for this thread. A due status therefore waits for
        a sample with the slack for it (its cost as last measured, decaying by half a
        status), or :attr:`STATUS_MAX_WALL_S` at the latest.
        """
        now = time.perf_counter()
        slack = arrived + self.budget.wall_period_s - now
        overdue = now - self._last_status_wall > self.STATUS_MAX_WALL_S
        if not (overdue or self._status_cost_s < slack):
            return
        self._status_due = False
        self._last_status_wall = now
        try:
            self._publish_status()
        except Exception:
            log.exception("status not published")
        cost = time.perf_counter() - now
        self._status_cost_s = max(cost, 0.5 * self._status_cost_s)

    def flush(self) -> None:
        """Wait until every record and checkpoint submitted so far is written."""
        self._worker.wait()

    def _notify(self, tr, event: str) -> None:
        """Tell a controller that follows its own plans (TE) about a transition event
        (and the recording's event log)."""
        if self.telemetry is not None:
            self.telemetry.event(self.k, self.t, f"transition {tr.id} "
                                 f"{tr.from_grade or '-'} -> {tr.grade}: {event}")
        hook = getattr(self.controller, "on_transition", None)
        if hook is not None:
            hook(event, tr.grade, self.t, duration_s=tr.duration_s)

    def _persist(self, tr, event: str, detail: str = "") -> None:
        self._worker.submit(self._save_transition, tr.as_dict(), event, self.t,
                            detail or tr.detail)

    def _save_transition(self, record, event, t, detail, actions=()) -> None:
        """The record, its state change and the event log's entries (``actions``: the
        operator's, then the state change's) in one transaction."""
        self.store.save_transition(record, event=event, process_time=t, detail=detail,
                                   events=(*actions, transition_event(record, event, t)))

    def record_action(self, what: str, detail: dict, identity: str, *,
                      event_id: str | None = None) -> Reply | None:
        """Commit an operator action (``action.<what>``, e.g. ``"mode"`` with
        ``{"mode": "on"}``, by ``identity``) to the event log; call it after the request
        is checked and before the action is acknowledged. None once committed; else the
        503 reply to send (the store degraded, with an alarm)."""
        event = action_event(what, detail, identity, self.t, event_id=event_id)
        try:
            self._commit(self.store.add_events, [event])
        except (sqlite3.Error, TimeoutError) as exc:
            self._store_failed(f"operator action {event.kind}", exc)
            return Reply(503, error=f"store: cannot commit the action ({exc}); retry later")
        self._store_ok()
        self._log_action(event)
        return None

    def _log_action(self, event) -> None:
        """A committed operator action into the recording's event log (``<unit>/events``)."""
        if self.telemetry is not None:
            self.telemetry.event(max(self.k, 0), self.t,
                                 f"{describe(event.view())} [{event.identity}]")

    # -- Zenoh callbacks -----------------------------------------------------------------
    def _on_plant_liveliness(self, sample) -> None:
        import zenoh

        if sample.kind == zenoh.SampleKind.PUT:
            with self._cond:  # a plant (re)started: its new incarnation may be followed
                self._plant_restarted = True
                self.plant_alive = True
        elif sample.kind == zenoh.SampleKind.DELETE:
            # the plant's liveliness token is gone (its lease ran out): the plant holds
            # its last move and regulatory layer; say so until it is back
            with self._lock:
                self.plant_alive = False
                self.alarms.append(f"plant node lost at sample {self.k} (liveliness): "
                                   "no measurements, the plant holds its last move")

    def _on_meas(self, sample) -> None:
        if self._accept(sample, time.perf_counter()):
            self._drain()

    def _accept(self, sample, arrived: float) -> bool:
        """Decode and check one measurement and make it the one waiting to be processed;
        False when it is rejected (bad, stale or repeated: counted)."""
        try:
            msg = Measurement.from_bytes(sample.payload.to_bytes(), unit=self.cfg.unit,
                                         ny=self.ny, nu=self.nu)
        except MessageError as exc:
            with self._lock:
                self.bad_measurements += 1
                self.alarms.append(f"bad measurement rejected: {exc}")
            log.warning("measurement rejected: %s", exc)
            return False
        with self._cond:
            if msg.incarnation != self._plant_incarnation:
                silent = arrived - self._followed_at > self.PLANT_SILENT_PERIODS * \
                    self.budget.wall_period_s
                if self._plant_incarnation is not None and not (
                        self._plant_restarted and silent):
                    # not a plant liveliness said was (re)started while the one followed
                    # went silent: forged or replayed
                    self.foreign_measurements += 1
                    if self.foreign_measurements in (1, 10, 100, 1000) or \
                            self.foreign_measurements % 10_000 == 0:
                        with self._lock:
                            self.alarms.append(
                                f"measurement of an unknown plant incarnation refused "
                                f"({self.foreign_measurements} so far)")
                    return False
                if self._plant_incarnation is not None:
                    with self._lock:
                        self.alarms.append(f"plant restarted: following its incarnation "
                                           f"{msg.incarnation[:8]} from sample {msg.seq}")
                # a (re)started plant counts its samples from 0 again
                self._plant_incarnation = msg.incarnation
                self._plant_restarted = False
                self._last_meas_seq = -1
            if msg.seq <= self._last_meas_seq:
                # duplicated, reordered or delayed: acting on it again would double-count
                self.stale_measurements += 1
                return False
            self._last_meas_seq = msg.seq
            self._followed_at = arrived
            if self._latest is not None:
                self._dropped += 1
            self._latest = (arrived, msg)
        return True

    def _drain(self) -> None:
        """Process the waiting measurement on this thread unless another thread is
        processing one (that thread takes it next)."""
        while not self._closing:
            if not self._busy.acquire(blocking=False):
                return
            try:
                with self._cond:
                    item, self._latest = self._latest, None
                if item is None:
                    return
                self._process_logged(item)
            finally:
                self._busy.release()
            # loop: a measurement may have arrived after the check and before the release

    def _process_logged(self, item) -> None:
        try:
            self.process(*item)
            self._busy_until = time.perf_counter()
        except Exception as exc:  # the loop must go on; the plant holds meanwhile
            self._failures.note("sample bookkeeping failed", exc)
            with self._lock:
                self.alarms.append(f"sample {item[1].seq} failed: {exc}")

    def _off_decision(self, u_plant) -> ControlDecision:
        """The decision of a sample in mode ``off``: the plant's move, nothing computed."""
        d = self.last_decision
        names = () if d is None else d.model_names
        return ControlDecision(u=np.asarray(u_plant, float), active_model=-1,
                               model_names=names, J=np.full(len(names), np.nan),
                               status="off")

    def _failed_decision(self, seq: int, hold: np.ndarray, exc: Exception) -> ControlDecision:
        """The decision of a sample whose controller step raised: the last move held,
        counted as failed (``failed_samples``), status ``failed`` and an alarm; the
        traceback is logged the first time this kind of failure happens."""
        repeats = self._failures.note("controller step failed", exc)
        with self._lock:
            self.failed_samples += 1
        alarm = f"sample {seq} failed ({type(exc).__name__}: {exc}): move held"
        if repeats:
            alarm += f" ({repeats + 1} times so far)"
        names = () if self.last_decision is None else self.last_decision.model_names
        return ControlDecision(u=hold.copy(), active_model=-1, model_names=names,
                               J=np.zeros(len(names)), solve_ms=0.0, fallback=True,
                               status="failed", alarms=(alarm,))

    def _on_query(self, query) -> None:
        try:
            action = str(query.key_expr).split("/cmd/", 1)[1].split("/")[0]
            req = (Request.from_bytes(query.payload.to_bytes()) if query.payload is not None
                   else Request(action=action))
            reply = self._handle(req)
        except MessageError as exc:
            reply = Reply(400, error=str(exc))
        except UnknownTransition as exc:
            reply = Reply(404, error=str(exc))
        except ConflictError as exc:
            reply = Reply(409, error=str(exc))
        except QueueFullError as exc:
            reply = Reply(429, error=str(exc))
        except (TransitionError, ValueError) as exc:
            reply = Reply(422, error=str(exc))
        except Exception as exc:  # never let a query kill the node
            log.exception("query failed")
            reply = Reply(500, error=f"internal error: {exc}")
        query.reply(query.key_expr, reply.to_bytes())

    def _handle(self, req: Request) -> Reply:
        if req.action == "status":
            return Reply(200, self.status())
        if req.action == "grades":
            return Reply(200, self.grades())
        if req.action == "kpis":
            return Reply(200, self.kpi_report())
        if req.action == "transition":
            return self._transition(req.args)
        if req.action in ("mode", "variable"):  # operator actions
            return operator_commands.handle(self, req.action, req.args)
        if req.action == "events":
            self._worker.wait()  # what was submitted before this query is in the store
            return events_reply(self.store, req.args)
        if req.action == "sample_times":  # diagnostics: where a late move's time went
            try:
                found = self.sample_times.lookup(req.args.get("seqs"))
            except ValueError as exc:
                return Reply(422, error=str(exc))
            return Reply(200, {"clock": "perf_counter", "samples": {
                str(k): v for k, v in found.items()}})
        if req.action == "reset_stats":  # benchmarks: count from a warm loop on
            with self._lock:
                self.stats = DeadlineStats(self.budget.budget_s)
            GC_PAUSES.reset()
            return Reply(200, self.status())
        return Reply(404, error=f"action: unknown action {req.action!r}")

    def _transition(self, args: dict) -> Reply:
        # Records are written by the worker; waiting for it while holding the node's
        # lock would deadlock (the worker's status snapshot takes that lock), so every
        # wait happens after the lock is released.
        op = args.get("op")
        if op not in ("create", "list", "get", "abort"):
            return Reply(422, error=f"op: expected create, get, abort or list, got {op!r}")
        if op == "list":
            self._worker.wait()
            return Reply(200, self.store.transitions())
        if op == "create":
            grade = args.get("grade")
            if not isinstance(grade, str):
                return Reply(422, error="grade: expected a grade name")
            duration = args.get("duration_s")
            if duration is not None and (isinstance(duration, bool)
                                         or not isinstance(duration, int | float)):
                return Reply(422, error="duration_s: expected a number")
            queue = args.get("queue", False)
            if not isinstance(queue, bool):
                return Reply(422, error="queue: expected a boolean")
            key = args.get("idempotency_key")
            if key is not None and not (isinstance(key, str) and 0 < len(key) <= 255):
                return Reply(422, error="idempotency_key: expected a string of 1..255")
            who = identity_of(args)
            if key is None:
                return self._create(grade, duration, queue, None, who)
            with self._create_lock:  # two requests with one key make one transition
                return self._create(grade, duration, queue, key, who)
        tid = args.get("id")
        if not isinstance(tid, str):
            return Reply(422, error="id: expected a transition id")
        if op == "abort":
            reply = self._abort(tid, args)
            if reply is not None:
                return reply
        return Reply(200, self._view(tid))

    #: Longest wait for the store to commit an abort, s (no sample runs meanwhile).
    ABORT_COMMIT_TIMEOUT_S = 5.0
    #: Time budget of a write a request is answered on (transition, operator action), s,
    #: from the request to the end of the write: under the API's 2 s, so that a store
    #: that cannot commit answers 503, not the API's 504.
    ACK_COMMIT_BUDGET_S = 1.5

    def _commit(self, fn, *args):
        """``fn(*args)`` on the store's worker, after what is queued, within
        :data:`ACK_COMMIT_BUDGET_S`: withdrawn if it has not started by then, and a lock
        held by another connection waited for only for what is left of the budget.
        TimeoutError or the store's error when it did not commit."""
        deadline = time.monotonic() + self.ACK_COMMIT_BUDGET_S

        def within():
            left = deadline - time.monotonic()
            if left <= 0.0:
                raise TimeoutError("store: no time left in the request's budget (not "
                                   "committed)")
            with self.store.waiting_at_most(left):
                return fn(*args)

        return self._worker.call(within, timeout=self.ACK_COMMIT_BUDGET_S)

    def _abort(self, tid: str, args: dict) -> Reply | None:
        """Abort transition ``tid``: committed to the store before anything changes.

        The abort is worked out on a copy of the transitions first and its record
        committed; only then does the node hold the set points (and tell the
        controller). A store that cannot commit leaves everything as it was: 503, the
        transition keeps running, and no checkpoint can later carry an abort the
        store never recorded. The operator's action (``args``' identity) is committed
        with it. No sample runs during the commit (the sample lock is
        held), so the transition cannot end otherwise meanwhile. None when ``tid`` is
        not in memory (the caller answers from the store).
        """
        with self._busy:
            with self._lock:
                found = self.tm.find(tid)
                if found is None:
                    return None
                if found.terminal:
                    return Reply(200, found.view(self.t, self.budget.speed))
                t = self.t
                trial = copy.deepcopy(self.tm).abort(tid, t)  # UnknownTransition: 404
                if trial.state != "aborted":
                    return Reply(200, found.view(self.t, self.budget.speed))
                record = trial.as_dict()
            action = action_event("transition.abort", {
                "transition": tid, "grade": record["grade"]}, identity_of(args), t,
                event_id=f"action-{tid}-abort")
            try:  # committed, with the operator action, before it is applied and acknowledged
                self._worker.call(self._save_transition, record, "aborted", t, trial.detail,
                                  (action,), timeout=self.ABORT_COMMIT_TIMEOUT_S)
            except (sqlite3.Error, TimeoutError) as exc:
                self._store_failed(f"abort of {tid}", exc)
                return Reply(503, error="store: cannot commit; the abort is not applied and "
                                        f"the transition goes on ({exc}); retry later")
            with self._lock:
                active = self.tm.find(tid) is self.tm.active
                tr = self.tm.abort(tid, t)
                if active:
                    self._notify(tr, "aborted")
                view = tr.view(self.t, self.budget.speed)
        self._store_ok()
        self._log_action(action)
        self.checkpoint(wait=True)
        self._drain()  # a measurement that came during the commit
        return Reply(200, view)

    def _create(self, grade: str, duration, queue: bool, key: str | None,
                identity: str) -> Reply:
        """A new transition (202), or, for a known idempotency ``key``, the one that key
        made (202 again; 422 when the request differs); ``identity`` made the request."""
        request = {"key": key, "grade": grade,
                   "duration_s": None if duration is None else float(duration), "queue": queue}
        if key is not None:
            with self._lock:
                found = self.tm.find_by_key(key)
                record = None if found is None else found.as_dict()
            if record is None:
                self._worker.wait()
                record = self.store.transition_by_key(key)
            if record is not None:
                if record.get("idempotency") != request:
                    return Reply(422, error="Idempotency-Key: already used by another request "
                                            f"(transition {record['id']})")
                return Reply(202, Transition.from_dict(record).view(self.t, self.budget.speed))
        if self.operated.mode != "on":  # nobody would move the plant along it
            return Reply(409, error=f"controller: {self.operated.mode}, it writes no moves; "
                                    "put it on (mode on) before a transition")
        # A controller that knows grades it cannot hold refuses them now, not
        # inside a later sample (the transition would run toward nothing).
        check = getattr(self.controller, "check_grade", None)
        if check is not None and grade in self.info.grades:
            try:
                with self._lock:
                    check(grade)
            except ValueError as exc:
                return Reply(422, error=str(exc))
        with self._create_lock:  # creates one at a time: nothing else admits meanwhile
            with self._lock:
                tr = self.tm.prepare(grade, self.t, duration, queue=queue,
                                     idempotency=None if key is None else request)
                record, t = tr.as_dict(), self.t
            detail = "queued" if tr.detail == "queued" else f"requested from {tr.from_grade}"
            action = action_event(
                "transition.queue" if tr.detail == "queued" else "transition.create",
                {"transition": tr.id, "grade": grade, "duration_h": tr.duration_s / 3600.0,
                 "queue": queue}, identity, t, event_id=f"action-{tr.id}-create")
            try:  # committed before it is admitted and acknowledged
                self._commit(self._save_transition, record, "pending", t, detail, (action,))
            except (sqlite3.Error, TimeoutError) as exc:
                self._store_failed(f"transition {tr.id}", exc)  # never admitted: not run
                return Reply(503, error=f"store: cannot commit, transition not accepted "
                                        f"({exc}); retry later")
            with self._lock:
                self.tm.admit(tr)
                view = tr.view(self.t, self.budget.speed)
        self._store_ok()
        self._log_action(action)
        self.checkpoint(wait=True)
        return Reply(202, view)

    def _view(self, tid: str) -> dict:
        with self._lock:
            found = self.tm.find(tid)
            if found is not None:
                return found.view(self.t, self.budget.speed)
        self._worker.wait()
        rec = self.store.transition(tid)
        if rec is None:
            raise UnknownTransition(f"id: no transition {tid!r}")
        return Transition.from_dict(rec).view(self.t, self.budget.speed)

    #: What a grade carries to the api besides its set points (TE: G/H ratio, rates).
    GRADE_FIELDS = ("description", "stability", "g_h_mass_ratio", "product_kg_h")

    def grades(self) -> dict:
        return {"unit": self.cfg.unit, "cvs": list(self.info.cv_names),
                "cv_units": list(self.info.cv_units), "current": self.tm.grade,
                "grades": {k: {"setpoints": dict(zip(self.info.cv_names, g["setpoints"])),
                               **{f: g[f] for f in self.GRADE_FIELDS if f in g}}
                           for k, g in self.info.grades.items()}}

    def status(self) -> dict:
        with self._lock:
            d = self.last_decision

            def named(names, values):
                return {n: (float(v) if math.isfinite(v) else None)
                        for n, v in zip(names, values)}

            active = self.tm.active
            return {
                "unit": self.cfg.unit, "plant": self.cfg.plant, "sample": self.k,
                "process_time_s": self.t, "speed": self.budget.speed,
                "cv": named(self.info.cv_names, self.y),
                "ref": named(self.track_names, self.r),
                "controller_mode": self.operated.mode,
                "variables": self._variables_view(),
                "mv": named(self.info.mv_names, self.u_last),
                # warm: the move the controller would write (None otherwise)
                "computed_mv": (named(self.info.mv_names, d.extra["computed_u"])
                                if d is not None and self.operated.mode == "warm"
                                and "computed_u" in d.extra else None),
                "active_model": None if d is None else int(d.active_model),
                "active_model_name": (None if d is None or not d.model_names
                                      or d.active_model < 0
                                      else d.model_names[d.active_model]),
                "active_model_detail": None if d is None else d.extra.get(
                    "active_model_detail"),
                "J": {} if d is None else named(d.model_names, np.asarray(d.J)),
                # J as the weighted RMS prediction error it stands for (units of the
                # CVs' scales; PerformanceIndex.rms_error)
                "prediction_rms": ({} if d is None or d.extra.get("prediction_rms") is None
                                   else named(d.model_names,
                                              np.asarray(d.extra["prediction_rms"]))),
                # the steady-state targets of the sample (units with a target layer)
                "targets": None if d is None else _json_targets(d.extra.get("targets")),
                # TE: the composition core's view (MPC strategies; None elsewhere)
                "composition": None if d is None else d.extra.get("composition"),
                "tuning": self.tuning,
                "solve_ms": None if d is None else float(d.solve_ms),
                "controller_status": None if d is None else d.status,
                "deadline_misses": self.stats.misses,
                "fallback_moves": self.stats.fallbacks,
                "budget_ms": self.stats.budget_s * 1e3,
                "sample_ms": self.stats.percentiles_ms(),
                "slowest_sample": self.stats.worst,
                "missed_samples": list(self.stats.missed),
                "gc_pauses": GC_PAUSES.as_dict(),
                "samples": self.stats.samples,
                "bad_measurements": self.bad_measurements,
                "stale_measurements": self.stale_measurements,
                "implausible_measurements": self.implausible_measurements,
                "foreign_measurements": self.foreign_measurements,
                "foreign_moves": self._foreign_moves,
                "store": "ok" if self.store_error is None else "degraded",
                "store_error": self.store_error,
                "plant_incarnation": self._plant_incarnation,
                "failed_samples": self.failed_samples,
                "dropped_measurements": self._dropped,
                "plant_shutdown": self.plant_shutdown,
                "plant_alive": self.plant_alive,
                "grade": self.tm.grade,
                "transition": None if active is None else active.view(self.t, self.budget.speed),
                "alarms": list(self.alarms),
                "restored_from_sample": self.restored_from,
                # samples sent to Rerun so far (None: no telemetry)
                "telemetry_samples": (self.telemetry.samples_logged
                                      if self.telemetry is not None
                                      and self.telemetry.enabled else None),
            }

    def _variables_view(self) -> list[dict]:
        """The ``variables`` of the status (the REST status contract): each CV, MV and DV
        with its value, target (a tracked CV's reference), limits and the limit it sits
        at. Call with the lock held."""
        values = {"cv": dict(zip(self.info.cv_names, self.y)),
                  "mv": dict(zip(self.info.mv_names, self.u_last))}
        targets = dict(zip(self.track_names, self.r))
        op, t_h = self.operated.state, self.t / 3600.0
        out = []
        for v in self.variables:
            x = values.get(v.kind, {}).get(v.name)
            x = float(x) if x is not None and math.isfinite(x) else None
            tgt = targets.get(v.name) if v.kind == "cv" else None
            mode = op.variable_mode(v.name)
            if v.kind == "mv" and mode in ("manual", "off"):
                tgt = op.control(v.name).value  # the held value
            lo, hi = op.effective_limits(v.name, t_h)  # the operator's, ramped
            out.append({**v.as_dict(), "value": x,
                        "target": float(tgt) if tgt is not None and math.isfinite(tgt) else None,
                        "lo": float(lo) if math.isfinite(lo) else None,
                        "hi": float(hi) if math.isfinite(hi) else None,
                        "at_limit": at_limit(x, lo, hi), "mode": mode})
        return out

    # -- the sample ----------------------------------------------------------------------
    def _publish_mv(self, meas_seq: int, u, fallback: bool) -> None:
        # Sequence numbers grow across restarts too (µs of the wall clock, or +1): a node
        # restored from an older checkpoint must not look stale to the plant.
        self.mv_seq = max(self.mv_seq + 1, time.time_ns() // 1000)
        # the move as Python floats: the message's check of them is then one C-level
        # pass, not a conversion of each numpy scalar (the same numbers, the same bytes)
        msg = MVMessage(unit=self.cfg.unit, seq=self.mv_seq, meas_seq=meas_seq,
                        u=tuple(np.asarray(u, float).tolist()), sender=self.sender,
                        fallback=fallback, tuning=self.tuning)
        self._mv_pub.put(msg.to_bytes())

    def _align(self, msg: Measurement) -> None:
        """First sample after a (re)start on a running plant: start from the plant's move.

        The move the plant holds (``Measurement.u``) becomes the node's last move (the
        watchdog's hold) and is handed to the controller (``align(u)`` if it has one,
        else :func:`align_multimodel`), so the move computed for this very sample starts
        from it and from the current measurement: no bump, however old the checkpoint.
        """
        self._align_pending = False
        if msg.mv_seq < 0:
            return  # a fresh plant: nothing to take over
        self.mv_seq = max(self.mv_seq, msg.mv_seq)
        u = np.asarray(msg.u, float)
        align = getattr(self.controller, "align", None)
        if callable(align):
            align(u)
        else:
            align_multimodel(self.controller, u)
        if self._restored_steps is not None and self._mv_span.shape == (self.nu,):
            self._ramp_in = RampIn(self._restored_steps, self._mv_span)
        with self._lock:
            self.u_last = u
            self.alarms.append(f"resumed at sample {msg.seq} from the plant's move")

    def process(self, arrived: float, msg: Measurement) -> None:
        """One sample: transition, reference, controller step, MV, bookkeeping."""
        t_begin = time.perf_counter()
        cpu_begin = time.thread_time()
        sw_begin = thread_switches()
        if self._align_pending:
            self._align(msg)
        elif msg.mv_seq > self.mv_seq:
            # the plant applied a move numbered beyond any this node sent: not ours
            self._foreign_moves += 1
            if self._foreign_moves in (1, 10, 100, 1000) or self._foreign_moves % 10_000 == 0:
                with self._lock:
                    self.alarms.append(f"sample {msg.seq}: the plant applies a move this "
                                       f"controller did not send ({self._foreign_moves} "
                                       "samples so far)")
        hold = self.u_last.copy()
        mode = self.operated.mode
        writes = mode == "on"  # off/warm: nothing is written this sample
        y = np.asarray(msg.y, float)
        if not self._plausible(msg.y):
            # Physically impossible value (a sensor fault): not acted on. Documented safe
            # action: the last move is held and an alarm raised; nothing else advances.
            outside = (y < self.y_lower) | (y > self.y_upper)
            names = [self.info.cv_names[i] for i in np.flatnonzero(outside)]
            with self._lock:
                self.implausible_measurements += 1
                self.alarms.append(f"implausible measurement at sample {msg.seq} "
                                   f"({', '.join(names)} out of range): move held")
                self.stats.record(time.perf_counter() - arrived, fallback=True)
            if writes:
                self._publish_mv(msg.seq, hold, True)
            with self._lock:  # no constraint activity or cost of an implausible sample
                self.kpis.count_held(msg.t, mode)
            return
        deadline = arrived + self.budget.budget_s
        if writes:
            self._watchdog.arm(deadline, lambda: self._publish_mv(msg.seq, hold, True))
        with self._lock:
            self.k, self.t = msg.seq, msg.t
            self.y = y
            ended = False  # a transition ended outside update(): checkpoint at once too
            if msg.shutdown and not self.plant_shutdown:
                self.plant_shutdown = True
                self.alarms.append(f"plant shut down at t={msg.t:.1f} s")
                tr = self.tm.fail(msg.t, "plant shut down")
                if tr is not None:
                    self._notify(tr, "failed")
                    self._persist(tr, "failed")
                    ended = True
            changes = self.tm.update(msg.t, self.y[self.track_idx])
            for tr, state in changes:
                self._notify(tr, state)
                # queued for the store before a query can see the new state (a flush
                # after a GET that says settled finds the event written)
                self._persist(tr, state)
            ref = self.tm.reference_at(msg.t, self.horizon)
            self.r = ref[0]
        t_step = time.perf_counter()
        try:
            decision = self.operated.step(msg.seq, msg.t, self.y, ref, msg.u)
            if decision is None:  # off: nothing computed, the plant holds its move
                decision = self._off_decision(msg.u)
        except Exception as exc:  # documented safe action: the move is held, loop goes on
            decision = self._failed_decision(msg.seq, hold, exc)
        t_stepped = time.perf_counter()
        fired = self._watchdog.disarm() if writes else False
        t_disarmed = time.perf_counter()
        u = np.asarray(decision.u, float)
        invalid = False
        if not writes:
            u = np.asarray(msg.u, float)  # what the plant holds
        elif not fired:
            if u.shape != (self.nu,) or not np.all(np.isfinite(u)):
                self.alarms.append(f"controller returned an invalid move at sample {msg.seq}; "
                                   "held")
                u, fb, invalid = hold, True, True
                self._continue_from(hold, msg.seq)
            else:
                fb = decision.fallback
                if self._ramp_in is not None:
                    u = self._ramp_limited(u, hold, msg.seq)
                # the plant side's tuning set the controller selects (TE), sent with
                # this move and every held one after it
                self.tuning = decision.extra.get("tuning") if decision.extra else None
            self._publish_mv(msg.seq, u, fb)
        else:
            u = hold  # the watchdog sent the held move: the law goes on from it
            self._continue_from(hold, msg.seq)
        # the budget covers the move going out, not only its computation
        elapsed = time.perf_counter() - arrived
        self.sample_times.note(msg.seq, arrived, arrived + elapsed)
        cpu_ms = (time.thread_time() - cpu_begin) * 1e3
        sw_end = thread_switches()
        with self._lock:
            self.stats.record(elapsed, fallback=fired or (writes and decision.fallback))
            if self.stats.keeps(elapsed):  # the record only for a sample that is kept
                self.stats.note_phases(elapsed, {
                    "sample": msg.seq, "at_unix_s": time.time() - elapsed,
                    "queue_ms": (t_begin - arrived) * 1e3,
                    # > 0: the loop thread was still on the previous sample when this arrived
                    "previous_busy_ms": (self._busy_until - arrived) * 1e3,
                    "prepare_ms": (t_step - t_begin) * 1e3,
                    "controller_ms": (t_stepped - t_step) * 1e3,
                    "watchdog_ms": (t_disarmed - t_stepped) * 1e3,
                    "publish_ms": (arrived + elapsed - t_disarmed) * 1e3,
                    # this thread's CPU time from the start of processing to the move, and
                    # the rest of that span: waiting for the interpreter lock or a CPU. The
                    # guest counts time the host takes its vCPU away as CPU time (no steal
                    # time here), so a cpu_ms well above the usual one is the host's doing.
                    "cpu_ms": cpu_ms,
                    # context switches of this thread meanwhile: "preempted" (involuntary: a
                    # CPU taken by another thread) and "blocked" (it waited: a lock, the
                    # interpreter lock); they tell the two kinds of waiting apart
                    "preempted": sw_end[1] - sw_begin[1], "blocked": sw_end[0] - sw_begin[0],
                    # the QP's part of controller_ms, when the controller reports it: a slow
                    # sample with a usual QP time and iteration count was slowed down, not
                    # given more work
                    **_qp_work(decision.extra),
                    "waited_ms": (arrived + elapsed - t_begin) * 1e3 - cpu_ms})
            self.u_last = np.asarray(u, float)
            self._moves.append(self.u_last)
            self.last_decision = decision
            self._count_kpis(msg.t, mode, fired or (writes and (decision.fallback or invalid)),
                             decision)
            for alarm in decision.alarms:
                self.alarms.append(alarm)
            if self.telemetry is not None and decision.alarms:
                # an alarm goes to the event log when it appears, not every sample it holds;
                # one alarm whatever its numbers (its key, as the event store counts it)
                new = [a for a in decision.alarms if alarm_key(a) not in self._alarms_logged]
                for alarm in new:
                    self.telemetry.event(msg.seq, msg.t, alarm, "WARN")
            self._alarms_logged = {alarm_key(a) for a in decision.alarms}
            alarm_events = self.alarm_events.update(decision.alarms, msg.seq, msg.t,
                                                    (self._plant_incarnation or "")[:8])
            if alarm_events:
                self._worker.submit(self.store.add_events, alarm_events)
            finish = getattr(self.controller, "finish_sample", None)
            if callable(finish):  # the sample's bookkeeping, now that the move is out
                try:
                    finish()
                except Exception as exc:  # the next step retries it; never stall the loop
                    self.alarms.append(f"bookkeeping after sample {msg.seq} failed: {exc}")
        if self.telemetry is not None:
            full = self.telemetry.add(msg.seq, msg.t, self.y, self.r, u,
                                      decision.active_model, decision.model_names, decision.J,
                                      decision.solve_ms, self.stats.slack_ms(elapsed),
                                      auto_flush=False)
            now = time.perf_counter()
            if full or now - self._last_flush > self.telemetry.max_wall_s:
                # in batches, but never more than a second behind (a live viewer)
                self._last_flush = now
                self._telemetry_worker.submit(self.telemetry.flush)
        if t_disarmed - self._last_steps_wall >= self.STEPS_WALL_S:
            # tiny: written every sample (at most every STEPS_WALL_S), the checkpoint waits
            steps = self._moves.steps()
            if steps is not None:
                self._last_steps_wall = t_disarmed
                self._worker.submit_latest("recent_steps", self.store.save_recent_steps,
                                           msg.seq, steps.tolist())
        if (changes or ended or msg.seq % self.cfg.checkpoint_every == 0
                or time.perf_counter() - self._last_checkpoint_wall > self.CHECKPOINT_WALL_S):
            self._checkpoint_due = True
        if self._checkpoint_due:  # a state change (ended, settled, ...) at once
            self._maybe_checkpoint(arrived, forced=bool(changes) or ended)
        now = time.perf_counter()
        if (msg.seq % self.cfg.status_every == 0
                and now - self._last_status_wall >= self.STATUS_MIN_WALL_S):
            self._status_due = True
        if self._status_due:
            self._maybe_publish_status(arrived)

    def _plausible(self, y) -> bool:
        """No value of the measurement ``y`` (finite floats, as decoded) outside its
        plausible range (:attr:`y_lower`, :attr:`y_upper`): the comparisons on the
        message's tuple and the ranges as lists (a few numpy calls cost 5 us here hot and
        several times that on the sample's first touch)."""
        bounds = self._plausible_bounds
        if bounds is None or bounds[0] is not self.y_lower or bounds[1] is not self.y_upper:
            bounds = self._plausible_bounds = (self.y_lower, self.y_upper,
                                               np.asarray(self.y_lower, float).tolist(),
                                               np.asarray(self.y_upper, float).tolist())
        return not (any(map(operator.lt, y, bounds[2])) or any(map(operator.gt, y, bounds[3])))

    def _ramp_limited(self, u, hold, seq: int):
        """The move after a resume, limited by the ramp-in (:mod:`services.nodes.ramp_in`);
        the controller goes on from the move sent."""
        ramp = self._ramp_in
        sent = ramp.limit(u, hold)
        if ramp.done:
            self._ramp_in = None
            if ramp.samples:
                with self._lock:
                    self.alarms.append(f"ramp-in after the resume done at sample {seq} "
                                       f"({ramp.samples} moves limited)")
            return u
        if sent is not u:
            self._continue_from(sent, seq)
        return sent

    def _continue_from(self, u, seq: int) -> None:
        """The plant keeps ``u``, not the move the controller computed for sample ``seq``
        (past the deadline, or invalid): the controller goes on from ``u``
        (:func:`~controller.units.takeover.continue_from_applied`)."""
        try:
            continue_from_applied(self.controller, u)
        except Exception as exc:  # never stall the loop; the next step holds on its own
            self._failures.note("taking over the held move failed", exc)
            with self._lock:
                self.alarms.append(f"sample {seq}: the controller could not take over the "
                                   f"held move ({exc})")

    def _publish_status(self) -> None:
        from services.io.messages import SCHEMA_VERSION, encode

        self._status_pub.put(encode({"schema": SCHEMA_VERSION, "kind": "status", **self.status()}))

    #: Measurements the busy-poll channel holds (more than one only when the loop is
    #: behind; the newest is processed, the others counted as dropped).
    POLL_QUEUE = 16

    def run(self, stop: threading.Event) -> None:
        """Keep the node up until ``stop`` is set (BLAS single-threaded meanwhile,
        :mod:`controller.blas`).

        By default the samples are processed on the threads that deliver them (see the
        module notes) and this only picks up any left. With ``busy_poll`` this thread
        polls for measurements without ever sleeping, so the CPU it runs on stays its
        own between samples and the step starts from warmer caches (on a shared VM the TE
        step after a 2.6 ms sleep measured ~1.8x the one after a spin, see
        ``docs/realtime.md``).
        It costs one CPU at 100 %. ``try_recv`` does not release the interpreter lock,
        so between polls the thread calls ``os.sched_yield``, which does: the other
        threads of the node (queries, liveliness, the watchdog) get the lock at once
        instead of after the switch interval, and a thread woken on this CPU runs at
        once. Measured, 3 alternated pairs of 20 s at 10,000x: misses 1/0/6 against
        12/27/3 without the yield, sample p99 1.18-1.35 against 1.26-1.65 ms, held
        moves unchanged (8/9/14 against 14/11/6).
        """
        with single_threaded_blas():
            self._run(stop)

    def _run(self, stop: threading.Event) -> None:
        if not self.busy_poll:
            while not stop.wait(0.1):
                self._drain()
            return
        try_recv, accept, now = self._sub.try_recv, self._accept, time.perf_counter
        yield_cpu = os.sched_yield
        while not stop.is_set() and not self._closing:
            try:
                sample = try_recv()
            except Exception:  # undeclared by close() meanwhile
                if self._closing:
                    return
                raise
            if sample is None:
                yield_cpu()
                continue
            got = accept(sample, now())
            while (sample := try_recv()) is not None:  # newest wins
                got = accept(sample, now()) or got
            if got:
                self._drain()

    def close(self) -> None:
        """Checkpoint, flush telemetry, undeclare everything (the caller closes the session).

        No sample starts after this is called; one in progress on a Zenoh thread is
        finished (its move published) before the final checkpoint."""
        self._closing = True
        for ent in (self._plant_live, self._token, self._qry, self._sub):
            try:
                ent.undeclare()
            except Exception:
                pass
        with self._busy:  # wait for a sample in progress
            pass
        self._watchdog.close()
        for ent in (self._status_pub, self._mv_pub):
            try:
                ent.undeclare()
            except Exception:
                pass
        try:
            self.checkpoint(wait=True)
        finally:
            self._worker.close()
            if self._telemetry_worker is not None:
                self._telemetry_worker.submit(self.telemetry.close)
                self._telemetry_worker.close()
