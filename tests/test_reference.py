"""Set-point schedules and first-order reference trajectories."""

import math

import numpy as np
import pytest

from controller.reference import ReferenceTrajectory, SetpointSchedule


def test_first_order_filter_matches_the_exponential_step_response():
    tau, dt = 2.0, 0.1
    ref = ReferenceTrajectory(SetpointSchedule.step(1.3, 5.0, t_step=0.0), tau, dt, initial=[1.3])
    values = np.array([ref.advance()[0] for _ in range(100)])
    t = dt * np.arange(1, 101)
    np.testing.assert_allclose(values, 5.0 + (1.3 - 5.0) * np.exp(-t / tau), rtol=1e-12)


def test_horizon_previews_future_samples_without_advancing():
    ref = ReferenceTrajectory(SetpointSchedule.step(0.0, 1.0, t_step=0.25), 0.5, 0.1)
    H = ref.horizon(6)
    assert H.shape == (6, 1)
    # first three samples still see the old set point (t = 0, 0.1, 0.2 < 0.25)
    np.testing.assert_allclose(H[:3, 0], 0.0)
    a = math.exp(-0.1 / 0.5)
    np.testing.assert_allclose(H[3:, 0], [1 - a, 1 - a**2, 1 - a**3], rtol=1e-12)
    np.testing.assert_allclose(ref.r, [0.0])  # unchanged
    np.testing.assert_allclose([ref.advance()[0] for _ in range(6)], H[:, 0])


def test_zero_time_constant_is_the_raw_setpoint():
    ref = ReferenceTrajectory(SetpointSchedule.step([1.0, 2.0], [3.0, 4.0], 0.0), 0.0, 0.1,
                              initial=[1.0, 2.0])
    np.testing.assert_allclose(ref.advance(), [3.0, 4.0])


def test_staircase_and_pulse_schedules():
    st = SetpointSchedule.staircase(1.3, 5.0, n_steps=4, t_first=1.0, step_duration=5.0)
    np.testing.assert_allclose([st.at(t)[0] for t in (0.5, 1.0, 6.0, 11.0, 16.0, 100.0)],
                               [1.3, 2.225, 3.15, 4.075, 5.0, 5.0])
    pu = SetpointSchedule.pulses(0.0, 0.389, t_first=2.0, width=3.0, period=7.0, count=2)
    np.testing.assert_allclose([pu.at(t)[0] for t in (1.0, 2.0, 4.9, 5.0, 9.5, 12.5)],
                               [0.0, 0.389, 0.389, 0.0, 0.389, 0.0])


def test_checkpoint_round_trip():
    ref = ReferenceTrajectory(SetpointSchedule.step(0.0, 1.0, 0.0), 1.0, 0.1)
    for _ in range(7):
        ref.advance()
    other = ReferenceTrajectory(SetpointSchedule.step(0.0, 1.0, 0.0), 1.0, 0.1)
    other.restore(ref.checkpoint())
    np.testing.assert_allclose(other.horizon(4), ref.horizon(4))


@pytest.mark.parametrize(
    "make, field",
    [(lambda: SetpointSchedule((0.0, 0.0), np.array([1.0, 2.0])), "times"),
     (lambda: SetpointSchedule((0.0,), np.array([np.nan])), "values"),
     (lambda: ReferenceTrajectory(SetpointSchedule.constant(1.0), -1.0, 0.1), "time_constant"),
     (lambda: ReferenceTrajectory(SetpointSchedule.constant(1.0), 1.0, 0.0), "dt"),
     (lambda: SetpointSchedule.pulses(0, 1, 1.0, 5.0, 4.0, 2), "width")],
)
def test_bad_input_names_the_field(make, field):
    with pytest.raises(ValueError, match=field):
        make()
