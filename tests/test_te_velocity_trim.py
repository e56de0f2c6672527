"""The velocity-form trim the TE cascade's outer loops share
(:mod:`controller.units.te.velocity_trim`), worked by hand."""

from __future__ import annotations

import pytest

from controller.units.te.velocity_trim import VelocityTrim


def test_first_sample_integrates_only_then_the_error_change_counts():
    t = VelocityTrim(-50.0, 50.0)
    # first sample: its own previous error, integral only: 2 x (0.01 / 0.5 x 3)
    assert t.step(3.0, 2.0, 0.5, 0.01, False) == pytest.approx(0.12, abs=1e-15)
    # next: 2 x ((1 - 3) + 0.01 / 0.5 x 1) = -3.96
    assert t.step(1.0, 2.0, 0.5, 0.01, False) == pytest.approx(0.12 - 3.96, abs=1e-14)


def test_held_keeps_the_trim_but_follows_the_error():
    t = VelocityTrim(-50.0, 50.0)
    t.step(1.0, 1.0, 1.0, 0.01, False)
    kept = t.value
    assert t.step(5.0, 1.0, 1.0, 0.01, True) == kept
    # released: no kick from the change 1 -> 5 made while held
    assert t.step(5.0, 1.0, 1.0, 0.01, False) == pytest.approx(kept + 0.05, abs=1e-15)


def test_the_trim_stays_in_its_range():
    t = VelocityTrim(0.0, 20.0)
    assert t.step(-100.0, 1.0, 0.01, 0.01, False) == 0.0  # would go to -100
    for _ in range(100):
        t.step(100.0, 1.0, 0.01, 0.01, False)
    assert t.value == 20.0


@pytest.mark.parametrize("lo, hi", [(1.0, 0.0), (float("nan"), 1.0), (0.0, float("inf"))])
def test_a_bad_range_is_refused(lo, hi):
    with pytest.raises(ValueError, match="lo/hi"):
        VelocityTrim(lo, hi)
