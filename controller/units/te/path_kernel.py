"""Compiled arithmetic of the grade plan's first-order paths at one sample (seed §7.7).

A grade plan's references between grades are first-order responses
(:mod:`controller.units.te.grades`): in the segment ``i`` of the last switch at or
before a time ``t``, column ``c`` of the path is::

    r(t) = target[i, c] + (start[i, c] - target[i, c]) * a,
    a    = exp(-(t - t_i) / tau[i, c])   (a = 0 where tau[i, c] = 0: a step)

:class:`controller.units.te.plan_lookup.SampleReferences` evaluates it at the
sample's times ``t + offsets[k]`` for the 41 XMEAS, the 12 XMV and the D-share
columns of the plan's table. This module does the arithmetic on each side of the
exponential in two compiled calls: :func:`path_exponents` (the segment of each time,
``numpy.searchsorted(times, t, side="right") - 1``, and the exponent ``-(t - t_i) /
tau``) and :func:`path_values` (the relaxation and the three answers). The
exponential itself stays numpy's ``exp`` on the whole (K, n) array between the two:
numpy's vectorized exp and the C library's ``exp`` that compiled code calls differ
in the last bit for about 5 % of arguments (measured on the AMD EPYC below, 10^6
arguments), and the references must be the plan's own to the last bit. The other
operations are the same IEEE operations in the same order as the numpy expression
(no fast-math, so no fused multiply-add), so the values are bit for bit those of
:meth:`TransitionPlan.xmeas_ref <controller.units.te.grades.TransitionPlan.xmeas_ref>`,
``xmv_ref`` and ``d_fraction_ref`` (``tests/test_te_path_kernel.py``,
``tests/test_te_plan_lookup.py``).

Shapes: ``times`` (L,) ascending h, ``times[0] = -inf``; ``tau_div``, ``start``,
``target`` (L, n) with ``tau_div`` = tau where tau > 0, else 1 (``positive`` says
which); ``offsets`` (K,) h; n = 41 + 12 + 1 columns in the plan's units.

**Measured** (plan 0 -> 2 -> 3, horizon 10: K = 11, n = 54; one sample's lookup,
median of 20,000 calls after 2,000 warm-up calls, both in one process, three
processes; AMD EPYC 2 vCPU shared with a 2-process campaign, load 4.5-5.0)::

    SampleReferences.__call__       numpy expression   these two kernels + np.exp
    one sample                      14.2-25.2 us       6.6-7.1 us
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["compile_path_kernels", "path_exponents", "path_values"]


@njit(cache=True)
def path_exponents(t, offsets, times, tau_div, seg, x):
    """Segments and exponents of the path at the times ``t + offsets``, written into
    ``seg`` and ``x`` (the caller's buffers: no allocation).

    Parameters
    ----------
    t : float
        Time of the first row, h.
    offsets : ndarray, shape (K,)
        Offsets of the rows from ``t``, h.
    times : ndarray, shape (L,)
        The plan's switch times, ascending, ``times[0] = -inf``.
    tau_div : ndarray, shape (L, n)
        Time constants, h (1 where the column steps).
    seg : ndarray of int64, shape (K,)
        Out: the segment of each row, ``searchsorted(times, t + offsets,
        side="right") - 1`` (a NaN time after every switch, as numpy sorts it).
    x : ndarray, shape (K, n)
        Out: ``-(t + offsets[k] - times[seg[k]]) / tau_div[seg[k], c]``.
    """
    K, L, n = offsets.size, times.size, tau_div.shape[1]
    for k in range(K):
        tk = t + offsets[k]
        i = L - 1
        if not math.isnan(tk):
            i = -1
            for j in range(L):
                if times[j] <= tk:
                    i = j
                else:
                    break
            if i < 0:  # before every switch: numpy's index -1 wraps to the last row
                i = L - 1
        seg[k] = i
        dt = tk - times[i]
        for c in range(n):
            x[k, c] = -dt / tau_div[i, c]


@njit(cache=True)
def path_values(a, seg, positive, all_positive, start, target, n_xmeas, n_xmv):
    """The path from the exponentials ``a = exp(x)`` of :func:`path_exponents`.

    Parameters
    ----------
    a : ndarray, shape (K, n)
        ``exp(x)``.
    seg : ndarray of int64, shape (K,)
    positive : ndarray of bool, shape (L, n)
        ``tau > 0`` (else the column steps: ``a = 0``).
    all_positive : bool
        Every entry of ``positive`` (no step anywhere).
    start, target : ndarray, shape (L, n)
    n_xmeas, n_xmv : int
        Columns ``[0, n_xmeas)`` are the XMEAS, the next ``n_xmv`` the XMV, the one
        after them the D share.

    Returns
    -------
    ym : ndarray, shape (K, n_xmeas)
        XMEAS references of every row.
    xv : ndarray, shape (2, n_xmv)
        XMV references of the first and the last row.
    d_share : float
        D share of the first row.
    """
    K = a.shape[0]
    ym = np.empty((K, n_xmeas))
    xv = np.empty((2, n_xmv))
    d_share = 0.0
    for k in range(K):
        i = seg[k]
        hi = n_xmeas
        if k == 0:
            hi = n_xmeas + n_xmv + 1
        elif k == K - 1:
            hi = n_xmeas + n_xmv
        for c in range(hi):
            ak = a[k, c]
            if not all_positive and not positive[i, c]:
                ak = 0.0
            tg = target[i, c]
            r = tg + (start[i, c] - tg) * ak
            if c < n_xmeas:
                ym[k, c] = r
            elif c < n_xmeas + n_xmv:
                if k == K - 1:
                    xv[1, c - n_xmeas] = r
                if k == 0:
                    xv[0, c - n_xmeas] = r
            else:
                d_share = r
    return ym, xv, d_share


def compile_path_kernels() -> None:
    """Compile both kernels (or load them from numba's on-disk cache) now, for the
    argument types :class:`~controller.units.te.plan_lookup.SampleReferences` passes, so
    that no sample pays for it. Cheap after the first call in a process."""
    if path_exponents.signatures and path_values.signatures:
        return
    tau = np.ones((1, 2))
    seg, x = np.zeros(1, dtype=np.int64), np.zeros((1, 2))
    path_exponents(0.0, np.zeros(1), np.array([-math.inf]), tau, seg, x)
    path_values(x, seg, np.ones((1, 2), dtype=np.bool_), True, tau, tau, 1, 0)
