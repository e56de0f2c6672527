"""The Cholesky floor test decides as the smallest eigenvalue does (numpy's eigvalsh)."""

import numpy as np
import pytest

from controller.adaptation import NLSSettings, NormalizedLeastSquares
from controller.definiteness import ABOVE, FLOOR, SINGULAR, floor_check, lowrank_floor_check

FLOOR_VALUE = 1.0


def _eig_decision(P: np.ndarray, floor: float) -> str:
    """The eigenvalue test the Cholesky test replaces (the former reset rule)."""
    lam = float(np.linalg.eigvalsh(P)[0])
    if lam > floor:
        return ABOVE
    return FLOOR if lam > 0 else SINGULAR


def _spd_with_spectrum(rng, eigenvalues) -> np.ndarray:
    n = len(eigenvalues)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    P = (Q * np.asarray(eigenvalues, dtype=float)) @ Q.T
    return 0.5 * (P + P.T)


def _cases(rng):
    """(P, lambda_min) of random, near-singular and indefinite matrices, N = 2..120."""
    for n in (2, 5, 16, 40, 64, 120):
        for lam_min in (5.0, 1.0 + 1e-6, 1.0 - 1e-6, 0.5, 1e-12, 0.0, -1e-9, -3.0):
            rest = rng.uniform(max(lam_min, 0.0) + 0.1, 50.0, size=n - 1)
            yield _spd_with_spectrum(rng, np.r_[lam_min, rest]), lam_min
        X = rng.standard_normal((n, n))
        P = X @ X.T / n + rng.uniform(0.0, 3.0) * np.eye(n)  # a plain random SPD matrix
        yield P, float(np.linalg.eigvalsh(P)[0])
        X = rng.standard_normal((n, n))
        yield 0.5 * (X + X.T), float(np.linalg.eigvalsh(0.5 * (X + X.T))[0])  # indefinite


def test_dense_decision_is_the_eigenvalue_decision():
    rng = np.random.default_rng(11)
    seen = set()
    for P, lam in _cases(rng):
        if min(abs(lam - FLOOR_VALUE), abs(lam)) < 1e-10 * max(1.0, np.abs(P).max()):
            continue  # inside the round-off band, where either test may go either way
        outcome, bound = floor_check(P, FLOOR_VALUE)
        assert outcome == _eig_decision(P, FLOOR_VALUE), (P.shape, lam)
        assert bound == FLOOR_VALUE
        seen.add(outcome)
    assert seen == {ABOVE, FLOOR, SINGULAR}


def test_near_singular_and_zero_eigenvalues_are_singular_not_floor():
    rng = np.random.default_rng(12)
    for lam_min in (1e-14, 0.0, -1e-14):
        P = _spd_with_spectrum(rng, np.r_[lam_min, np.linspace(2.0, 20.0, 29)])
        assert floor_check(P, FLOOR_VALUE)[0] in (FLOOR, SINGULAR)  # below the floor
    P = _spd_with_spectrum(rng, np.r_[-1e-6, np.linspace(2.0, 20.0, 29)])
    assert floor_check(P, FLOOR_VALUE)[0] == SINGULAR


def test_bound_is_above_the_floor_and_below_the_smallest_eigenvalue():
    rng = np.random.default_rng(13)
    for n in (3, 20, 64):
        for lam_min in (1.001, 1.5, 4.0, 9.9):
            P = _spd_with_spectrum(rng, np.r_[lam_min, rng.uniform(lam_min, 10.0, n - 1)])
            outcome, bound = floor_check(P, FLOOR_VALUE, want_bound=True)
            assert outcome == ABOVE
            assert FLOOR_VALUE < bound <= lam_min * (1 + 1e-12)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nonfinite_covariance_is_singular(bad):
    P = 5.0 * np.eye(4)
    P[1, 2] = P[2, 1] = bad
    assert floor_check(P, FLOOR_VALUE)[0] == SINGULAR
    assert lowrank_floor_check(5.0, np.full((2, 2), bad), FLOOR_VALUE)[0] == SINGULAR


def test_lowrank_decision_is_the_eigenvalue_decision_of_the_dense_matrix():
    rng = np.random.default_rng(14)
    seen = set()
    for N, r in ((10, 3), (50, 20), (130, 80), (8, 12)):
        for c in (10.0, 3.0, 1.0, 0.5):
            for scale in (0.01, 0.1, 0.3, 1.0):
                V = scale * rng.standard_normal((N, r))
                P = c * np.eye(N) - V @ V.T
                lam = float(np.linalg.eigvalsh(P)[0])
                if min(abs(lam - FLOOR_VALUE), abs(lam)) < 1e-10 * max(1.0, c):
                    continue
                outcome, bound = lowrank_floor_check(c, V.T @ V, FLOOR_VALUE, want_bound=True)
                assert outcome == _eig_decision(P, FLOOR_VALUE), (N, r, c, scale)
                if outcome == ABOVE:
                    assert FLOOR_VALUE < bound <= lam * (1 + 1e-12)
                seen.add(outcome)
    assert seen == {ABOVE, FLOOR, SINGULAR}


def test_lowrank_without_columns_is_the_identity_part():
    empty = np.zeros((0, 0))
    assert lowrank_floor_check(10.0, empty, FLOOR_VALUE) == (ABOVE, 10.0)
    assert lowrank_floor_check(0.7, empty, FLOOR_VALUE)[0] == FLOOR
    assert lowrank_floor_check(-1.0, empty, FLOOR_VALUE)[0] == SINGULAR


def _explicit(nls) -> np.ndarray:
    """The estimator's covariance as a dense matrix, without changing its form."""
    if nls._Pd is not None:
        return nls._Pd.copy()
    return nls._c * np.eye(nls.n_params) - nls._V @ nls._V.T


@pytest.mark.parametrize("n_params", [6, 150])  # dense, and implicit c I - V V' until dense
def test_estimator_resets_exactly_when_the_smallest_eigenvalue_reaches_the_floor(n_params):
    """At every step: the textbook covariance update (eq. 4.1 with g_d = gamma, i.e.
    recursive least squares) of the explicit covariance, and the reset exactly when
    its smallest eigenvalue (eigvalsh) is at or below the floor."""
    rng = np.random.default_rng(15)
    s = NLSSettings(kappa=10.0, gain=1.0, rate=1.0, eig_floor=1.0,
                    exact_check_max_params=200)
    nls = NormalizedLeastSquares(s, np.zeros(n_params), dt=1.0)
    decided = {True: 0, False: 0}
    for _ in range(150):
        W = rng.standard_normal((2, n_params)) * rng.uniform(0.05, 1.0) / np.sqrt(n_params)
        y = rng.standard_normal(2)
        P = _explicit(nls)
        S = np.eye(2) + W @ P @ W.T
        P_next = P - P @ W.T @ np.linalg.solve(S, W @ P)
        lam = float(np.linalg.eigvalsh(0.5 * (P_next + P_next.T))[0])
        if abs(lam - s.eig_floor) < 1e-8:
            continue  # round-off band
        before = nls.n_resets
        nls.update(W, y)
        reset = nls.n_resets > before
        assert reset == (lam <= s.eig_floor), lam
        if not reset:
            np.testing.assert_allclose(_explicit(nls), P_next, atol=1e-9)
        decided[reset] += 1
    assert decided[True] > 3 and decided[False] > 10


def test_incremental_factor_decides_as_the_eigenvalues_block_by_block():
    """V grown by blocks of 3 columns: the Gram buffer holds V' V, the rows of the factor
    added per block are those of the whole matrix's Cholesky factor, and the check says
    "above" exactly while lambda_min(c I - V V') > floor."""
    from controller.definiteness import cholesky_extend
    from controller.lowrank_kernel import lowrank_append

    rng = np.random.default_rng(21)
    n, cap, c = 40, 30, 10.0
    V, G, L = np.zeros((n, cap)), np.zeros((cap, cap)), np.zeros((cap, cap))
    r, done, outcomes = 0, 0, set()
    while r + 3 <= cap:
        block = rng.standard_normal((n, 3)) * 0.35
        assert lowrank_append(V, G, r, block, np.eye(3), 1.0, np.zeros((3, cap)))
        np.testing.assert_array_equal(V[:, r:r + 3], block)
        r += 3
        np.testing.assert_allclose(G[:r, :r], V[:, :r].T @ V[:, :r], rtol=0, atol=1e-12)
        np.testing.assert_array_equal(G[:r, :r], G[:r, :r].T)
        lam = float(np.linalg.eigvalsh(c * np.eye(n) - V[:, :r] @ V[:, :r].T)[0])
        if abs(lam - FLOOR_VALUE) < 1e-9:
            continue
        done = cholesky_extend(L, G, done, r, c - FLOOR_VALUE)
        above = done == r
        assert above == (lam > FLOOR_VALUE), (r, lam)
        outcomes.add(above)
        if above:
            want = np.linalg.cholesky((c - FLOOR_VALUE) * np.eye(r) - G[:r, :r])
            np.testing.assert_allclose(np.tril(L[:r, :r]), want, rtol=0, atol=1e-10)
        else:
            break
    assert outcomes == {True, False}
