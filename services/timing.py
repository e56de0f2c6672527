"""Sample clock in scaled real time, the per-sample timing budget, deadline misses.

At ``speed`` X (process seconds per wall second) a sample period of ``Ts``
process seconds lasts ``Ts / X`` wall seconds. The controller must deliver its
move within ``budget = fraction * Ts / X`` wall seconds of receiving the
measurement; a sample that takes longer is a deadline miss. A miss never stalls
the loop: :class:`Watchdog` publishes the fallback move at the deadline while
the late computation finishes, and the miss is counted.
"""

from __future__ import annotations

import math
import resource
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["TimingBudget", "SampleClock", "DeadlineStats", "SampleTimes", "Watchdog",
           "GC_PAUSES", "percentile_summary", "miss_cause", "MISS_CAUSES", "thread_switches"]

#: Where a missed sample's time went, by its largest part (see :func:`miss_cause`).
MISS_CAUSES = ("queued", "computing", "waiting")


def miss_cause(phases_ms: dict) -> str:
    """The largest part of a sample's time, from its phase breakdown.

    Parameters
    ----------
    phases_ms : dict
        A controller node's phase record (ms): ``queue_ms`` (from arrival to the start
        of processing: decoding, a previous sample still running), ``cpu_ms`` (the
        sample thread's CPU time while processing) and ``waited_ms`` (the rest of the
        processing: waiting for the interpreter lock or for a CPU). The record's
        ``preempted`` and ``blocked`` counts (the thread's involuntary and voluntary
        context switches meanwhile) tell which of the two a "waiting" sample did.

    Returns
    -------
    str
        One of :data:`MISS_CAUSES`: ``"queued"``, ``"computing"`` or ``"waiting"``.
        A sample whose code is the usual one but whose ``cpu_ms`` is several times the
        usual is "computing": on a VM the guest counts time the host takes the vCPU away
        as CPU time.
    """
    parts = {"queued": phases_ms["queue_ms"], "computing": phases_ms["cpu_ms"],
             "waiting": phases_ms["waited_ms"]}
    return max(MISS_CAUSES, key=lambda k: parts[k])


def thread_switches() -> tuple[int, int]:
    """(voluntary, involuntary) context switches of the calling thread so far (Linux;
    (0, 0) where the platform does not count them per thread): the ``blocked`` and
    ``preempted`` counts of a phase record (:func:`miss_cause`)."""
    try:
        ru = resource.getrusage(resource.RUSAGE_THREAD)
    except (AttributeError, OSError):
        return 0, 0
    return ru.ru_nvcsw, ru.ru_nivcsw


def percentile_summary(values, scale: float = 1.0) -> dict | None:
    """``{"p50", "p99", "max", "n"}`` of ``values * scale``; None when there are none."""
    a = np.asarray(values, dtype=float) * scale
    if a.size == 0:
        return None
    p50, p99 = np.percentile(a, [50, 99])
    return {"p50": float(p50), "p99": float(p99), "max": float(a.max()), "n": int(a.size)}


@dataclass(frozen=True)
class TimingBudget:
    """The wall-clock timing of one unit's loop.

    Parameters
    ----------
    sample_period_s : float
        Sample period in process seconds.
    speed : float
        Process seconds per wall second (1 = real time).
    fraction : float
        Share of the wall-clock sample period the controller may use, in (0, 1].
    """

    sample_period_s: float
    speed: float = 1.0
    fraction: float = 0.5

    def __post_init__(self) -> None:
        if not (math.isfinite(self.sample_period_s) and self.sample_period_s > 0):
            raise ValueError(f"sample_period_s: must be positive, got {self.sample_period_s}")
        if not (math.isfinite(self.speed) and self.speed > 0):
            raise ValueError(f"speed: must be positive (process s per wall s), got {self.speed}")
        if not (0 < self.fraction <= 1):
            raise ValueError(f"fraction: budget fraction must be in (0, 1], got {self.fraction}")

    @property
    def wall_period_s(self) -> float:
        """Wall-clock length of one sample, s."""
        return self.sample_period_s / self.speed

    @property
    def budget_s(self) -> float:
        """Wall-clock time the controller may spend on one sample, s."""
        return self.fraction * self.wall_period_s


class SampleClock:
    """Boundaries ``start + k * period`` on the monotonic clock.

    :meth:`wait_next` sleeps until the next boundary. If the caller fell more
    than one period behind, the clock does not burst to catch up: it re-anchors
    at now and counts the skipped boundaries in :attr:`overruns`.
    """

    def __init__(self, wall_period_s: float, *, start: float | None = None,
                 now: Callable[[], float] = time.perf_counter) -> None:
        if not wall_period_s > 0:
            raise ValueError(f"wall_period_s: must be positive, got {wall_period_s}")
        self.period = float(wall_period_s)
        self._now = now
        self.start = now() if start is None else float(start)
        self.k = 0
        self.overruns = 0

    def deadline(self, k: int | None = None) -> float:
        return self.start + (self.k if k is None else k) * self.period

    def wait_next(self, stop: threading.Event | None = None,
                  poll: Callable[[], object] | None = None) -> int:
        """Advance to the next boundary and wait until it; return its index k.

        Sleeps, or with ``poll`` calls ``poll()`` over and over until the boundary
        (or until ``stop`` is set) instead of sleeping: a sleeping thread's wake-up
        can come milliseconds late on a virtual machine (``docs/realtime.md``).
        """
        self.k += 1
        target = self.deadline()
        now = self._now()
        if now - target > self.period:
            skipped = int((now - target) // self.period)
            self.overruns += skipped
            self.start = now - self.k * self.period
            return self.k
        if poll is not None:
            while self._now() < target and not (stop is not None and stop.is_set()):
                poll()
            return self.k
        delay = target - now
        if delay > 0:
            if stop is not None:
                stop.wait(delay)
            else:
                time.sleep(delay)
        return self.k


class DeadlineStats:
    """Count samples and deadline misses; keep the compute times of the last samples."""

    #: How many of the latest missed samples keep their phase breakdown.
    KEEP_MISSED = 32

    def __init__(self, budget_s: float, keep: int = 4096) -> None:
        self.budget_s = float(budget_s)
        self.samples = 0
        self.misses = 0
        self.fallbacks = 0
        self.last_ms = 0.0
        self.max_ms = 0.0
        self._keep = keep
        self.recent_ms: list[float] = []
        self.worst: dict | None = None  # phase breakdown of the slowest sample (ms)
        #: phase breakdowns of the last :attr:`KEEP_MISSED` samples over budget (ms)
        self.missed: deque[dict] = deque(maxlen=self.KEEP_MISSED)

    def record(self, elapsed_s: float, *, fallback: bool = False) -> bool:
        """Record one sample's compute time; return True if it missed the budget."""
        self.samples += 1
        ms = elapsed_s * 1e3
        self.last_ms = ms
        self.max_ms = max(self.max_ms, ms)
        self.recent_ms.append(ms)
        if len(self.recent_ms) > self._keep:
            del self.recent_ms[: len(self.recent_ms) - self._keep]
        missed = elapsed_s > self.budget_s
        if missed:
            self.misses += 1
        if fallback:
            self.fallbacks += 1
        return missed

    def slack_ms(self, elapsed_s: float) -> float:
        """Budget left over (negative on a miss), ms."""
        return (self.budget_s - elapsed_s) * 1e3

    def keeps(self, elapsed_s: float) -> bool:
        """Whether :meth:`note_phases` would keep a sample of ``elapsed_s``: the slowest
        so far or over budget (the caller builds the phase record only then)."""
        return (self.worst is None or elapsed_s * 1e3 > self.worst["total_ms"]
                or elapsed_s > self.budget_s)

    def note_phases(self, elapsed_s: float, phases_ms: dict) -> None:
        """Keep ``phases_ms`` (name -> ms) if this is the slowest sample so far, and
        among :attr:`missed` if it was over budget: where a miss came from (waiting for
        the loop thread, the controller, publishing; computing or waiting)."""
        ms = elapsed_s * 1e3
        record = None
        if self.worst is None or ms > self.worst["total_ms"]:
            record = {"total_ms": ms, **{k: float(v) for k, v in phases_ms.items()}}
            self.worst = record
        if elapsed_s > self.budget_s:
            self.missed.append(record or {"total_ms": ms,
                                          **{k: float(v) for k, v in phases_ms.items()}})

    def percentiles_ms(self) -> dict:
        """p50/p99/max of the kept compute times, ms (None before the first sample)."""
        return (percentile_summary(self.recent_ms)
                or {"p50": None, "p99": None, "max": None, "n": 0})

    def as_dict(self) -> dict:
        return {"samples": self.samples, "deadline_misses": self.misses,
                "fallback_moves": self.fallbacks, "last_ms": self.last_ms,
                "max_ms": self.max_ms, "budget_ms": self.budget_s * 1e3}


class SampleTimes:
    """When each of the latest samples arrived and when its move went out.

    A ring of the last ``capacity`` samples: sequence number, arrival and
    publication on ``time.perf_counter`` (CLOCK_MONOTONIC on Linux: the same clock in
    every process of one host, so a plant node's record of a sample can be set beside
    this one). One :meth:`note` per sample, ~1 us.

    Parameters
    ----------
    capacity : int
        Samples kept (default 32,768: a minute at 10,000x for TE).
    """

    #: Most samples one :meth:`lookup` answers.
    MAX_LOOKUP = 256

    def __init__(self, capacity: int = 32768) -> None:
        if capacity < 1:
            raise ValueError(f"capacity: must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self._seq = np.full(self.capacity, -1, dtype=np.int64)
        self._t = np.zeros((self.capacity, 2))

    def note(self, seq: int, arrived_s: float, published_s: float) -> None:
        """Record sample ``seq`` (>= 0): measurement arrival and move publication, s."""
        i = seq % self.capacity
        self._seq[i] = seq
        self._t[i, 0] = arrived_s
        self._t[i, 1] = published_s

    def lookup(self, seqs) -> dict[int, dict[str, float]]:
        """The records of the given samples still in the ring: seq -> ``arrived_s``,
        ``published_s``. Unknown or overwritten samples are left out.

        Raises
        ------
        ValueError
            ``seqs`` is not a list of at most :attr:`MAX_LOOKUP` integers >= 0.
        """
        if not isinstance(seqs, list) or len(seqs) > self.MAX_LOOKUP or not all(
                isinstance(k, int) and not isinstance(k, bool) and k >= 0 for k in seqs):
            raise ValueError(f"seqs: expected a list of at most {self.MAX_LOOKUP} sample "
                             "numbers >= 0")
        out = {}
        for k in seqs:
            i = k % self.capacity
            if self._seq[i] == k:
                out[k] = {"arrived_s": float(self._t[i, 0]), "published_s": float(self._t[i, 1])}
        return out


class Watchdog:
    """Run ``action`` at a wall-clock deadline unless disarmed first.

    One background thread serves all samples. :meth:`arm` sets the deadline
    (absolute, ``time.perf_counter`` seconds) and the action; :meth:`disarm`
    returns True if the deadline has passed (the sample missed): the action has fired,
    or, where the thread has not got to it yet (a loaded machine's scheduler, the
    jitter slack below), it runs in the disarming thread then, so a result that comes
    after its deadline is never taken for one in time.

    Parameters
    ----------
    period_hint_s : float, optional
        The expected wall time between arms (the sample period). With it, the
        thread, once disarmed, sleeps until the next deadline the period predicts
        and :meth:`arm` wakes it only when its deadline comes earlier than that:
        in a periodic loop the thread then wakes once per sample at the deadline,
        when the loop thread is normally idle, instead of at the start of every
        step, where waking it takes the interpreter lock from the step.
        ``n_notified`` counts the wake-ups :meth:`arm` had to request. A deadline
        less than :attr:`JITTER_FRACTION` of the period before the predicted wake-up
        does not request one: the fallback then goes out at most that much late
        (the sample is counted as missed either way).
    """

    JITTER_FRACTION = 0.05

    def __init__(self, period_hint_s: float | None = None) -> None:
        if period_hint_s is not None and not (math.isfinite(period_hint_s)
                                              and period_hint_s > 0):
            raise ValueError(f"period_hint_s: must be a positive number of seconds, got "
                             f"{period_hint_s!r}")
        self._cond = threading.Condition()
        self._period = period_hint_s
        # a deadline this little before the predicted wake-up fires that much late
        # rather than costing a wake-up (arrival jitter)
        self._slack = 0.0 if period_hint_s is None else self.JITTER_FRACTION * period_hint_s
        self._deadline: float | None = None
        self._last_deadline: float | None = None
        self._wake_at = math.inf  # when the thread wakes next (it holds no lock then)
        self._action: Callable[[], None] | None = None
        self._fired = False
        self._closed = False
        self.n_notified = 0
        self._thread = threading.Thread(target=self._run, name="ssmpc-watchdog", daemon=True)
        self._thread.start()

    def arm(self, deadline: float, action: Callable[[], None]) -> None:
        with self._cond:
            self._deadline = deadline
            self._last_deadline = deadline
            self._action = action
            self._fired = False
            if deadline < self._wake_at - self._slack:
                self.n_notified += 1
                self._cond.notify()

    def disarm(self) -> bool:
        late = None
        with self._cond:
            fired = self._fired
            if not fired and self._deadline is not None \
                    and time.perf_counter() >= self._deadline:
                late, fired = self._action, True
                self._fired = True
            self._deadline = None
            self._action = None
        if late is not None:
            try:
                late()
            except Exception:  # as in the thread: a failing fallback is not the step's
                pass
        return fired

    def close(self) -> None:
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._thread.join(timeout=1.0)

    def _idle_wait(self, now: float) -> None:
        if self._period is None or self._last_deadline is None:
            self._wake_at = math.inf
            self._cond.wait()
            return
        # the next deadline the period predicts (skipping any already past)
        n = math.floor((now - self._last_deadline) / self._period) + 1
        self._wake_at = self._last_deadline + max(n, 1) * self._period
        self._cond.wait(self._wake_at - now)

    def _run(self) -> None:
        with self._cond:
            while not self._closed:
                now = time.perf_counter()
                if self._deadline is None:
                    self._idle_wait(now)
                    continue
                delay = self._deadline - now
                if delay > 0:
                    self._wake_at = self._deadline
                    self._cond.wait(delay)
                    continue
                self._wake_at = math.inf
                action = self._action
                self._deadline = None
                self._action = None
                self._fired = True
                if action is not None:
                    try:
                        action()
                    except Exception:  # a failing fallback must not kill the watchdog
                        pass


class GCPauses:
    """Pauses of the cyclic garbage collector, per generation (a source of deadline
    misses that the phase breakdown cannot name). :meth:`install` once per process."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._t0 = 0.0
        self.installed = False
        self.reset()

    def reset(self) -> None:
        with self._lock:
            self.count = [0, 0, 0]
            self.max_ms = [0.0, 0.0, 0.0]
            self.total_ms = [0.0, 0.0, 0.0]

    def install(self) -> None:
        import gc

        if not self.installed:
            gc.callbacks.append(self._callback)
            self.installed = True

    def _callback(self, phase: str, info: dict) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
            return
        ms = (time.perf_counter() - self._t0) * 1e3
        g = min(int(info.get("generation", 2)), 2)
        with self._lock:
            self.count[g] += 1
            self.total_ms[g] += ms
            self.max_ms[g] = max(self.max_ms[g], ms)

    def as_dict(self) -> dict | None:
        if not self.installed:
            return None
        with self._lock:
            return {f"gen{g}": {"count": self.count[g], "max_ms": self.max_ms[g],
                                "total_ms": self.total_ms[g]} for g in range(3)}


#: The process's collector pauses (installed by the nodes' real-time tuning).
GC_PAUSES = GCPauses()
