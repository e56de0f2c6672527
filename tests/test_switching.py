"""Performance index (eq. 4.6, discrete) and dwell-time switching."""

import math

import numpy as np
import pytest

from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex


def test_index_matches_closed_form_for_constant_errors():
    # constant e: I(k) = dt e^2 (1 - q^k) / (1 - q), q = exp(-lambda dt)
    s = IndexSettings(mu=1.0, nu=0.1, forgetting=0.5, min_dwell=0.1)
    dt, k = 0.05, 200
    idx = PerformanceIndex(s, 2, dt)
    e = np.array([0.3, -1.2])
    for _ in range(k):
        J = idx.update(e)
    q = math.exp(-0.5 * dt)
    integral = dt * e**2 * (1 - q**k) / (1 - q)
    np.testing.assert_allclose(J, e**2 + 0.1 * integral, rtol=1e-12)


def test_index_approaches_continuous_integral_for_small_dt():
    # e(t) = 1 for all t: integral_0^T exp(-lambda (T - tau)) dtau = (1 - exp(-lambda T)) / lambda
    s = IndexSettings(mu=0.0, nu=1.0, forgetting=2.0, min_dwell=1.0)
    dt, T = 1e-3, 3.0
    idx = PerformanceIndex(s, 1, dt)
    for _ in range(round(T / dt)):
        idx.update([1.0])
    assert idx.J[0] == pytest.approx((1 - math.exp(-2.0 * T)) / 2.0, rel=2e-3)


@pytest.mark.parametrize("mu, nu, lam", [(0.0, 1.0, 1.0), (1.0, 0.1, 0.5), (0.3, 2.0, 4.0)])
def test_rms_error_reads_a_held_error_back_in_the_outputs_units(mu, nu, lam):
    # two outputs with scales 20 and 1 (weights 1/scale^2); model 0 misses them by
    # 10 and 0.5 (half a scale each), model 1 by 40 and 0 (two scales in one)
    s = IndexSettings(mu=mu, nu=nu, forgetting=lam, min_dwell=0.1,
                      output_weights=(1 / 20**2, 1.0))
    idx = PerformanceIndex(s, 2, 0.01)
    e = np.array([[10.0, 0.5], [40.0, 0.0]])
    for _ in range(round(20 / lam / 0.01)):  # 20 forgetting times: the integral settled
        idx.update(e)
    np.testing.assert_allclose(idx.rms_error(), [math.sqrt(0.5**2 + 0.5**2), 2.0], rtol=1e-6)


def test_mimo_errors_use_weighted_squared_norm():
    idx = PerformanceIndex(IndexSettings(mu=1, nu=0, output_weights=(1.0, 4.0)), 2, 0.1)
    J = idx.update(np.array([[1.0, 1.0], [2.0, 0.0]]))
    np.testing.assert_allclose(J, [5.0, 4.0])


def test_index_picks_the_model_that_matches_a_known_plant():
    # plant y(k+1) = 0.9 y(k) + 0.2 u(k); three candidate models, the second is exact
    rng = np.random.default_rng(0)
    models = [(0.5, 0.2), (0.9, 0.2), (0.9, 0.5)]
    idx = PerformanceIndex(IndexSettings(mu=1, nu=0.1, forgetting=0.5, min_dwell=0.5), 3, 0.1)
    sw = ModelSwitcher(3, min_dwell=0.5, dt=0.1, initial=0)
    y = 0.0
    for _ in range(100):
        u = rng.standard_normal()
        preds = np.array([a * y + b * u for a, b in models])
        y = 0.9 * y + 0.2 * u
        dec = sw.step(idx.update(preds - y))
    assert dec.active == 1 and dec.best == 1
    assert np.argmin(idx.J) == 1


def test_dwell_time_is_respected():
    dt, dwell = 0.1, 0.35  # rounds up to 4 samples
    sw = ModelSwitcher(2, min_dwell=dwell, dt=dt)
    assert sw.dwell_samples == 4
    rng = np.random.default_rng(1)
    switch_samples = []
    for k in range(400):
        J = rng.random(2)  # best model changes at random, often
        if sw.step(J).switched:
            switch_samples.append(k)
    gaps = np.diff(switch_samples)
    assert len(switch_samples) > 10
    assert gaps.min() >= sw.dwell_samples
    assert sw.n_switches == len(switch_samples) and sw.n_held > 0


def test_ties_and_nonfinite_values_do_not_switch():
    sw = ModelSwitcher(3, min_dwell=0.1, dt=0.1, initial=1)
    assert not sw.step([1.0, 1.0, 1.0]).switched
    assert not sw.step([np.nan, 2.0, np.inf]).switched
    dec = sw.step([0.5, 2.0, 3.0], allowed=[False, True, True])
    assert dec.active == 1 and not dec.switched


def test_checkpoint_round_trip():
    sw = ModelSwitcher(3, min_dwell=1.0, dt=0.1)
    sw.step([3.0, 1.0, 2.0])
    other = ModelSwitcher(3, min_dwell=1.0, dt=0.1)
    other.restore(sw.checkpoint())
    # both hold model 1 for the rest of the dwell time
    for _ in range(5):
        assert sw.step([0.0, 1.0, 2.0]) == other.step([0.0, 1.0, 2.0])


@pytest.mark.parametrize(
    "kwargs, field",
    [({"mu": -1}, "mu"), ({"nu": float("inf")}, "nu"), ({"forgetting": -0.1}, "forgetting"),
     ({"min_dwell": 0}, "min_dwell"), ({"mu": 0, "nu": 0}, "mu"),
     ({"output_weights": (1.0, -2.0)}, "output_weights")],
)
def test_settings_name_the_bad_field(kwargs, field):
    with pytest.raises(ValueError, match=field):
        IndexSettings(**kwargs)
