"""The compiled first-order-hold arithmetic equals the numpy expressions it replaces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.hold_kernel import (
    hold_advance,
    hold_errors,
    hold_estimates,
    hold_forward,
    hold_regressor_parts,
)

#: Largest difference allowed between the kernels and numpy (0: bit for bit).
HOLD_ATOL = 0.0


def _numpy_forward(c, Fd_T, y_prev, h):
    cF = c @ Fd_T
    return cF, cF - y_prev[:, None] * h[None, :]


def _numpy_estimates(est, t2, cF, free, h):
    """OutputHoldCorrection.estimates in numpy (before the kernel)."""
    num = est + t2 @ free.T
    den = 1.0 - t2 @ h
    safe = np.abs(den) > 1e-6
    if safe.all():
        return num / den[:, None]
    out = est + t2 @ cF.T
    out[safe] = num[safe] / den[safe, None]
    return out


def _same(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=HOLD_ATOL)
    assert np.array_equal(a, b, equal_nan=True)


def _case(rng, k=4, p=5, n=8):
    T = rng.normal(size=(k * p, 2 * n * p)) * 10.0 ** rng.uniform(-3, 1, (k * p, 2 * n * p))
    t2 = T[::p, n * p: n * p + n]  # strided, as StateSharedModel.theta2_all
    t2.flags.writeable = False
    est = rng.normal(2700, 100, (k, p))
    c = rng.normal(size=(p, n)) * 10.0 ** rng.uniform(-4, 1, (p, n))
    Fd_T = np.ascontiguousarray(rng.normal(size=(n, n)) * 0.3)
    y_prev, y = rng.normal(2700, 100, p), rng.normal(2700, 100, p)
    h = rng.uniform(0.0, 0.2, n)
    return est, t2, c, Fd_T, y_prev, y, h


@pytest.mark.parametrize("shape", [(4, 5, 8), (3, 2, 4), (2, 2, 2)])
def test_random_cases_bit_for_bit(shape):
    """k, p, n > 1: numpy's products are then the BLAS dgemm/dgemv numba's are (a
    dimension of 1 takes numpy to other calls; OutputHoldCorrection keeps numpy there)."""
    rng = np.random.default_rng(sum(shape))
    for _ in range(300):
        est, t2, c, Fd_T, y_prev, y, h = _case(rng, *shape)
        cF, free = hold_forward(c, Fd_T, y_prev, h)
        want_cF, want_free = _numpy_forward(c, Fd_T, y_prev, h)
        _same(cF, want_cF)
        _same(free, want_free)
        want = _numpy_estimates(est, t2, cF, free, h)
        _same(hold_estimates(est, t2, cF, free, h), want)
        _same(hold_errors(y, est, t2, cF, free, h), y[None, :] - want)
        _same(hold_advance(cF, y, y_prev, h), cF + (y - y_prev)[:, None] * h[None, :])


@pytest.mark.parametrize("den", [0.0, 1e-7, -1e-7, 1e-6, math.nan])
def test_rows_without_a_slope_take_the_fallback(den):
    """A model whose ``1 - theta2' h`` is (near) zero or NaN: est + theta2 cF'."""
    rng = np.random.default_rng(4)
    est, t2, c, Fd_T, y_prev, y, h = _case(rng)
    t2 = np.array(t2)
    h = np.zeros(8)
    h[0] = 1.0
    t2[1, 0] = 1.0 - den  # row 1: den = 1 - t2[1] @ h
    cF, free = hold_forward(c, Fd_T, y_prev, h)
    with np.errstate(invalid="ignore"):
        want = _numpy_estimates(est, t2, cF, free, h)
        _same(hold_estimates(est, t2, cF, free, h), want)
        _same(hold_errors(y, est, t2, cF, free, h), y[None, :] - want)


def test_nonfinite_values_propagate_as_in_numpy():
    rng = np.random.default_rng(9)
    est, t2, c, Fd_T, y_prev, y, h = _case(rng)
    est[2, 3], y[1], c[0, 0] = math.inf, math.nan, math.nan
    with np.errstate(invalid="ignore"):
        cF, free = hold_forward(c, Fd_T, y_prev, h)
        want_cF, want_free = _numpy_forward(c, Fd_T, y_prev, h)
        _same(cF, want_cF)
        _same(free, want_free)
        want = _numpy_estimates(est, t2, cF, free, h)
        _same(hold_errors(y, est, t2, cF, free, h), y[None, :] - want)
        _same(hold_advance(cF, y, y_prev, h), cF + (y - y_prev)[:, None] * h[None, :])


def test_regressor_parts_equal_numpy():
    rng = np.random.default_rng(21)
    for _ in range(100):
        p, n, start = 5, 8, 200
        W = rng.normal(size=(p, 213))
        free, h = rng.normal(size=(p, n)), rng.uniform(0, 0.2, n)
        want_W = W.copy()
        want_W[:, start:start + n] += free
        want_d = np.zeros(213)
        want_d[start:start + n] = h
        got_W = W.copy()
        got_d = hold_regressor_parts(got_W, free, h, start)
        _same(got_W, want_W)
        _same(got_d, want_d)
