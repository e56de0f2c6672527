"""Grade transitions: state machine, first-order reference, progress, ISE so far, ETA.

A transition moves the controlled variables from the current set points
``r0`` to the set points of a grade ``r1`` along a first-order trajectory
(the seed's transitions, ch. 5–7)::

    r(t) = r1 + (r0 - r1) * exp(-(t - t0) / tau),   tau = duration / 4

so that 98 % of the move is done after ``duration``. States::

    pending ──▶ running ──▶ settled
       │           ├──────▶ aborted   (DELETE: hold the set points of that moment)
       └───────────┴──────▶ failed    (plant shutdown, or not settled by timeout)

A request while one is pending or running is refused (409) unless queued: a
queued transition stays ``pending`` and starts when the ones before it end. At most
``max_queued`` wait; one more is refused (:class:`QueueFullError`, REST 429).

A request may carry an idempotency key (REST ``Idempotency-Key``): it is kept in
the record (``idempotency``: the key and the request it came with), so the node can
give back the transition a repeated request made instead of a second one.

``settled`` means: the reference has reached ``r1`` (t ≥ t0 + duration) and
every CV stayed within ``settle_tolerance * scale`` of ``r1`` for
``settle_samples`` consecutive samples. ``progress`` is the share of the set
point distance the measured CVs have covered (mean over the CVs that move,
clipped to [0, 1]; 1 once settled). ``ise`` is the integral of the squared
scaled tracking error ``sum_i ((y_i - r_i) / scale_i)^2 dt`` in process seconds.
``eta_s`` is the process time left until the planned end (None when over).
"""

from __future__ import annotations

import math
import uuid
from dataclasses import asdict, dataclass, field

import numpy as np

from controller.readback import finite_number, finite_vector

__all__ = [
    "STATES",
    "TERMINAL",
    "TransitionError",
    "ConflictError",
    "QueueFullError",
    "UnknownTransition",
    "Transition",
    "TransitionManager",
]

STATES = ("pending", "running", "settled", "aborted", "failed")
TERMINAL = frozenset({"settled", "aborted", "failed"})
_ALLOWED = {
    "pending": {"running", "aborted", "failed"},
    "running": {"settled", "aborted", "failed"},
}


class TransitionError(ValueError):
    """A transition request that cannot be honoured (the message names the field)."""


class ConflictError(TransitionError):
    """A transition is already pending or running (REST 409)."""


class QueueFullError(TransitionError):
    """Too many transitions wait already (REST 429)."""


class UnknownTransition(TransitionError):
    """No transition with that id (REST 404)."""


@dataclass
class Transition:
    """One transition's record (JSON-serialisable via :meth:`as_dict`)."""

    id: str
    unit: str
    grade: str
    from_grade: str | None
    target: list[float]
    duration_s: float
    requested_t: float
    state: str = "pending"
    start_ref: list[float] = field(default_factory=list)
    started_t: float | None = None
    ended_t: float | None = None
    ise: float = 0.0
    progress: float = 0.0
    in_band_samples: int = 0
    samples: int = 0
    detail: str = ""
    #: ``{"key", "grade", "duration_s", "queue"}`` of a request with an idempotency key
    idempotency: dict | None = None

    @property
    def terminal(self) -> bool:
        return self.state in TERMINAL

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> Transition:
        names = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in d.items() if k in names})

    def eta_s(self, t: float) -> float | None:
        """Process seconds until the planned end; None when terminal or not started."""
        if self.terminal:
            return None
        start = self.started_t if self.started_t is not None else t
        return max(0.0, start + self.duration_s - t)

    def view(self, t: float, speed: float | None = None) -> dict:
        """What the REST GET shows: state, progress, ISE so far, ETA."""
        eta = self.eta_s(t)
        out = {
            "id": self.id, "unit": self.unit, "grade": self.grade, "from_grade": self.from_grade,
            "state": self.state, "progress": self.progress, "ise": self.ise,
            "eta_s": eta, "eta_wall_s": None if eta is None or not speed else eta / speed,
            "duration_s": self.duration_s, "requested_t": self.requested_t,
            "started_t": self.started_t, "ended_t": self.ended_t, "target": self.target,
            "detail": self.detail,
        }
        return out


class TransitionManager:
    """Set points of one unit and the transition that moves them.

    Parameters
    ----------
    unit : str
        Unit name.
    grades : dict of str to sequence of float
        Set points (CV values, shape (ny,)) of each grade.
    scales : sequence of float, shape (ny,)
        Engineering scale of each CV, used for the settle band and the ISE.
    initial_grade : str
        Grade whose set points hold at start.
    sample_period_s : float
        Process seconds per sample (integration step of the ISE).
    default_duration_s : float
        Duration used when a request gives none.
    settle_tolerance : float
        Band half-width as a fraction of ``scales``.
    settle_samples : int
        Consecutive in-band samples needed to settle.
    timeout_factor : float
        A running transition fails if not settled by ``t0 + timeout_factor * duration``.
    max_queued : int
        Transitions that may wait behind the one under way.
    """

    def __init__(self, unit: str, grades: dict[str, list[float]], scales, initial_grade: str,
                 sample_period_s: float, default_duration_s: float,
                 settle_tolerance: float = 0.02, settle_samples: int = 5,
                 timeout_factor: float = 3.0, max_queued: int = 8) -> None:
        if initial_grade not in grades:
            raise TransitionError(f"initial_grade: unknown grade {initial_grade!r}")
        self.unit = unit
        self.grades = {k: np.asarray(v, dtype=float) for k, v in grades.items()}
        self.scales = np.asarray(scales, dtype=float)
        if np.any(~np.isfinite(self.scales)) or np.any(self.scales <= 0):
            raise TransitionError("scales: must be positive and finite")
        self.Ts = float(sample_period_s)
        self.default_duration_s = float(default_duration_s)
        self.settle_tolerance = float(settle_tolerance)
        self.settle_samples = int(settle_samples)
        self.timeout_factor = float(timeout_factor)
        if isinstance(max_queued, bool) or not isinstance(max_queued, int) or max_queued < 0:
            raise TransitionError(f"max_queued: must be an integer >= 0, got {max_queued!r}")
        self.max_queued = max_queued
        self.grade: str | None = initial_grade
        self.hold = self.grades[initial_grade].copy()
        self.active: Transition | None = None
        #: transitions requested with ``queue=True`` while another was under way
        self.queued: list[Transition] = []

    # -- requests ------------------------------------------------------------------
    def request(self, grade: str, t: float, duration_s: float | None = None,
                queue: bool = False, idempotency: dict | None = None) -> Transition:
        """Create a pending transition to ``grade`` (:meth:`prepare`, then :meth:`admit`).

        While one is pending or running: 409 (:class:`ConflictError`), unless
        ``queue`` — then it waits (``pending``) and starts when the ones before it end,
        or 429 (:class:`QueueFullError`) when ``max_queued`` wait already.
        ``idempotency`` is kept in the record as it is.
        """
        tr = self.prepare(grade, t, duration_s, queue, idempotency)
        self.admit(tr)
        return tr

    def prepare(self, grade: str, t: float, duration_s: float | None = None,
                queue: bool = False, idempotency: dict | None = None) -> Transition:
        """The transition :meth:`request` would make, checked but not admitted yet: the
        caller may store it first and :meth:`admit` it once it is committed, so a
        transition that was never stored never starts."""
        if grade not in self.grades:
            raise UnknownTransition(
                f"grade: unknown grade {grade!r} for unit {self.unit!r}; "
                f"known: {', '.join(self.grades)}")
        busy = self.active is not None and not self.active.terminal
        if busy and not queue:
            raise ConflictError(
                f"transition {self.active.id} to {self.active.grade} is {self.active.state}; "
                "abort it first, or queue this one")
        if busy and len(self.queued) >= self.max_queued:
            raise QueueFullError(
                f"queue: {len(self.queued)} transitions wait already (the limit, "
                "transition_queue_limit); retry when one has started")
        duration = self.default_duration_s if duration_s is None else float(duration_s)
        if not (math.isfinite(duration) and duration > 0):
            raise TransitionError(f"duration_h: must be positive, got {duration_s}")
        tr = Transition(id=uuid.uuid4().hex[:12], unit=self.unit, grade=grade,
                        from_grade=None if busy else self.grade,
                        target=self.grades[grade].tolist(), duration_s=duration,
                        requested_t=float(t), idempotency=idempotency)
        if busy:
            tr.detail = "queued"
        return tr

    def admit(self, tr: Transition) -> None:
        """Make a :meth:`prepare` d transition active, or queue it behind the one under
        way (it starts when the ones before it end)."""
        if tr.detail == "queued" or (self.active is not None and not self.active.terminal):
            tr.detail = "queued"
            self.queued.append(tr)
        else:
            self.active = tr

    def find(self, tid: str) -> Transition | None:
        """The active or a queued transition with this id."""
        if self.active is not None and self.active.id == tid:
            return self.active
        return next((q for q in self.queued if q.id == tid), None)

    def find_by_key(self, key: str) -> Transition | None:
        """The active or a queued transition made by a request with idempotency ``key``."""
        for tr in ([self.active] if self.active is not None else []) + self.queued:
            if tr.idempotency is not None and tr.idempotency.get("key") == key:
                return tr
        return None

    def abort(self, tid: str, t: float) -> Transition:
        """Abort: hold the set points of this moment. Aborting a finished one is a no-op;
        aborting a queued one just takes it out of the queue."""
        for q in self.queued:
            if q.id == tid:
                self.queued.remove(q)
                q.state, q.ended_t, q.detail = "aborted", float(t), "aborted while queued"
                return q
        tr = self.active
        if tr is None or tr.id != tid:
            raise UnknownTransition(f"id: no active transition {tid!r}")
        if tr.terminal:
            return tr
        self.hold = self.reference_at(t)[0].copy()
        self.grade = None
        self._end(tr, "aborted", t, "aborted by request; set points held")
        return tr

    def fail(self, t: float, reason: str) -> Transition | None:
        tr = self.active
        if tr is None or tr.terminal:
            return None
        self.hold = self.reference_at(t)[0].copy()
        self.grade = None
        self._end(tr, "failed", t, reason)
        return tr

    # -- per sample ----------------------------------------------------------------
    def reference_at(self, t: float, horizon: int = 1) -> np.ndarray:
        """Set points over ``horizon`` samples from ``t``, shape (horizon, ny)."""
        tr = self.active
        if tr is None or tr.state != "running":
            return np.tile(self.hold, (horizon, 1))
        times = t + self.Ts * np.arange(horizon)
        r0 = np.asarray(tr.start_ref)
        r1 = np.asarray(tr.target)
        tau = tr.duration_s / 4.0
        decay = np.exp(-np.clip(times - tr.started_t, 0.0, None) / tau)[:, None]
        return r1 + (r0 - r1) * decay

    def update(self, t: float, y) -> list[tuple[Transition, str]]:
        """Advance the active transition with the measurement ``y`` at process time ``t``.

        Returns the state changes that happened, as ``(transition, new_state)``.
        """
        changes: list[tuple[Transition, str]] = []
        tr = self.active
        if (tr is None or tr.terminal) and self.queued:
            tr = self.active = self.queued.pop(0)
            tr.from_grade = self.grade
        if tr is None or tr.terminal:
            return changes
        y = np.asarray(y, dtype=float)
        if tr.state == "pending":
            tr.start_ref = self.hold.tolist()
            tr.started_t = float(t)
            tr.state = "running"
            if tr.detail == "queued":
                tr.detail = ""
            changes.append((tr, "running"))
        r = self.reference_at(t)[0]
        err = (y - r) / self.scales
        tr.ise += float(err @ err) * self.Ts
        tr.samples += 1
        r0 = np.asarray(tr.start_ref)
        r1 = np.asarray(tr.target)
        span = r1 - r0
        moving = np.abs(span) > 1e-12 * self.scales
        if np.any(moving):
            covered = np.clip((y[moving] - r0[moving]) / span[moving], 0.0, 1.0)
            tr.progress = float(np.mean(covered))
        else:
            tr.progress = 1.0
        in_band = bool(np.all(np.abs(y - r1) <= self.settle_tolerance * self.scales))
        tr.in_band_samples = tr.in_band_samples + 1 if in_band else 0
        if t >= tr.started_t + tr.duration_s and tr.in_band_samples >= self.settle_samples:
            tr.progress = 1.0
            self.hold = r1.copy()
            self.grade = tr.grade
            self._end(tr, "settled", t, "")
            changes.append((tr, "settled"))
        elif t > tr.started_t + self.timeout_factor * tr.duration_s:
            self.fail(t, f"not settled within {self.timeout_factor:g} x duration")
            changes.append((tr, "failed"))
        return changes

    def _end(self, tr: Transition, state: str, t: float, detail: str) -> None:
        if state not in _ALLOWED.get(tr.state, set()):
            raise TransitionError(f"state: cannot go from {tr.state} to {state}")
        tr.state = state
        tr.ended_t = float(t)
        tr.detail = detail

    # -- persistence ---------------------------------------------------------------
    def checkpoint(self) -> dict:
        return {"grade": self.grade, "hold": self.hold.tolist(),
                "active": None if self.active is None else self.active.as_dict(),
                "queued": [q.as_dict() for q in self.queued]}

    def restore(self, state: dict) -> None:
        """Take :meth:`checkpoint`'s state back, checked whole before any of it is used.

        Raises
        ------
        ValueError
            An entry does not fit this unit: the grade is not one of its grades, the
            held set points are not ``ny`` finite numbers, or a transition's record is
            damaged (:meth:`checked_record`). The controller node refuses such a checkpoint.
        """
        grade = state.get("grade")
        if grade is not None and grade not in self.grades:
            raise ValueError(f"transitions: unknown grade {grade!r}")
        hold = finite_vector(state["hold"], self.hold.size, "transitions: hold")
        active = state.get("active")
        active = None if active is None else self.checked_record(active)
        queued = state.get("queued", [])
        if not isinstance(queued, list):
            raise ValueError("transitions: queued: expected a list")
        queued = [self.checked_record(q) for q in queued]
        self.grade, self.hold, self.active, self.queued = grade, hold, active, queued

    def checked_record(self, d) -> Transition:
        """A transition's record read back (a checkpoint's, the store's) as a
        :class:`Transition` of this unit; ``ValueError`` naming what is damaged:
        its state, grade, target and start (``ny`` finite numbers; the start empty until
        it starts), its duration (finite, > 0), its times and counts."""
        if not isinstance(d, dict):
            raise ValueError("transitions: a transition is not a mapping")
        tr = Transition.from_dict(d)  # TypeError: a field missing
        ny = self.hold.size
        where = f"transitions: {tr.id!r}"
        if tr.state not in STATES:
            raise ValueError(f"{where}: unknown state {tr.state!r}")
        if tr.grade not in self.grades:
            raise ValueError(f"{where}: unknown grade {tr.grade!r}")
        if tr.from_grade is not None and tr.from_grade not in self.grades:
            raise ValueError(f"{where}: unknown from_grade {tr.from_grade!r}")
        tr.target = finite_vector(tr.target, ny, f"{where}: target").tolist()
        # a transition that started has its start; one aborted or failed while it
        # waited has none
        if tr.started_t is not None or tr.state in ("running", "settled") or tr.start_ref:
            tr.start_ref = finite_vector(tr.start_ref, ny, f"{where}: start_ref").tolist()
        if not (finite_number(tr.duration_s) and tr.duration_s > 0):
            raise ValueError(f"{where}: duration_s must be a positive number")
        for name in ("requested_t", "ise", "progress"):
            if not finite_number(getattr(tr, name)):
                raise ValueError(f"{where}: {name} must be a finite number")
        for name in ("started_t", "ended_t"):
            v = getattr(tr, name)
            if v is not None and not finite_number(v):
                raise ValueError(f"{where}: {name} must be a finite number or null")
        if tr.state == "running" and tr.started_t is None:
            raise ValueError(f"{where}: running without started_t")
        for name in ("in_band_samples", "samples"):
            v = getattr(tr, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise ValueError(f"{where}: {name} must be a whole number >= 0")
        if not isinstance(tr.id, str) or not isinstance(tr.detail, str):
            raise ValueError(f"{where}: id and detail must be text")
        if tr.idempotency is not None and not isinstance(tr.idempotency, dict):
            raise ValueError(f"{where}: idempotency must be a mapping or null")
        return tr
