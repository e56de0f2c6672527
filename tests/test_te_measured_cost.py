"""The TE operating cost from the measurements alone (plant_sim.tennessee_eastman.cost)
against the simulator's own cost, which reads the model's internal product flow; the
base case against Downs & Vogel's number; and each unit's cost for the KPIs
(controller.units.economics)."""

from __future__ import annotations

import numpy as np
import pytest

from controller.units.economics import operating_cost
from plant_sim.tennessee_eastman import model as M
from plant_sim.tennessee_eastman.cost import (
    BASE_CASE_COST_USD_H,
    measured_operating_cost,
    product_flow_from_measurements,
)
from plant_sim.tennessee_eastman.simulator import TESimulator
from services.registry import get_unit

# docs/facts/te.md section 9: Downs & Vogel's base case, about 170.6 $/h; the stripper
# product of the base case 211.3 kmol/h (= lb-mol/h x 0.454)
BASE_CASE_FACT_USD_H = 170.6
BASE_PRODUCT_KMOL_H = 211.3


def test_base_case_is_downs_and_vogels():
    sim = TESimulator(mode="base")
    sim.step()
    assert sim.cost() == pytest.approx(BASE_CASE_FACT_USD_H, abs=0.05)
    assert BASE_CASE_COST_USD_H == BASE_CASE_FACT_USD_H
    flow = product_flow_from_measurements(sim.xmeas)
    assert flow * 0.454 == pytest.approx(BASE_PRODUCT_KMOL_H, rel=1e-3)


@pytest.mark.parametrize("mode", ["base", "3"])
def test_measured_cost_matches_the_simulators_without_noise(mode):
    sim = TESimulator(mode=mode, noise=False)
    for _ in range(10):
        sim.run_steps(40)  # every 72 s over 12 minutes
        ftm13 = float(sim._mem[M.M_FTM13])  # the model's own product flow, lb-mol/h
        # the light components are taken at the base case's: exact there, within the
        # module's measured limits elsewhere
        assert product_flow_from_measurements(sim.xmeas) == pytest.approx(
            ftm13, rel=1e-4 if mode == "base" else 5e-3)
        assert measured_operating_cost(sim.xmeas) == pytest.approx(
            sim.cost(), abs=0.01 if mode == "base" else 0.15)


def test_measured_cost_with_noise_is_right_on_the_mean():
    sim = TESimulator(mode="base", noise=True)
    ours, theirs = [], []
    for _ in range(50):  # 0.5 h, a sample every 36 s
        sim.run_steps(20)
        ours.append(measured_operating_cost(sim.xmeas))
        theirs.append(sim.cost())
    assert abs(np.mean(ours) - np.mean(theirs)) < 0.1  # $/h
    assert np.max(np.abs(np.subtract(ours, theirs))) < 1.0
    blind = np.array(sim.xmeas)
    blind[36:41] = 0.0  # no analyzer reading: no cost, rather than a wrong one
    assert np.isnan(measured_operating_cost(blind))


def test_each_unit_has_its_cost_or_none():
    te = get_unit("te")
    cost = operating_cost(te)
    assert cost is not None and cost.base_usd_h == BASE_CASE_FACT_USD_H
    assert "Downs & Vogel" in cost.base_origin
    sim = TESimulator(mode="base")
    sim.step()
    assert cost.usd_per_h(sim.xmeas) == pytest.approx(sim.cost(), abs=0.01)
    for unit in ("cstr", "bioreactor", "two_phase_reactor"):
        assert operating_cost(get_unit(unit)) is None
