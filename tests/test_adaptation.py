"""Normalized least squares (eq. 4.1): convergence, boundedness, resets, bad input."""

import json

import numpy as np
import pytest

from controller.adaptation import AdaptiveKind, NLSSettings, NormalizedLeastSquares

PARAM_RTOL = 0.01  # R4.1: with PE, theta converges to the true value within 1 %


def _arx_data(theta, n_samples, rng, excite=True):
    """Regressors and outputs of y(k) = a1 y(k-1) + a2 y(k-2) + b1 u(k-1) + b2 u(k-2)."""
    a1, a2, b1, b2 = theta
    y = np.zeros(n_samples + 2)
    u = np.sign(rng.standard_normal(n_samples + 2)) if excite else np.ones(n_samples + 2)
    rows, outs = [], []
    for k in range(2, n_samples + 2):
        w = np.array([y[k - 1], y[k - 2], u[k - 1], u[k - 2]])
        y[k] = w @ theta
        rows.append(w[None, :])
        outs.append(np.array([y[k]]))
    return rows, outs


def test_converges_to_true_parameters_of_a_known_arx_plant_under_pe():
    rng = np.random.default_rng(1)
    theta = np.array([1.2, -0.5, 0.4, 0.2])  # poles 0.6 +/- 0.37j, stable
    rows, outs = _arx_data(theta, 400, rng)
    nls = NormalizedLeastSquares(NLSSettings(kappa=10, gain=1.0, rate=1.0), np.zeros(4), dt=1.0)
    for W, y in zip(rows, outs):
        nls.update(W, y)
    np.testing.assert_allclose(nls.p, theta, rtol=PARAM_RTOL)


def test_mimo_measurement_matrix_converges():
    rng = np.random.default_rng(2)
    p_true = rng.standard_normal(7)
    nls = NormalizedLeastSquares(NLSSettings(gain=5.0, rate=1.0), np.zeros(7), dt=0.1)
    for _ in range(600):
        W = rng.standard_normal((3, 7))  # three outputs share some parameters
        nls.update(W, W @ p_true)
    np.testing.assert_allclose(nls.p, p_true, rtol=PARAM_RTOL, atol=1e-6)


def test_covariance_floor_holds_and_resets_are_counted():
    rng = np.random.default_rng(3)
    s = NLSSettings(kappa=10, gain=1.0, rate=1.0, eig_floor=1.0)
    nls = NormalizedLeastSquares(s, np.zeros(4), dt=1.0)
    rows, outs = _arx_data(np.array([1.2, -0.5, 0.4, 0.2]), 300, rng)
    for W, y in zip(rows, outs):
        nls.update(W, y)
        assert nls.smallest_eigenvalue() > s.eig_floor
    assert nls.n_resets > 0
    assert nls.reset_reasons.get("floor", 0) == nls.n_resets


def test_bounded_without_excitation_and_with_noise():
    rng = np.random.default_rng(4)
    s = NLSSettings(kappa=10, gain=1.0, rate=1.0)
    nls = NormalizedLeastSquares(s, np.zeros(3), dt=1.0)
    W = np.array([[1.0, 2.0, 1.0]])  # constant regressor: not persistently exciting
    for _ in range(5000):
        nls.update(W, np.array([3.0 + 0.1 * rng.standard_normal()]))
    assert np.all(np.isfinite(nls.p)) and np.linalg.norm(nls.p) < 10.0
    assert np.all(np.isfinite(nls.P))
    assert s.eig_floor < nls.smallest_eigenvalue() <= s.reset_to + 1e-9


def test_nan_measurement_skips_the_update_and_leaves_state_clean():
    nls = NormalizedLeastSquares(NLSSettings(), np.ones(3), dt=0.05)
    p0, P0 = nls.p.copy(), nls.P.copy()
    step = nls.update(np.array([[1.0, np.nan, 0.0]]), np.array([1.0]))
    assert not step.updated and step.reason == "invalid_data"
    step = nls.update(np.array([[1.0, 0.0, 0.0]]), np.array([np.nan]))
    assert not step.updated
    assert nls.n_skipped == 2
    np.testing.assert_array_equal(nls.p, p0)
    np.testing.assert_array_equal(nls.P, P0)


@pytest.mark.parametrize("W", [
    [[np.inf, 1.0, 1.0]],        # inf against a zero parameter
    [[np.inf, -np.inf, 1.0]],    # infinities that would cancel
    [[1.0, 1.0, 1.0], [np.nan, 0.0, 0.0]],
])
def test_nonfinite_regressor_skips_even_where_it_meets_zero_parameters(W):
    nls = NormalizedLeastSquares(NLSSettings(), np.array([0.0, 0.0, 2.0]), dt=0.05)
    W = np.array(W)
    step = nls.update(W, np.ones(W.shape[0]))
    assert not step.updated and step.reason == "invalid_data"
    assert np.isnan(step.error).all() and nls.n_skipped == 1
    np.testing.assert_array_equal(nls.p, [0.0, 0.0, 2.0])


def test_covariance_set_from_outside_is_checked_at_the_next_update():
    nls = NormalizedLeastSquares(NLSSettings(), np.zeros(2), dt=0.05)
    P = np.eye(2)
    P[1, 0] = np.nan
    nls.P = P
    step = nls.update(np.array([[1.0, 1.0]]), np.array([1.0]))
    assert step.updated and nls.reset_reasons == {"nonfinite": 1}
    assert np.isfinite(nls.p).all() and np.isfinite(nls.P).all()


def test_singular_covariance_is_reset_and_counted():
    nls = NormalizedLeastSquares(NLSSettings(), np.zeros(3), dt=0.05)
    state = nls.checkpoint()
    state["P"] = np.zeros((3, 3)).tolist()
    nls.restore(json.loads(json.dumps(state)))
    step = nls.update(np.array([[1.0, 0.5, 0.0]]), np.array([1.0]))
    assert step.reset and step.reason == "singular"
    assert nls.reset_reasons == {"singular": 1}
    assert nls.smallest_eigenvalue() == pytest.approx(nls.settings.reset_to)


def test_nonfinite_covariance_is_reset_and_no_nan_enters_parameters():
    nls = NormalizedLeastSquares(NLSSettings(), np.zeros(2), dt=0.05)
    nls.P[0, 0] = np.inf
    nls.update(np.array([[1.0, 1.0]]), np.array([1.0]))
    assert nls.reset_reasons.get("nonfinite") == 1
    assert np.all(np.isfinite(nls.p)) and np.all(np.isfinite(nls.P))


def test_checkpoint_round_trip_continues_identically():
    rng = np.random.default_rng(5)
    rows, outs = _arx_data(np.array([1.2, -0.5, 0.4, 0.2]), 60, rng)
    a = NormalizedLeastSquares(NLSSettings(gain=1, rate=1), np.zeros(4), dt=1.0)
    for W, y in zip(rows[:30], outs[:30]):
        a.update(W, y)
    b = NormalizedLeastSquares(NLSSettings(gain=1, rate=1), np.zeros(4), dt=1.0)
    b.restore(json.loads(json.dumps(a.checkpoint())))
    for W, y in zip(rows[30:], outs[30:]):
        a.update(W, y)
        b.update(W, y)
    np.testing.assert_allclose(a.p, b.p, rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize(
    "kwargs, field",
    [({"kappa": 0}, "kappa"), ({"gain": -1}, "gain"), ({"rate": float("nan")}, "rate"),
     ({"eig_floor": 20.0}, "kappa"), ({"reset_value": 0.5}, "reset_value")],
)
def test_settings_name_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        NLSSettings(**kwargs)


def test_per_sample_gain_above_rate_is_rejected():
    with pytest.raises(ValueError, match="gain"):
        NormalizedLeastSquares(NLSSettings(gain=50.0, rate=1.0), np.zeros(2), dt=0.1)


def test_adaptive_kind_parse():
    assert AdaptiveKind.parse("free-running") is AdaptiveKind.FREE_RUNNING
    assert AdaptiveKind.parse("REINITIALIZED") is AdaptiveKind.REINITIALIZED
    assert not AdaptiveKind.FIXED.adaptive
    with pytest.raises(ValueError, match="kind"):
        AdaptiveKind.parse("sometimes")


def _mimo_data(n_samples, rng, n=2, m=2, dt=0.1):
    """Regressors of a state-shared model whose outputs are generated by a known model."""
    from controller.state_shared import ModelSpec, StateSharedModel

    a = [2.0, 3.0] if n == 2 else list(np.poly(-np.arange(1.0, n + 1))[1:][::-1])
    theta = np.zeros((2 * n * m, m))
    theta[: n * m] = 0.3 * rng.standard_normal((n * m, m))
    t2 = np.array([-0.5, 0.4])[:n]
    for i in range(m):
        theta[n * m + i * n : n * m + (i + 1) * n, i] = t2
    bias = rng.standard_normal(m)
    ssm = StateSharedModel(a, m, dt, [ModelSpec("true", theta, bias)])
    p_true = ssm.params_from_theta(theta, bias)
    ssm.initialize(np.zeros(m), ssm.estimates()[0])
    rows, outs = [], []
    u = np.zeros(m)
    for k in range(n_samples):
        W = ssm.regressor()
        y = W @ p_true
        rows.append(W)
        outs.append(y)
        if k % 5 == 0:
            u = np.sign(rng.standard_normal(m))
        ssm.update(u, y)
    return rows, outs, p_true


def test_mimo_state_shared_parameters_converge_under_pe():
    rng = np.random.default_rng(7)
    rows, outs, p_true = _mimo_data(3000, rng)
    s = NLSSettings(kappa=1000.0, gain=10.0, rate=1.0, eig_floor=1e-3)
    est = NormalizedLeastSquares(s, np.zeros_like(p_true), 0.1)
    for W, y in zip(rows, outs):
        est.update(W, y)
    np.testing.assert_allclose(est.p, p_true, rtol=PARAM_RTOL, atol=PARAM_RTOL * 0.1)


def test_implicit_low_rank_covariance_runs_the_same_algorithm_as_the_dense_one():
    # N = 130 >= lowrank_min_params: implicit c I - V V'; a twin forced dense must agree
    rng = np.random.default_rng(9)
    N, m = 130, 3
    p_true = rng.standard_normal(N)
    # exact floor checks in both (the dense form otherwise resets on the cheap bound)
    implicit = NLSSettings(kappa=10.0, gain=5.0, rate=1.0, lowrank_max_rank=40,
                           exact_check_max_params=200)
    dense = NLSSettings(kappa=10.0, gain=5.0, rate=1.0, lowrank_min_params=10**6,
                        exact_check_max_params=200)
    a = NormalizedLeastSquares(implicit, np.zeros(N), 0.1)
    b = NormalizedLeastSquares(dense, np.zeros(N), 0.1)
    assert a._Pd is None and b._Pd is not None
    for k in range(60):
        W = rng.standard_normal((m, N)) / np.sqrt(N)
        y = W @ p_true
        sa, sb = a.update(W, y), b.update(W, y)
        assert sa.reset == sb.reset
        if k == 30:  # checkpoint of the implicit form restores exactly
            twin = NormalizedLeastSquares(implicit, np.zeros(N), 0.1)
            twin.restore(json.loads(json.dumps(a.checkpoint())))
            np.testing.assert_allclose(twin.P, a.P, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(a.p, b.p, rtol=1e-9, atol=1e-10)
    np.testing.assert_allclose(a.P, b.P, rtol=1e-9, atol=1e-9)
    assert a.smallest_eigenvalue() == pytest.approx(b.smallest_eigenvalue(), rel=1e-9)
