"""Δu MPC formulation (seed R6.0): predictions, unconstrained optimum, LQR limit, limits.

References are computed independently of :mod:`controller.mpc.formulation`: by
simulating the plain state-space model, numpy least squares and scipy's Riccati solver.
"""

from __future__ import annotations

import hypothesis.extra.numpy as hnp
import hypothesis.strategies as st
import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import given, settings

from controller.mpc import (
    DAQPBackend,
    MPCSettings,
    MPCSettingsError,
    ProxsuiteBackend,
    augment,
    build_formulation,
)

# Named tolerances.
ALGEBRA_RTOL = 1e-9     # same linear algebra done two ways
SOLVER_ATOL = 1e-6      # QP solution vs closed form (solver tolerances ~1e-9..1e-6)
LQR_ATOL = 1e-7         # finite horizon + Riccati terminal weight vs LQR gain
LONG_HORIZON_ATOL = 1e-5  # long horizon without terminal weight vs LQR gain


def random_stable(rng, n, nu, ny, rho=0.95):
    Q, _ = np.linalg.qr(rng.normal(size=(n, n)))
    eig = rng.uniform(0.3, rho, size=n)
    Phi = Q @ np.diag(eig) @ Q.T
    return Phi, rng.normal(size=(n, nu)), rng.normal(size=(ny, n))


def simulate(Phi, Gamma, C, x_prev, u_prev, x, d, u_seq):
    """Outputs y(k+1..k+P) of x+ = Φx + Γu, y = Cx + d, for inputs u(k..k+P-1)."""
    ys = []
    for u in u_seq:
        x = Phi @ x + Gamma @ u
        ys.append(C @ x + d)
    return np.array(ys)


@pytest.fixture
def system():
    rng = np.random.default_rng(7)
    n, nu, ny = 4, 2, 2
    Phi, Gamma, C = random_stable(rng, n, nu, ny)
    return rng, Phi, Gamma, C


def test_augmented_model_is_eq_6_3(system):
    _, Phi, Gamma, C = system
    Phi_a, Psi_a, C_a = augment(Phi, Gamma, C)
    n, ny = 4, 2
    np.testing.assert_array_equal(Phi_a[:n, n:], np.zeros((n, ny)))
    np.testing.assert_array_equal(Phi_a[n:, n:], np.eye(ny))
    np.testing.assert_allclose(Phi_a[n:, :n], C @ Phi, rtol=ALGEBRA_RTOL)
    np.testing.assert_allclose(Psi_a, np.vstack([Gamma, C @ Gamma]), rtol=ALGEBRA_RTOL)
    np.testing.assert_array_equal(C_a, np.hstack([np.zeros((ny, n)), np.eye(ny)]))


def stacked_by_simulation(Phi, Gamma, C, x_prev, x, d, u_prev, P, M):
    """Free response and dynamic matrix by simulating unit moves (independent of S_x/S_u)."""
    nu = Gamma.shape[1]

    def inputs(dU):
        dU = dU.reshape(M, nu)
        us = [u_prev + dU[: min(i + 1, M)].sum(axis=0) for i in range(P)]
        return us

    y0 = simulate(Phi, Gamma, C, None, u_prev, x, d, inputs(np.zeros(M * nu))).ravel()
    G = np.zeros((P * C.shape[0], M * nu))
    for j in range(M * nu):
        e = np.zeros(M * nu)
        e[j] = 1.0
        G[:, j] = simulate(Phi, Gamma, C, None, u_prev, x, d, inputs(e)).ravel() - y0
    return y0, G


def test_prediction_matches_simulation(system):
    rng, Phi, Gamma, C = system
    P, M = 9, 3
    s = MPCSettings(nu=2, ny=2, P=P, M=M)
    form = build_formulation(Phi, Gamma, C, s)
    x_prev, u_prev, d = rng.normal(size=4), rng.normal(size=2), rng.normal(size=2)
    x = Phi @ x_prev + Gamma @ u_prev
    y = C @ x + d  # measured output with an unmodelled offset d
    y0, G = stacked_by_simulation(Phi, Gamma, C, x_prev, x, d, u_prev, P, M)
    x_a = form.augmented_state(x - x_prev, y)
    np.testing.assert_allclose(form.S_x @ x_a, y0, rtol=ALGEBRA_RTOL, atol=1e-10)
    np.testing.assert_allclose(form.S_u, G, rtol=ALGEBRA_RTOL, atol=1e-10)


@pytest.mark.parametrize("backend", [DAQPBackend, ProxsuiteBackend])
def test_unconstrained_equals_least_squares(system, backend):
    rng, Phi, Gamma, C = system
    P, M = 10, 4
    Xi, Lam = np.array([3.0, 0.5]), np.array([0.2, 1.0])
    s = MPCSettings(nu=2, ny=2, P=P, M=M, Xi=Xi, Lambda=Lam)
    form = build_formulation(Phi, Gamma, C, s)
    x_prev, u_prev, d = rng.normal(size=4), rng.normal(size=2), rng.normal(size=2)
    x = Phi @ x_prev + Gamma @ u_prev
    y = C @ x + d
    R = rng.normal(size=(P, 2))  # time-varying reference over the horizon
    y0, G = stacked_by_simulation(Phi, Gamma, C, x_prev, x, d, u_prev, P, M)
    w = np.sqrt(np.tile(Xi, P))
    lhs = np.vstack([w[:, None] * G, np.diag(np.sqrt(np.tile(Lam, M)))])
    rhs = np.concatenate([w * (R.ravel() - y0), np.zeros(M * 2)])
    dU_ref = np.linalg.lstsq(lhs, rhs, rcond=None)[0]

    v = form.qp_vectors(form.augmented_state(x - x_prev, y), u_prev, R)
    assert form.nz == M * 2 and form.n_rows == 0
    res = backend(form.H, form.A).solve(v)
    assert res.ok, res
    np.testing.assert_allclose(res.x, dU_ref, atol=SOLVER_ATOL)


def lqr_gain(Phi_a, Psi_a, Q, R):
    X = sla.solve_discrete_are(Phi_a, Psi_a, Q, R)
    K = np.linalg.solve(R + Psi_a.T @ X @ Psi_a, Psi_a.T @ X @ Phi_a)
    return X, K


def test_terminal_weight_gives_lqr(system):
    rng, Phi, Gamma, C = system
    Xi, Lam = np.array([2.0, 1.0]), np.array([0.5, 0.3])
    Phi_a, Psi_a, C_a = augment(Phi, Gamma, C)
    Q = C_a.T @ np.diag(Xi) @ C_a
    X, K = lqr_gain(Phi_a, Psi_a, Q, np.diag(Lam))
    P = 6
    s = MPCSettings(nu=2, ny=2, P=P, M=P, Xi=Xi, Lambda=Lam)
    form = build_formulation(Phi, Gamma, C, s, terminal_weight=X - Q)
    for _ in range(3):
        x_a = rng.normal(size=Phi_a.shape[0])
        v = form.qp_vectors(x_a, np.zeros(2), np.zeros(2))
        res = DAQPBackend(form.H, form.A).solve(v)
        assert res.ok
        np.testing.assert_allclose(res.x[:2], -K @ x_a, atol=LQR_ATOL)


def test_long_horizon_approaches_lqr(system):
    rng, Phi, Gamma, C = system
    Xi, Lam = np.array([2.0, 1.0]), np.array([0.5, 0.3])
    Phi_a, Psi_a, C_a = augment(Phi, Gamma, C)
    _, K = lqr_gain(Phi_a, Psi_a, C_a.T @ np.diag(Xi) @ C_a, np.diag(Lam))
    P = 120
    s = MPCSettings(nu=2, ny=2, P=P, M=P, Xi=Xi, Lambda=Lam)
    form = build_formulation(Phi, Gamma, C, s)
    # Unconstrained: the first move is linear in x_a; its gain is the first rows of H⁻¹F_x.
    gain = np.linalg.solve(form.H, form.F_x)[:2]
    np.testing.assert_allclose(gain, K, atol=LONG_HORIZON_ATOL)


def test_constrained_solution_respects_limits(system):
    rng, Phi, Gamma, C = system
    P, M = 10, 4
    s = MPCSettings(nu=2, ny=2, P=P, M=M, u_min=[-0.5, -1.0], u_max=[0.5, 1.0],
                    du_max=[0.2, 0.3], y_min=[-1.0, -2.0], y_max=[1.0, 2.0])
    form = build_formulation(Phi, Gamma, C, s)
    tol = 1e-6
    for _ in range(20):
        x_a = rng.normal(size=6) * 3
        u_prev = rng.uniform(-0.5, 0.5, size=2)
        v = form.qp_vectors(x_a, u_prev, rng.normal(size=(P, 2)) * 5)
        for backend in (DAQPBackend, ProxsuiteBackend):
            res = backend(form.H, form.A).solve(v)
            assert res.ok, res  # soft output limits: always feasible
            dU = res.x[:M * 2].reshape(M, 2)
            assert np.all(np.abs(dU) <= s.du_max + tol)
            u = u_prev + np.cumsum(dU, axis=0)
            assert np.all(u <= s.u_max + tol) and np.all(u >= s.u_min - tol)
            eps = res.x[-1]
            assert eps >= -tol
            Y = form.predict(x_a, res.x[:M * 2])
            assert np.all(Y <= s.y_max + eps * s.slack_scale + 1e-5)
            assert np.all(Y >= s.y_min - eps * s.slack_scale - 1e-5)


def test_exact_penalty_keeps_reachable_limit_exact(system):
    """A reference beyond a soft limit that can be met: the slack stays zero."""
    _, Phi, Gamma, C = system
    P, M = 10, 4
    s = MPCSettings(nu=2, ny=2, P=P, M=M, y_max=[0.2, np.inf], slack_linear=1e4)
    form = build_formulation(Phi, Gamma, C, s)
    x_a = np.zeros(6)
    v = form.qp_vectors(x_a, np.zeros(2), np.array([1.0, 0.0]))
    res = DAQPBackend(form.H, form.A).solve(v)
    assert res.ok
    assert res.x[-1] == pytest.approx(0.0, abs=1e-9)
    Y = form.predict(x_a, res.x[:-1])
    assert np.max(Y[:, 0]) <= 0.2 + 1e-7


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"u_min": [1.0, 0.0], "u_max": [0.0, 1.0]}, "u_min/u_max"),
        ({"y_min": [0.0, 2.0], "y_max": [1.0, 1.0]}, "y_min/y_max"),
        ({"M": 11}, "M"),
        ({"Lambda": [0.0, 1.0]}, "Lambda"),
        ({"Xi": [np.nan, 1.0]}, "Xi"),
        ({"du_max": [0.0, 1.0]}, "du_max"),
        ({"filter_alpha": 0.0}, "filter_alpha"),
        ({"backend": "osqp"}, "backend"),
        ({"budget_ms": -1.0}, "budget_ms"),
        ({"u_max": [1.0, 2.0, 3.0]}, "u_max"),
    ],
)
def test_bad_settings_name_the_field(kwargs, field):
    base = {"nu": 2, "ny": 2, "P": 10, "M": 4}
    base.update(kwargs)
    with pytest.raises(MPCSettingsError, match=field.replace("/", ".")):
        MPCSettings(**base)


def test_model_shape_mismatch_is_an_error(system):
    _, Phi, Gamma, C = system
    s = MPCSettings(nu=3, ny=2, P=5, M=2)
    with pytest.raises(ValueError, match="Gamma"):
        build_formulation(Phi, Gamma, C, s)


def test_measured_disturbance_prediction_matches_simulation(system):
    """Δd(k) feedforward: S_x x_a + S_u ΔU + S_d Δd equals the simulated outputs."""
    rng, Phi, Gamma, C = system
    Gd = rng.normal(size=(4, 1))
    P, M = 8, 3
    s = MPCSettings(nu=2, ny=2, P=P, M=M)
    form = build_formulation(Phi, Gamma, C, s, Gamma_d=Gd)
    x_prev, u_prev = rng.normal(size=4), rng.normal(size=2)
    d_prev, d_now = np.array([0.3]), np.array([1.1])
    x = Phi @ x_prev + Gamma @ u_prev + Gd @ d_prev
    dU = rng.normal(size=M * 2)
    ys, xs, u = [], x.copy(), u_prev.copy()
    for i in range(P):
        if i < M:
            u = u + dU[i * 2:(i + 1) * 2]
        xs = Phi @ xs + Gamma @ u + Gd @ d_now
        ys.append(C @ xs)
    x_a = form.augmented_state(x - x_prev, C @ x)
    np.testing.assert_allclose(form.predict(x_a, dU, d_now - d_prev).ravel(),
                               np.concatenate(ys), rtol=ALGEBRA_RTOL, atol=1e-10)


def test_input_target_term_matches_least_squares(system):
    """With input targets the unconstrained optimum is again a least-squares solution."""
    rng, Phi, Gamma, C = system
    P, M = 10, 3
    Xi, Lam, W = np.array([1.0, 2.0]), np.array([0.3, 0.3]), np.array([0.5, 0.0])
    u_t = np.array([0.2, -1.0])
    s = MPCSettings(nu=2, ny=2, P=P, M=M, Xi=Xi, Lambda=Lam, u_target=u_t,
                    u_target_weight=W)
    form = build_formulation(Phi, Gamma, C, s)
    x_prev, u_prev, d = rng.normal(size=4), rng.normal(size=2), rng.normal(size=2)
    x = Phi @ x_prev + Gamma @ u_prev
    R = rng.normal(size=(P, 2))
    y0, G = stacked_by_simulation(Phi, Gamma, C, x_prev, x, d, u_prev, P, M)
    T = np.kron(np.tril(np.ones((M, M))), np.eye(2))
    w = np.sqrt(np.tile(Xi, P))
    wu = np.sqrt(np.tile(W, M))
    lhs = np.vstack([w[:, None] * G, np.diag(np.sqrt(np.tile(Lam, M))), wu[:, None] * T])
    rhs = np.concatenate([w * (R.ravel() - y0), np.zeros(M * 2),
                          wu * np.tile(u_t - u_prev, M)])
    dU_ref = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    v = form.qp_vectors(form.augmented_state(x - x_prev, C @ x + d), u_prev, R)
    res = DAQPBackend(form.H, form.A).solve(v)
    assert res.ok
    np.testing.assert_allclose(res.x, dU_ref, atol=SOLVER_ATOL)


_FEAS_SYS = random_stable(np.random.default_rng(11), 4, 2, 2)
_FEAS_SETTINGS = MPCSettings(nu=2, ny=2, P=10, M=4, u_min=[-0.5, -1.0], u_max=[0.5, 1.0],
                             du_max=[0.05, 0.1], y_min=[-0.1, -0.2], y_max=[0.1, 0.2])
_FEAS_FORM = build_formulation(*_FEAS_SYS, _FEAS_SETTINGS)


@settings(max_examples=60, deadline=None)
@given(
    x_a=hnp.arrays(np.float64, 6, elements=st.floats(-1e4, 1e4)),
    frac=hnp.arrays(np.float64, 2, elements=st.floats(0.0, 1.0)),
    ref=hnp.arrays(np.float64, (10, 2), elements=st.floats(-1e3, 1e3)),
)
def test_soft_output_limits_feasible_from_any_state(x_a, frac, ref):
    s = _FEAS_SETTINGS
    u_prev = s.u_min + frac * (s.u_max - s.u_min)  # any admissible current input
    res = DAQPBackend(_FEAS_FORM.H, _FEAS_FORM.A, warm_start=False).solve(
        _FEAS_FORM.qp_vectors(x_a, u_prev, ref))
    assert res.ok, res.status
    assert res.x[-1] >= -1e-9  # slack


def test_settings_shared_parts_leave_each_formulation_as_built_alone(system):
    """The settings-only arrays made once per settings object: two models under one
    settings object, and the same settings rebuilt as another object (another input
    target weight, limits), give the matrices and vectors of formulations built alone."""
    rng, Phi, Gamma, C = system
    kw = dict(nu=2, ny=2, P=8, M=3, u_min=[-0.5, -np.inf], u_max=[0.5, np.inf],
              du_max=[0.2, 0.3], y_min=[-1.0, -np.inf], y_max=[1.0, 2.0],
              u_target_weight=[0.1, 0.0])
    s = MPCSettings(**kw)
    Phi2, Gamma2, C2 = random_stable(rng, 4, 2, 2)
    shared = [build_formulation(Phi, Gamma, C, s), build_formulation(Phi2, Gamma2, C2, s)]
    other = MPCSettings(**{**kw, "u_target_weight": [0.0, 0.0], "u_max": [0.4, 1.0]})
    for form, model in zip(shared, ((Phi, Gamma, C), (Phi2, Gamma2, C2)), strict=True):
        alone = build_formulation(*model, MPCSettings(**kw))  # its own settings object
        for name in ("H", "A", "F_x", "F_r", "F_ut", "lb0", "ub0", "input_rows",
                     "ymax_rows", "ymin_rows"):
            np.testing.assert_array_equal(getattr(form, name), getattr(alone, name), name)
        x_a, u_prev = rng.normal(size=6), rng.uniform(-0.5, 0.5, size=2)
        R = rng.normal(size=(8, 2))
        a, b = form.qp_vectors(x_a, u_prev, R), alone.qp_vectors(x_a, u_prev, R)
        for name in ("f", "lb", "ub", "bl", "bu"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), name)
    changed = build_formulation(Phi, Gamma, C, other)
    # both inputs limited now: M nu input rows (3 before), 2 P y_max and P y_min rows
    assert changed.F_ut is None and changed.A.shape[0] == 3 * 2 + 16 + 8
    assert shared[0].A.shape[0] == 3 + 16 + 8
    assert not np.array_equal(changed.H, shared[0].H)
