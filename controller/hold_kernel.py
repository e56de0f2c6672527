"""Compiled per-sample arithmetic of the first-order hold of the outputs (seed eq. 3.10).

:class:`controller.multimodel.OutputHoldCorrection` carries the correction ``c`` (p, n)
of the output part of the shared state for outputs taken linear between samples;
this module does its three per-sample steps in one compiled call each:

- :func:`hold_forward`: ``c Fd'`` and ``c Fd' - y_prev h'`` (the part of the next
  state known before the output comes in);
- :func:`hold_estimates`: every model's a-priori estimate with the hold, the
  solution of ``yhat = est_j + theta2_j' (free + h yhat')`` (explicit per output)::

      yhat_j = (est_j + free theta2_j) / (1 - theta2_j' h)    where |1 - theta2_j' h| > 1e-6
      yhat_j = est_j + cF theta2_j                             elsewhere

  and, given ``y``, the errors ``y - yhat_j``;
- :func:`hold_advance`: ``c <- c Fd' + (y - y_prev) h'``;
- :func:`hold_regressor_parts`: the next sample's regressor before its output, the
  shared regressor with ``free`` added in the n2 columns and ``d`` (h in those
  columns), so that ``W = W_base + y d'``.

The products are the BLAS ``dgemm`` / ``dgemv`` numpy makes (numba's ``@``), the other
operations the same IEEE operations in the same order as the numpy expressions they
replace (no fast-math), so the numbers are numpy's to the last bit
(``tests/test_hold_kernel.py``) where numpy's products are those BLAS calls too: k, p
and n all above 1 (with a dimension of 1 numpy's matmul takes ``ddot`` or another
``dgemv``, and :class:`~controller.multimodel.OutputHoldCorrection` keeps numpy).

Shapes: k models, p outputs, n the order of the shared basis; ``est`` (k, p) the
models' zero-order-hold estimates (output units), ``theta2`` (k, n), ``c``, ``cF``,
``free`` (p, n) in output units, ``Fd_T`` (n, n), ``h`` (n,) dimensionless.

**Measured** (TE: k = 4, p = 5, n = 8; per-call median of 5,000 calls, numpy and
kernels alternated three times in one process; AMD EPYC 2 vCPU shared with another
2-process campaign, load 3.3)::

    method                                  numpy          kernels
    OutputHoldCorrection.errors             19.7-20.0 us   8.0-8.5 us
    OutputHoldCorrection.regressor_parts    12.7-12.9 us   6.3-6.7 us
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["hold_advance", "hold_errors", "hold_estimates", "hold_forward",
           "hold_regressor_parts"]

#: Smallest |1 - theta2' h| solved for the estimate over the sample (else no slope).
DEN_MIN = 1e-6


@njit(cache=True)
def hold_forward(c, Fd_T, y_prev, h):
    """``(c Fd', c Fd' - y_prev h')``, shapes (p, n) each."""
    cF = c @ Fd_T
    p, n = cF.shape
    free = np.empty((p, n))
    for i in range(p):
        for j in range(n):
            free[i, j] = cF[i, j] - y_prev[i] * h[j]
    return cF, free


@njit(cache=True)
def hold_estimates(est, theta2, cF, free, h):
    """A-priori estimates of all models with the first-order hold, shape (k, p).

    Parameters
    ----------
    est : ndarray, shape (k, p)
        The zero-order-hold estimates ``Theta_j' n + b_j``.
    theta2 : ndarray, shape (k, n)
        Every model's theta2 (any strides).
    cF, free : ndarray, shape (p, n)
        :func:`hold_forward` of the current correction.
    h : ndarray, shape (n,)
    """
    k, n = theta2.shape
    p = est.shape[1]
    t2 = np.empty((k, n))
    for j in range(k):
        for i in range(n):
            t2[j, i] = theta2[j, i]
    tf = t2 @ free.T
    den = t2 @ h
    out = np.empty((k, p))
    tc = np.empty((0, 0))
    for j in range(k):
        d = 1.0 - den[j]
        if abs(d) > DEN_MIN:
            for i in range(p):
                out[j, i] = (est[j, i] + tf[j, i]) / d
        else:  # no slope over the sample
            if tc.shape[0] == 0:
                tc = t2 @ cF.T
            for i in range(p):
                out[j, i] = est[j, i] + tc[j, i]
    return out


@njit(cache=True)
def hold_errors(y, est, theta2, cF, free, h):
    """``y - yhat_j`` for every model, shape (k, p) (:func:`hold_estimates`)."""
    out = hold_estimates(est, theta2, cF, free, h)
    k, p = out.shape
    for j in range(k):
        for i in range(p):
            out[j, i] = y[i] - out[j, i]
    return out


@njit(cache=True)
def hold_advance(cF, y, y_prev, h):
    """The next correction ``cF + (y - y_prev) h'``, shape (p, n)."""
    p, n = cF.shape
    c = np.empty((p, n))
    for i in range(p):
        dy = y[i] - y_prev[i]
        for j in range(n):
            c[i, j] = cF[i, j] + dy * h[j]
    return c


@njit(cache=True)
def hold_regressor_parts(W, free, h, start):
    """Add ``free`` (p, n) to the n2 columns ``start .. start + n - 1`` of the shared
    regressor ``W`` (p, N), in place, and return ``d`` (N,): ``h`` in those columns,
    zeros elsewhere."""
    p, n = free.shape
    for i in range(p):
        for c in range(n):
            W[i, start + c] += free[i, c]
    d = np.zeros(W.shape[1])
    for c in range(n):
        d[start + c] = h[c]
    return d
