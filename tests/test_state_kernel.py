"""The compiled read-outs of the shared state equal the numpy expressions (eq. 3.10)."""

import numpy as np
import pytest

from controller.state_shared import ModelSpec, StateSharedModel


def _model(rng, n=3, m=2, p=None, k=4):
    ssm = StateSharedModel(tuple(float(c) for c in np.poly(-np.arange(1.0, n + 1))[1:][::-1]),
                           m, 0.1, p=p)
    for j in range(k):
        par = 0.1 * rng.standard_normal(ssm.n_params + ssm.p)
        theta, bias = ssm.theta_from_params(par)
        ssm.add_model(ModelSpec(f"M{j}", theta, bias, "adaptive" if j == k - 1 else "fixed"))
    ssm.initialize(rng.standard_normal(m), rng.standard_normal(ssm.p))
    for _ in range(5):
        ssm.update(rng.standard_normal(m), rng.standard_normal(ssm.p))
    return ssm


@pytest.mark.parametrize("p", [None, 3])  # square, and more outputs than inputs
def test_errors_equal_the_stacked_estimates_expression(p):
    rng = np.random.default_rng(1)
    ssm = _model(rng, p=p)
    for _ in range(10):
        y = rng.standard_normal(ssm.p)
        expected = y[None, :] - ((ssm._Taug @ ssm._Z.reshape(-1)).reshape(-1, ssm.p) + ssm._B)
        np.testing.assert_array_equal(ssm.errors(y), expected)
        # and the model-by-model reading Theta_j^T n + b_j, to round-off
        n = ssm.n
        by_model = np.stack([y - (ssm.theta(j).T @ n + ssm.bias(j)) for j in range(ssm.k)])
        np.testing.assert_allclose(ssm.errors(y), by_model, rtol=1e-12, atol=1e-14)
        ssm.update(rng.standard_normal(ssm.m), y)


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [0.0, np.inf], [1.0]])
def test_bad_measurement_still_names_the_field(bad):
    ssm = _model(np.random.default_rng(2))
    with pytest.raises(ValueError, match="^y: "):
        ssm.errors(np.array(bad))


@pytest.mark.parametrize("p", [None, 3])
def test_set_params_writes_what_set_theta_writes(p):
    rng = np.random.default_rng(3)
    a, b = _model(rng, p=p), _model(np.random.default_rng(3), p=p)
    j = a.k - 1
    for _ in range(3):
        par = rng.standard_normal(a.n_params + a.p)
        a.set_params(j, par)
        theta, bias = b.theta_from_params(par)
        b.set_theta(j, theta, bias)
        np.testing.assert_array_equal(a._T, b._T)
        np.testing.assert_array_equal(a._Taug, b._Taug)
        np.testing.assert_array_equal(a._B, b._B)
        np.testing.assert_array_equal(a.theta(j), theta)
        np.testing.assert_array_equal(a.params_from_theta(a.theta(j), a.bias(j)), par)


@pytest.mark.parametrize("p", [None, 3])
def test_regressor_predicts_every_structured_model(p):
    """``W p_j`` is model j's estimate ``Theta_j^T n + b_j`` (the regressor's meaning)."""
    rng = np.random.default_rng(4)
    ssm = _model(rng, p=p)
    for _ in range(5):
        W = ssm.regressor()
        assert W.shape == (ssm.p, ssm.n_params + ssm.p)
        n = ssm.n
        for j in range(ssm.k):
            p_j = ssm.params_from_theta(ssm.theta(j), ssm.bias(j))
            np.testing.assert_allclose(W @ p_j, ssm.theta(j).T @ n + ssm.bias(j),
                                       rtol=1e-12, atol=1e-14)
        ssm.update(rng.standard_normal(ssm.m), rng.standard_normal(ssm.p))


#: Largest difference allowed between advance_state and numpy (0: bit for bit).
ADVANCE_ATOL = 0.0


@pytest.mark.parametrize("shape", [(5, 5, 8), (2, 3, 4), (1, 1, 2)])
def test_advance_state_equals_numpy(shape):
    """``Z[:, -1] = [u; y]; Z[:, :-1] = Z @ M`` (n > 1, where numpy's product is dgemm)."""
    from controller.state_kernel import advance_state

    m, p, n = shape
    rng = np.random.default_rng(m + 10 * p + 100 * n)
    for trial in range(200):
        Z = rng.normal(size=(m + p, n + 1)) * 10.0 ** rng.uniform(-3, 3, (m + p, n + 1))
        M = rng.normal(size=(n + 1, n)) * 0.5
        u, y = rng.normal(size=m) * 100.0, rng.normal(size=p) * 1000.0
        if trial % 20 == 0:
            (u if trial % 40 else y)[0] = (np.nan, np.inf)[trial % 3 == 0]
        want = Z.copy()
        finite = bool(np.isfinite(u).all() and np.isfinite(y).all())
        if finite:
            want[:, -1] = np.concatenate((u, y))
            want[:, :-1] = want @ M
        got = Z.copy()
        assert advance_state(got, M, u, y) is finite
        np.testing.assert_allclose(got, want, rtol=0, atol=ADVANCE_ATOL)
        assert np.array_equal(got, want)


def test_update_rejects_bad_samples_without_touching_the_state():
    ssm = StateSharedModel(np.array([1.0, 3.0, 2.0]), 2, 0.1)
    ssm.initialize(np.ones(2), np.ones(2))
    before = ssm.n.copy()
    for u, y in ((np.array([np.nan, 1.0]), np.ones(2)), (np.ones(2), np.array([1.0, np.inf]))):
        with pytest.raises(ValueError):
            ssm.update(u, y)
        np.testing.assert_array_equal(ssm.n, before)
