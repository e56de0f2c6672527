"""Ramp-in after a take-over: a restarted controller node moves each MV away from the
move the plant holds no faster than that MV moved before the restart.

Why. A controller node killed and restarted finds the plant on the move it held
meanwhile (zero-order hold, as a DCS does). The restored law starts from that move
(:func:`controller.units.takeover.align_multimodel`), but its other terms have gone on
in process time while nobody controlled: the grade plan's ramps and input targets, the
D share's feedforward, the MPC's predictions from a shared state re-initialized at the
current sample. Measured on TE (mode 0 -> 2, a restart 100 samples after the
checkpoint, offline): the first move jumped by 35.8 % on XMV2, 20 kPa (the MPC's rate
limit) on the reactor pressure set point, 11.7 % on XMV9, against largest steps of 2.8
%, 0.29 kPa and 0.15 % in the 20 samples before.

What. The node keeps its last :data:`STEP_WINDOW` + 1 published moves and
stores the largest single-sample step of each MV in its checkpoint and, every sample
(at most every 50 wall ms), in a row of its own (``UnitStore.save_recent_steps``; the
checkpoint waits for a sample with slack, up to 10 wall s). After a resume on
a running plant, each move is limited to that step from the previous one (an MV that
did not move at all before gets :data:`FLOOR_FRACTION` of its instrument range, so that
it is not frozen), and the controller is told the move the plant got
(``applied``), so the law goes on from it. The ramp-in lasts at least
:data:`MIN_SAMPLES` samples (a law re-initialized at the take-over can want a large move
again after one that happened to be small) and ends at the first sample after them
whose move is within the steps of every MV. Bumpless transfer with a rate-limited output is
the DCS practice for a controller put back in automatic.
"""

from __future__ import annotations

from collections import deque

import numpy as np

__all__ = ["FLOOR_FRACTION", "MIN_SAMPLES", "STEP_WINDOW", "MoveHistory", "RampIn"]

#: Step per sample of the ramp-in for an MV that did not move before the restart, as a
#: fraction of its instrument range (TE: 0.05 % of a valve, 0.225 kPa of the reactor
#: pressure set point).
FLOOR_FRACTION = 5e-4
#: Steps looked back for the ramp-in's limits: a quarter of the 20 samples of the
#: bumpless rule, so that a record written up to 15 samples before the kill (the store's
#: writes run behind the loop, at most one every 50 wall ms, and a SIGKILL loses the
#: queued ones) still lies within the rule's window and its largest step is no larger
#: than the rule's bound. A record's window reaching back before the rule's allowed,
#: while a transition's moves shrank, steps above the rule's bound on six or more of the
#: 12 TE MVs: with the whole 20 at every kill at 1800x, with 10 once in about ten
#: loaded runs (a record 11 samples behind).
STEP_WINDOW = 5
#: Fewest samples the ramp-in lasts after a take-over.
MIN_SAMPLES = 20


class MoveHistory:
    """The last ``window + 1`` moves and their largest single-sample steps.

    Parameters
    ----------
    nu : int
        Number of MVs.
    window : int
        Steps looked back (20: the bumpless rule's window).
    """

    def __init__(self, nu: int, window: int = 20) -> None:
        if window < 1:
            raise ValueError(f"window: must be >= 1 sample, got {window}")
        self.nu = int(nu)
        self.window = int(window)
        self._moves: deque[np.ndarray] = deque(maxlen=self.window + 1)

    def append(self, u) -> None:
        """One published move, shape (nu,)."""
        self._moves.append(np.asarray(u, dtype=float).copy())

    def steps(self) -> np.ndarray | None:
        """Largest ``|u_k - u_(k-1)|`` per MV over the window, shape (nu,); None with
        fewer than two moves."""
        if len(self._moves) < 2:
            return None
        return np.max(np.abs(np.diff(np.asarray(self._moves), axis=0)), axis=0)


class RampIn:
    """Rate limit on the moves after a take-over (module notes).

    Parameters
    ----------
    steps : array_like (nu,)
        Largest step per sample of each MV before the restart (finite, >= 0).
    span : array_like (nu,)
        Instrument range of each MV (hi - lo); an MV whose step is 0 gets
        ``FLOOR_FRACTION * span`` (an infinite or unknown span: it stays frozen until the
        controller's move is the held one).
    """

    def __init__(self, steps, span) -> None:
        steps = np.asarray(steps, dtype=float).reshape(-1)
        span = np.asarray(span, dtype=float).reshape(-1)
        if steps.shape != span.shape or not np.all(np.isfinite(steps)) or np.any(steps < 0):
            raise ValueError(f"steps: expected {span.size} finite values >= 0, got {steps!r}")
        floor = np.where(np.isfinite(span) & (span > 0), FLOOR_FRACTION * span, 0.0)
        self.steps = np.where(steps > 0, steps, floor)
        self.samples = 0  # moves limited so far
        self.seen = 0  # moves asked for so far
        self.done = False

    def limit(self, u, previous) -> np.ndarray:
        """The move to send: ``u`` moved toward from ``previous`` by at most the steps.

        A ``u`` within the steps of ``previous`` for every MV is sent as it is; the first
        one after :data:`MIN_SAMPLES` moves ends the ramp-in (:attr:`done`)."""
        u = np.asarray(u, dtype=float)
        previous = np.asarray(previous, dtype=float)
        delta = u - previous
        self.seen += 1
        if np.all(np.abs(delta) <= self.steps):
            self.done = self.seen >= MIN_SAMPLES
            return u
        self.samples += 1
        return previous + np.clip(delta, -self.steps, self.steps)
