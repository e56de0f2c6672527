"""Compiled arithmetic of one normalized least-squares step (seed eq. 4.1, MIMO form).

:class:`controller.adaptation.NormalizedLeastSquares` keeps the covariance, the
counters and the reset rules; this module only does the step's small dense
arithmetic in one compiled call: at TE size (m = 5 outputs, N = 213 parameters)
the same step as some twenty numpy calls costs ~30 us of call overhead per sample
on the path between the measurement and the move, the arithmetic itself a few us.

Everything here is O(N m + m^3); the (N, N) covariance is not an argument.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["OK", "INVALID_DATA", "FROZEN", "DEAD_ZONE", "SINGULAR", "DIVERGED", "NONFINITE",
           "compile_nls_step", "nls_step"]

#: Result codes of :func:`nls_step` (the reasons of :class:`controller.adaptation.NLSStep`).
OK, INVALID_DATA, FROZEN, DEAD_ZONE, SINGULAR, DIVERGED, NONFINITE = range(7)


@njit(cache=True)
def nls_step(W_base, d, Pc, y, p, g_d, rate, lower, upper, max_abs, dead_zone, freeze,
             K, PWt, L_inv):
    """One step of eq. 4.1 for ``y = W p`` with ``W = W_base + y d'``.

    Parameters
    ----------
    W_base : ndarray, shape (m, N)
        Measurement matrix, less its part linear in ``y``.
    d : ndarray, shape (N,)
        That part: ``W = W_base + y d'`` (zeros: ``W = W_base``).
    Pc : ndarray, shape (N, m + 1)
        ``[P W_base', P d]`` for the current covariance ``P``, so that
        ``P W' = Pc[:, :m] + Pc[:, m] y'``.
    y : ndarray, shape (m,)
        Measured outputs.
    p : ndarray, shape (N,)
        Current parameters (finite).
    g_d, rate : float
        Per-sample gain and normalization rate (``S = I + rate W P W'``).
    lower, upper : ndarray, shape (N,)
        Projection box.
    max_abs : float
        Largest admissible ``|p|`` (else ``DIVERGED``).
    dead_zone : float
        No update while ``max |e| <= dead_zone`` (when > 0).
    freeze : bool
        Compute the error only.
    K, PWt : ndarray, shape (N, m)
        Written: ``P W' S^-1`` (zeros unless the code is OK, DIVERGED or NONFINITE) and
        ``P W'`` (set from FROZEN on).
    L_inv : ndarray, shape (m, m)
        Written: the inverse of the lower Cholesky factor of ``S`` (zeros before it).

    The three are the caller's buffers, kept from sample to sample: a compiled
    function's returned array costs ~0.7 µs of boxing each.

    Returns
    -------
    code : int
        ``OK`` (updated), ``INVALID_DATA`` (non-finite error: NaN/inf in W or y),
        ``FROZEN``, ``DEAD_ZONE``, ``SINGULAR`` (S not positive definite),
        ``DIVERGED`` (``|p_new|`` too large or NaN) or ``NONFINITE`` (the
        covariance decrement's trace; ``p`` is updated).
    e : ndarray, shape (m,)
        ``y - W p`` before the update.
    p_new : ndarray, shape (N,)
        Updated and projected parameters (``p`` itself unless the code is OK or
        NONFINITE).
    projected : bool
        The box changed ``p_new``.
    trace_dP : float
        ``g_d trace(K (P W')')``, the trace of the covariance decrement.
    """
    m, n = W_base.shape
    W = np.empty((m, n))
    e = np.empty(m)
    K[:, :] = 0.0
    L_inv[:, :] = 0.0
    finite = True
    for i in range(m):
        acc = 0.0
        for j in range(n):
            w = W_base[i, j] + y[i] * d[j]
            W[i, j] = w
            acc += w * p[j]
        e[i] = y[i] - acc
        if not math.isfinite(e[i]):
            finite = False
    if not finite:
        return INVALID_DATA, e, p, False, 0.0
    for j in range(n):
        for k in range(m):
            PWt[j, k] = Pc[j, k] + Pc[j, m] * y[k]
    if freeze:
        return FROZEN, e, p, False, 0.0
    if dead_zone > 0.0:
        big = 0.0
        for i in range(m):
            big = max(big, abs(e[i]))
        if big <= dead_zone:
            return DEAD_ZONE, e, p, False, 0.0
    # S = I + rate W P W', symmetrized
    S = np.empty((m, m))
    for i in range(m):
        for k in range(m):
            acc = 0.0
            for j in range(n):
                acc += W[i, j] * PWt[j, k]
            S[i, k] = rate * acc
    for i in range(m):
        for k in range(i + 1):
            s = 0.5 * (S[i, k] + S[k, i])
            S[i, k] = s
            S[k, i] = s
        S[i, i] += 1.0
    # Cholesky S = L L' (lower), then L^-1 by forward substitution
    L = np.zeros((m, m))
    for j in range(m):
        pivot = S[j, j]
        for k in range(j):
            pivot -= L[j, k] * L[j, k]
        if not pivot > 0.0:  # also NaN
            return SINGULAR, e, p, False, 0.0
        L[j, j] = math.sqrt(pivot)
        for i in range(j + 1, m):
            s = S[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    for j in range(m):
        L_inv[j, j] = 1.0 / L[j, j]
        for i in range(j + 1, m):
            s = 0.0
            for k in range(j, i):
                s -= L[i, k] * L_inv[k, j]
            L_inv[i, j] = s / L[i, i]
    # S^-1 = L^-T L^-1; K = P W' S^-1
    S_inv = np.zeros((m, m))
    for i in range(m):
        for k in range(m):
            acc = 0.0
            for j in range(max(i, k), m):
                acc += L_inv[j, i] * L_inv[j, k]
            S_inv[i, k] = acc
    p_new = np.empty(n)
    diverged = False
    trace = 0.0
    for j in range(n):
        ke = 0.0
        for k in range(m):
            acc = 0.0
            for i in range(m):
                acc += PWt[j, i] * S_inv[i, k]
            K[j, k] = acc
            ke += acc * e[k]
            trace += acc * PWt[j, k]
        p_new[j] = p[j] + g_d * ke
        if not abs(p_new[j]) <= max_abs:  # also NaN
            diverged = True
    if diverged:
        return DIVERGED, e, p, False, 0.0
    projected = False
    for j in range(n):
        clipped = min(max(p_new[j], lower[j]), upper[j])
        if clipped != p_new[j]:
            projected = True
            p_new[j] = clipped
    trace_dP = g_d * trace
    if not math.isfinite(trace_dP):
        return NONFINITE, e, p_new, projected, trace_dP
    return OK, e, p_new, projected, trace_dP


def compile_nls_step() -> None:
    """Compile :func:`nls_step` (or load it from numba's on-disk cache) now, for the
    argument types every estimator passes, so that no sample pays for it: the first
    compilation on a machine takes about a second. Idempotent and cheap after the
    first call in a process."""
    if nls_step.signatures:
        return
    z1, z2 = np.zeros(2), np.zeros((1, 2))
    nls_step(z2, z1, np.zeros((2, 2)), np.zeros(1), z1, 0.0, 1.0, z1, z1, 1.0, 0.0, False,
             np.zeros((2, 1)), np.zeros((2, 1)), np.zeros((1, 1)))
