"""Compiled products of the implicit covariance ``P = c I - V V'`` (seed eq. 4.1).

The normalized least squares of :mod:`controller.adaptation` keeps a large
estimator's covariance as ``c I - V V'`` (V: N x r, grown by a block of m columns
per update, reset when its smallest eigenvalue falls to the floor of seed §5.1.3).
Its two products with V are the bulk of the adaptation's arithmetic:

- before an update, ``P W' = c W' - V (V' W')`` for the next measurement matrix
  (:func:`lowrank_products`, with the hold part ``d``: ``P [W_base', d]``);
- after it, the covariance step ``P <- P - g_d K W P`` of eq. 4.1 as one more block
  of V, ``B = sqrt(g_d) (P W') L^-T`` with ``S = L L'``, and the Gram matrix ``V' V``
  bordered by ``V' B`` and ``B' B`` (:func:`lowrank_append`), which the floor check
  (:mod:`controller.definiteness`) factors.

Each is one compiled call on the estimator's own buffers (no argument copies, no
temporaries), where the same products as numpy expressions cost some fifteen calls
and their temporaries. The loops run over V's rows, contiguous in its C-ordered
buffer, and may reassociate the sums (``fastmath`` ``reassoc``/``contract``, never
``nnan``: a NaN or inf in the data still comes out as one), so a product differs
from BLAS's in the last bits: the TE moves of ``tests/data/te_moves`` (48 h and the
short cases) stay within 4e-9 of those made with numpy's products, the difference two
numpy builds make (``tests/test_te_moves_reference.py`` allows 1e-6).

**Measured** (AMD EPYC, 2 vCPU, one BLAS thread, quiet; TE size N = 265, m = 5;
mean of 20,000 calls, µs; "numpy": the expressions these replace, with their
errstate, column stack, finiteness check and buffer copies):

=====  =====================  =====================
r      products numpy / here  append numpy / here
=====  =====================  =====================
10     9.0 / 6.7              9.6 / 6.3
40     15.5 / 11.6            13.1 / 8.5
75-80  25.3 / 21.1 (80)       18.1 / 11.8 (75)
=====  =====================  =====================

In the TE ``ssmpc`` closed loop V grows from 0 to 80 columns and is reset about every
17 samples (r about 40 on average). ``ssmpc bench te-closed-loop`` went from 38.2 to
40.4-40.9 process-h/s on the same quiet machine (ssmpc, three 48 h runs each).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["lowrank_append", "lowrank_products", "compile_lowrank"]

_FASTMATH = {"reassoc", "contract"}


@njit(cache=True, fastmath=_FASTMATH)
def lowrank_products(V, r, c, W_base, d, Pc, T):  # pragma: no cover - compiled
    """``Pc = P [W_base', d]`` for ``P = c I - V[:, :r] V[:, :r]'``.

    Parameters
    ----------
    V : ndarray, shape (N, R)
        Buffer of V (C order); its first ``r`` columns are read.
    r : int
        Columns of V in use (``0 <= r <= R``).
    c : float
        Scale of the identity part.
    W_base : ndarray, shape (m, N)
        Measurement matrix (its part not linear in the coming output).
    d : ndarray, shape (N,)
        The part linear in the output (zeros when there is none).
    Pc : ndarray, shape (N, m + 1)
        Written: ``[P W_base', P d]``.
    T : ndarray, shape (m + 1, >= r)
        Scratch: ``([W_base', d]' V)``, the first ``r`` columns written.
    """
    N = V.shape[0]
    m = W_base.shape[0]
    for j in range(m + 1):
        for i in range(r):
            T[j, i] = 0.0
    for n in range(N):
        for j in range(m):
            x = W_base[j, n]
            for i in range(r):
                T[j, i] += V[n, i] * x
        x = d[n]
        for i in range(r):
            T[m, i] += V[n, i] * x
    for n in range(N):
        for j in range(m + 1):
            s = 0.0
            for i in range(r):
                s += V[n, i] * T[j, i]
            x = W_base[j, n] if j < m else d[n]
            Pc[n, j] = c * x - s


@njit(cache=True, fastmath=_FASTMATH)
def lowrank_append(V, G, r, PWt, L_inv, scale, T):  # pragma: no cover - compiled
    """Append the covariance step's block ``B = scale PWt L_inv'`` to V and ``V' V``.

    ``P - g_d K (P W')'`` with ``K = P W' S^-1`` and ``S^-1 = L^-T L^-1`` is
    ``c I - [V, B] [V, B]'`` for ``B = sqrt(g_d) (P W') L^-T`` (``scale = sqrt(g_d)``).

    Parameters
    ----------
    V : ndarray, shape (N, R)
        Buffer of V; columns ``r .. r+m-1`` are written with B (``r + m <= R``).
    G : ndarray, shape (R, R)
        Buffer of ``V' V``; rows and columns ``r .. r+m-1`` are written (only when B is
        finite).
    r : int
        Columns of V so far.
    PWt : ndarray, shape (N, m)
        ``P W'`` of the update.
    L_inv : ndarray, shape (m, m)
        Inverse of the lower Cholesky factor of ``S`` (its lower triangle is read).
    scale : float
        ``sqrt(g_d)``.
    T : ndarray, shape (>= m, >= r + m)
        Scratch: ``B' [V, B]``.

    Returns
    -------
    bool
        False when B has a NaN or inf (then G is untouched, and V's columns past
        ``r`` hold values that no reader sees).
    """
    N, m = PWt.shape
    finite = True
    for n in range(N):
        for b in range(m):
            s = 0.0
            for a in range(b + 1):
                s += PWt[n, a] * L_inv[b, a]
            v = scale * s
            V[n, r + b] = v
            if not math.isfinite(v):
                finite = False
    if not finite:
        return False
    k = r + m
    for b in range(m):
        for a in range(k):
            T[b, a] = 0.0
    for n in range(N):
        for b in range(m):
            x = V[n, r + b]
            for a in range(k):
                T[b, a] += V[n, a] * x
    for b in range(m):
        for a in range(k):
            G[a, r + b] = T[b, a]
            G[r + b, a] = T[b, a]
    return True


def compile_lowrank(N: int, m: int) -> None:
    """Compile both kernels (or load them from numba's on-disk cache) now, with the
    argument types the estimator passes (C-ordered float64 buffers, Python ints and
    floats), on scratch arrays."""
    V, G = np.zeros((N, m + 1)), np.zeros((m + 1, m + 1))
    lowrank_products(V, 0, 1.0, np.zeros((m, N)), np.zeros(N), np.zeros((N, m + 1)),
                     np.zeros((m + 1, m + 1)))
    lowrank_append(V, G, 0, np.zeros((N, m)), np.eye(m), 1.0, np.zeros((m + 1, m + 1)))
