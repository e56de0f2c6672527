"""Orthonormal shared-state basis: input-normal pair, exact representation up to order 400."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg
import scipy.signal

from controller.linear import Realization
from controller.shared_basis import SharedBasis, orthonormal_block, roots_from_poles
from controller.state_shared import StateSharedModel

FREQ_RTOL = 1e-9  # required relative frequency-response agreement (well-conditioned basis)


def random_model(rng, n, m, spread, p=None, complex_pairs=0, skew=0.0):
    """Random stable (A, B, C): real poles spread geometrically over ``spread``, some
    complex pairs, an optional non-normal part; and its poles."""
    p = m if p is None else p
    mags = np.geomspace(1 / np.sqrt(spread), np.sqrt(spread), n)
    poles = list(-mags[: n - 2 * complex_pairs])
    D = np.diag(-mags).astype(float)
    for k in range(complex_pairs):
        i = n - 2 * (k + 1)
        r, w = mags[i], 0.8 * mags[i]
        D[i:i + 2, i:i + 2] = [[-r, w], [-w, -r]]
        poles += [complex(-r, w), complex(-r, -w)]
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = Q @ (D + skew * np.triu(rng.standard_normal((n, n)), 2)) @ Q.T
    return A, rng.standard_normal((n, m)), rng.standard_normal((p, n)), np.array(poles)


def rel_freq_error(ssm, j, A, B, C, w):
    Ac, Bc, Cc, _, _ = ssm.continuous_form(j)
    ref = Realization(A, B, C, None).frequency_response(w)
    ours = Realization(Ac, Bc, Cc, None).frequency_response(w)
    return float(np.max(np.abs(ours - ref)) / np.max(np.abs(ref)))


# -- the pair --------------------------------------------------------------------------
def test_orthonormal_pair_is_input_normal_with_omegas_roots():
    roots = [-0.1, -1.0 + 2.0j, -1.0 - 2.0j, -30.0, -0.5 + 0.1j, -0.5 - 0.1j]
    F, g = orthonormal_block(roots)
    P = scipy.linalg.solve_continuous_lyapunov(F, -np.outer(g, g))
    np.testing.assert_allclose(P, np.eye(6), atol=1e-12)
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(F)), np.sort_complex(roots),
                               rtol=1e-10)


def test_white_input_regressor_covariance_is_the_identity():
    # discrete ZOH state under white piecewise-constant input: covariance ~ dt I
    n, dt = 20, 1e-3
    roots = -np.geomspace(0.1, 10.0, n)
    orth = StateSharedModel(SharedBasis.orthonormal(roots), 1, dt)
    P = scipy.linalg.solve_discrete_lyapunov(orth.Fd, orth.Gd @ orth.Gd.T) / dt
    assert np.linalg.cond(P) < 1.1
    comp = StateSharedModel(SharedBasis.orthonormal(roots[:8]).a, 1, dt)  # the seed's
    Pc = scipy.linalg.solve_discrete_lyapunov(comp.Fd, comp.Gd @ comp.Gd.T) / dt
    assert np.linalg.cond(Pc) > 1e6


@pytest.mark.parametrize("bad", [[], [0.5], [-1.0 + 1.0j], [np.nan], [-1.0, 0.0]])
def test_bad_roots_rejected(bad):
    with pytest.raises(ValueError, match="roots"):
        SharedBasis.orthonormal(bad)


def test_bad_basis_name_rejected():
    with pytest.raises(ValueError, match="basis"):
        StateSharedModel([1.0, 1.0], 2, 0.1, basis="legendre")


# -- representation --------------------------------------------------------------------
@pytest.mark.parametrize("n,m,spread", [(10, 5, 100.0), (20, 5, 100.0), (40, 5, 10.0),
                                        (40, 5, 100.0)])
def test_random_mimo_represented_to_1e9_up_to_order_400(n, m, spread):
    rng = np.random.default_rng(n * 7 + int(spread))
    A, B, C, poles = random_model(rng, n, m, spread, complex_pairs=2, skew=0.2)
    basis = SharedBasis.orthonormal(1.1 * poles)
    spec = StateSharedModel.model_from_linear("M", A, B, C, np.zeros(m), np.zeros(m), basis)
    ssm = StateSharedModel(basis, m, 0.1, [spec])
    assert ssm.order == 2 * n * m
    w = np.logspace(np.log10(1 / np.sqrt(spread)) - 2, np.log10(np.sqrt(spread)) + 2, 41)
    assert rel_freq_error(ssm, 0, A, B, C, w) <= FREQ_RTOL


def test_geometric_roots_and_lower_degree_model_padded():
    rng = np.random.default_rng(3)
    A, B, C, _ = random_model(rng, 4, 2, 10.0, p=3)
    basis = SharedBasis.orthonormal(-np.geomspace(0.2, 5.0, 7))
    for pad in (None, 2.0):
        spec = StateSharedModel.model_from_linear("M", A, B, C, [0, 0], [0, 0, 0], basis,
                                                  pad_root=pad, square=False)
        ssm = StateSharedModel(basis, 2, 0.1, [spec], p=3)
        assert rel_freq_error(ssm, 0, A, B, C, np.logspace(-3, 3, 31)) <= FREQ_RTOL
    with pytest.raises(ValueError, match="square"):
        StateSharedModel.model_from_linear("M", A, B, C, [0, 0], [0, 0, 0], basis)
    with pytest.raises(ValueError, match="degree"):
        StateSharedModel.model_from_linear("M", *random_model(rng, 9, 2, 10.0)[:3], [0, 0],
                                           [0, 0], basis)


def test_unstable_model_with_reflected_roots():
    rng = np.random.default_rng(5)
    A, B, C, _ = random_model(rng, 6, 3, 10.0)
    A = A + 0.6 * np.eye(6)  # two poles in the right half plane
    lam = np.linalg.eigvals(A)
    assert lam.real.max() > 0
    basis = SharedBasis.orthonormal(roots_from_poles(lam))
    spec = StateSharedModel.model_from_linear("M", A, B, C, np.zeros(3), np.zeros(3), basis)
    ssm = StateSharedModel(basis, 3, 0.1, [spec])
    assert rel_freq_error(ssm, 0, A, B, C, np.logspace(-2, 2, 41)) <= FREQ_RTOL


def test_same_model_same_response_in_both_bases():
    # the basis changes the coordinates, not the model: estimates along a trajectory agree
    rng = np.random.default_rng(9)
    A, B, C, poles = random_model(rng, 3, 2, 5.0)
    u_op, y_op = np.array([1.0, -2.0]), np.array([10.0, 3.0])
    orth = SharedBasis.orthonormal(1.2 * poles)
    comp = orth.a
    models = {}
    for name, b in (("orth", orth), ("comp", comp)):
        spec = StateSharedModel.model_from_linear("M", A, B, C, u_op, y_op, b)
        models[name] = StateSharedModel(b, 2, 0.05, [spec])
        models[name].initialize(u_op, y_op)
    np.testing.assert_allclose(models["orth"].estimates(), [y_op], rtol=1e-12)
    for _ in range(200):
        u, y = u_op + rng.standard_normal(2), y_op + rng.standard_normal(2)
        for ssm in models.values():
            ssm.update(u, y)
        np.testing.assert_allclose(models["orth"].estimates(), models["comp"].estimates(),
                                   rtol=1e-9, atol=1e-9)


# -- the state-shared model in orthonormal coordinates ---------------------------------
def test_update_is_exact_zoh_and_prediction_form_steps_like_the_model():
    rng = np.random.default_rng(11)
    A, B, C, poles = random_model(rng, 4, 2, 20.0, complex_pairs=1)
    basis = SharedBasis.orthonormal(roots_from_poles(poles))
    dt = 0.1
    spec = StateSharedModel.model_from_linear("M", A, B, C, np.zeros(2), np.zeros(2), basis)
    ssm = StateSharedModel(basis, 2, dt, [spec])
    Fd, Gd, *_ = scipy.signal.cont2discrete((ssm.F, ssm.G, np.eye(8), np.zeros((8, 2))), dt)
    np.testing.assert_allclose(ssm.Fd, Fd, atol=1e-13)
    np.testing.assert_allclose(ssm.Gd, Gd, atol=1e-13)
    Phi, Gam, Cj, b = ssm.prediction_form(0)
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, C, np.zeros((2, 2))), dt, "zoh")
    x, z = np.zeros(4), np.zeros(ssm.order)
    peak, err = 0.0, 0.0
    for _ in range(100):
        x, z = Ad @ x + Bd[:, 1], Phi @ z + Gam[:, 1]
        peak = max(peak, np.max(np.abs(C @ x)))
        err = max(err, np.max(np.abs(Cj @ z + b - C @ x)))
    assert err <= 1e-9 * peak


def test_parameters_regressor_and_checkpoint_in_orthonormal_basis():
    rng = np.random.default_rng(12)
    A, B, C, poles = random_model(rng, 3, 3, 10.0)
    basis = SharedBasis.orthonormal(1.3 * poles)
    spec = StateSharedModel.model_from_linear("M", A, B, C, np.ones(3), 2 * np.ones(3), basis)
    ssm = StateSharedModel(basis, 3, 0.1, [spec])
    for _ in range(10):
        ssm.update(rng.standard_normal(3), rng.standard_normal(3))
    prm = ssm.params_from_theta(spec.theta, spec.bias)
    np.testing.assert_allclose(ssm.regressor() @ prm, ssm.estimates()[0], rtol=1e-12)
    state = json.loads(json.dumps(ssm.checkpoint()))
    other = StateSharedModel.from_checkpoint(state)
    assert other.basis.kind == "orthonormal"
    np.testing.assert_array_equal(other.estimates(), ssm.estimates())
    np.testing.assert_array_equal(other.Fb, ssm.Fb)
    with pytest.raises(ValueError, match="basis"):
        StateSharedModel(SharedBasis.orthonormal(poles), 3, 0.1).restore(state)
    with pytest.raises(ValueError, match="basis"):
        StateSharedModel(basis.a, 3, 0.1).restore(state)


def test_coefficient_theta_reads_the_companion_coefficients():
    # a SISO model in the orthonormal basis reads back as the seed's eq. 3.8 coefficients
    k1, k2, k3, k4 = 0.3, 0.3732, 1.1605, 0.2337  # H = (k1 s + k2)/(s^2 + k3 s + k4)
    A = np.array([[0.0, 1.0], [-k4, -k3]])
    B, C = np.array([[0.0], [1.0]]), np.array([[k2, k1]])
    basis = SharedBasis.of((1.0, 1.0), "orthonormal")
    spec = StateSharedModel.model_from_linear("M", A, B, C, [0.0], [0.0], basis)
    ssm = StateSharedModel(basis, 1, 0.1, [spec])
    np.testing.assert_allclose(ssm.coefficient_theta(0)[:, 0], [k2, k1, 1.0 - k4, 1.0 - k3],
                               atol=1e-12)
