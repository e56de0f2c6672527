"""The compiled NLS step (``controller.nls_kernel.nls_step``) against eq. 4.1 written
with numpy/scipy dense algebra (an independent reference), and its result codes."""

import numpy as np
import pytest
import scipy.linalg

from controller import nls_kernel as nk

RTOL = 1e-12  # same arithmetic, other summation order


def _case(m=5, n=40, seed=0, with_d=True):
    rng = np.random.default_rng(seed)
    Q = rng.standard_normal((n, n))
    P = Q @ Q.T / n + np.eye(n)
    W_base = rng.standard_normal((m, n))
    d = np.zeros(n)
    if with_d:
        d[10:14] = rng.standard_normal(4)
    y = rng.standard_normal(m)
    p = rng.standard_normal(n)
    return P, W_base, d, y, p


def _run(P, W_base, d, y, p, g_d=0.05, rate=1.0, lower=None, upper=None, max_abs=1e8,
         dead_zone=0.0, freeze=False):
    n = p.size
    lower = np.full(n, -np.inf) if lower is None else lower
    upper = np.full(n, np.inf) if upper is None else upper
    m = W_base.shape[0]
    K, PWt, L_inv = np.zeros((n, m)), np.zeros((n, m)), np.zeros((m, m))
    code, e, p_new, projected, trace = nk.nls_step(
        W_base, d, np.column_stack((P @ W_base.T, P @ d)), y, p, g_d, rate, lower, upper,
        max_abs, dead_zone, freeze, K, PWt, L_inv)
    return code, e, p_new, projected, K, PWt, L_inv, trace


@pytest.mark.parametrize("with_d", [True, False])
def test_step_matches_the_dense_formula(with_d):
    P, W_base, d, y, p = _case(with_d=with_d)
    g_d, rate = 0.05, 1.0
    code, e, p_new, projected, K, PWt, L_inv, trace = _run(P, W_base, d, y, p, g_d, rate)
    W = W_base + np.outer(y, d)
    e_ref = y - W @ p
    S = np.eye(5) + rate * W @ P @ W.T
    K_ref = scipy.linalg.solve(S, W @ P, assume_a="pos").T  # P W' S^-1
    assert code == nk.OK and not projected
    np.testing.assert_allclose(e, e_ref, rtol=RTOL, atol=1e-13)
    np.testing.assert_allclose(PWt, P @ W.T, rtol=RTOL, atol=1e-12)
    np.testing.assert_allclose(K, K_ref, rtol=1e-10, atol=1e-13)
    np.testing.assert_allclose(p_new, p + g_d * K_ref @ e_ref, rtol=1e-10, atol=1e-13)
    # the inverse of S's lower Cholesky factor (the deferred covariance step uses it)
    np.testing.assert_allclose(L_inv @ np.linalg.cholesky(S), np.eye(5), rtol=0, atol=1e-12)
    assert np.array_equal(L_inv, np.tril(L_inv))
    np.testing.assert_allclose(trace, g_d * np.trace(K_ref @ (P @ W.T).T), rtol=1e-10)


def test_non_finite_output_is_invalid_data_and_leaves_p():
    P, W_base, d, y, p = _case()
    y[2] = np.nan
    code, _, p_new, *_ = _run(P, W_base, d, y, p)
    assert code == nk.INVALID_DATA
    assert p_new is p or np.array_equal(p_new, p)


def test_freeze_and_dead_zone_compute_the_error_only():
    P, W_base, d, y, p = _case()
    code, e, p_new, *_ = _run(P, W_base, d, y, p, freeze=True)
    assert code == nk.FROZEN and np.array_equal(p_new, p)
    np.testing.assert_allclose(e, y - (W_base + np.outer(y, d)) @ p, rtol=RTOL)
    big = float(np.abs(e).max())
    assert _run(P, W_base, d, y, p, dead_zone=1.01 * big)[0] == nk.DEAD_ZONE
    assert _run(P, W_base, d, y, p, dead_zone=0.99 * big)[0] == nk.OK


def test_indefinite_normalization_is_singular():
    P, W_base, d, y, p = _case()
    assert _run(-P, W_base, d, y, p)[0] == nk.SINGULAR  # S = I - W P W' not PD


def test_too_large_parameters_are_diverged_and_the_box_projects():
    P, W_base, d, y, p = _case()
    ok = _run(P, W_base, d, y, p)
    assert _run(P, W_base, d, y, p, max_abs=0.5 * np.abs(ok[2]).max())[0] == nk.DIVERGED
    lower = np.full(p.size, -0.1)
    upper = np.full(p.size, 0.1)
    code, _, p_new, projected, *_ = _run(P, W_base, d, y, p, lower=lower, upper=upper)
    assert code == nk.OK and projected
    np.testing.assert_array_equal(p_new, np.clip(ok[2], -0.1, 0.1))
