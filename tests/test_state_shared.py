"""State-shared model (eq. 3.10-3.16): exactness against independent references."""

from __future__ import annotations

import json

import control
import numpy as np
import pytest
import scipy.signal

from controller.linear.mfd import LeftMFD, left_mfd
from controller.state_shared import (
    ModelSpec,
    StateSharedModel,
    companion_pair,
    designer_polynomial,
    mfd_from_theta,
    theta_from_mfd,
)

FREQ_RTOL = 1e-9  # relative frequency-response agreement required of the representation
STEP_TOL = 1e-9  # step responses, relative to the peak output
SEED_PRINT_TOL = 5e-5  # the seed prints 4 decimals


def random_stable(rng, nx, m, p=None):
    """Random stable strictly proper (A, B, C) with well-separated poles."""
    p = m if p is None else p
    poles = -rng.uniform(0.2, 5.0, nx)
    Q, _ = np.linalg.qr(rng.standard_normal((nx, nx)))
    A = Q @ np.diag(poles) @ Q.T + 0.3 * (Q @ np.triu(rng.standard_normal((nx, nx)), 1) @ Q.T)
    B = rng.standard_normal((nx, m))
    C = rng.standard_normal((p, nx))
    return A, B, C


def hurwitz(n, rng):
    roots = -rng.uniform(0.5, 3.0, n)
    return designer_polynomial(roots)


# -- (F, G) -----------------------------------------------------------------------
def test_companion_pair_r34_two_phase_structure():
    # R3.4: a1 = a2 = 1, m = 3 -> F 6x6, G 6x3, poles (-1 +- j sqrt 3)/2, 20 params, order 12.
    F, G = companion_pair([1.0, 1.0], 3)
    assert F.shape == (6, 6) and G.shape == (6, 3)
    ev = np.sort_complex(np.linalg.eigvals(F))
    expected = np.sort_complex(np.array([-0.5 + 0.5j * np.sqrt(3), -0.5 - 0.5j * np.sqrt(3)] * 3))
    np.testing.assert_allclose(ev, expected, atol=1e-7)
    ss = StateSharedModel([1.0, 1.0], 3, 1.0)
    assert ss.n_params == 20 and ss.order == 12
    # controllable pair
    ctrb = control.ctrb(F, G)
    assert np.linalg.matrix_rank(ctrb) == 6


def test_companion_pair_r311_calcium_structure():
    # R3.11: a = (1, 2, 3), m = 3 -> order 18, 30 params; printed roots -2.3247, -0.3376 +- 0.5623j.
    F, G = companion_pair([1.0, 2.0, 3.0], 3)
    assert F.shape == (9, 9) and G.shape == (9, 3)
    ev = np.linalg.eigvals(F[:3, :3])
    ev = ev[np.argsort(ev.real)]
    assert abs(ev[0] - (-2.3247)) < SEED_PRINT_TOL
    assert abs(abs(ev[1].imag) - 0.5623) < SEED_PRINT_TOL
    assert abs(ev[1].real - (-0.3376)) < SEED_PRINT_TOL
    ss = StateSharedModel([1.0, 2.0, 3.0], 3, 0.01)
    assert ss.order == 18 and ss.n_params == 30


def test_block_transfer_is_power_vector():
    # (sI - F_i)^-1 g_i = [1, s, ..., s^(n-1)]^T / omega(s)  (eq. 3.14)
    a = np.array([2.0, 5.0, 4.0])
    F, G = companion_pair(a, 1)
    s = 0.3 + 1.7j
    v = np.linalg.solve(s * np.eye(3) - F, G[:, 0])
    omega = a[0] + a[1] * s + a[2] * s**2 + s**3
    np.testing.assert_allclose(v, np.array([1, s, s**2]) / omega, rtol=1e-13)


@pytest.mark.parametrize("a", [[-1.0], [1.0, -0.1], [0.0, 1.0], [], [np.nan, 1.0], [1.0, np.inf]])
def test_bad_designer_polynomial(a):
    with pytest.raises(ValueError, match="^a: "):
        companion_pair(a, 2)
    with pytest.raises(ValueError):
        StateSharedModel(a, 2, 0.1)


def test_bad_sizes_and_dt():
    with pytest.raises(ValueError, match="m"):
        companion_pair([1.0], 0)
    for dt in (0.0, -1.0, np.nan, np.inf):
        with pytest.raises(ValueError, match="dt"):
            StateSharedModel([1.0, 1.0], 2, dt)


# -- seed example eq. 3.5-3.8 (SISO closed form) -----------------------------------
def test_siso_closed_form_eq_3_8():
    # H = (k1 s + k2)/(s^2 + k3 s + k4), F = [[0,1],[-a1,-a2]] ->
    # theta1 = (k2, k1), theta2 = (a1 - k4, a2 - k3)
    k1, k2, k3, k4 = 0.3, 0.3732, 1.1605, 0.2337
    a = [1.0, 1.0]
    mfd = LeftMFD(d=[k4, k3, 1.0], N=[[[k2, k1]]], D0=[[0.0]])
    th = theta_from_mfd(mfd, a)
    np.testing.assert_allclose(th[:, 0], [k2, k1, 1.0 - k4, 1.0 - k3], rtol=0, atol=1e-15)


def test_r35_printed_theta2_from_derived_denominator():
    # R3.5: d(s) = s^2 + 3.7482 s + 0.2431 with a1 = a2 = 1 gives the printed 0.7569, -2.7482.
    mfd = LeftMFD(d=[0.2431, 3.7482, 1.0], N=np.zeros((3, 3, 2)), D0=np.zeros((3, 3)))
    th = theta_from_mfd(mfd, [1.0, 1.0])
    for i in range(3):
        np.testing.assert_allclose(th[6 + 2 * i : 8 + 2 * i, i], [0.7569, -2.7482], atol=1e-12)
    assert np.count_nonzero(th[6:]) == 6


# -- exactness of the state-shared realization --------------------------------------
@pytest.mark.parametrize("seed,nx,m", [(0, 1, 1), (1, 3, 1), (2, 2, 2), (3, 4, 2), (4, 3, 3),
                                       (5, 5, 3), (6, 6, 4)])
def test_frequency_response_equals_transfer_matrix(seed, nx, m):
    rng = np.random.default_rng(seed)
    A, B, C = random_stable(rng, nx, m)
    a = hurwitz(nx, rng)
    theta = theta_from_mfd(left_mfd(A, B, C), a)
    ssm = StateSharedModel(a, m, 0.1, [ModelSpec("M", theta)])
    Ac, Bc, Cc, _, _ = ssm.continuous_form(0)
    w = np.logspace(-3, 3, 41)
    ref = control.ss(A, B, C, np.zeros((m, m))).frequency_response(w).complex
    ours = control.ss(Ac, Bc, Cc, np.zeros((m, m))).frequency_response(w).complex
    ref = np.asarray(ref).reshape(m, m, -1)
    ours = np.asarray(ours).reshape(m, m, -1)
    scale = np.max(np.abs(ref), axis=(0, 1))
    assert np.max(np.abs(ours - ref) / scale) < FREQ_RTOL


@pytest.mark.parametrize("seed,nx,m", [(10, 2, 1), (11, 3, 2), (12, 4, 3)])
def test_step_response_equals_zoh_of_original(seed, nx, m):
    rng = np.random.default_rng(seed)
    A, B, C = random_stable(rng, nx, m)
    a = hurwitz(nx, rng)
    dt = 0.2
    ssm = StateSharedModel(a, m, dt, [ModelSpec("M", theta_from_mfd(left_mfd(A, B, C), a))])
    Phi, Gam, Cj, b = ssm.prediction_form(0)
    Ad, Bd, Cd, _, _ = scipy.signal.cont2discrete((A, B, C, np.zeros((m, m))), dt, "zoh")
    for j in range(m):
        u = np.zeros(m)
        u[j] = 1.0
        x = np.zeros(nx)
        z = np.zeros(ssm.order)
        peak, err = 0.0, 0.0
        for _ in range(150):
            y_ref = Cd @ x
            y_ss = Cj @ z + b
            peak = max(peak, np.max(np.abs(y_ref)))
            err = max(err, np.max(np.abs(y_ss - y_ref)))
            x = Ad @ x + Bd @ u
            z = Phi @ z + Gam @ u
        assert err <= STEP_TOL * peak


def test_discretization_matches_scipy_zoh():
    a = designer_polynomial([-0.5, -1.0, -2.0])
    ssm = StateSharedModel(a, 2, 0.3)
    Fd, Gd, *_ = scipy.signal.cont2discrete((ssm.F, ssm.G, np.eye(6), np.zeros((6, 2))), 0.3)
    np.testing.assert_allclose(ssm.Fd, Fd, atol=1e-13)
    np.testing.assert_allclose(ssm.Gd, Gd, atol=1e-13)


def test_update_exact_for_held_signals():
    # With u and y piecewise constant, update() equals the exact continuous solution.
    rng = np.random.default_rng(7)
    a = designer_polynomial([-1.0, -1.5])
    m, dt = 2, 0.25
    ssm = StateSharedModel(a, m, dt)
    nm = 4
    Ad, Bd, *_ = scipy.signal.cont2discrete(
        (np.kron(np.eye(2), ssm.F), np.kron(np.eye(2), ssm.G), np.eye(2 * nm),
         np.zeros((2 * nm, 2 * m))), dt, "zoh")
    x = np.zeros(2 * nm)
    for _ in range(30):
        u, y = rng.standard_normal(m), rng.standard_normal(m)
        ssm.update(u, y)
        x = Ad @ x + Bd @ np.concatenate((u, y))
    np.testing.assert_allclose(ssm.n, x, atol=1e-12)


def test_estimates_are_all_models_measurement_equations():
    # y_j = Theta_j^T n + b_j for every model, fixed and adaptive alike (eq. 3.10).
    rng = np.random.default_rng(8)
    a = hurwitz(2, rng)
    ssm = StateSharedModel(a, 2, 0.1)
    ths = [rng.standard_normal((8, 2)) for _ in range(3)]
    bs = [rng.standard_normal(2) for _ in range(3)]
    for i, (t, b) in enumerate(zip(ths, bs)):
        ssm.add_model(ModelSpec(f"m{i}", t, b, "adaptive" if i == 2 else "fixed"))
    for _ in range(5):
        ssm.update(rng.standard_normal(2), rng.standard_normal(2))
    est = ssm.estimates()
    assert est.shape == (3, 2)
    for j in range(3):
        np.testing.assert_allclose(est[j], ths[j].T @ ssm.n + bs[j], rtol=1e-14)
    y = rng.standard_normal(2)
    np.testing.assert_allclose(ssm.errors(y), y[None] - est, rtol=1e-14)


def test_switching_theta_keeps_state_continuous():
    rng = np.random.default_rng(9)
    a = hurwitz(3, rng)
    A1, B1, C1 = random_stable(rng, 3, 2)
    A2, B2, C2 = random_stable(rng, 3, 2)
    ssm = StateSharedModel(a, 2, 0.05)
    ssm.add_model(ModelSpec("fixed", theta_from_mfd(left_mfd(A1, B1, C1), a)))
    j = ssm.add_model(ModelSpec("adaptive", theta_from_mfd(left_mfd(A1, B1, C1), a),
                                kind="adaptive"))
    for _ in range(40):
        ssm.update(rng.standard_normal(2), rng.standard_normal(2))
    n_before = ssm.n
    new_theta = theta_from_mfd(left_mfd(A2, B2, C2), a)
    ssm.set_theta(j, new_theta)
    np.testing.assert_array_equal(ssm.n, n_before)
    np.testing.assert_allclose(ssm.estimates()[j], new_theta.T @ n_before, rtol=1e-14)
    # the cached prediction form follows the new theta
    assert np.array_equal(ssm.prediction_form(j).C, new_theta.T)


# -- bias (operating-point offset) ----------------------------------------------------
def test_model_from_linear_holds_at_its_operating_point():
    rng = np.random.default_rng(11)
    A, B, C = random_stable(rng, 2, 2)
    a = designer_polynomial([-1.0, -2.0])
    u_op, y_op = np.array([3.0, -1.0]), np.array([100.0, 47.0])
    spec = StateSharedModel.model_from_linear("OPI", A, B, C, u_op, y_op, a)
    ssm = StateSharedModel(a, 2, 0.1, [spec])
    ssm.initialize(u_op, y_op)
    np.testing.assert_allclose(ssm.estimates()[0], y_op, rtol=1e-12)
    ssm.update(u_op, y_op)  # equilibrium is a fixed point of the update
    np.testing.assert_allclose(ssm.estimates()[0], y_op, rtol=1e-12)
    # prediction form with its affine term holds the same equilibrium
    pf = ssm.prediction_form(0)
    z = ssm.n
    z_next = pf.Phi @ z + pf.Gamma @ u_op + pf.f
    np.testing.assert_allclose(z_next, z, atol=1e-9 * np.max(np.abs(z)))
    # and its DC gain from u is the model's: H(0) = -C A^-1 B
    du = np.array([0.01, -0.02])
    for _ in range(2000):
        z = pf.Phi @ z + pf.Gamma @ (u_op + du) + pf.f
    dy = pf.C @ z + pf.b - y_op
    np.testing.assert_allclose(dy, -C @ np.linalg.solve(A, B) @ du, rtol=1e-6, atol=1e-12)


# -- parameters -----------------------------------------------------------------------
def test_parameter_vector_round_trip_and_regressor():
    rng = np.random.default_rng(12)
    n, m = 3, 3
    a = hurwitz(n, rng)
    A, B, C = random_stable(rng, n, m)
    theta = theta_from_mfd(left_mfd(A, B, C), a)
    bias = rng.standard_normal(m)
    ssm = StateSharedModel(a, m, 0.1, [ModelSpec("M", theta, bias)])
    p = ssm.params_from_theta(theta, bias)
    assert p.size == n * (m * m + 1) + m == ssm.n_params + m
    th2, b2 = ssm.theta_from_params(p)
    np.testing.assert_array_equal(th2, theta)
    np.testing.assert_array_equal(b2, bias)
    for _ in range(10):
        ssm.update(rng.standard_normal(m), rng.standard_normal(m))
    W = ssm.regressor()
    assert W.shape == (m, ssm.n_params + m)
    np.testing.assert_allclose(W @ p, ssm.estimates()[0], rtol=1e-12)
    ssm.set_params(0, p * 0.5)
    np.testing.assert_allclose(ssm.estimates()[0], W @ (p * 0.5), rtol=1e-12)


@pytest.mark.parametrize("p_out", [None, 3])  # square, and p = 3 outputs for m = 2 inputs
def test_set_params_writes_what_set_theta_writes(p_out):
    """The per-sample path (stacked rows written directly, spec built when read) gives
    bit for bit the estimates, Theta, bias, prediction form and checkpoint of set_theta."""
    rng = np.random.default_rng(21)
    a, m = hurwitz(3, rng), 2
    q = m if p_out is None else p_out
    order = 3 * (m + q)

    def structured():
        th = np.zeros((order, q))
        th[: 3 * m] = rng.standard_normal((3 * m, q))
        t2 = rng.standard_normal(3) * 0.1
        for i in range(q):
            th[3 * m + 3 * i : 3 * m + 3 * (i + 1), i] = t2
        return th

    specs = [ModelSpec("F", structured(), rng.standard_normal(q)),
             ModelSpec("A", structured(), rng.standard_normal(q), "adaptive")]
    fast = StateSharedModel(a, m, 0.1, specs, p=p_out)
    slow = StateSharedModel(a, m, 0.1, specs, p=p_out)
    for _ in range(5):
        uy = (rng.standard_normal(m), rng.standard_normal(q))
        fast.update(*uy)
        slow.update(*uy)
    for _ in range(3):
        theta, bias = structured(), rng.standard_normal(q)
        params = slow.params_from_theta(theta, bias)
        fast.set_params(1, params)
        slow.set_theta(1, theta, bias)
        np.testing.assert_array_equal(fast.estimates(), slow.estimates())
        np.testing.assert_array_equal(fast.theta2_all(), slow.theta2_all())
    np.testing.assert_array_equal(fast.theta(1), slow.theta(1))
    np.testing.assert_array_equal(fast.bias(1), slow.bias(1))
    assert fast.model(1).kind == "adaptive" and fast.names == ["F", "A"]
    for x, y in zip(fast.prediction_form(1), slow.prediction_form(1)):
        np.testing.assert_array_equal(x, y)
    assert fast.checkpoint() == slow.checkpoint()
    with pytest.raises(ValueError, match="p"):
        fast.set_params(1, np.full(params.size, np.nan))


def test_mfd_round_trip_through_theta():
    rng = np.random.default_rng(13)
    a = hurwitz(3, rng)
    mfd = left_mfd(*random_stable(rng, 3, 2))
    back = mfd_from_theta(theta_from_mfd(mfd, a), a, 2)
    np.testing.assert_allclose(back.d, mfd.d, rtol=1e-12)
    np.testing.assert_allclose(back.N, mfd.N, rtol=1e-12, atol=1e-14)


def test_unstructured_theta2_is_rejected_for_params():
    ssm = StateSharedModel([1.0, 1.0], 2, 0.1)
    theta = np.zeros((8, 2))
    theta[4, 1] = 1.0  # off the block diagonal
    with pytest.raises(ValueError, match="Theta2"):
        ssm.params_from_theta(theta)


# -- bad input ---------------------------------------------------------------------------
def test_non_square_and_feedthrough_rejected():
    rng = np.random.default_rng(14)
    A, B, C = random_stable(rng, 2, 2, p=3)
    with pytest.raises(ValueError, match="square"):
        theta_from_mfd(left_mfd(A, B, C), [1.0, 1.0])
    A, B, C = random_stable(rng, 2, 2)
    with pytest.raises(ValueError, match="D0"):
        theta_from_mfd(left_mfd(A, B, C, np.eye(2)), [1.0, 1.0])
    with pytest.raises(ValueError, match="degree"):
        theta_from_mfd(left_mfd(A, B, C), [1.0])


def test_lower_degree_needs_padding_and_padding_is_exact():
    rng = np.random.default_rng(15)
    A, B, C = random_stable(rng, 2, 2)
    a = designer_polynomial([-1.0, -2.0, -3.0, -4.0])
    mfd = left_mfd(A, B, C)
    with pytest.raises(ValueError, match="pad_root"):
        theta_from_mfd(mfd, a)
    theta = theta_from_mfd(mfd, a, pad_root=2.5)
    ssm = StateSharedModel(a, 2, 0.1, [ModelSpec("M", theta)])
    Ac, Bc, Cc, _, _ = ssm.continuous_form(0)
    s = 0.7j
    ref = C @ np.linalg.solve(s * np.eye(2) - A, B)
    ours = Cc @ np.linalg.solve(s * np.eye(Ac.shape[0]) - Ac, Bc)
    np.testing.assert_allclose(ours, ref, rtol=1e-10)


def test_mismatched_dimensions_rejected():
    ssm = StateSharedModel([1.0, 1.0], 2, 0.1)
    with pytest.raises(ValueError, match="theta"):
        ssm.add_model(ModelSpec("M", np.zeros((6, 2))))
    with pytest.raises(ValueError, match="kind"):
        ModelSpec("M", np.zeros((8, 2)), kind="other")
    with pytest.raises(ValueError, match="bias"):
        ModelSpec("M", np.zeros((8, 2)), bias=[1.0])
    ssm.add_model(ModelSpec("M", np.zeros((8, 2))))
    with pytest.raises(ValueError, match="name"):
        ssm.add_model(ModelSpec("M", np.zeros((8, 2))))
    with pytest.raises(ValueError, match="u"):
        ssm.update([1.0], [1.0, 2.0])
    with pytest.raises(ValueError, match="j"):
        ssm.prediction_form(3)
    with pytest.raises(ValueError, match="p"):
        ssm.set_params(0, np.zeros(3))


def test_nan_measurement_raises_and_leaves_state():
    ssm = StateSharedModel([1.0, 1.0], 2, 0.1)
    ssm.update([1.0, 2.0], [3.0, 4.0])
    before = ssm.n
    with pytest.raises(ValueError, match="y"):
        ssm.update([1.0, 2.0], [np.nan, 4.0])
    with pytest.raises(ValueError, match="u"):
        ssm.update([np.inf, 2.0], [1.0, 4.0])
    np.testing.assert_array_equal(ssm.n, before)


def test_checkpoint_round_trip_is_exact():
    rng = np.random.default_rng(16)
    a = hurwitz(3, rng)
    ssm = StateSharedModel(a, 2, 0.1)
    ssm.add_model(ModelSpec("f", rng.standard_normal((12, 2)), rng.standard_normal(2)))
    ssm.add_model(ModelSpec("ad", rng.standard_normal((12, 2)), kind="adaptive"))
    for _ in range(7):
        ssm.update(rng.standard_normal(2), rng.standard_normal(2))
    state = json.loads(json.dumps(ssm.checkpoint()))
    other = StateSharedModel.from_checkpoint(state)
    np.testing.assert_array_equal(other.n, ssm.n)
    np.testing.assert_array_equal(other.estimates(), ssm.estimates())
    assert other.names == ["f", "ad"] and other.kinds == ["fixed", "adaptive"]
    u, y = rng.standard_normal(2), rng.standard_normal(2)
    ssm.update(u, y)
    other.update(u, y)
    np.testing.assert_array_equal(other.n, ssm.n)
    with pytest.raises(ValueError, match="state.m"):
        StateSharedModel(a, 3, 0.1).restore(state)


# -- numerical limits (documented in the module) ---------------------------------------
CONDITIONING_TOL = 1e-9


def test_te_sized_io_with_order_ten_is_exact():
    # m = 5 (TE's CVs), n = 10 with poles spread over a decade: still exact to 1e-9.
    rng = np.random.default_rng(40)
    n, m = 10, 5
    poles = -np.geomspace(1 / np.sqrt(10), np.sqrt(10), n)
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    A = Q @ np.diag(poles) @ Q.T
    B, C = rng.standard_normal((n, m)), rng.standard_normal((m, n))
    a = designer_polynomial(1.1 * poles)
    ssm = StateSharedModel(a, m, 0.05, [ModelSpec("M", theta_from_mfd(left_mfd(A, B, C), a))])
    Ac, Bc, Cc, _, _ = ssm.continuous_form(0)
    w = np.logspace(-2, 2, 41)
    ref = control.ss(A, B, C, np.zeros((m, m))).frequency_response(w).complex
    ours = control.ss(Ac, Bc, Cc, np.zeros((m, m))).frequency_response(w).complex
    assert np.max(np.abs(np.asarray(ours) - np.asarray(ref))) <= CONDITIONING_TOL * np.max(
        np.abs(ref))


def test_state_setter_validates():
    ssm = StateSharedModel([1.0, 1.0], 2, 0.1)
    ssm.n = np.arange(8.0)
    np.testing.assert_array_equal(ssm.n, np.arange(8.0))
    with pytest.raises(ValueError, match="n"):
        ssm.n = np.zeros(7)
    with pytest.raises(ValueError):
        ssm.F[0, 0] = 1.0  # designer matrices are read-only


def test_sampled_form_reproduces_update_driven_by_own_output():
    rng = np.random.default_rng(21)
    a = designer_polynomial([-1.0, -2.0])
    A, B, C = random_stable(rng, 2, 2)
    spec = StateSharedModel.model_from_linear("M", A, B, C, [1.0, 2.0], [3.0, 4.0], a)
    ssm = StateSharedModel(a, 2, 0.1, [spec])
    ssm.initialize([1.0, 2.0], [3.0, 4.0])
    Phi, Gam, Cj, b = pf = ssm.sampled_form(0)
    z = ssm.n
    for _ in range(20):
        u = rng.standard_normal(2)
        y = ssm.estimates()[0]
        ssm.update(u, y)
        z = Phi @ z + Gam @ u + pf.f
        np.testing.assert_allclose(ssm.n, z, rtol=1e-12, atol=1e-12)
    # the two forms differ by O(dt^2) against a one-step change of O(dt): the relative
    # difference shrinks like dt
    rel = []
    for dt in (1e-2, 1e-3):
        m_ = StateSharedModel(a, 2, dt, [spec])
        S, P = m_.sampled_form(0).Phi, m_.prediction_form(0).Phi
        rel.append(np.max(np.abs(S - P)) / np.max(np.abs(P - np.eye(P.shape[0]))))
    assert rel[1] < 0.2 * rel[0]


# -- p outputs != m inputs (extension of the seed) ----------------------------------------
@pytest.mark.parametrize("seed,nx,m,p", [(50, 3, 2, 3), (51, 4, 3, 2), (52, 2, 1, 3)])
def test_non_square_frequency_response_and_api(seed, nx, m, p):
    rng = np.random.default_rng(seed)
    A, B, C = random_stable(rng, nx, m, p)
    a = hurwitz(nx, rng)
    with pytest.raises(ValueError, match="square"):
        theta_from_mfd(left_mfd(A, B, C), a)
    theta = theta_from_mfd(left_mfd(A, B, C), a, square=False)
    assert theta.shape == (nx * (m + p), p)
    ssm = StateSharedModel(a, m, 0.1, [ModelSpec("M", theta)], p=p)
    assert ssm.order == nx * (m + p) and ssm.n_params == nx * (m * p + 1)
    Ac, Bc, Cc, _, _ = ssm.continuous_form(0)
    w = np.logspace(-3, 3, 31)
    ref = np.asarray(control.ss(A, B, C, np.zeros((p, m))).frequency_response(w).complex)
    ours = np.asarray(control.ss(Ac, Bc, Cc, np.zeros((p, m))).frequency_response(w).complex)
    assert np.max(np.abs(ours - ref)) <= FREQ_RTOL * np.max(np.abs(ref))
    # step response through the exact prediction form vs ZOH of the original
    dt = 0.1
    Phi, Gam, Cj, b = ssm.prediction_form(0)
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, C, np.zeros((p, m))), dt, "zoh")
    x, z = np.zeros(nx), np.zeros(ssm.order)
    for _ in range(60):
        x, z = Ad @ x + Bd[:, 0], Phi @ z + Gam[:, 0]
    np.testing.assert_allclose(Cj @ z + b, C @ x, atol=1e-9 * max(1.0, np.max(np.abs(C @ x))))
    # parameters, regressor, bias and checkpoint
    bias = rng.standard_normal(p)
    ssm.set_theta(0, theta, bias)
    for _ in range(5):
        ssm.update(rng.standard_normal(m), rng.standard_normal(p))
    prm = ssm.params_from_theta(theta, bias)
    assert prm.size == ssm.n_params + p
    np.testing.assert_allclose(ssm.regressor() @ prm, ssm.estimates()[0], rtol=1e-12)
    th2, b2 = ssm.theta_from_params(prm)
    np.testing.assert_array_equal(th2, theta)
    other = StateSharedModel.from_checkpoint(json.loads(json.dumps(ssm.checkpoint())))
    np.testing.assert_array_equal(other.estimates(), ssm.estimates())
    with pytest.raises(ValueError, match="y"):
        ssm.update(np.zeros(m), np.zeros(m + p))
    back = mfd_from_theta(theta, a, m, p)
    assert back.shape == (p, m)


def test_non_square_model_from_linear_holds_its_point():
    rng = np.random.default_rng(53)
    A, B, C = random_stable(rng, 3, 2, 3)
    a = designer_polynomial([-1.0, -2.0, -3.0])
    spec = StateSharedModel.model_from_linear("M", A, B, C, [1.0, 2.0], [3.0, 4.0, 5.0], a,
                                              square=False)
    ssm = StateSharedModel(a, 2, 0.1, [spec], p=3)
    ssm.initialize([1.0, 2.0], [3.0, 4.0, 5.0])
    np.testing.assert_allclose(ssm.estimates()[0], [3.0, 4.0, 5.0], rtol=1e-12)
    with pytest.raises(ValueError, match="theta"):
        StateSharedModel(a, 2, 0.1, p=2).add_model(spec)  # a 3-output model in a square set
