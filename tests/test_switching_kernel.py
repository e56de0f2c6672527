"""The compiled index update and smallest-J choice equal the numpy expressions of
eq. 4.6 and the switch rule, to the last bit."""

import math

import numpy as np
import pytest

from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
from controller.switching_kernel import index_step, smallest_index


def test_index_step_equals_the_numpy_recursion():
    rng = np.random.default_rng(1)
    w = rng.uniform(0.1, 3.0, 5)
    integral = rng.uniform(0.0, 2.0, 4)
    decay, dt, mu, nu = np.exp(-0.5 * 0.01), 0.01, 1.0, 0.1
    for _ in range(50):
        e = rng.standard_normal((4, 5)) * 10.0 ** rng.uniform(-6, 2)
        J, new, finite = index_step(e, w, integral, decay, dt, mu, nu)
        e2 = (e * e) @ w
        want_integral = decay * integral + dt * e2
        np.testing.assert_array_equal(new, want_integral)
        np.testing.assert_array_equal(J, mu * e2 + nu * want_integral)
        assert finite
        integral = new


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nonfinite_error_is_reported_and_the_index_keeps_its_state(bad):
    index = PerformanceIndex(IndexSettings(output_weights=(1.0, 2.0)), 3, 0.1)
    index.update(np.ones((3, 2)))
    J, integral = index.J.copy(), index.integral.copy()
    e = np.ones((3, 2))
    e[1, 0] = bad
    with pytest.raises(ValueError, match="non-finite"):
        index.update(e)
    np.testing.assert_array_equal(index.J, J)
    np.testing.assert_array_equal(index.integral, integral)


def _numpy_rule(J, active, hysteresis, tol):
    """The smallest-J rule as it was written with numpy (argmin over J, inf for
    non-finite)."""
    masked = np.where(np.isfinite(J), J, np.inf)
    if not np.any(np.isfinite(masked)):
        return active, False, False
    best = int(np.argmin(masked))
    threshold = (1.0 - hysteresis) * masked[active] - tol
    return best, True, not (best == active or masked[best] >= threshold)


def test_smallest_index_is_the_numpy_rule_with_ties_and_nonfinite_values():
    rng = np.random.default_rng(2)
    pool = [0.0, 1.0, 1.0 + 1e-13, 2.0, np.nan, np.inf, -np.inf, 5e-13]
    for _ in range(3000):
        k = int(rng.integers(1, 6))
        J = rng.choice(pool, size=k) if rng.uniform() < 0.5 else rng.uniform(0, 3, k)
        active = int(rng.integers(0, k))
        h = float(rng.choice([0.0, 0.1, 0.5]))
        got = smallest_index(np.asarray(J, dtype=float), active, h, ModelSwitcher.J_TOL)
        assert (int(got[0]), bool(got[1]), bool(got[2])) == _numpy_rule(
            np.asarray(J, dtype=float), active, h, ModelSwitcher.J_TOL), (J, active, h)


def test_switcher_still_holds_for_the_dwell_time_and_excludes_disallowed_models():
    sw = ModelSwitcher(3, min_dwell=0.3, dt=0.1)
    assert sw.step([1.0, 0.5, 2.0]).switched  # free at the first sample
    assert sw.step([0.1, 0.5, 2.0]).held  # model 0 better, dwell of 3 samples holds
    sw.step([0.1, 0.5, 2.0])
    dec = sw.step([0.1, 0.5, 2.0])
    assert dec.switched and dec.active == 0
    sw2 = ModelSwitcher(3, min_dwell=0.1, dt=0.1, initial=2)
    dec = sw2.step([0.1, 0.5, 2.0], allowed=[False, True, True])
    assert dec.active == 1 and dec.best == 1


#: Largest difference allowed between steady_output_errors and numpy (0: bit for bit).
STEADY_ERRORS_ATOL = 0.0


def _numpy_steady_output_errors(errors, theta2, steady):
    """MultiModelController's steady-output scaling in numpy (before the kernel)."""
    ratio = (1.0 - theta2 @ steady).tolist()
    scale = np.array([1.0 / abs(r) if math.isfinite(r) and abs(r) > 1e-12 else 1.0
                      for r in ratio])
    return errors * scale[:, None]


@pytest.mark.parametrize("k, p, n", [(4, 5, 8), (2, 1, 3), (3, 2, 1)])
def test_steady_output_errors_equal_numpy(k, p, n):
    from controller.switching_kernel import steady_output_errors

    rng = np.random.default_rng(k * 100 + p * 10 + n)
    for trial in range(300):
        T = rng.normal(size=(k * 2, n + 3)) * 10.0 ** rng.uniform(-3, 1, (k * 2, n + 3))
        theta2 = T[::2, 1:1 + n]  # strided, as StateSharedModel.theta2_all
        theta2.flags.writeable = False
        steady = rng.normal(size=n)
        errors = rng.normal(size=(k, p)) * 10.0 ** rng.uniform(-6, 2, (k, p))
        if trial % 25 == 0:  # a model at 1 - theta2' n_ss = 0, or not finite
            theta2 = np.array(theta2)
            theta2[0] = 0.0
            theta2[0, 0] = 1.0 / steady[0] if trial % 50 else np.nan
        with np.errstate(invalid="ignore"):
            want = _numpy_steady_output_errors(errors, theta2, steady)
        got = steady_output_errors(errors, theta2, steady)
        np.testing.assert_allclose(got, want, rtol=0, atol=STEADY_ERRORS_ATOL)
        assert np.array_equal(got, want, equal_nan=True)
