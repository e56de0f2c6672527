"""Back-off grades of TE modes 4-6 (controller.units.te.max_production)."""

import numpy as np
import pytest

from controller.units.te.control import plant_seed_for, run_te
from controller.units.te.grades import (
    CONTROL_MARGIN,
    CONTROLLED_VALVES,
    Leg,
    TransitionPlan,
    check_reachable,
    grade,
)
from controller.units.te.max_production import BACKOFF_MARGIN, BACKOFFS, BackOff

#: Seed Table 7.3 (R7.3), Ricker's maximum-production optima: G mol% (XMEAS 40) and
#: production m3/h (XMEAS 17).
RICKER_MAX = {"mode4": (53.35, 36.04), "mode5": (11.65, 23.55), "mode6": (90.07, 20.20)}
#: The limiting valve of each optimum (Ricker 1995 states 39-50: XMV(1) or XMV(2) at 100 %).
LIMITING = {"mode4": 1, "mode5": 2, "mode6": 1}
LAST = 100  # samples of the last hour (36 s each)


@pytest.mark.parametrize("name", sorted(RICKER_MAX))
def test_grade_backs_off_production_and_keeps_the_product_ratio(name):
    g = grade(name)
    g_mol, production = RICKER_MAX[name]
    assert g.xmeas[16] < production  # lower production than the optimum
    assert g.xmeas[16] > 0.9 * production  # ... by a back-off, not another grade
    assert abs(g.g_mol - g_mol) < 0.5
    assert g.reactor_level == pytest.approx(65.0, abs=0.1)
    assert g.xmeas[6] == pytest.approx(2800.0, abs=5.0)  # reactor pressure, kPa


@pytest.mark.parametrize("name", sorted(RICKER_MAX))
def test_transitions_from_mode0_and_the_same_ratio_are_accepted(name):
    a, b = check_reachable("mode0", name)
    assert b.name == name
    check_reachable(BACKOFFS[name].neighbour, name)
    check_reachable(name, "mode0")


def test_backoff_settings_validate():
    with pytest.raises(ValueError, match="neighbour"):
        BackOff("mode4", "mode2", 1, 0.5)
    with pytest.raises(ValueError, match="fraction"):
        BackOff("mode4", "mode1", 1, 1.5)
    with pytest.raises(ValueError, match="grade"):
        BackOff("mode3", "mode0", 1, 0.5)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(RICKER_MAX))
def test_cascade_settles_at_the_grade_with_every_valve_in_its_margin(name):
    # the rule, checked on the plant: run the cascade there (noise off, 36 h from the
    # grade of the same G/H ratio) and read the valves it settles at
    plan = TransitionPlan(BACKOFFS[name].neighbour, (Leg(1.0, name),))
    run = run_te("ssmpc", plan, 36.0, noise=False)
    assert run.shutdown is None
    u = run.xmv[-LAST:].mean(axis=0)
    y = run.xmeas[-LAST:].mean(axis=0)
    assert u[LIMITING[name] - 1] <= 100.0 - BACKOFF_MARGIN
    for v in CONTROLLED_VALVES:
        assert CONTROL_MARGIN <= u[v - 1] <= 100.0 - CONTROL_MARGIN, f"XMV({v}) = {u[v - 1]}"
    g = grade(name)
    assert y[16] == pytest.approx(g.xmeas[16], rel=0.01)
    assert y[39] == pytest.approx(g.g_mol, abs=0.5)
    np.testing.assert_allclose(u[[0, 1, 3]], g.xmv[[0, 1, 3]], atol=1.0)


def test_closed_loop_0_to_4_with_noise_does_not_trip():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode4"),))
    run = run_te("ssmpc", plan, 12.0, noise=True, plant_seed=plant_seed_for(1))
    assert run.shutdown is None
    assert run.xmeas[:, 6].max() < 3000.0
    # heading for mode 4: the production rose by more than half the grade change
    p0, p4 = grade("mode0").xmeas[16], grade("mode4").xmeas[16]
    assert run.xmeas[-LAST:, 16].mean() > p0 + 0.5 * (p4 - p0)
