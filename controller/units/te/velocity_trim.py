"""A velocity-form PI trim of one MPC input target (the TE cascade's outer loops).

The MPC strategies' outer loops (production, A in the reactor feed, separator
temperature; :mod:`controller.units.te.control`) each add a trim to one of the core's
input targets. Each is the velocity form of a PI on ``e = r - y``:

    trim_k = clip(trim_{k-1} + K ((e_k - e_{k-1}) + dt / Ti e_k) - dt / Tw trim_{k-1}, lo, hi)

held (trim and integral kept, the error still followed, so a release gives no
proportional kick) when its loop says so. ``e_{k-1}`` is None after a start or a
take-over: the first sample is its own previous error. ``Tw`` is a washout time
(infinite for a plain PI): with it the trim decays toward 0, held or not, and the
loop acts on the error's variation over hours, not on its mean, which is left to
the loops and targets that set the handle's steady value (the production loop on
the condenser, :data:`controller.units.te.control.PRODUCTION_CONDENSER_LOOP`).
"""

from __future__ import annotations

import math


class VelocityTrim:
    """One trim and its previous error.

    Parameters
    ----------
    lo, hi : float
        The trim's range (units of the target it trims: % of valve).
    washout_h : float
        Time constant of the trim's decay toward 0, h (> 0; ``math.inf``: none). It
        goes on while the loop is held.
    """

    def __init__(self, lo: float, hi: float, washout_h: float = math.inf) -> None:
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ValueError(f"lo/hi: need finite lo <= hi, got {lo!r}, {hi!r}")
        if not washout_h > 0:
            raise ValueError(f"washout_h: need > 0 h (inf: none), got {washout_h!r}")
        self.lo, self.hi = float(lo), float(hi)
        self.washout_h = float(washout_h)
        self.value = 0.0
        self.e_prev: float | None = None

    def step(self, e: float, gain: float, ti_h: float, dt_h: float, held: bool) -> float:
        """Follow the error ``e`` (finite) for one sample of ``dt_h`` h and return the
        trim; ``held``: keep the trim (but for its washout)."""
        if self.e_prev is None:
            self.e_prev = e
        # a washout goes on while the loop is held: what the loop answered is gone
        self.value -= dt_h / self.washout_h * self.value
        if not held:
            self.value += gain * ((e - self.e_prev) + dt_h / ti_h * e)
        self.value = min(max(self.value, self.lo), self.hi)
        self.e_prev = e
        return self.value
