"""The soft output limits' constraint window (``MPCSettings.output_limit_start``).

A measured output beyond its limit: with the limit on every prediction the first move
must bring it back within one sample; with the window starting later the controller
has those samples to do it with a smaller move. Predictions are simulated here from
the velocity-form model ``Δx(k+1) = Φ Δx(k) + Γ Δu(k)``, ``y(k+1) = y(k) + C Δx(k+1)``,
independently of :mod:`controller.mpc.formulation`.
"""

from __future__ import annotations

import numpy as np
import pytest

from controller.mpc import DAQPBackend, MPCSettings, MPCSettingsError, build_formulation

LIMIT_ATOL = 1e-7   # a met soft limit: solver tolerance
SLACK_ATOL = 1e-9   # an exact penalty that can be met leaves no slack

PHI, GAMMA, C = np.array([[0.9]]), np.array([[0.1]]), np.array([[1.0]])
Y_MAX = 1.0
Y_NOW = 1.05  # measured, beyond the limit


def _predict(dU, P):
    dx, y, out = 0.0, Y_NOW, []
    for j in range(P):
        dx = PHI[0, 0] * dx + GAMMA[0, 0] * (dU[j] if j < len(dU) else 0.0)
        y = y + C[0, 0] * dx
        out.append(y)
    return np.array(out)


def _solve(start, P=10, M=4):
    s = MPCSettings(nu=1, ny=1, P=P, M=M, Xi=[1.0], Lambda=[0.1], du_max=[10.0],
                    y_max=[Y_MAX], slack_linear=1e6, slack_quadratic=1e4,
                    output_limit_start=start)
    form = build_formulation(PHI, GAMMA, C, s)
    v = form.qp_vectors(np.array([0.0, Y_NOW]), np.zeros(1), np.array([Y_MAX]))
    res = DAQPBackend(form.H, form.A).solve(v)
    assert res.ok, res
    return res.x[:M], res.x[-1]


def test_limit_on_every_prediction_brings_the_output_back_in_one_sample():
    dU, eps = _solve(start=1)
    assert eps == pytest.approx(0.0, abs=SLACK_ATOL)
    Y = _predict(dU, 10)
    assert np.all(Y <= Y_MAX + LIMIT_ATOL)
    # y(k+1) = 1.05 + 0.1 du(k) <= 1: at least a move of -0.5
    assert dU[0] <= -0.5 + LIMIT_ATOL


def test_window_leaves_the_first_predictions_free_and_moves_less():
    dU1, _ = _solve(start=1)
    dU3, eps = _solve(start=3)
    assert eps == pytest.approx(0.0, abs=SLACK_ATOL)
    Y = _predict(dU3, 10)
    assert np.all(Y[2:] <= Y_MAX + LIMIT_ATOL)  # held from the third prediction on
    assert Y[0] > Y_MAX + 1e-3                   # the first is left above the limit
    assert abs(dU3[0]) < 0.6 * abs(dU1[0])


def test_window_at_one_is_the_limit_on_every_prediction():
    base = MPCSettings(nu=1, ny=1, P=10, M=4, y_max=[Y_MAX])
    one = MPCSettings(nu=1, ny=1, P=10, M=4, y_max=[Y_MAX], output_limit_start=1)
    assert build_formulation(PHI, GAMMA, C, base).ymax_rows.size == 10
    np.testing.assert_array_equal(build_formulation(PHI, GAMMA, C, base).ymax_rows,
                                  build_formulation(PHI, GAMMA, C, one).ymax_rows)
    later = MPCSettings(nu=1, ny=1, P=10, M=4, y_max=[Y_MAX], output_limit_start=4)
    assert build_formulation(PHI, GAMMA, C, later).ymax_rows.size == 7


@pytest.mark.parametrize("start", [0, 11, True, 2.5, "3"])
def test_bad_window_names_the_field(start):
    with pytest.raises(MPCSettingsError, match="output_limit_start"):
        MPCSettings(nu=1, ny=1, P=10, M=4, y_max=[Y_MAX], output_limit_start=start)
