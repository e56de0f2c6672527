"""MRAC (seed §5.1): matching equation against Table 5.4, closed loop follows Wm."""

import math

import numpy as np
import pytest

from controller.mrac import matching_gains, reference_model_step, table_5_4_row

# Table 5.3 plants k1 (s + k2)/(s^2 + k3 s + k4) -> Table 5.4 rows (printed, 4 decimals)
TABLE_5_3 = {"OPI": (0.3, 1.2440, 1.1605, 0.2337), "OPII": (0.3, 4.9310, 2.1493, 2.3286)}
TABLE_5_4 = {"OPI": (0.3000, 0.0732, 0.8395, -0.0732), "OPII": (0.3000, 1.1793, -0.1493, -1.1793)}
PRINTED = 0.5e-4  # half a unit of the last printed digit


@pytest.mark.parametrize("op", ["OPI", "OPII"])
def test_table_5_4_fixed_rows_follow_from_model_matching(op):
    row = table_5_4_row(*TABLE_5_3[op])
    np.testing.assert_allclose(row, TABLE_5_4[op], atol=PRINTED)


def test_matching_gives_the_reference_model_in_closed_loop():
    # closed-loop characteristic polynomial equals Zp Rm (Zp cancelled), DC gain 1
    kp, z, a1, a0 = 0.3, 1.2440, 1.1605, 0.2337
    g = matching_gains(kp, z, a1, a0)
    Rp = np.array([1.0, a1, a0])
    Zp = np.array([1.0, z])
    Lam = np.array([1.0, 1.0])
    lhs = np.polysub(np.polymul(Rp, np.polysub(Lam, [g.theta1])),
                     kp * np.polymul(Zp, np.polyadd([g.theta2], g.theta3 * Lam)))
    np.testing.assert_allclose(lhs, np.polymul(Zp, [1.0, 2.0, 1.0]), atol=1e-12)
    assert g.c0 == pytest.approx(1 / kp)


def test_unstable_zero_or_zero_gain_is_rejected():
    with pytest.raises(ValueError, match="z"):
        matching_gains(0.3, -0.5, 1.0, 1.0)
    with pytest.raises(ValueError, match="kp"):
        matching_gains(0.0, 1.0, 1.0, 1.0)


def test_reference_model_step_is_exact():
    ym, dt = 0.0, 0.1
    for _ in range(20):
        ym = reference_model_step(ym, 1.0, dt)
    assert ym == pytest.approx(1 - math.exp(-2.0), rel=1e-12)
