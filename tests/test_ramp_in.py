"""The ramp-in after a take-over (services.nodes.ramp_in): the moves after a resume step by
no more than the largest recent step of each MV, and reach the controller's move."""

import numpy as np
import pytest

from services.nodes.ramp_in import FLOOR_FRACTION, MIN_SAMPLES, MoveHistory, RampIn


def test_move_history_keeps_the_largest_step_of_the_window():
    h = MoveHistory(2, window=3)
    assert h.steps() is None
    for u in ([0.0, 5.0], [9.0, 5.0], [9.5, 5.0], [9.0, 4.0], [9.2, 4.5]):
        h.append(u)
    # the first move (0 -> 9) has left the window of 3 steps
    np.testing.assert_allclose(h.steps(), [0.5, 1.0])


def test_moves_approach_the_wanted_move_by_the_recent_steps():
    ramp = RampIn([0.5, 2.0], span=[100.0, 450.0])
    prev = np.array([10.0, 2800.0])
    wanted = np.array([14.0, 2780.0])
    path = [prev]
    while not ramp.done:
        path.append(ramp.limit(wanted, path[-1]))
        assert len(path) < 100
    steps = np.abs(np.diff(np.asarray(path), axis=0))
    assert np.all(steps <= [0.5 + 1e-12, 2.0 + 1e-12])
    np.testing.assert_allclose(path[-1], wanted)
    assert len(path) - 1 >= MIN_SAMPLES


def test_an_mv_that_did_not_move_gets_the_floor_not_a_freeze():
    ramp = RampIn([0.0, 1.0], span=[100.0, 10.0])
    out = ramp.limit([20.0, 0.0], [10.0, 0.0])
    assert out[0] == pytest.approx(10.0 + FLOOR_FRACTION * 100.0)


def test_a_move_within_the_steps_goes_out_unchanged_and_the_ramp_in_ends():
    ramp = RampIn([1.0], span=[10.0])
    for _ in range(MIN_SAMPLES):
        u = np.array([3.5])
        assert ramp.limit(u, [3.0]) is u
    assert ramp.done and ramp.samples == 0


@pytest.mark.parametrize("steps", [[np.nan], [-1.0], [1.0, 2.0]])
def test_bad_steps_are_refused(steps):
    with pytest.raises(ValueError, match="steps"):
        RampIn(steps, span=[10.0])
