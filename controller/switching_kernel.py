"""Compiled per-sample arithmetic of the performance index and the switch (seed eq. 4.6).

:class:`controller.switching.PerformanceIndex` and
:class:`controller.switching.ModelSwitcher` keep their state and rules; the sample's
arithmetic on the k models is one compiled call each here:

- :func:`index_step`: ``|e_j|^2_W = (e ∘ e) W`` (the same BLAS ``dgemv`` numpy uses),
  ``I_j <- exp(-lambda dt) I_j + dt |e_j|^2``, ``J_j = mu |e_j|^2 + nu I_j``;
- :func:`smallest_index`: the model with the smallest finite J (the first on a tie, as
  ``numpy.argmin``) and the switching threshold ``(1 - hysteresis) J_active - J_TOL``;
- :func:`steady_output_errors`: the errors on one scale at low frequency
  (:attr:`controller.multimodel.MultiModelSettings.index_errors` ``"steady_output"``),
  row j times ``1 / |1 - theta2_j' n_ss|`` (1 where that is not finite or below 1e-12;
  the product the BLAS ``dgemv`` numpy makes for k > 1 models).

Elementwise the same operations in the same order as the numpy expressions they
replace (no fast-math), so J and the decisions are the same to the last bit
(``tests/test_switching_kernel.py``).

**Measured** (TE: 4 models, 5 outputs; median of 5,000 calls, two runs, shared 2-core
AMD EPYC at load 8.3): :meth:`PerformanceIndex.update` 9.1-9.2 -> 3.3-3.5 µs,
:meth:`ModelSwitcher.step` 11.0-11.1 -> 2.7-2.9 µs (what is left is the call and the
decision object). ``MultiModelController``'s steady-output scaling of the errors (TE:
4 models, n = 8) 4.3-4.4 -> 2.2 µs (median of 5,000 calls, numpy and kernel
alternated three times in one process, AMD EPYC 2 vCPU at load 2).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["index_step", "smallest_index", "steady_output_errors"]


@njit(cache=True)
def index_step(errors, weights, integral, decay, dt, mu, nu):
    """One sample of eq. 4.6 for k models.

    Parameters
    ----------
    errors : ndarray, shape (k, m)
        Model errors ``y - y_j``, output units.
    weights : ndarray, shape (m,)
        Output weights of the squared error.
    integral : ndarray, shape (k,)
        Discounted integral before the sample.
    decay, dt, mu, nu : float
        ``exp(-lambda dt)``, sample time, the weights of eq. 4.6.

    Returns
    -------
    J : ndarray, shape (k,)
    integral : ndarray, shape (k,)
        The new integral (a new array).
    finite : bool
        False when a squared error is not finite (nothing is to be kept then).
    """
    e2 = (errors * errors) @ weights
    finite = True
    for i in range(e2.size):
        if not math.isfinite(e2[i]):
            finite = False
    new_integral = decay * integral + dt * e2
    J = mu * e2 + nu * new_integral
    return J, new_integral, finite


@njit(cache=True)
def smallest_index(J, active, hysteresis, j_tol):
    """The model with the smallest finite J and whether it beats the active one.

    Parameters
    ----------
    J : ndarray, shape (k,)
        Index values (non-finite: the model is out).
    active : int
        The active model.
    hysteresis, j_tol : float
        Relative margin and round-off tolerance of the switch rule.

    Returns
    -------
    best : int
        Smallest finite J (first on a tie); ``active`` when no J is finite.
    any_finite : bool
    beats : bool
        ``best != active`` and ``J_best < (1 - hysteresis) J_active - j_tol``, with a
        non-finite ``J_active`` taken as +inf.
    """
    best = -1
    best_value = np.inf
    for i in range(J.size):
        v = J[i]
        if math.isfinite(v) and (best < 0 or v < best_value):
            best, best_value = i, v
    if best < 0:
        return active, False, False
    a = J[active]
    if not math.isfinite(a):
        a = np.inf
    threshold = (1.0 - hysteresis) * a - j_tol
    return best, True, best != active and best_value < threshold


@njit(cache=True)
def steady_output_errors(errors, theta2, steady):
    """The model errors scaled to one scale at low frequency.

    Parameters
    ----------
    errors : ndarray, shape (k, p)
        Model errors, output units.
    theta2 : ndarray, shape (k, n)
        Every model's theta2 (any strides).
    steady : ndarray, shape (n,)
        The shared basis's steady state for a unit input.

    Returns
    -------
    ndarray, shape (k, p)
        ``errors[j] / |1 - theta2_j' steady|`` (``errors[j]`` where that is not finite
        or ``|.| <= 1e-12``).
    """
    k, n = theta2.shape
    t2 = np.empty((k, n))
    for j in range(k):
        for i in range(n):
            t2[j, i] = theta2[j, i]
    g = t2 @ steady
    p = errors.shape[1]
    out = np.empty((k, p))
    for j in range(k):
        r = 1.0 - g[j]
        scale = 1.0
        if math.isfinite(r) and abs(r) > 1e-12:
            scale = 1.0 / abs(r)
        for i in range(p):
            out[j, i] = errors[j, i] * scale
    return out
