"""The soak: a long closed-loop run over the real services with transitions, IDVs and faults.

Layout (one machine, loopback)::

    plant node (thread, own session) ─┐                ┌─ controller node (process)
                                      ├─ ChaosRelay ───┤
    plant-side hub session ───────────┘                └─ controller-side hub ── api node (process)

- The **controller** and the **api** are child processes (``python -m
  services.soak.faults controller`` — ``ssmpc controller`` with optional stall
  windows — and ``ssmpc api`` with a random bearer token). They connect to the
  controller-side hub session of this process, so a restarted one finds the
  mesh again at the same endpoint.
- The **plant node** runs in a thread of this process on its own session
  connected to the plant-side hub. Killing it tears its loop and its session
  down (no undeclare: its liveliness token vanishes) while the simulated
  process keeps running with the valves held — as a real plant does when its
  DCS gateway dies — until a new node takes the same plant over.
- The :class:`~services.soak.faults.ChaosRelay` forwards measurements and MVs
  between the two sides and injects the message faults.

The orchestrator drives the run in process time (the plant's clock): random
grade transitions through the REST API with the token (some aborted with
DELETE), random IDVs through the plant's command query, unauthorized and
malformed writes (which must be refused), and the fault schedule. At the end it
reads the transition history (REST, and the SQLite store) and writes the report
(docs/soak.md).

Report (``soak --report F``): ``process_hours``, ``transitions`` (requested,
settled, aborted, failed), ``shutdowns`` (time, reason, IDVs on, preventable),
``deadline_misses``, ``fallback_moves``, ``restarts``, ``bumpless_resumes``,
``records_lost``, ``unhandled_errors``, ``faults_injected`` (by kind), and
details (wall time, achieved speed, machine, settings, per-restart checks).

Counting rules
--------------
- *records lost*: a transition the api accepted (202) that is missing from the
  history at the end, a transition whose state went backwards between two
  observations, a transition running at a controller kill that is not running
  or finished after the restart, or a stored transition whose event history
  does not start with ``pending`` and end with its recorded state.
- *unhandled errors*: ERROR log lines or tracebacks of any node, a node exiting
  by itself, a 500/502 from the api, an unexpected status code to a probe
  (e.g. a write without the token that is not refused with 401), an exception
  in this orchestrator's threads.
- *bumpless resume* (:func:`bumpless_verdict`): after a controller restart, every
  move it sends up to its :data:`FIRST_MOVES`-th computed one steps from the move
  before it (the first from the move the plant held) by no more than the largest
  single-sample move of that MV in the 20 samples before the kill (plus 1e-9 relative).
  The moves are recorded in the report (``details.controller_resumes``: ``moves_before``,
  ``held``, ``moves_after``), so the verdict can be checked from them. Reported beside
  it: whether the first computed move matches a replay from the checkpoint the killed
  node left (``replay_matches``).
- *preventable shutdown*: a trip that the fault-free twin (:func:`fault_free_twin`: the
  same plant, seed, controller, transitions and IDVs offline, without faults or
  timing) does not have within 2 process hours, unless an IDV of ``unpreventable_idvs``
  was on. A trip the twin has too is the controller's and the process's own.
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import random
import secrets
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from services.io import keys
from services.io.messages import MVMessage, Reply, Request
from services.soak.faults import ChaosRelay, FaultWindow, default_faults, report_kind

__all__ = ["SoakSettings", "Soak", "run_soak", "REPORT_KEYS", "bumpless_verdict"]

log = logging.getLogger("ssmpc.soak")

#: Keys of the report (docs/soak.md); scripts rely on them.
REPORT_KEYS = ("process_hours", "transitions", "shutdowns", "deadline_misses", "fallback_moves",
               "restarts", "bumpless_resumes", "records_lost", "unhandled_errors",
               "faults_injected")
_ORDER = {"pending": 0, "running": 1, "settled": 2, "aborted": 2, "failed": 2}
#: Grades the soak moves TE between by default. Modes 4-6 run at a back-off from
#: Ricker's maximum-production optima (``controller.units.te.max_production``).
#: Modes 1 and 3 are reachable, but measured offline without any fault (07:25 UTC) the
#: current TE controller trips on reactor pressure in mode 0 -> 1 -> 2 (strategies
#: "ssmpc" and "pi", 2 h into the second leg) and in mode 3 -> 0; mode 0 <-> 2 holds.
#: Include them with ``--grades mode0,mode1,mode2,mode3``.
TE_GRADES = ("mode0", "mode2")
#: TE disturbances switched on at random, for ``idv_on_h`` (3 h) each: all twenty. IDV(7)
#: (C header pressure loss) holds at modes 0, 2, 3 for 48 h with the feed overrides
#: (:mod:`controller.units.te.overrides`); IDV(6) at mode 2 trips 11.8 h after its
#: onset, far beyond the 3 h it is on (offline, no faults, noise on, "ssmpc").
TE_IDVS = tuple(range(1, 21))
LEASE_MS = 1000
#: Computed moves after a controller restart judged by the bumpless rule.
FIRST_MOVES = 3
#: Samples before the kill whose largest single-sample move bounds the moves after it.
BUMP_WINDOW = 20
#: A restarted controller's first move matches the replay from its checkpoint within this
#: relative tolerance. Diagnostic only: a controller whose solver has a wall-clock budget
#: (the MPC's ``budget_ms``) can take another branch in the replay.
REPLAY_RTOL = 1e-9
#: A trip counts as the controller's own (not preventable by the services) if the
#: fault-free twin trips no later than this many process hours after it.
TWIN_MARGIN_H = 2.0


@dataclass(frozen=True)
class SoakSettings:
    """What a soak run does.

    Parameters
    ----------
    unit : str
        Unit of :mod:`services.registry` (``te``).
    hours : float
        Process hours to run.
    speed : float
        Process seconds per wall second of the plant node (real-time mode).
    seed : int
        Seed of every random choice (transitions, IDVs, fault hits, plant noise).
    faults : tuple of FaultWindow or None
        The fault schedule; None = every kind once (:func:`default_faults`).
    transition_gap_h : float
        Mean process time between the end of one transition and the next request.
    abort_probability : float
        Share of transitions aborted (DELETE) at a random time while they run.
    idv_gap_h, idv_on_h : float
        Mean process time between disturbances, and their mean duration.
    grades, idvs : tuple
        Grades to move between and IDVs to switch; empty = the unit's defaults.
    unpreventable_idvs : tuple of int
        A trip while one of these is on is not counted as preventable.
    noise : bool
        TE measurement noise.
    unit_config : dict
        Overrides of the unit's registry config (as ``--unit-config`` of the nodes), e.g.
        ``{"strategy": "pi"}``; the soak adds ``checkpoint_every=1``.
    state_dir : str or None
        Where the store, logs and unit config go (None: a temporary directory).
    plant_outage_samples : int
        Sample periods the plant runs without its node after a plant kill.
    ready_timeout_s : float
        Longest wait for a node process to start, wall s.
    """

    unit: str = "te"
    hours: float = 2.0
    speed: float = 3600.0
    seed: int = 0
    faults: tuple[FaultWindow, ...] | None = None
    transition_gap_h: float = 2.0
    abort_probability: float = 0.2
    idv_gap_h: float = 6.0
    idv_on_h: float = 3.0
    grades: tuple[str, ...] = ()
    idvs: tuple[int, ...] = ()
    unpreventable_idvs: tuple[int, ...] = ()
    noise: bool = True
    unit_config: dict = field(default_factory=dict)
    state_dir: str | None = None
    plant_outage_samples: int = 5
    ready_timeout_s: float = 120.0

    def __post_init__(self) -> None:
        for name in ("hours", "speed", "transition_gap_h", "idv_gap_h", "idv_on_h",
                     "ready_timeout_s"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise ValueError(f"{name}: must be a positive number, got {v!r}")
        if not (0 <= self.abort_probability <= 1):
            raise ValueError(f"abort_probability: must be in [0, 1], got "
                             f"{self.abort_probability}")
        if self.plant_outage_samples < 0:
            raise ValueError("plant_outage_samples: must be >= 0")
        if not isinstance(self.unit_config, dict):
            raise ValueError("unit_config: expected a dict of unit config fields")
        keys.check_unit_name(self.unit)


def _pdeathsig():  # pragma: no cover - runs in the child
    try:
        import ctypes

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)
    except Exception:
        pass


class _NodeProcess:
    """A node child process: started, waited ready, killed, restarted; stderr to a file."""

    def __init__(self, role: str, argv: list[str], log_path: Path, env: dict | None = None):
        self.role, self.argv, self.log_path, self.env = role, argv, log_path, env
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self.unexpected_exits = 0

    def start(self, timeout_s: float) -> None:
        self.starts += 1
        err = open(self.log_path, "a")  # noqa: SIM115 - handed to the child
        err.write(f"--- start {self.starts} ---\n")
        err.flush()
        self.proc = subprocess.Popen([sys.executable, *self.argv], stdout=subprocess.PIPE,
                                     stderr=err, text=True, env=self.env,
                                     preexec_fn=_pdeathsig)
        err.close()
        from services.nodes.supervisor import _lines

        lines = _lines(self.proc)  # read on a thread: select misses buffered lines
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            try:
                line = lines.get(timeout=0.2)
            except queue.Empty:
                continue
            if line is None:  # its output ended: it exited
                try:
                    self.proc.wait(timeout=5.0)
                except subprocess.TimeoutExpired:
                    self.kill()
                raise RuntimeError(f"{self.role}: exited with {self.proc.returncode} before "
                                   f"ready; see {self.log_path}")
            if line.startswith("ready"):
                threading.Thread(target=self._discard, args=(lines,), daemon=True).start()
                return
        self.kill()
        raise RuntimeError(f"{self.role}: not ready within {timeout_s:g} s")

    @staticmethod
    def _discard(lines) -> None:
        while lines.get() is not None:
            pass

    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()

    def stop(self, grace_s: float = 15.0) -> int | None:
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(grace_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


class _PlantHost:
    """The plant node in a thread; a kill leaves the simulated process running, valves held."""

    def __init__(self, cfg, runner, hub_endpoint: str, speed: float, errors: Counter) -> None:
        self.cfg, self.runner, self.ep, self.speed = cfg, runner, hub_endpoint, speed
        self.errors = errors
        self.node = None
        self.session = None
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._field_stop = threading.Event()
        self._field: threading.Thread | None = None

    def start(self) -> None:
        from services.io.zenoh_session import SessionSettings, open_session
        from services.nodes.plant import PlantNode

        self.session = open_session(SessionSettings(connect=(self.ep,), lease_ms=LEASE_MS))
        # a new node counts its samples from 0 again (as a restarted gateway process does);
        # the process time goes on with the plant
        self.node = PlantNode(self.cfg, self.session, speed=self.speed, runner=self.runner)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(self.node, self._stop),
                                        name="soak-plant", daemon=True)
        self._thread.start()

    def _run(self, node, stop) -> None:
        try:
            node.run(stop)
        except Exception:
            log.exception("plant node failed")
            self.errors["plant node exception"] += 1

    def kill(self, outage_s: float) -> None:
        """Stop the node's loop and drop its session without goodbye; hold the valves."""
        self._stop.set()
        self._thread.join(10)
        try:
            self.session.close()
        except Exception:
            pass
        self.node = None
        self._field_stop = threading.Event()
        self._field = threading.Thread(target=self._hold, args=(self._field_stop,),
                                       name="soak-field", daemon=True)
        self._field.start()
        time.sleep(outage_s)
        self._field_stop.set()
        self._field.join(10)
        self.start()

    def _hold(self, stop) -> None:
        from services.timing import SampleClock

        clock = SampleClock(self.cfg.sample_period_s / self.speed)
        u = self.runner.u
        try:
            while not stop.is_set():
                clock.wait_next(stop)
                if stop.is_set():
                    break
                self.runner.advance(u, self.cfg.sample_period_s)
        except Exception:
            log.exception("plant (no node) failed")
            self.errors["plant exception while its node was down"] += 1

    @property
    def t(self) -> float:
        return float(self.runner.t)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(10)
        if self.node is not None:
            self.node.close()
        if self.session is not None:
            self.session.close()


class _ErrorCounter(logging.Handler):
    """Counts ERROR records of the ssmpc loggers in this process."""

    def __init__(self, counter: Counter) -> None:
        super().__init__(logging.ERROR)
        self.counter = counter

    def emit(self, record) -> None:
        if record.name.startswith("ssmpc"):
            self.counter[f"{record.name}: {record.getMessage()[:80]}"] += 1


class Soak:
    """One soak run; :meth:`run` returns the report dict."""

    def __init__(self, settings: SoakSettings) -> None:
        from controller.units.config import UnitConfig
        from services.registry import load_unit_config

        self.s = settings
        self.rng = random.Random(settings.seed)
        base = load_unit_config(settings.unit)
        # A checkpoint every sample: a killed controller resumes from the sample before.
        self.unit_overrides = {**settings.unit_config, "checkpoint_every": 1}
        self.cfg = UnitConfig.from_dict(self.unit_overrides, base)
        self.faults = (tuple(settings.faults) if settings.faults is not None
                       else tuple(default_faults(settings.hours, self.cfg.sample_period_s)))
        known = tuple(self._unit_grades())
        self.grades = settings.grades or (TE_GRADES if self.cfg.plant == "te" else known)
        unknown = [g for g in self.grades if g not in known]
        if unknown or len(set(self.grades)) < 2:
            raise ValueError(f"grades: need at least two of {', '.join(known)}; got "
                             f"{', '.join(self.grades)}")
        self.idvs = settings.idvs or (TE_IDVS if self.cfg.plant == "te" else ())
        self.errors: Counter[str] = Counter()
        self.injected: Counter[str] = Counter()
        self.accepted: dict[str, str] = {}
        self.seen_state: dict[str, str] = {}
        self.shutdowns: list[dict] = []
        self.restarts: Counter[str] = Counter()
        self.resumes: list[dict] = []
        self.resume_checks: list[dict] = []
        self.node_checks: list[dict] = []
        self.plant_kill_t = 0.0
        self.probes: Counter[str] = Counter()
        self.unavailable = 0
        self.idv_on: dict[int, float] = {}
        self.idv_log: list[dict] = []
        self._recent_mv: deque = deque(maxlen=BUMP_WINDOW + 1)
        self._recent_meas: dict[int, bytes] = {}
        self._await_resume: dict | None = None
        self._mv_lock = threading.Lock()

    def _unit_grades(self):
        from controller.units.config import build_plant, grade_setpoints

        return grade_setpoints(self.cfg, build_plant(self.cfg)).keys()

    # -- observers ------------------------------------------------------------------------
    def _on_meas(self, payload: bytes, wall: float) -> None:
        try:
            seq = int(json.loads(payload)["seq"])
        except Exception:
            return
        with self._mv_lock:
            self._recent_meas.pop(seq, None)  # a restarted plant node reuses numbers: newest last
            self._recent_meas[seq] = payload
            while len(self._recent_meas) > 400:
                self._recent_meas.pop(next(iter(self._recent_meas)))

    def _on_mv(self, payload: bytes, wall: float) -> None:
        try:
            msg = MVMessage.from_bytes(payload)
        except Exception:
            return
        u = np.asarray(msg.u, float)
        with self._mv_lock:
            pending = self._await_resume
            if pending is not None and wall > pending["killed_wall"]:
                # every sample the restarted node processes gets exactly one MV (computed or,
                # past the deadline, the held move); collect them up to the first computed one
                pending.setdefault("mvs", []).append(
                    (msg.meas_seq, msg.fallback, self._recent_meas.get(msg.meas_seq), u))
                if not msg.fallback:
                    pending.setdefault("first_move", u)
                    pending["computed"] = pending.get("computed", 0) + 1
                    if pending["computed"] >= FIRST_MOVES:
                        self._await_resume = None
            self._recent_mv.append(u)

    # -- REST ---------------------------------------------------------------------------------
    #: Ports the api node is started on before the soak gives up: a port found free may
    #: be taken (an outgoing connection's ephemeral port) before the api binds it.
    API_PORT_TRIES = 3

    def _start_api(self, port: int, ep_ctrl: str, state: Path, env: dict,
                   timeout_s: float) -> int:
        """Start the api node on ``port``, or on another free port if that one was
        taken meanwhile; return the port it serves on."""
        from services.io.zenoh_session import free_port
        from services.nodes.supervisor import port_taken

        for attempt in range(1, self.API_PORT_TRIES + 1):
            self.api = _NodeProcess(
                "api", ["-m", "services.cli", "api", "--connect", ep_ctrl, "--lease-ms",
                        str(LEASE_MS), "--port", str(port)], state / "api.log", env=env)
            try:
                self.api.start(timeout_s)
                break
            except RuntimeError:
                last_start = (state / "api.log").read_text(errors="replace")
                if not port_taken(last_start.rsplit("--- start", 1)[-1]) \
                        or attempt == self.API_PORT_TRIES:
                    raise
                port = free_port()
        self.http.base_url = f"http://127.0.0.1:{port}"
        return port

    def _rest(self, method: str, path: str, *, auth: bool = True, **kw):
        """One REST call; None when the api node is unreachable (counted)."""
        import httpx

        headers = {"Authorization": f"Bearer {self.token}"} if auth else {}
        try:
            r = self.http.request(method, path, headers=headers, **kw)
        except httpx.HTTPError:
            self.unavailable += 1
            return None
        if r.status_code in (500, 502):
            self.errors[f"api {r.status_code} on {method} {path.split('/')[-1]}"] += 1
        elif r.status_code in (503, 504):
            self.unavailable += 1
        return r

    def _observe(self, view: dict) -> None:
        tid, state = view["id"], view["state"]
        prev = self.seen_state.get(tid)
        if prev is not None and (_ORDER[state] < _ORDER[prev]
                                 or (_ORDER[prev] == 2 and state != prev)):
            self.errors_lost.append(f"transition {tid} went from {prev} to {state}")
        self.seen_state[tid] = state

    def _probe_security(self) -> None:
        """A write without the token, and a malformed body: both refused, nothing 5xx."""
        path = f"/api/v1/units/{self.cfg.unit}/transitions"
        r = self._rest("POST", path, auth=False, json={"grade": self.grades[0]})
        if r is not None:
            self.probes["unauthorized write"] += 1
            if r.status_code != 401:
                self.errors[f"write without token answered {r.status_code}"] += 1
        r = self._rest("POST", path, json={"grade": 7, "duration_h": "soon"})
        if r is not None:
            self.probes["malformed body"] += 1
            if r.status_code != 422:
                self.errors[f"malformed body answered {r.status_code}"] += 1
        r = self._rest("POST", path, json={"grade": "no-such-grade"})
        if r is not None:
            self.probes["unknown grade"] += 1
            if r.status_code != 404:
                self.errors[f"unknown grade answered {r.status_code}"] += 1

    def _status(self) -> dict | None:
        r = self._rest("GET", f"/api/v1/units/{self.cfg.unit}/status")
        if r is None or r.status_code != 200:
            return None
        return r.json()

    # -- random operations --------------------------------------------------------------------
    def _request_transition(self, t: float) -> None:
        st = self._status()
        if st is None:
            return
        if st.get("transition") and st["transition"]["state"] in ("pending", "running"):
            return
        choices = [g for g in self.grades if g != st.get("grade")]
        grade = self.rng.choice(choices)
        self._probe_security()
        body = {"grade": grade}
        if self.rng.random() < 0.5:
            body["duration_h"] = round(self.rng.uniform(6.0, 14.0), 2)
        r = self._rest("POST", f"/api/v1/units/{self.cfg.unit}/transitions", json=body)
        if r is None:
            return
        if r.status_code == 202:
            view = r.json()
            self.accepted[view["id"]] = grade
            self._observe(view)
            self.active_tid = view["id"]
            if self.rng.random() < self.s.abort_probability:
                dur = view["duration_s"]
                self.abort_at = t + self.rng.uniform(0.1, 0.9) * dur
            else:
                self.abort_at = None
        elif r.status_code not in (409, 503, 504):
            self.errors[f"transition request answered {r.status_code}"] += 1

    def _abort(self) -> None:
        tid = self.active_tid
        self.abort_at = None
        r = self._rest("DELETE", f"/api/v1/units/{self.cfg.unit}/transitions/{tid}")
        if r is not None and r.status_code == 200:
            self._observe(r.json())
        elif r is not None and r.status_code not in (503, 504):
            self.errors[f"abort answered {r.status_code}"] += 1

    def _poll_active(self) -> bool:
        """Observe the active transition; True when there is none pending or running."""
        tid = getattr(self, "active_tid", None)
        if tid is None:
            return True
        r = self._rest("GET", f"/api/v1/units/{self.cfg.unit}/transitions/{tid}")
        if r is None or r.status_code != 200:
            return False
        view = r.json()
        self._observe(view)
        if view["state"] in ("settled", "aborted", "failed"):
            self.active_tid = None
            return True
        return False

    def _plant_cmd(self, action: str, args: dict) -> Reply | None:
        rs = list(self.hub_plant.get(keys.plant_cmd(self.cfg.unit, action),
                                     payload=Request(action, args).to_bytes(), timeout=5.0))
        for r in rs:
            if r.ok is not None:
                return Reply.from_bytes(r.ok.payload.to_bytes())
        return None

    def _set_idv(self, k: int, on: bool, t: float) -> None:
        rep = self._plant_cmd("disturbance", {"name": f"IDV{k}", "value": 1 if on else 0})
        if rep is None or not rep.ok:
            self.errors[f"IDV{k} command failed"] += 1
            return
        if on:
            self.idv_on[k] = t
        else:
            self.idv_on.pop(k, None)
        self.idv_log.append({"t_h": t / 3600.0, "idv": k, "on": on})

    # -- faults ---------------------------------------------------------------------------------
    def _kill(self, target: str, t: float) -> None:
        self.injected[report_kind("kill", target)] += 1
        self.restarts[target] += 1
        if target == "controller":
            tid = getattr(self, "active_tid", None)
            before = None
            if tid is not None:
                self._poll_active()
                before = self.seen_state.get(tid)
            self.ctrl.kill()  # SIGKILL, and waited for
            # the moves it sent up to its death (one may still be on its way to the relay)
            # and the move the plant holds from now on
            time.sleep(max(0.05, 2 * self.cfg.sample_period_s / self.s.speed))
            with self._mv_lock:
                recent = [u.tolist() for u in self._recent_mv]
                resume = {"t_h": t / 3600.0, "killed_wall": time.perf_counter(),
                          "moves_before": recent}
                self._await_resume = resume
            u_held = np.asarray(self.plant.runner.u, float)
            copy = self._copy_store()
            self.ctrl.start(self.s.ready_timeout_s)
            self._check_resume(resume, copy, u_held)
            if tid is not None and before in ("pending", "running"):
                # the restarted node must still be driving that transition (not only have
                # it in its store): its status names it as the active one, or it ended
                t_end = time.monotonic() + 10
                after = active = None
                while time.monotonic() < t_end and after is None:
                    st = self._status()
                    r = self._rest("GET", f"/api/v1/units/{self.cfg.unit}/transitions/{tid}")
                    if st is not None and r is not None and r.status_code == 200:
                        after = r.json()["state"]
                        active = (st.get("transition") or {}).get("id")
                    else:
                        time.sleep(0.1)
                ok = (after in ("settled", "aborted", "failed")
                      or (after in ("pending", "running") and active == tid))
                self.resume_checks.append({"t_h": t / 3600.0, "transition": tid,
                                           "before": before, "after": after,
                                           "active_after": active, "ok": ok})
                if not ok:
                    self.errors_lost.append(f"transition {tid} was {before} at the kill, "
                                            f"{after} (active: {active}) after the restart")
        elif target == "api":
            self.api.kill()
            self.api.start(self.s.ready_timeout_s)
            # the restarted api finds the controller again (it keeps no state of its own)
            ok = self._wait(lambda: self._status() is not None)
            self.node_checks.append({"t_h": t / 3600.0, "node": "api", "ok": ok})
            if not ok:
                self.errors["the restarted api does not reach the controller"] += 1
        elif target == "plant":
            before = self._status()
            outage = self.s.plant_outage_samples * self.cfg.sample_period_s / self.s.speed
            self.plant.kill(outage)
            # the controller acts on the new node's samples at once, although they count
            # from 0 again (below the last sample it saw: nothing stale about them)
            k0 = None if before is None else before["sample"]

            def acting():
                st = self._status()
                return (st is not None and k0 is not None and 0 <= st["sample"] < k0
                        and st["process_time_s"] > self.plant_kill_t)

            self.plant_kill_t = t
            ok = self._wait(acting)
            self.node_checks.append({"t_h": t / 3600.0, "node": "plant", "ok": ok})
            if not ok:
                self.errors["the controller does not act on the restarted plant node"] += 1

    def _wait(self, predicate, timeout_s: float = 15.0) -> bool:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            if predicate():
                return True
            time.sleep(0.1)
        return False

    def _copy_store(self) -> Path:
        """A copy of the killed controller's store (database and WAL) for the replay."""
        import shutil

        dst = self.state / f"replay-{self.restarts['controller']}"
        dst.mkdir(exist_ok=True)
        for suffix in ("", "-wal"):
            src = Path(str(self.store_path) + suffix)
            if src.exists():
                shutil.copyfile(src, dst / (src.name))
        return dst / self.store_path.name

    def _check_resume(self, resume: dict, store_copy: Path, u_held) -> None:
        """Bumpless (:func:`bumpless_verdict`): the restarted node's first moves step by
        no more than the largest recent step of each MV; beside it, whether its first
        computed move equals a replay from its checkpoint."""
        t_end = time.monotonic() + 10.0
        while time.monotonic() < t_end and resume.get("computed", 0) < FIRST_MOVES:
            time.sleep(0.02)
        with self._mv_lock:
            if self._await_resume is resume:
                self._await_resume = None
        resume.pop("killed_wall", None)
        computed = resume.pop("computed", 0)
        first, mvs = resume.pop("first_move", None), resume.pop("mvs", [])
        resume["held"] = u_held.tolist()
        resume["moves_after"] = [{"fallback": bool(m[1]), "u": np.asarray(m[3]).tolist()}
                                 for m in mvs]
        verdict = bumpless_verdict(resume["moves_before"], resume["held"],
                                   resume["moves_after"])
        resume.update(verdict)
        if computed < FIRST_MOVES:
            resume.update(bumpless=False, why=f"{computed} computed moves after the restart "
                                              f"(of {FIRST_MOVES} judged)")
        upto_first = mvs[:next((i + 1 for i, m in enumerate(mvs) if not m[1]), len(mvs))]
        try:
            u_ckpt, u_replay, replayed = replay_first_move(self.cfg, store_copy, upto_first)
            resume["samples_replayed"] = replayed
        except Exception as exc:
            resume["replay"] = f"failed: {exc}"
            self.resumes.append(resume)
            return
        resume["checkpoint_vs_held"] = float(np.max(np.abs(u_ckpt - u_held)))
        if first is None or u_replay is None:
            resume["replay_matches"] = None
        else:
            diff = float(np.max(np.abs(first - u_replay) / (1 + np.abs(u_replay))))
            resume["first_move_vs_replay"] = diff
            resume["replay_matches"] = diff <= REPLAY_RTOL
        self.resumes.append(resume)

    def _stall_windows(self) -> list[str]:
        return [f"{w.start_s}:{w.end_s}" for w in self.faults if w.kind == "stall"]

    # -- the run --------------------------------------------------------------------------------
    def run(self) -> dict:
        import httpx

        from services.io.zenoh_session import (
            SessionSettings,
            free_port,
            free_tcp_endpoint,
            open_session,
        )
        from services.nodes.plant import make_runner

        s = self.s
        own_tmp = None
        if s.state_dir is None:
            own_tmp = tempfile.TemporaryDirectory(prefix="ssmpc-soak-")
            state = Path(own_tmp.name)
        else:
            state = Path(s.state_dir)
            state.mkdir(parents=True, exist_ok=True)
        self.state = state
        store_path = self.store_path = state / f"ssmpc-{self.cfg.unit}.sqlite"
        if store_path.exists():
            raise ValueError(f"state_dir: {str(state)!r} already holds a store; use a fresh "
                             "directory (the soak checks the history it creates)")
        unit_cfg = state / "unit.json"
        unit_cfg.write_text(json.dumps(self.unit_overrides))
        self.token = secrets.token_urlsafe(24)
        self.errors_lost: list[str] = []
        self.active_tid = None
        self.abort_at = None
        handler = _ErrorCounter(self.errors)
        logging.getLogger("ssmpc").addHandler(handler)
        ep_plant, ep_ctrl = free_tcp_endpoint(), free_tcp_endpoint()
        port = free_port()
        hub_settings = {"lease_ms": LEASE_MS}
        self.hub_plant = open_session(SessionSettings(listen=(ep_plant,), **hub_settings))
        self.hub_ctrl = open_session(SessionSettings(listen=(ep_ctrl,), **hub_settings))
        relay = None
        self.plant = None
        self.ctrl = self.api = None
        self.http = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10.0)
        wall0 = time.perf_counter()
        t_end = s.hours * 3600.0
        try:
            relay = ChaosRelay(self.cfg.unit, self.hub_plant, self.hub_ctrl,
                               sample_period_s=self.cfg.sample_period_s, speed=s.speed,
                               windows=self.faults, seed=s.seed, on_mv=self._on_mv,
                               on_meas=self._on_meas)
            common = ["--unit", self.cfg.unit, "--unit-config", str(unit_cfg), "--speed",
                      str(s.speed), "--connect", ep_ctrl, "--lease-ms", str(LEASE_MS)]
            stall = [a for w in self._stall_windows() for a in ("--stall", w)]
            stall_factor = next((w.amount for w in self.faults if w.kind == "stall"), 4.0)
            self.ctrl = _NodeProcess(
                "controller", ["-m", "services.soak.faults", "controller", *common, "--state-dir",
                               str(state), *stall, "--stall-factor", str(stall_factor)],
                state / "controller.log")
            env = {**os.environ, "SSMPC_API_TOKEN": self.token}
            self.ctrl.start(s.ready_timeout_s)
            port = self._start_api(port, ep_ctrl, state, env, s.ready_timeout_s)
            self.plant_seed = float(1 + s.seed % 10_000)
            runner = (make_runner(self.cfg, noise=s.noise, seed=self.plant_seed)
                      if self.cfg.plant == "te" else make_runner(self.cfg))
            time.sleep(0.3)
            self.plant = _PlantHost(self.cfg, runner, ep_plant, s.speed, self.errors)
            self.plant.start()
            # wait until the api sees the controller
            deadline = time.monotonic() + s.ready_timeout_s
            while time.monotonic() < deadline:
                st = self._status()
                if st is not None and st["sample"] >= 1:
                    break
                time.sleep(0.1)
            wall_loop0 = time.perf_counter()
            t_loop0 = self.plant.t
            kills = sorted((w.start_s, w.target) for w in self.faults if w.kind == "kill")
            next_tr = self.rng.expovariate(1 / (s.transition_gap_h * 3600.0)) * 0.25
            next_idv = self.rng.expovariate(1 / (s.idv_gap_h * 3600.0))
            idv_off_at: dict[int, float] = {}
            last_poll = 0.0
            while True:
                t = self.plant.t
                if t >= t_end and not kills:
                    break  # (a kill still due happens first: a restart can outlast the run)
                if self.plant.runner.shutdown:
                    self._record_shutdown(t)
                    break
                while kills and kills[0][0] <= t:
                    self._kill(kills.pop(0)[1], t)
                for name, node in (("controller", self.ctrl), ("api", self.api)):
                    if not node.alive():
                        self.errors[f"{name} exited by itself "
                                    f"(code {node.proc.returncode})"] += 1
                        self.restarts[name] += 1
                        node.start(s.ready_timeout_s)
                now = time.perf_counter()
                if now - last_poll > 0.25:
                    last_poll = now
                    idle = self._poll_active()
                    if self.abort_at is not None and t >= self.abort_at and not idle:
                        self._abort()
                    elif idle and t >= next_tr:
                        self._request_transition(t)
                        next_tr = t + self.rng.expovariate(1 / (s.transition_gap_h * 3600.0))
                if t >= next_idv and self.idvs and not self.idv_on:
                    k = self.rng.choice(self.idvs)
                    self._set_idv(k, True, t)
                    idv_off_at[k] = t + self.rng.expovariate(1 / (s.idv_on_h * 3600.0))
                    next_idv = idv_off_at[k] + self.rng.expovariate(1 / (s.idv_gap_h * 3600.0))
                for k, t_off in list(idv_off_at.items()):
                    if t >= t_off:
                        self._set_idv(k, False, t)
                        del idv_off_at[k]
                time.sleep(0.02)
            wall_loop = time.perf_counter() - wall_loop0
            t_loop = self.plant.t - t_loop0
            self._poll_active()
            final_status = self._status()
            history = self._history()
            relay_injected = dict(relay.injected)
        finally:
            logging.getLogger("ssmpc").removeHandler(handler)
            if relay is not None:
                relay.close()
            if self.plant is not None:
                self.plant.close()
            codes = {}
            for name, node in (("controller", self.ctrl), ("api", self.api)):
                if node is not None:
                    codes[name] = node.stop()
            self.http.close()
            self.hub_plant.close()
            self.hub_ctrl.close()
        for name, code in codes.items():
            if code not in (0, None):
                self.errors[f"{name} stopped with code {code}"] += 1
        self._scan_logs()
        stored = self._stored_history(store_path)
        if self.shutdowns and self.cfg.plant == "te":
            self._judge_shutdowns(stored)
        report = self._report(final_status, history, stored, relay_injected,
                              time.perf_counter() - wall0, wall_loop, t_loop)
        if own_tmp is not None:
            own_tmp.cleanup()
        return report

    # -- end of run ------------------------------------------------------------------------------
    def _record_shutdown(self, t: float) -> None:
        sd = self.plant.runner.sim.shutdown if hasattr(self.plant.runner, "sim") else None
        reason = getattr(sd, "reason", "shutdown")
        idvs = sorted(self.idv_on)
        self.shutdowns.append({"process_hours": t / 3600.0, "reason": str(reason),
                               "idvs_on": idvs,
                               "preventable": not any(k in self.s.unpreventable_idvs
                                                      for k in idvs)})

    def _judge_shutdowns(self, stored: dict) -> None:
        """Run the fault-free twin for each trip; a trip the twin has too (within
        :data:`TWIN_MARGIN_H`) is the controller's and the process's, not preventable by
        the services."""
        for sd in self.shutdowns:
            try:
                twin = fault_free_twin(self.cfg, self.plant_seed, self.s.noise, stored,
                                       self.idv_log, (sd["process_hours"] + TWIN_MARGIN_H)
                                       * 3600.0)
            except Exception as exc:  # the verdict stays "preventable"
                sd["fault_free_twin"] = f"failed: {exc}"
                continue
            sd["fault_free_twin_trip_hours"] = None if twin is None else twin / 3600.0
            if twin is not None:
                sd["preventable"] = False

    def _history(self) -> list[dict] | None:
        for _ in range(50):
            r = self._rest("GET", f"/api/v1/units/{self.cfg.unit}/transitions")
            if r is not None and r.status_code == 200:
                return r.json()
            time.sleep(0.2)
        return None

    def _stored_history(self, path: Path) -> dict:
        from services.store import UnitStore

        store = UnitStore(path, self.cfg.unit)
        try:
            return {"transitions": store.transitions(), "events": store.events()}
        finally:
            store.close()

    def _scan_logs(self) -> None:
        for node in (self.ctrl, self.api):
            if node is None or not node.log_path.exists():
                continue
            text = node.log_path.read_text(errors="replace")
            if self.token in text:
                self.errors[f"{node.role} log contains the api token"] += 1
            for line in text.splitlines():
                if " ERROR " in line or " CRITICAL " in line or line.startswith("Traceback"):
                    self.errors[f"{node.role}: {line[:120]}"] += 1

    def _report(self, final_status, history, stored, relay_injected, wall_s, wall_loop,
                t_loop) -> dict:
        from services.machine import machine_description

        lost = list(self.errors_lost)
        if history is None:
            lost.append("the transition history could not be read through the api")
            history = []
        hist_ids = {h["id"] for h in history}
        for tid in self.accepted:
            if tid not in hist_ids:
                lost.append(f"accepted transition {tid} missing from the history")
        events: dict[str, list[str]] = {}
        for ev in stored["events"]:
            events.setdefault(ev["transition_id"], []).append(ev["state"])
        for rec in stored["transitions"]:
            evs = events.get(rec["id"], [])
            if not evs or evs[0] != "pending" or evs[-1] != rec["state"]:
                lost.append(f"transition {rec['id']}: events {evs} do not match its state "
                            f"{rec['state']}")
        stored_ids = {r["id"] for r in stored["transitions"]}
        for tid in self.accepted:
            if tid not in stored_ids:
                lost.append(f"accepted transition {tid} missing from the store")
        states = Counter(h["state"] for h in history if h["id"] in self.accepted)
        faults = Counter(self.injected)
        faults.update(relay_injected)
        # a stall is counted per window (its effect shows in deadline_misses)
        n_stall = sum(1 for w in self.faults if w.kind == "stall"
                      and w.start_s <= (self.plant.t if self.plant else 0.0))
        if n_stall:
            faults["stall"] += n_stall
        st = final_status or {}
        return {
            "process_hours": self.plant.t / 3600.0 if self.plant else 0.0,
            "transitions": {"requested": len(self.accepted), "settled": states["settled"],
                            "aborted": states["aborted"], "failed": states["failed"],
                            "running_at_end": states["running"] + states["pending"]},
            "shutdowns": self.shutdowns,
            "deadline_misses": int(st.get("deadline_misses", -1)),
            "fallback_moves": int(st.get("fallback_moves", -1)),
            "restarts": sum(self.restarts.values()),
            "bumpless_resumes": sum(1 for r in self.resumes if r["bumpless"]),
            "records_lost": len(lost),
            "unhandled_errors": sum(self.errors.values()),
            "faults_injected": dict(sorted(faults.items())),
            "details": {
                "unit": self.cfg.unit, "speed": self.s.speed, "seed": self.s.seed,
                "hours_requested": self.s.hours, "wall_s": wall_s,
                "loop_wall_s": wall_loop,
                "achieved_speed": t_loop / wall_loop if wall_loop > 0 else None,
                "machine": machine_description(),
                "source": _source_version(),
                "restarts_by_node": dict(self.restarts),
                "controller_resumes": self.resumes,
                "transition_resume_checks": self.resume_checks,
                "node_restart_checks": self.node_checks,
                "records_lost": lost,
                "unhandled_errors": dict(self.errors),
                "api_unavailable": self.unavailable,
                "security_probes": dict(self.probes),
                "idv_events": self.idv_log,
                # counters of the controller process running at the end (since its start)
                "controller_since_start": {
                    k: st.get(k) for k in ("samples", "bad_measurements",
                                           "dropped_measurements", "stale_measurements",
                                           "implausible_measurements")},
                "plant_mv_rejected_since_start": (
                    None if self.plant is None or self.plant.node is None
                    else self.plant.node.status()["mv_rejected"]),
                "faults": [f"{w.name}@{w.start_s / 3600:.3f}h-{w.end_s / 3600:.3f}h"
                           f" p={w.probability:g} amount={w.amount:g}" for w in self.faults],
            },
        }


class _Entity:
    def undeclare(self) -> None:
        pass


class _RecordingPublisher(_Entity):
    def __init__(self, puts: list, key: str) -> None:
        self.puts, self.key = puts, key

    def put(self, payload: bytes) -> None:
        self.puts.append((self.key, bytes(payload)))


class _RecordingSession:
    """Stands in for a Zenoh session: records puts, declares nothing on any network."""

    def __init__(self) -> None:
        self.puts: list[tuple[str, bytes]] = []

    def declare_publisher(self, key, **kw):
        return _RecordingPublisher(self.puts, str(key))

    def declare_subscriber(self, key, callback=None, **kw):
        return _Entity()

    def declare_queryable(self, key, callback=None, **kw):
        return _Entity()

    def liveliness(self):
        return self

    def declare_token(self, key, **kw):
        return _Entity()


def bumpless_verdict(moves_before, held, moves_after) -> dict:
    """The bumpless rule on recorded moves (module notes, *bumpless resume*).

    Parameters
    ----------
    moves_before : sequence of (nu,) sequences
        The MVs the controller sent before the kill, oldest first (the last
        :data:`BUMP_WINDOW` + 1 of them).
    held : sequence (nu,)
        The move the plant held when the restarted controller took over.
    moves_after : sequence of dict
        ``{"fallback": bool, "u": (nu,)}`` the restarted controller sent, in order, up to
        its :data:`FIRST_MOVES`-th computed one.

    Returns
    -------
    dict
        ``bumpless`` (bool), ``bound`` (nu,: the largest single-sample move of each MV
        before the kill), ``max_step_ratio`` (largest step after / bound over the MVs
        that moved before), ``worst_mv`` (index, step, bound) and ``why`` when not
        bumpless.
    """
    before = np.asarray(moves_before, dtype=float)
    u_held = np.asarray(held, dtype=float)
    if before.ndim != 2 or len(before) < 2:
        return {"bumpless": False, "why": "fewer than two moves recorded before the kill"}
    if not moves_after:
        return {"bumpless": False, "why": "no move after the restart"}
    bound = np.max(np.abs(np.diff(before, axis=0)), axis=0)
    path = np.vstack([u_held] + [np.asarray(m["u"], dtype=float) for m in moves_after])
    steps = np.max(np.abs(np.diff(path, axis=0)), axis=0)
    allowed = bound + 1e-9 * (1 + np.abs(u_held))
    over = steps - allowed
    worst = int(np.argmax(over))
    moved = bound > 0
    ratio = float(np.max(steps[moved] / bound[moved])) if np.any(moved) else None
    out = {"bumpless": bool(np.all(over <= 0)), "bound": bound.tolist(),
           "max_step_ratio": ratio,
           "worst_mv": {"index": worst, "step": float(steps[worst]),
                        "bound": float(bound[worst])}}
    if not out["bumpless"]:
        out["why"] = (f"MV {worst} stepped {steps[worst]:.6g} after the restart, "
                      f"largest step before {bound[worst]:.6g}")
    return out


def replay_first_move(cfg, store_path: Path, mvs):
    """Restore a controller node from ``store_path`` and replay what a restarted node did.

    ``mvs`` are the MV messages the restarted node published, in order, as
    ``(meas_seq, fallback, measurement payload)`` up to its first computed move. The
    re-asserted move (fallback, answering the restored sample) is skipped; every other
    one answers a measurement the node processed, which the replay processes in the same
    order. Returns ``(u_last of the checkpoint, the move the replay publishes for the
    last measurement or None, number of samples replayed)``. The node runs on a
    :class:`_RecordingSession` at speed 1 (its budget cannot run out; a past-deadline
    step changes only which move goes out, not the controller's state) and writes only
    to ``store_path`` (a copy).
    """
    from services.io.messages import Measurement
    from services.nodes.controller import ControllerNode
    from services.store import UnitStore

    store = UnitStore(store_path, cfg.unit)
    session = _RecordingSession()
    node = None
    try:
        node = ControllerNode(cfg, session, store, None, speed=1.0)
        u_ckpt = node.u_last.copy()
        k0 = node.restored_from
        todo = list(mvs)
        if todo and todo[0][1] and todo[0][0] == k0:
            todo = todo[1:]  # the re-asserted move of the restart
        u = None
        replayed = 0
        for _seq, _fallback, payload, *_ in todo:
            if payload is None:
                return u_ckpt, None, replayed
            n = len(session.puts)
            node.process(time.perf_counter(), Measurement.from_bytes(payload))
            replayed += 1
            moves = [MVMessage.from_bytes(p) for k, p in session.puts[n:] if k.endswith("/mv")]
            u = np.asarray(moves[-1].u, float) if moves else None
        return u_ckpt, u, replayed
    finally:
        if node is not None:
            node.close()
        store.close()


def fault_free_twin(cfg, plant_seed: float, noise: bool, stored: dict, idv_log,
                    until_s: float) -> float | None:
    """The soak's run again offline, without faults, nodes or timing: the same plant
    (seed, noise), the unit's controller, the transition events the controller recorded
    (``running``/``aborted``/``failed`` at their process times) and the same IDV
    switches. Returns the process time of its trip, s, or None if it runs to
    ``until_s`` (TE units only)."""
    from controller.units.config import build_plant
    from services.nodes.plant import make_runner
    from services.registry import build_controller

    runner = make_runner(cfg, noise=noise, seed=plant_seed)
    ctl = build_controller(cfg, build_plant(cfg))
    grade = {r["id"]: r["grade"] for r in stored["transitions"]}
    events = sorted(((e["process_time"], "t", e["state"], grade.get(e["transition_id"]))
                     for e in stored["events"]
                     if e["state"] in ("running", "aborted", "failed")
                     and e["process_time"] is not None),
                    key=lambda e: e[0])
    events += [(ev["t_h"] * 3600.0, "i", ev["idv"], ev["on"]) for ev in idv_log]
    events.sort(key=lambda e: e[0])
    ts = cfg.sample_period_s
    k = 0
    hook = getattr(ctl, "on_transition", None)
    while runner.t < until_s:
        t = runner.t
        while events and events[0][0] <= t + 1e-9:
            _, kind, a, b = events.pop(0)
            if kind == "i":
                runner.set_idv(int(a), bool(b))
            elif hook is not None and b is not None:
                hook(a, b, t)
        d = ctl.step(k, t, runner.y(), None)
        runner.advance(d.u, ts)
        k += 1
        if runner.shutdown:
            return float(runner.t)
    return None


def _source_version() -> dict:
    """The git commit of the code that ran and whether the tree had local changes."""
    root = Path(__file__).resolve().parents[1]
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=root, capture_output=True,
                                text=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=root, capture_output=True, text=True,
                               timeout=10).stdout.rstrip("\n")
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "modified_files": None}
    return {"commit": commit or None,
            "modified_files": sorted(line[3:] for line in dirty.splitlines())}


def run_soak(settings: SoakSettings) -> dict:
    """Run a soak and return its report."""
    return Soak(settings).run()
