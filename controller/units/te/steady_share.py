"""The share in force of a steady-grade action: it ramps in after a grade change, out while held.

Two of the cascade's actions at a steady grade, the pressure loop's lead
(:mod:`controller.units.te.pressure_gain`) and the A+C feed's balance trim
(:mod:`controller.units.te.feed_balance`), act through a share ``s`` in [0, 1]::

    s(k+1) = min(s(k) + T / ramp_h, 1)    while steady (long enough after the grade
                                          change, and nothing holds the action)
    s(k+1) = max(s(k) - T / ramp_h, 0)    otherwise

with ``T`` the caller's sample, h. Neither action steps in or out: each enters and
leaves over ``ramp_h``. This is bookkeeping of the product's own, not an equation of the
seed; its limits are those of float arithmetic (``s`` stays in [0, 1] exactly, and a
sample longer than ``ramp_h`` moves it all the way in one step).
"""

from __future__ import annotations

__all__ = ["ramp_share"]


def ramp_share(share: float, steady: bool, sample_h: float, ramp_h: float) -> float:
    """The share in force after one sample.

    Parameters
    ----------
    share : float
        The share in force, in [0, 1].
    steady : bool
        The action may act: it ramps in; else out.
    sample_h, ramp_h : float
        The caller's sample and the ramp's length, h (both > 0).

    Returns
    -------
    float
        The new share, in [0, 1].
    """
    step = sample_h / ramp_h
    return min(share + step, 1.0) if steady else max(share - step, 0.0)
