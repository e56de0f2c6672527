"""First-order hold of the outputs in model comparison and identification (y_hold="foh").

References are independent of the code under test: the closed-form Theta of eq. 3.16
for G(s) = k1 (s + k2)/(s^2 + k3 s + k4) on omega = s^2 + s + 1, numerical quadrature
for H, and the exact (matrix-exponential) samples of the continuous plant.
"""

import json

import control as ct
import numpy as np
import pytest
import scipy.integrate
import scipy.linalg

from controller.adaptation import NLSSettings, NormalizedLeastSquares
from controller.multimodel import MultiModelController, MultiModelSettings, OutputHoldCorrection
from controller.state_shared import ModelSpec, StateSharedModel
from controller.switching import IndexSettings

A_POLY = (1.0, 1.0)  # omega(s) = s^2 + s + 1 (seed §5.2.3)
K_TRUE = (0.3, 1.244, 1.1605, 0.2337)  # Table 5.3 OPI
K_START = (0.3, 4.931, 2.1493, 2.3286)  # Table 5.3 OPII
PARAM_RTOL = 0.01  # R4.1: theta within 1 % under persistent excitation
ZOH_BIAS_MIN = 0.05  # the held-output identifier is off by more than this (14.7 % measured)
H_RTOL = 1e-9


def _theta_closed_form(k):
    """eq. 3.16 by hand: theta1 = numerator (k1 k2, k1), theta2 = a - d = (1 - k4, 1 - k3)."""
    k1, k2, k3, k4 = k
    theta = np.zeros((4, 1))
    theta[:, 0] = (k1 * k2, k1, A_POLY[0] - k4, A_POLY[1] - k3)
    return theta


def _plant(k, dt):
    k1, k2, k3, k4 = k
    sys = ct.ss(ct.tf([k1, k1 * k2], [1.0, k3, k4]))
    A, B, C = (np.asarray(M, dtype=float) for M in (sys.A, sys.B, sys.C))
    M = np.zeros((3, 3))
    M[:2, :2], M[:2, 2:] = A * dt, B * dt
    E = scipy.linalg.expm(M)
    return E[:2, :2], E[:2, 2], C[0]


def _identify(hold: str, dt: float, n_samples: int = 4000):
    """Open-loop PRBS identification of the continuous plant K_TRUE, starting from K_START."""
    ssm = StateSharedModel(A_POLY, 1, dt, [
        ModelSpec("M1", _theta_closed_form(K_TRUE)),
        ModelSpec("M3", _theta_closed_form(K_START), kind="adaptive")])
    est = NormalizedLeastSquares(NLSSettings(kappa=1000.0, gain=1.0 / dt, eig_floor=1e-3),
                                 ssm.params_from_theta(ssm.theta(1)), dt)
    corr = OutputHoldCorrection(ssm)
    Ad, Bd, C = _plant(K_TRUE, dt)
    rng = np.random.default_rng(0)
    x, u = np.zeros(2), 0.0
    ssm.initialize([0.0], [0.0])
    corr.reset([0.0])
    for k in range(n_samples):
        y = np.array([C @ x])
        corr.advance(y)
        est.update(corr.regressor() if hold == "foh" else ssm.regressor(), y)
        if k % 10 == 0:
            u = float(np.sign(rng.standard_normal()))
        ssm.update([u], y)
        x = Ad @ x + Bd * u
    truth = ssm.params_from_theta(_theta_closed_form(K_TRUE))
    return np.max(np.abs(est.p[:4] - truth[:4]) / np.abs(truth[:4]))


def test_first_order_hold_identifies_the_continuous_theta_of_eq_3_16():
    assert _identify("foh", 0.05) <= PARAM_RTOL


def test_held_outputs_identify_a_sampled_model_away_from_the_continuous_theta():
    # documents why the correction exists: the zero-order-hold identifier is biased
    assert _identify("zoh", 0.05) >= ZOH_BIAS_MIN


def test_h_matches_numerical_quadrature():
    dt = 0.3
    ssm = StateSharedModel(A_POLY, 1, dt)
    corr = OutputHoldCorrection(ssm)
    F, g = np.asarray(ssm.Fb), np.asarray(ssm.gb)
    h, _ = scipy.integrate.quad_vec(lambda s: scipy.linalg.expm(F * (dt - s)) @ g * s / dt,
                                    0.0, dt, epsabs=1e-13, epsrel=1e-12)
    np.testing.assert_allclose(corr.h, h, rtol=H_RTOL, atol=1e-14)


def _smooth_run(hold_errors: bool, dt=0.05, n=400):
    """Largest a-priori error of the true (in-class) model over the second half of a run."""
    ssm = StateSharedModel(A_POLY, 1, dt, [ModelSpec("M1", _theta_closed_form(K_TRUE))])
    corr = OutputHoldCorrection(ssm)
    Ad, Bd, C = _plant(K_TRUE, dt)
    x = np.zeros(2)
    ssm.initialize([0.0], [0.0])
    corr.reset([0.0])
    worst = 0.0
    for k in range(n):
        y = np.array([C @ x])
        e = corr.errors(y) if hold_errors else ssm.errors(y)
        corr.advance(y)
        if k > n // 2:
            worst = max(worst, float(abs(e[0, 0])))
        u = 1.0 if (k // 40) % 2 else -1.0  # a square wave: y itself is smooth
        ssm.update([u], y)
        x = Ad @ x + Bd * u
    return worst


def test_a_priori_error_of_an_in_class_model_is_second_order_with_the_hold():
    dt = 0.05
    e_foh, e_zoh = _smooth_run(True, dt), _smooth_run(False, dt)
    assert e_foh <= 0.1 * e_zoh  # the O(dt) lag of the held output is gone
    # halving dt divides the remaining error by 4 or more (at least second order)
    assert _smooth_run(True, dt / 2, 800) <= 0.35 * e_foh


def test_a_model_in_equilibrium_predicts_its_steady_output_with_the_hold():
    theta = _theta_closed_form(K_TRUE)
    u, y = 0.4, 1.3
    n_ss = np.array([u / A_POLY[0], 0.0, y / A_POLY[0], 0.0])  # F n + g v = 0 per block
    ssm = StateSharedModel(A_POLY, 1, 0.05, [ModelSpec("M1", theta, y - theta.T @ n_ss)])
    corr = OutputHoldCorrection(ssm)
    ssm.initialize([u], [y])
    corr.reset([y])
    np.testing.assert_allclose(corr.estimates(), [[y]], rtol=0, atol=1e-12)


class _HoldLaw:
    def reset(self, u, y):
        pass

    def compute(self, k, model, ssm, y, reference, u_last):
        return u_last + 0.1 * (reference[0] - y), {"status": "solved"}

    def checkpoint(self):
        return {}

    def restore(self, state):
        pass


def _controller():
    ssm = StateSharedModel(A_POLY, 1, 0.05, [
        ModelSpec("M1", _theta_closed_form(K_TRUE)),
        ModelSpec("M3", _theta_closed_form(K_START), kind="adaptive")])
    s = MultiModelSettings(NLSSettings(kappa=10.0, gain=3.0), IndexSettings(1.0, 0.1, 0.5, 0.5),
                           y_hold="foh")
    return MultiModelController(ssm, _HoldLaw(), [0.0], s)


def test_checkpoint_restore_continues_identically_with_the_hold():
    a, b = _controller(), _controller()
    ys = 0.3 * np.sin(0.07 * np.arange(120))
    for k in range(60):
        a.step(k, 0.05 * k, [ys[k]], [[1.0]])
    b.restore(json.loads(json.dumps(a.checkpoint())))
    for k in range(60, 120):
        da, db = a.step(k, 0.05 * k, [ys[k]], [[1.0]]), b.step(k, 0.05 * k, [ys[k]], [[1.0]])
        np.testing.assert_array_equal(da.u, db.u)
        np.testing.assert_array_equal(da.J, db.J)


def test_invalid_measurement_keeps_the_hold_finite():
    ctl = _controller()
    ctl.step(0, 0.0, [0.1], [[1.0]])
    dec = ctl.step(1, 0.05, [float("nan")], [[1.0]])
    assert dec.status == "invalid_measurement"
    assert np.all(np.isfinite(ctl.hold.c))
    assert ctl.step(2, 0.1, [0.12], [[1.0]]).status == "solved"


def test_unknown_hold_is_rejected_naming_the_field():
    with pytest.raises(ValueError, match="y_hold"):
        MultiModelSettings(y_hold="linear")


class _PRBSLaw(_HoldLaw):
    """Open loop: a pseudo-random binary input switching every 10 samples."""

    def __init__(self, seed=0):
        self.rng = np.random.default_rng(seed)

    def compute(self, k, model, ssm, y, reference, u_last):
        if k % 10 == 0:
            return np.array([float(np.sign(self.rng.standard_normal()))]), {"status": "solved"}
        return u_last, {"status": "solved"}


def test_default_controller_identifies_the_continuous_plant_in_its_own_class():
    dt = 0.05
    ssm = StateSharedModel(A_POLY, 1, dt, [
        ModelSpec("M1", _theta_closed_form(K_START)),
        ModelSpec("M3", _theta_closed_form(K_START), kind="adaptive")])
    s = MultiModelSettings(NLSSettings(kappa=1000.0, gain=1.0 / dt, eig_floor=1e-3))
    assert s.y_hold == "foh"
    ctl = MultiModelController(ssm, _PRBSLaw(), [0.0], s, kinds=["fixed", "free-running"])
    Ad, Bd, C = _plant(K_TRUE, dt)
    x = np.zeros(2)
    for k in range(4000):
        dec = ctl.step(k, k * dt, [C @ x], [[0.0]])
        x = Ad @ x + Bd * dec.u[0]
    truth = ssm.params_from_theta(_theta_closed_form(K_TRUE))
    rel = np.abs(ctl.params(1)[:4] - truth[:4]) / np.abs(truth[:4])
    assert np.max(rel) <= PARAM_RTOL


def test_a_checkpoint_without_the_hold_restores_into_a_hold_controller():
    ssm = StateSharedModel(A_POLY, 1, 0.05, [
        ModelSpec("M1", _theta_closed_form(K_TRUE)),
        ModelSpec("M3", _theta_closed_form(K_START), kind="adaptive")])
    old = MultiModelController(ssm, _HoldLaw(), [0.0], MultiModelSettings(
        NLSSettings(kappa=10.0, gain=3.0), IndexSettings(1.0, 0.1, 0.5, 0.5), y_hold="zoh"))
    for k in range(30):
        old.step(k, 0.05 * k, [0.01 * k], [[1.0]])
    state = json.loads(json.dumps(old.checkpoint()))
    assert "hold" not in state
    new = _controller()
    new.restore(state)
    np.testing.assert_array_equal(new.hold.c, 0.0)  # the slope starts afresh
    assert new.step(30, 1.5, [0.3], [[1.0]]).status == "solved"


def test_regressor_parts_give_the_regressor_after_the_next_output():
    """W_base + y d' (known before y) is the regressor once y is in and advanced."""
    ssm = StateSharedModel((1.0, 2.0, 1.5), 2, 0.1, [ModelSpec("M1", _structured_theta())])
    corr = OutputHoldCorrection(ssm)
    rng = np.random.default_rng(4)
    ssm.initialize([0.1, 0.2], [0.3, 0.4])
    corr.reset([0.3, 0.4])
    for _ in range(30):
        W_base, d = corr.regressor_parts()
        y = rng.standard_normal(2)
        corr.advance(y)
        np.testing.assert_allclose(W_base + np.outer(y, d), corr.regressor(), rtol=1e-12,
                                   atol=1e-13)
        ssm.update(rng.standard_normal(2), y)


def _structured_theta():
    """A Theta (2nm, m) = (12, 2) with the D = dI block structure (n = 3, m = 2)."""
    th = np.zeros((12, 2))
    th[:6] = np.arange(12).reshape(6, 2) * 0.1
    th[6:9, 0] = th[9:12, 1] = (0.2, -0.1, 0.05)
    return th
