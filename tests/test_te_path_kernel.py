"""The compiled plan-path arithmetic equals the numpy expression it replaces, to the last bit."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.path_kernel import path_exponents, path_values

#: Largest difference allowed between the kernels and numpy (0: bit for bit).
PATH_ATOL = 0.0
N_XMEAS, N_XMV = 41, 12


def _numpy_path(t, offsets, times, tau_div, positive, start, target):
    """SampleReferences' numpy expression (before the kernels)."""
    tt = t + offsets
    i = np.searchsorted(times, tt, side="right") - 1
    dt = (tt - times[i])[:, None]
    a = np.exp(-dt / tau_div[i])
    if not positive.all():
        a = np.where(positive[i], a, 0.0)
    tg = target[i]
    r = tg + (start[i] - tg) * a
    return (np.ascontiguousarray(r[:, :N_XMEAS]), r[[0, -1], N_XMEAS:N_XMEAS + N_XMV],
            float(r[0, N_XMEAS + N_XMV]))


def _kernel_path(t, offsets, times, tau_div, positive, start, target):
    seg = np.empty(offsets.size, dtype=np.int64)
    x = np.empty((offsets.size, tau_div.shape[1]))
    path_exponents(float(t), offsets, times, tau_div, seg, x)
    np.exp(x, out=x)
    return path_values(x, seg, positive, bool(positive.all()), start, target, N_XMEAS, N_XMV)


def _table(rng, n_switch, steps):
    n = N_XMEAS + N_XMV + 1
    times = np.concatenate([[-math.inf], np.sort(rng.uniform(0.0, 40.0, n_switch))])
    L = times.size
    tau = rng.uniform(0.05, 3.0, (L, n))
    if steps:
        tau[rng.random((L, n)) < 0.3] = 0.0
    positive = tau > 0
    tau_div = np.ascontiguousarray(np.where(positive, tau, 1.0))
    start = rng.normal(0.0, 1.0, (L, n)) * 10.0 ** rng.uniform(-2, 3, (L, n))
    target = rng.normal(0.0, 1.0, (L, n)) * 10.0 ** rng.uniform(-2, 3, (L, n))
    start[0] = target[0]  # the start segment holds the start grade
    return times, tau_div, positive, start, target


def _assert_same(got, want):
    for g, w in zip(got[:2], want[:2], strict=True):
        assert g.shape == w.shape
        np.testing.assert_allclose(g, w, rtol=0, atol=PATH_ATOL)
        assert np.array_equal(g, w, equal_nan=True)
    assert got[2] == want[2] or (math.isnan(got[2]) and math.isnan(want[2]))


@pytest.mark.parametrize("steps", [False, True])
@pytest.mark.parametrize("horizon", [0, 1, 10])
def test_random_tables_bit_for_bit(steps, horizon):
    rng = np.random.default_rng(7 + horizon + 100 * steps)
    for _ in range(40):
        times, tau_div, positive, start, target = _table(rng, int(rng.integers(0, 5)), steps)
        offsets = float(rng.uniform(0.001, 0.5)) * np.arange(horizon + 1)
        sw = times[1:]
        ts = np.concatenate([rng.uniform(-1.0, 48.0, 10), sw, sw - 1e-12, sw + 1e-12,
                             [0.0]])
        for t in ts:
            args = (float(t), offsets, times, tau_div, positive, start, target)
            _assert_same(_kernel_path(*args), _numpy_path(*args))


@pytest.mark.parametrize("t", [math.nan, math.inf, -math.inf, -1e300, 1e300])
def test_edge_times_as_numpy(t):
    rng = np.random.default_rng(3)
    times, tau_div, positive, start, target = _table(rng, 3, True)
    offsets = 0.01 * np.arange(11)
    args = (t, offsets, times, tau_div, positive, start, target)
    with np.errstate(invalid="ignore"):
        _assert_same(_kernel_path(*args), _numpy_path(*args))
