"""The TE controller settles each of Ricker's optimal grades at his optimum's cost.

The reference is independent of the controller: the Downs & Vogel cost of Ricker's
(1995) optimal steady state of the mode, computed by the plant model at that state
(:meth:`TESimulator.cost` at ``mode=m``). Mode 0 is the Downs & Vogel base case, an
operating point and not an optimum (its optimum for the same product is Ricker's mode
1): there the economic targets are checked against the base case's 170.6 $/h instead.
"""

from __future__ import annotations

import pytest

from controller.units.te.control import plant_seed_for, run_te
from controller.units.te.grades import TransitionPlan
from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman.cost import BASE_CASE_COST_USD_H

#: The settled cost within this share of the optimum's.
COST_RTOL = 0.03


@pytest.mark.parametrize("mode", [1, 2, 3])
def test_ssmpc_settles_at_the_cost_of_rickers_optimum(mode):
    optimum = TESimulator(mode=str(mode), noise=False).cost()
    r = run_te("ssmpc", TransitionPlan(f"mode{mode}"), 24.0, noise=True, seed=1,
               plant_seed=plant_seed_for(1))
    assert r.shutdown is None
    settled = float(r.cost[r.t >= 16.0].mean())
    assert settled == pytest.approx(optimum, rel=COST_RTOL), (settled, optimum)


def test_ssmpc_runs_the_base_case_below_its_published_cost():
    r = run_te("ssmpc", TransitionPlan("mode0"), 24.0, noise=True, seed=1,
               plant_seed=plant_seed_for(1))
    assert r.shutdown is None
    # the economic targets: measured 140-144 $/h over hours 16-24
    assert float(r.cost[r.t >= 16.0].mean()) < 0.9 * BASE_CASE_COST_USD_H
