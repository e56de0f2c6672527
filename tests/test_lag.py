"""The scalar first-order lag (controller.lag) against the continuous lag and the vector
filter of seed §6.1.2."""

import math

import numpy as np
import pytest

from controller.lag import lag_step
from controller.mpc.filters import FirstOrderFilter

#: Backward Euler at dt/tau = 0.01 against exp: 0.6303 against 0.6321 after one tau.
EULER_TOL_AT_0_01 = 2.5e-3


def test_step_response_follows_the_continuous_lag():
    tau, dt = 1.0, 0.01
    x, t = 0.0, 0.0
    worst = 0.0
    for _ in range(300):
        x = lag_step(x, 1.0, dt, tau)
        t += dt
        worst = max(worst, abs(x - (1.0 - math.exp(-t / tau))))
    assert worst < EULER_TOL_AT_0_01


def test_zero_time_constant_passes_the_sample():
    assert lag_step(3.0, -2.5, 0.01, 0.0) == -2.5


@pytest.mark.parametrize("dt", [1e-3, 0.5, 10.0, 1e6])
def test_never_overshoots_at_any_sample(dt):
    x = lag_step(0.0, 1.0, dt, 1.0)
    assert 0.0 < x <= 1.0


def test_equals_the_vector_filter_with_its_weight():
    rng = np.random.default_rng(3)
    u = rng.normal(size=200)
    dt, tau = 0.01, 0.25
    f = FirstOrderFilter(dt / (tau + dt), y0=[u[0]])
    x = float(u[0])
    for v in u:
        x = lag_step(x, float(v), dt, tau)
        assert x == pytest.approx(float(f.update([v])[0]), rel=1e-12, abs=1e-12)


def test_a_bad_sample_is_left_to_the_caller():
    assert math.isnan(lag_step(1.0, math.nan, 0.01, 0.1))
