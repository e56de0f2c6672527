"""Compiled assembly of the condensed QP's per-sample vectors (seed eq. 6.10).

:meth:`controller.mpc.formulation.DeltaUFormulation.qp_vectors` forms, at each
sample, the augmented state ``x_a = [x(k) - x(k-1); y(k)]`` and::

    f[:M nu] = F_x x_a - F_r vec(R) (+ F_ut tile(u(k-1) - u_target))
    bl, bu   = settings' rows - u(k-1) on the input rows,
               y_max - S_x x_a, y_min - S_x x_a on the soft output rows

With the settings' own limits and no measured disturbance (the usual sample) this is
one compiled call here instead of some fifteen numpy calls; the rest (an operator's
limits, feedforward of a measured disturbance) stays in numpy. The matrix-vector
products are the same BLAS ``dgemv`` calls numpy makes (numba's ``@`` on contiguous
float64 arrays), in the same order, so the vectors are the numpy expression's to the
last bit (``tests/test_vector_kernel.py`` compares them).

**Measured** (TE size: 80 states + 5 outputs, P = 10, M = 4, nu = 5, 21 variables,
20 input and 10 soft output rows; one call, median of 2,000, ``OPENBLAS_NUM_THREADS=1``,
shared 2-core AMD EPYC at load 7.5, two alternated runs): numpy expression 12-20 µs,
this kernel 6.6-10.5 µs (most of it the call's argument unboxing).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["clip_move", "qp_vectors_kernel", "stacked_bounds"]


@njit(cache=True)
def qp_vectors_kernel(x, x_prev, y, F_x, F_r, r, F_ut, ut_dev, slack_linear, has_slack,
                      bl0, bu0, in_idx, u_prev, Sx_max, Sx_min):
    """The QP's linear term and row bounds at one sample (the settings' limits).

    Parameters
    ----------
    x, x_prev : ndarray, shape (n,)
        Model state now and one sample ago.
    y : ndarray, shape (ny,)
        Filtered measurement.
    F_x : ndarray, shape (M nu, n + ny)
    F_r : ndarray, shape (M nu, P ny)
    r : ndarray, shape (P ny,)
        Reference, row-major over the horizon.
    F_ut : ndarray, shape (M nu, M nu) or (0, 0)
        Input-target term (empty: none).
    ut_dev : ndarray, shape (M nu,) or (0,)
        ``tile(u(k-1) - u_target, M)`` (empty with an empty ``F_ut``).
    slack_linear : float
        Exact penalty of the slack (the last variable, when ``has_slack``).
    has_slack : bool
    bl0, bu0 : ndarray, shape (rows,)
        The settings' row bounds (input rows, then y_max rows, then y_min rows).
    in_idx : ndarray of int64, shape (n_in,)
        Input of each input row.
    u_prev : ndarray, shape (nu,)
        ``u(k-1)``.
    Sx_max, Sx_min : ndarray, shapes (n_max, n + ny), (n_min, n + ny)
        Rows of ``S_x`` of the soft output limits.

    Returns
    -------
    x_a : ndarray, shape (n + ny,)
    f : ndarray, shape (M nu [+ 1],)
    bl, bu : ndarray, shape (rows,)
    """
    n, ny = x.size, y.size
    x_a = np.empty(n + ny)
    for i in range(n):
        x_a[i] = x[i] - x_prev[i]
    for i in range(ny):
        x_a[n + i] = y[i]
    n_moves = F_x.shape[0]
    f = np.empty(n_moves + (1 if has_slack else 0))
    fx = F_x @ x_a
    fr = F_r @ r
    for i in range(n_moves):
        f[i] = fx[i] - fr[i]
    if F_ut.shape[0] > 0:
        fu = F_ut @ ut_dev
        for i in range(n_moves):
            f[i] += fu[i]
    if has_slack:
        f[n_moves] = slack_linear
    bl = bl0.copy()
    bu = bu0.copy()
    n_in = in_idx.size
    for i in range(n_in):
        up = u_prev[in_idx[i]]
        bl[i] -= up
        bu[i] -= up
    if has_slack:
        n_max = Sx_max.shape[0]
        if n_max > 0:
            smax = Sx_max @ x_a
            for i in range(n_max):
                bu[n_in + i] -= smax[i]
        if Sx_min.shape[0] > 0:
            smin = Sx_min @ x_a
            for i in range(Sx_min.shape[0]):
                bl[n_in + n_max + i] -= smin[i]
    return x_a, f, bl, bu


@njit(cache=True)
def stacked_bounds(f, lb, ub, bl, bu, upper, lower):
    """The QP data check and DAQP's stacked bounds in one call.

    Parameters
    ----------
    f, lb, ub : ndarray, shape (nz,)
    bl, bu : ndarray, shape (rows,)
    upper, lower : ndarray, shape (nz + rows,)
        Written: ``[ub; bu]`` and ``[lb; bl]``, the order DAQP takes them in (the
        solver's own buffers: a returned array would cost ~0.7 µs of boxing each).

    Returns
    -------
    clean : bool
        ``f`` finite and no bound NaN (an infinite bound is an open one).
    """
    clean = True
    for i in range(f.size):
        if not math.isfinite(f[i]):
            clean = False
    nz, rows = lb.size, bl.size
    for i in range(nz):
        upper[i], lower[i] = ub[i], lb[i]
    for i in range(rows):
        upper[nz + i], lower[nz + i] = bu[i], bl[i]
    for i in range(nz + rows):
        if math.isnan(upper[i]) or math.isnan(lower[i]):
            clean = False
    return clean


@njit(cache=True)
def clip_move(du, du_max, u_prev, u_min, u_max):
    """``u = clip(u(k-1) + clip(du, -du_max, du_max), u_min, u_max)`` (as numpy's
    ``minimum(maximum(.))``); returns ``(clipped du, u)``, shapes (nu,)."""
    nu = du.size
    d = np.empty(nu)
    u = np.empty(nu)
    for i in range(nu):
        v = du[i]
        if v < -du_max[i]:  # a NaN stays NaN, as in numpy.maximum
            v = -du_max[i]
        if v > du_max[i]:
            v = du_max[i]
        d[i] = v
        w = u_prev[i] + v
        if w < u_min[i]:
            w = u_min[i]
        if w > u_max[i]:
            w = u_max[i]
        u[i] = w
    return d, u
