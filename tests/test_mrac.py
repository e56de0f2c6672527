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


def test_mrac_law_rejects_a_model_with_an_unstable_zero_and_keeps_its_gains():
    import control as ct

    from controller.mrac import MRACLaw
    from controller.state_shared import ModelSpec, StateSharedModel

    def spec(name, num, den, kind="fixed"):
        sys = ct.ss(ct.tf(num, den))
        s = StateSharedModel.model_from_linear(name, np.asarray(sys.A), np.asarray(sys.B),
                                               np.asarray(sys.C), [0.4], [1.3], [1.0, 1.0])
        return ModelSpec(name, s.theta, s.bias, kind)

    ssm = StateSharedModel([1.0, 1.0], 1, 0.05,
                           [spec("good", [0.3, 0.3732], [1.0, 1.1605, 0.2337]),
                            spec("bad", [0.3, -0.3], [1.0, 1.1605, 0.2337])])
    law = MRACLaw(0.05)
    law.reset([0.4], [1.3])
    u0, _ = law.compute(0, 0, ssm, np.array([1.3]), np.array([[1.3]]), np.array([0.4]))
    assert u0[0] == pytest.approx(0.4, abs=1e-9)  # steady state of the model is kept
    gains = law.gains
    u1, info = law.compute(1, 1, ssm, np.array([1.3]), np.array([[1.3]]), u0)
    assert law.gains == gains and law.n_rejected == 1
    assert any("rejected" in a for a in info["alarms"])
