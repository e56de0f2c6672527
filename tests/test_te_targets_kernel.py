"""The compiled steady-state-target arithmetic equals the numpy expressions it replaces."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.targets import VIOLATION_TOL
from controller.units.te.targets_kernel import (
    AT_BOUNDS,
    NO_TARGETS,
    PLAN,
    QP,
    offset_step,
    target_fields,
)

#: Largest difference allowed between the kernels and numpy (0: bit for bit).
TARGETS_ATOL = 0.0
_P = 2


def _numpy_offset(G, y, u, y_plan, u_plan, du_lagged, offset, lag, alpha):
    """CoreTargets.observe's numpy arithmetic (before the kernel)."""
    if not np.isfinite(np.concatenate((y, u, y_plan, u_plan))).all():
        return False, du_lagged, offset
    du = u - u_plan
    du_lagged = du_lagged + lag * (du - du_lagged)
    e = y - y_plan - G @ du_lagged
    return True, du_lagged, offset + alpha * (e - offset)


def _numpy_targets(G, u_plan, y_plan, d, u_min, u_max, band, c, lift, q, y_min, y_max,
                   y_scale):
    """CoreTargets._fields, _cheaper_within, the plan's point and _at_bounds in numpy
    (before the kernel): (outcome, cheaper, checked, u_ref, u_lo, u_hi, u, y)."""
    if not (np.isfinite(u_plan).all() and np.isfinite(y_plan).all()):
        return NO_TARGETS, False, False, None, None, None, None, None
    u_ref = np.minimum(np.maximum(u_plan, u_min), u_max)
    u_lo = np.maximum(u_min, u_ref - band)
    u_hi = np.minimum(u_max, u_ref + band)
    if c is not None:
        u_hi[_P] = min(u_hi[_P], u_ref[_P] + lift)
    moving = np.concatenate((G.ravel(), u_ref, y_plan, d, u_lo, u_hi))
    checked = bool(np.isfinite(moving).all() and (u_lo <= u_hi).all())
    cheaper = c is not None and bool(np.any(((c < 0) & (u_ref < u_hi))
                                            | ((c > 0) & (u_ref > u_lo))))
    if not cheaper:
        y_pp = y_plan + d
        if (y_pp >= y_min).all() and (y_pp <= y_max).all():
            return PLAN, cheaper, checked, u_ref, u_lo, u_hi, u_ref.copy(), y_pp
        return QP, cheaper, checked, u_ref, u_lo, u_hi, None, None
    x = -(c - q * u_ref) / q
    up, down = x >= u_hi, x <= u_lo
    if not (up | down).all():
        return QP, cheaper, checked, u_ref, u_lo, u_hi, None, None
    u = np.where(up, u_hi, u_lo)
    y = (y_plan + d) - G @ u_ref + G @ u
    tol = VIOLATION_TOL * y_scale
    if not ((y <= y_max - tol).all() and (y >= y_min + tol).all()):
        return QP, cheaper, checked, u_ref, u_lo, u_hi, None, None
    return AT_BOUNDS, cheaper, checked, u_ref, u_lo, u_hi, u, y


def _same(a, b):
    np.testing.assert_allclose(a, b, rtol=0, atol=TARGETS_ATOL)
    assert np.array_equal(a, b, equal_nan=True)


def test_offset_step_equals_numpy():
    rng = np.random.default_rng(11)
    for trial in range(300):
        G = rng.normal(size=(5, 5)) * 10.0 ** rng.uniform(-3, 2, (5, 5))
        y, y_plan = rng.normal(2700, 50, 5), rng.normal(2700, 50, 5)
        u, u_plan = rng.uniform(0, 100, 5), rng.uniform(0, 100, 5)
        du_lagged, offset = rng.normal(size=5), rng.normal(size=5)
        if trial % 10 == 0:
            (y, u, y_plan, u_plan)[trial % 4][rng.integers(5)] = (math.nan, math.inf)[trial % 2]
        lag, alpha = 1.0 - math.exp(-0.01), 1.0 - math.exp(-0.01 / rng.uniform(0.1, 3))
        ok, want_du, want_off = _numpy_offset(G, y, u, y_plan, u_plan, du_lagged, offset,
                                              lag, alpha)
        got_du, got_off = du_lagged.copy(), offset.copy()
        assert offset_step(G, y, u, y_plan, u_plan, got_du, got_off, lag, alpha) == ok
        _same(got_du, want_du)
        _same(got_off, want_off)


def _problem(rng, priced):
    G = rng.normal(size=(5, 5)) * 10.0 ** rng.uniform(-2, 1, (5, 5))
    u_min = np.array([0.0, 0.0, 2500.0, 110.0, 0.0])
    u_max = np.array([100.0, 100.0, 2950.0, 130.0, 100.0])
    u_plan = rng.uniform(u_min - 5.0, u_max + 5.0)
    band = np.where(rng.random(5) < 0.5, 0.0, rng.uniform(0, 300, 5))
    y_plan = rng.normal(2700, 100, 5)
    d = rng.normal(0, 20, 5)
    y_min = np.where(rng.random(5) < 0.7, -np.inf, rng.normal(2500, 100, 5))
    y_max = np.where(rng.random(5) < 0.3, np.inf, rng.normal(2850, 100, 5))
    q = rng.uniform(0.5, 1000, 5)
    c = None
    if priced:
        c = np.zeros(5)
        c[_P] = -rng.uniform(0.01, 1.0) * 1e4
        if rng.random() < 0.3:
            c[rng.integers(5)] = rng.normal() * 1e4
    lift = float(rng.uniform(0, 100))
    return G, u_plan, y_plan, d, u_min, u_max, band, c, lift, q, y_min, y_max, \
        rng.uniform(1, 20, 5)


def _compare(args):
    G, u_plan, y_plan, d, u_min, u_max, band, c, lift, q, y_min, y_max, y_scale = args
    want = _numpy_targets(*args)
    got = target_fields(G, u_plan, y_plan, d, u_min, u_max, band, c is not None,
                        np.zeros(5) if c is None else c, lift, _P, q, y_min, y_max,
                        VIOLATION_TOL * y_scale)
    assert got[0] == want[0]
    if want[0] == NO_TARGETS:
        return want[0]
    assert got[1:3] == want[1:3]
    for g, w in zip(got[3:6], want[3:6], strict=True):
        _same(g, w)
    if want[0] in (PLAN, AT_BOUNDS):
        _same(got[6], want[6])
        _same(got[7], want[7])
    return want[0]


@pytest.mark.parametrize("priced", [False, True])
def test_target_fields_equal_numpy_on_random_problems(priced):
    rng = np.random.default_rng(5 + priced)
    seen = set()
    for _ in range(2000):
        seen.add(_compare(_problem(rng, priced)))
    assert {PLAN, QP} <= seen if not priced else {AT_BOUNDS, QP} <= seen


@pytest.mark.parametrize("where", ["u_plan", "y_plan", "d", "G", "lo>hi", "zeros"])
def test_target_fields_edge_inputs(where):
    rng = np.random.default_rng(3)
    for priced in (False, True):
        args = list(_problem(rng, priced))
        if where == "u_plan":
            args[1][1] = math.nan
        elif where == "y_plan":
            args[2][0] = math.inf
        elif where == "d":
            args[3][2] = math.nan
        elif where == "G":
            args[0][1, 1] = math.inf
        elif where == "lo>hi":
            args[4][2], args[5][2] = 2950.0, 2500.0
        else:  # signed zeros at the limits
            args[1][:] = [-0.0, 0.0, 2500.0, 110.0, -0.0]
            args[6][:] = 0.0
        with np.errstate(invalid="ignore"):
            _compare(tuple(args))
