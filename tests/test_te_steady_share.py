"""The share of a steady-grade action ramps in over its ramp and out while held."""

from controller.units.te.steady_share import ramp_share


def test_the_share_ramps_in_over_its_length_and_out_at_the_same_rate():
    s, seen = 0.0, []
    for _ in range(30):  # 0.01 h samples, a 0.25 h ramp: in after 25 samples
        s = ramp_share(s, True, 0.01, 0.25)
        seen.append(s)
    assert 0.0 < seen[0] < seen[1] and seen[23] < 1.0 and seen[25:] == [1.0] * 5
    for _ in range(10):
        s = ramp_share(s, False, 0.01, 0.25)
    assert abs(s - 0.6) < 1e-12
    for _ in range(40):
        s = ramp_share(s, False, 0.01, 0.25)
    assert s == 0.0


def test_a_sample_longer_than_the_ramp_moves_it_all_the_way_and_no_further():
    assert ramp_share(0.3, True, 1.0, 0.25) == 1.0
    assert ramp_share(0.3, False, 1.0, 0.25) == 0.0
