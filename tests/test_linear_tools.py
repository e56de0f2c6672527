"""controller.linear: minimal realization, balanced truncation, Re, ARe, ZOH, MFD.

References are independent: python-control / slycot (hsvd, balred, minreal, c2d),
scipy, closed forms and the seed's printed numbers.
"""

from __future__ import annotations

import control
import numpy as np
import pytest
import scipy.signal

from controller.linear.balanced import (
    balanced_truncation,
    hankel_singular_values,
    relative_error,
    select_order,
)
from controller.linear.discretize import zoh
from controller.linear.errors import average_relative_error
from controller.linear.mfd import LeftMFD, left_mfd
from controller.linear.realization import Realization, minimal_realization

HSV_RTOL = 1e-8
FREQ_ATOL_REL = 1e-8  # frequency responses relative to the peak gain
ZOH_ATOL = 1e-12


def rand_sys(seed, nx, m, p):
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((nx, nx))
    A -= (np.max(np.linalg.eigvals(A).real) + rng.uniform(0.1, 1.0)) * np.eye(nx)
    return Realization(A, rng.standard_normal((nx, m)), rng.standard_normal((p, nx)), None)


def fr(sys, w):
    """Frequency response through python-control, shape (len(w), p, m)."""
    r = control.ss(sys.A, sys.B, sys.C, sys.D).frequency_response(w).complex
    r = np.asarray(r).reshape(sys.n_outputs, sys.n_inputs, -1)
    return np.moveaxis(r, 2, 0)


W = np.logspace(-3, 3, 61)


# -- balanced truncation vs slycot -------------------------------------------------
@pytest.mark.parametrize("seed,nx,m,p", [(0, 4, 1, 1), (1, 6, 2, 2), (2, 8, 3, 3), (3, 10, 2, 3),
                                         (4, 12, 3, 2)])
def test_hsv_match_slycot(seed, nx, m, p):
    sys = rand_sys(seed, nx, m, p)
    ours = hankel_singular_values(sys)
    ref = control.hsvd(sys.to_control())
    # small sigmas are only determined to ~eps * sigma_1 * cond: compare relative to sigma_1
    np.testing.assert_allclose(ours, ref, rtol=0, atol=HSV_RTOL * ref[0])


@pytest.mark.parametrize("method", ["truncate", "matchdc"])
@pytest.mark.parametrize("seed,nx,m,p,k", [(5, 5, 1, 1, 2), (6, 7, 2, 2, 3), (7, 9, 3, 3, 4),
                                           (8, 10, 2, 3, 5)])
def test_truncation_matches_slycot_balred(seed, nx, m, p, k, method):
    sys = rand_sys(seed, nx, m, p)
    ours = balanced_truncation(sys, order=k, method=method)
    ref = control.balred(sys.to_control(), k, method=method)
    peak = np.max(np.abs(fr(sys, W)))
    err = np.max(np.abs(ours.reduced.frequency_response(W) - fr(Realization(
        ref.A, ref.B, ref.C, ref.D), W)))
    assert err <= FREQ_ATOL_REL * peak
    assert ours.reduced.order == k
    assert ours.reduced.is_stable()
    # H-infinity bound 2 sum sigma_(i>k) (eq. 3.20), checked on a dense grid
    hinf = np.max(np.linalg.norm(fr(sys, W) - ours.reduced.frequency_response(W), ord=2,
                                 axis=(1, 2)))
    assert hinf <= ours.error_bound * (1 + 1e-9)


def test_matchdc_keeps_dc_gain():
    sys = rand_sys(9, 6, 2, 2)
    red = balanced_truncation(sys, order=2, method="matchdc").reduced
    np.testing.assert_allclose(red.dc_gain(), sys.dc_gain(), rtol=1e-9, atol=1e-12)


def test_re_definition_eq_3_22():
    hsv = np.array([4.0, 2.0, 1.0, 0.5])
    # closed form: sqrt(1 + 0.25) / sqrt(16 + 4 + 1 + 0.25)
    assert relative_error(hsv, 2) == pytest.approx(np.sqrt(1.25) / np.sqrt(21.25), rel=1e-15)
    assert relative_error(hsv, 4) == 0.0
    assert relative_error(hsv, 0) == pytest.approx(1.0)
    assert select_order(hsv, 0.3) == 2  # Re(1) = 0.434 , Re(2) = 0.2425
    assert select_order(hsv, 0.2) == 3
    res = balanced_truncation(rand_sys(10, 6, 2, 2), re_threshold=0.05)
    assert res.Re < 0.05
    assert relative_error(res.hsv, res.order - 1) >= 0.05


def test_truncation_bad_input():
    sys = rand_sys(11, 4, 1, 1)
    with pytest.raises(ValueError, match="order"):
        balanced_truncation(sys)
    with pytest.raises(ValueError, match="order"):
        balanced_truncation(sys, order=5)
    with pytest.raises(ValueError, match="method"):
        balanced_truncation(sys, order=2, method="x")
    with pytest.raises(ValueError, match="re_threshold"):
        select_order([1.0, 0.1], 0.0)
    unstable = Realization(np.diag([1.0, -1.0]), np.ones((2, 1)), np.ones((1, 2)), None)
    with pytest.raises(ValueError, match="stable"):
        balanced_truncation(unstable, order=1)


def test_truncation_of_nonminimal_model_beyond_mcmillan_degree_rejected():
    sys = rand_sys(12, 3, 1, 1)
    # append an unobservable mode
    A = np.block([[sys.A, np.zeros((3, 1))], [np.zeros((1, 3)), -np.eye(1)]])
    big = Realization(A, np.vstack((sys.B, [[1.0]])), np.hstack((sys.C, [[0.0]])), None)
    assert np.sum(hankel_singular_values(big) > 1e-10) == 3
    with pytest.raises(ValueError, match="McMillan"):
        balanced_truncation(big, order=4)
    red = balanced_truncation(big, order=3).reduced
    np.testing.assert_allclose(red.frequency_response(W), fr(sys, W), atol=1e-8)


# -- minimal realization -----------------------------------------------------------
def test_minimal_realization_removes_hidden_modes():
    sys = rand_sys(13, 3, 2, 2)
    rng = np.random.default_rng(13)
    # uncontrollable mode (-0.5) and unobservable mode (-2)
    A = np.zeros((5, 5))
    A[:3, :3] = sys.A
    A[3, 3], A[4, 4] = -0.5, -2.0
    A[3, :3] = rng.standard_normal(3) * 0  # keep it uncontrollable
    B = np.vstack((sys.B, np.zeros((1, 2)), rng.standard_normal((1, 2))))
    C = np.hstack((sys.C, rng.standard_normal((2, 1)), np.zeros((2, 1))))
    big = Realization(A, B, C, None)
    mini = minimal_realization(big)
    assert mini.order == 3
    np.testing.assert_allclose(mini.frequency_response(W), big.frequency_response(W), atol=1e-9)


@pytest.mark.parametrize("m,p", [(1, 1), (2, 3), (3, 2)])
def test_minimal_realization_is_python_controls_minreal(m, p):
    """The direct SLICOT call gives what ``control.minreal`` gives, to the bit, on
    systems with a hidden mode (padding of B and C for m != p included)."""
    import control

    rng = np.random.default_rng(40 + 3 * m + p)
    for hide in ("uncontrollable", "unobservable"):
        A = rng.standard_normal((5, 5))
        B = rng.standard_normal((5, m))
        C = rng.standard_normal((p, 5))
        D = rng.standard_normal((p, m))
        if hide == "uncontrollable":
            A[-1, :-1], B[-1] = 0.0, 0.0
        else:
            A[1:, 0], C[:, 0] = 0.0, 0.0
        ours = minimal_realization(A, B, C, D)
        ref = control.minreal(control.ss(A, B, C, D), verbose=False)
        assert ours.order == 4
        for got, want in ((ours.A, ref.A), (ours.B, ref.B), (ours.C, ref.C), (ours.D, ref.D)):
            np.testing.assert_array_equal(got, np.asarray(want))


# -- MFD --------------------------------------------------------------------------------
@pytest.mark.parametrize("seed,nx,m,p", [(20, 1, 1, 1), (21, 3, 2, 2), (22, 5, 3, 3),
                                         (23, 4, 2, 3), (24, 8, 3, 3)])
def test_left_mfd_reproduces_transfer_matrix(seed, nx, m, p):
    sys = rand_sys(seed, nx, m, p)
    mfd = left_mfd(sys)
    assert mfd.degree == nx and mfd.shape == (p, m)
    np.testing.assert_allclose(mfd.d[::-1], np.poly(sys.A), rtol=1e-10, atol=1e-12)
    s = 1j * W
    ref = fr(sys, W)
    peak = np.max(np.abs(ref))
    assert np.max(np.abs(mfd.evaluate(s) - ref)) <= FREQ_ATOL_REL * peak


def test_left_mfd_siso_closed_form():
    # H = (2 s + 3)/(s^2 + 4 s + 5) in controllable canonical form
    A = [[0.0, 1.0], [-5.0, -4.0]]
    mfd = left_mfd(A, [[0.0], [1.0]], [[3.0, 2.0]])
    np.testing.assert_allclose(mfd.d, [5.0, 4.0, 1.0], rtol=1e-12)
    np.testing.assert_allclose(mfd.N[0, 0], [3.0, 2.0], rtol=1e-12)


def test_left_mfd_uses_mcmillan_degree():
    # H = I/(s+1) (2x2) has McMillan degree 2 -> d = (s+1)^2, N = (s+1) I.
    mfd = left_mfd(-np.eye(2), np.eye(2), np.eye(2))
    np.testing.assert_allclose(mfd.d, [1.0, 2.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(mfd.N[:, :, 0], np.eye(2), atol=1e-12)
    np.testing.assert_allclose(mfd.N[:, :, 1], np.eye(2), atol=1e-12)


def test_left_mfd_bad_input():
    with pytest.raises(ValueError, match="B"):
        left_mfd(np.eye(2), np.ones((3, 1)), np.ones((1, 2)))
    with pytest.raises(ValueError, match="d"):
        LeftMFD(d=[1.0, 2.0], N=np.zeros((1, 1, 1)), D0=np.zeros((1, 1)))


# -- ZOH --------------------------------------------------------------------------------
@pytest.mark.parametrize("seed,nx,m,p", [(30, 3, 1, 1), (31, 6, 2, 3)])
def test_zoh_matches_scipy_and_control(seed, nx, m, p):
    sys = rand_sys(seed, nx, m, p)
    dt = 0.37
    d = zoh(sys, dt=dt)
    Ad, Bd, *_ = scipy.signal.cont2discrete((sys.A, sys.B, sys.C, sys.D), dt, "zoh")
    np.testing.assert_allclose(d.Phi, Ad, atol=ZOH_ATOL)
    np.testing.assert_allclose(d.Gamma, Bd, atol=ZOH_ATOL)
    ref = control.c2d(sys.to_control(), dt, "zoh")
    np.testing.assert_allclose(d.Phi, ref.A, atol=ZOH_ATOL)
    with pytest.raises(ValueError, match="dt"):
        zoh(sys, dt=0.0)


# -- ARe -------------------------------------------------------------------------------
def test_are_closed_form():
    nominal = np.array([100.0, -50.0])
    y_ref = nominal + np.array([[1.0, 0.5], [2.0, -0.5], [0.0, 0.0], [-1.0, 1.0]])
    y_est = nominal + np.array([[1.5, 0.5], [1.0, -0.5], [0.0, 1.0], [-1.0, 1.0]])
    # output 0: mean |.| = (0.5 + 1 + 0 + 0)/4 = 0.375 -> 0.375 %; output 1: 1/4 / 50 -> 0.5 %
    np.testing.assert_allclose(average_relative_error(y_ref, y_est, nominal), [0.375, 0.5])
    with pytest.raises(ValueError, match="nominal"):
        average_relative_error(y_ref, y_est, [1.0, 0.0])
    with pytest.raises(ValueError, match="y_est"):
        average_relative_error(y_ref, y_est[:2], nominal)


def test_unstable_part_kept_matches_slycot_ab09md():
    rng = np.random.default_rng(40)
    n = 8
    A = rng.standard_normal((n, n))
    # Shift between the 2nd and 3rd largest *distinct* real parts (a complex pair counts
    # once): shifting between the two halves of a pair would put it on the imaginary
    # axis, where the LAPACK build's last bit decides whether it is stable.
    re = np.unique(np.round(np.linalg.eigvals(A).real, 9))
    A -= 0.5 * (re[-3] + re[-2]) * np.eye(n)  # the two rightmost modes (or pairs) unstable
    sys = Realization(A, rng.standard_normal((n, 2)), rng.standard_normal((2, n)), None)
    n_unstable = int(np.sum(np.linalg.eigvals(A).real > 0))
    assert n_unstable >= 1
    with pytest.raises(ValueError, match="stable"):
        balanced_truncation(sys, order=5)
    ours = balanced_truncation(sys, order=5, unstable="keep")
    ref = control.balred(sys.to_control(), 5)
    refr = Realization(ref.A, ref.B, ref.C, ref.D)
    peak = np.max(np.abs(fr(sys, W)))
    assert np.max(np.abs(ours.reduced.frequency_response(W) - fr(refr, W))) <= FREQ_ATOL_REL * peak
    assert int(np.sum(ours.reduced.poles().real > 0)) == n_unstable
    with pytest.raises(ValueError, match="unstable modes"):
        balanced_truncation(sys, order=n_unstable, unstable="keep")
