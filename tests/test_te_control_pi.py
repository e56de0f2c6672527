"""The TE cascade with the decentralized PI baseline on the original plant."""

import math

import numpy as np
import pytest

from controller.units.te.control import INNER_LOOPS, make_te_controller, run_te
from controller.units.te.grades import Leg, TransitionPlan, grade

G_BAND = 1.0  # mol%, R7.14 check
P_HOLD = 5.0  # kPa around the mode-0 pressure while holding the grade


def test_bad_strategy_and_sample():
    with pytest.raises(ValueError, match="strategy"):
        make_te_controller("lqr")
    with pytest.raises(ValueError, match="sample_h"):
        make_te_controller("pi", sample_h=0.0101)


def test_inner_level_loops_are_table_7_10():
    got = {(lp.cv, lp.mv, lp.gain, lp.ti_h) for lp in INNER_LOOPS[1:4]}
    assert got == {(8, 1, 4.0, 1.0), (12, 7, -5.0, 1.0), (15, 8, -1.5, 1.0)}


def test_controller_decision_layout():
    ctl, spec = make_te_controller("pi")
    x0 = np.r_[grade(0).xmeas]
    dec = ctl.step(0, 0.0, x0, None)
    owned = [i - 1 for i in spec.loop_xmvs]
    assert np.all(np.isnan(dec.u[owned]))
    written = [i - 1 for i in spec.written_xmvs]
    assert np.all(np.isfinite(dec.u[written]))
    assert dec.extra["setpoints"].shape == (len(spec.loops),)
    bad = ctl.step(1, 0.01, np.zeros(5), None)
    assert bad.fallback and bad.status == "invalid_measurement"


def test_pi_baseline_holds_mode0():
    run = run_te("pi", TransitionPlan("mode0"), 24.0)
    assert run.shutdown is None
    assert np.max(np.abs(run.xmeas[:, 6] - grade(0).xmeas[6])) < P_HOLD
    # R7.11 check: levels within +-2 % for 24 h
    for col, sp in ((7, 75.0), (11, 50.0), (14, 50.0)):
        assert np.max(np.abs(run.xmeas[:, col] - sp)) < 2.0


def test_pi_baseline_mode0_to_mode2_without_shutdown():
    run = run_te("pi", TransitionPlan("mode0", (Leg(1.0, "mode2"),)), 40.0)
    assert run.shutdown is None
    assert run.margins["reactor pressure"]["margin"] > 0
    g_end = run.xmeas[-40:, 39].mean()
    assert abs(g_end - grade(2).g_mol) < G_BAND
    assert math.isfinite(run.cost[-1])
