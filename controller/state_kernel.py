"""Compiled per-sample arithmetic of the shared state's read-outs (seed eq. 3.10).

:class:`controller.state_shared.StateSharedModel` keeps the shared state as an
``(m+p, n+1)`` matrix ``Z`` (the last column the latest ``[u; y]``) and every model's
``Theta_j^T`` stacked; this module does two of its per-sample steps in one compiled
call each:

- :func:`model_errors`: ``e_j = y - (Theta_j^T n + b_j)`` for all k models (the a-priori
  errors of eq. 3.10), with the finiteness check of ``y``; the product is the same
  BLAS ``dgemv`` numpy makes, so the errors are numpy's to the last bit;
- :func:`regressor`: the shared regressor ``W`` built from the shared state (only
  copies: exact);
- :func:`write_params`: an adaptive model's structured parameter vector written into
  the stacked ``Theta^T`` and its copy with the ``[u; y]`` column (only copies: exact);
- :func:`advance_state`: one sample of the shared state with ``[u; y]`` held,
  ``Z[:, :n] <- Z [Fbd'; gbd']`` after ``Z[:, n] <- [u; y]``, with the finiteness
  check of ``u`` and ``y``; the product is the BLAS ``dgemm`` numpy makes for
  ``n > 1`` (for ``n = 1`` numpy takes ``dgemv`` and the caller keeps numpy), so the
  state is numpy's to the last bit.

**Measured** (TE: 4 models, n = 8, m = p = 5, 213 parameters; median of 3,000 calls,
two runs each, shared 2-core AMD EPYC at load 10-11): ``StateSharedModel.errors``
8.6-8.7 -> 3.5-3.7 µs, ``set_params`` 10.9-12.1 -> 5.8-6.3 µs (the rest: the
argument checks and the model's slot), ``update`` (TE: Z (10, 9)) 7.0-7.4 -> 2.1-2.3 µs
(median of 5,000 calls, numpy and kernel alternated three times in one process, AMD
EPYC 2 vCPU at load 4-5); ``tests/test_state_kernel.py`` checks the equality.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["advance_state", "model_errors", "regressor", "write_params"]


@njit(cache=True)
def model_errors(y, Taug, z, B):
    """A-priori errors of all models.

    Parameters
    ----------
    y : ndarray, shape (p,)
        Measured outputs.
    Taug : ndarray, shape (k p, (m+p)(n+1))
        Stacked ``Theta_j^T`` with zeros at the ``[u; y]`` column.
    z : ndarray, shape ((m+p)(n+1),)
        The shared-state matrix ``Z`` row-major.
    B : ndarray, shape (k, p)
        Biases.

    Returns
    -------
    errors : ndarray, shape (k, p)
        Empty (0, p) when ``y`` is not finite.
    """
    p = y.size
    for i in range(p):
        if not math.isfinite(y[i]):
            return np.empty((0, p))
    est = Taug @ z
    k = B.shape[0]
    out = np.empty((k, p))
    for j in range(k):
        for i in range(p):
            out[j, i] = y[i] - (est[j * p + i] + B[j, i])
    return out


@njit(cache=True)
def write_params(T, Taug, B, j, params, n, m, q):
    """Write model j's structured parameters (``[vec Theta1^T; theta2; bias]``).

    Parameters
    ----------
    T : ndarray, shape (k q, n(m+q))
        Stacked ``Theta^T``; rows ``j q .. (j+1) q - 1`` are written.
    Taug : ndarray, shape (k q, (m+q)(n+1))
        The same with a zero column after every block of n.
    B : ndarray, shape (k, q)
    j : int
    params : ndarray, shape (n m q + n + q,)
    n, m, q : int
        Degree, inputs, outputs.
    """
    nm = n * m
    width = n * (m + q)
    for i in range(q):
        r = j * q + i
        for c in range(nm):
            T[r, c] = params[i * nm + c]
        for c in range(nm, width):
            T[r, c] = 0.0
        for c in range(n):
            T[r, nm + i * n + c] = params[nm * q + c]
        for blk in range(m + q):
            for c in range(n):
                Taug[r, blk * (n + 1) + c] = T[r, blk * n + c]
    for i in range(q):
        B[j, i] = params[nm * q + n + i]


@njit(cache=True)
def regressor(Z, n, m, q, n_cols):
    """The shared regressor ``W`` (q, n_cols) of the shared state ``Z`` ((m+q), n+1).

    Row i: the input blocks ``Z[:m, :n]`` row-major in columns ``i n m .. (i+1) n m``,
    output block i ``Z[m+i, :n]`` in columns ``n m q ..``, and 1 in the bias column
    ``n m q + n + i``; zeros elsewhere.
    """
    W = np.zeros((q, n_cols))
    nm = n * m
    for i in range(q):
        for a in range(m):
            for c in range(n):
                W[i, i * nm + a * n + c] = Z[a, c]
        for c in range(n):
            W[i, nm * q + c] = Z[m + i, c]
        W[i, nm * q + n + i] = 1.0
    return W


@njit(cache=True)
def advance_state(Z, M, u, y):
    """One sample of the shared state with ``u`` and ``y`` held (zero-order hold), in place.

    Parameters
    ----------
    Z : ndarray, shape (m+p, n+1)
        In/out: the shared state; its last column takes ``[u; y]``, the others
        ``Z @ M``.
    M : ndarray, shape (n+1, n)
        ``[Fbd'; gbd']``.
    u, y : ndarray, shapes (m,), (p,)

    Returns
    -------
    bool
        False (``Z`` untouched) when ``u`` or ``y`` is not finite.
    """
    m, p = u.size, y.size
    for i in range(m):
        if not math.isfinite(u[i]):
            return False
    for i in range(p):
        if not math.isfinite(y[i]):
            return False
    n = Z.shape[1] - 1
    for i in range(m):
        Z[i, n] = u[i]
    for i in range(p):
        Z[m + i, n] = y[i]
    nxt = Z @ M
    for i in range(m + p):
        for c in range(n):
            Z[i, c] = nxt[i, c]
    return True
