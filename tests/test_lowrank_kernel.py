"""The implicit covariance's compiled products (:mod:`controller.lowrank_kernel`)
against the same products formed by numpy in plain float64, and what they do with a
NaN or inf in their data."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.lowrank_kernel import lowrank_append, lowrank_products

#: Largest relative difference from numpy's products: the kernels may reassociate a
#: sum of at most N + r terms (N = 265), numpy's BLAS sums in its own order.
PRODUCT_RTOL = 1e-12


def _case(seed: int, N: int = 265, R: int = 88, m: int = 5):
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((N, R)) * 0.2
    W = rng.standard_normal((m, N))
    d = rng.standard_normal(N)
    return V, W, d


@pytest.mark.parametrize("r", [0, 1, 17, 40, 88])
@pytest.mark.parametrize("with_d", [True, False])
def test_products_equal_numpys(r, with_d):
    V, W, d = _case(r)
    if not with_d:
        d = np.zeros_like(d)
    c, m = 10.0, W.shape[0]
    Pc = np.full((V.shape[0], m + 1), np.nan)
    lowrank_products(V, r, c, W, d, Pc, np.full((m + 1, V.shape[1]), np.nan))
    P = c * np.eye(V.shape[0]) - V[:, :r] @ V[:, :r].T
    want = P @ np.column_stack((W.T, d))
    scale = np.abs(want).max()
    np.testing.assert_allclose(Pc, want, rtol=0, atol=PRODUCT_RTOL * scale)


@pytest.mark.parametrize("r", [0, 5, 40, 83])
def test_append_is_the_covariance_step_of_eq_4_1(r):
    """``c I - [V, B][V, B]'`` equals ``P - g_d (P W') S^-1 (P W')'``, and the Gram
    buffer holds ``[V, B]' [V, B]``."""
    V, W, _ = _case(100 + r)
    N, R = V.shape
    m, c, g_d = W.shape[0], 10.0, 0.3
    G = np.full((R, R), np.nan)
    G[:r, :r] = V[:, :r].T @ V[:, :r]
    P = c * np.eye(N) - V[:, :r] @ V[:, :r].T
    PWt = P @ W.T
    S = np.eye(m) + W @ PWt
    L_inv = np.linalg.inv(np.linalg.cholesky(S))
    L_inv[np.triu_indices(m, 1)] = np.nan  # only the lower triangle may be read
    assert lowrank_append(V, G, r, PWt, L_inv, math.sqrt(g_d), np.zeros((m, R)))
    Vn = V[:, :r + m]
    P_next = P - g_d * PWt @ np.linalg.solve(S, PWt.T)
    np.testing.assert_allclose(c * np.eye(N) - Vn @ Vn.T, P_next, rtol=0,
                               atol=PRODUCT_RTOL * np.abs(P).max())
    gram = Vn.T @ Vn
    np.testing.assert_allclose(G[:r + m, :r + m], gram, rtol=0,
                               atol=PRODUCT_RTOL * np.abs(gram).max())
    np.testing.assert_array_equal(G[:r + m, :r + m], G[:r + m, :r + m].T)


def test_append_refuses_a_nonfinite_block_and_leaves_the_gram_matrix():
    V, W, _ = _case(7)
    N, R = V.shape
    r, m = 10, W.shape[0]
    G = V.T @ V
    before = G.copy()
    PWt = W.T.copy()
    PWt[3, 2] = np.inf
    assert not lowrank_append(V, G, r, PWt, np.eye(m), 1.0, np.zeros((m, R)))
    np.testing.assert_array_equal(G, before)


def test_a_nan_in_the_data_comes_out_as_nan():
    """The kernels' fast math may reorder sums but never assumes finite values: a NaN
    in the measurement matrix reaches the products (the step then skips the sample)."""
    V, W, d = _case(3)
    m = W.shape[0]
    W[2, 11] = np.nan
    Pc = np.zeros((V.shape[0], m + 1))
    lowrank_products(V, 20, 10.0, W, d, Pc, np.zeros((m + 1, V.shape[1])))
    assert np.isnan(Pc[:, 2]).all()
    assert np.isfinite(np.delete(Pc, 2, axis=1)).all()
