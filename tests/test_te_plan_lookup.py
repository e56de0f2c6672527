"""One evaluation of a sample's plan references equals the plan's three calls."""

from __future__ import annotations

import numpy as np
import pytest

from controller.units.te.grades import Leg, TransitionPlan
from controller.units.te.leg_references import LegReferenceSettings
from controller.units.te.plan_lookup import SampleReferences
from controller.units.te.service import HeldPlan

PLANS = [
    TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(25.0, "mode3"))),
    TransitionPlan("mode0", (Leg(1.0, "mode2"), Leg(2.5, "mode3"), Leg(9.0, "mode0")),
                   tau_xmeas_h=0.7, tau_xmv_h=1.3),
    TransitionPlan("mode0", (Leg(1.0, "mode2"),), tau_xmeas_h=0.0),  # steps
    TransitionPlan("mode3"),
    # the MPC's faster level and temperature references, segment by segment
    TransitionPlan("mode0", (Leg(1.0, "mode1"), Leg(4.0, "mode2"), Leg(9.0, "mode0")),
                   leg_references=LegReferenceSettings()),
]


@pytest.mark.parametrize("plan", PLANS)
@pytest.mark.parametrize("horizon", [0, 10])
def test_sample_references_are_the_plan_calls_bit_for_bit(plan, horizon):
    sh = 0.01
    lookup = SampleReferences.for_plan(plan, sh, horizon)
    times = np.concatenate([[0.0, 0.995, 1.0, 1.0 - 1e-12, 2.5, 9.0 - 0.05, 24.99],
                            np.linspace(0.0, 48.0, 97)])
    for t in times:
        ym, xv, d = lookup(float(t))
        np.testing.assert_array_equal(ym, plan.xmeas_ref(t + sh * np.arange(horizon + 1)))
        np.testing.assert_array_equal(xv, plan.xmv_ref(np.array([t, t + horizon * sh])))
        assert d == plan.d_fraction_ref(float(t))
        assert ym.shape == (horizon + 1, 41) and xv.shape == (2, 12)


def test_a_held_plan_gets_no_lookup():
    assert SampleReferences.for_plan(HeldPlan(PLANS[0], 3.0), 0.01, 10) is None
