"""The scalar first-order lag of the supervisory guards, one sample at a time.

``tau dx/dt = u - x`` stepped by backward Euler over a sample ``dt``:

    x(k+1) = x(k) + dt / (tau + dt) (u(k) - x(k))

The step's weight ``dt / (tau + dt)`` lies in (0, 1] for every ``dt > 0`` and ``tau >= 0``,
so the lag never overshoots and is stable at any sample; ``tau = 0`` passes the sample.
It is the scalar counterpart of :class:`controller.mpc.filters.FirstOrderFilter` (seed
§6.1.2's ``y_f(k) = a y(k) + (1 - a) y_f(k-1)`` with ``a = dt / (tau + dt)``), without
the array a vector filter builds each sample on the 36 s path of the TE guards.

Limits (measured: a unit step from 0, the value after one time constant, against
``1 - e^-1 = 0.6321`` of the continuous lag)

==========  ======  ========
dt / tau    steps   x(tau)
==========  ======  ========
0.01        100     0.6303
0.1         10      0.6145
0.5         2       0.5556
1           1       0.5
==========  ======  ========

The TE guards' defaults run at ``dt / tau`` of 0.01-0.2 (0.01 h samples; lags of 0.05 h,
the feed overrides' delivered shares, to 1 h, the washouts); the feed balance refuses a
washout under two samples (0.5).
"""

from __future__ import annotations

__all__ = ["lag_step"]


def lag_step(state: float, sample: float, dt: float, tau: float) -> float:
    """One backward-Euler step of ``tau dx/dt = u - x``.

    Parameters
    ----------
    state : float
        ``x(k)``, in the sample's units.
    sample : float
        ``u(k)``, in the same units.
    dt : float
        Sample period (> 0), in the time unit of ``tau``.
    tau : float
        Time constant (>= 0); 0 returns ``sample``.

    Returns
    -------
    float
        ``x(k+1)``. A non-finite ``sample`` or ``state`` gives a non-finite result: the
        caller decides what a bad sample means.
    """
    return state + dt / (tau + dt) * (sample - state)
