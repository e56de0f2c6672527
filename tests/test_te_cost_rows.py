"""The operating cost of many samples at once equals the per-sample cost bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman.simulator import cost_from_measurements, cost_from_rows


def test_cost_rows_equal_each_sample_cost():
    sim = TESimulator(noise=True, mode="2")
    rows, flows, costs = [], [], []
    for _ in range(40):
        sim.run_steps(20)
        rows.append(sim.xmeas)
        flows.append(sim.product_flow_lbmol_h)
        costs.append(sim.cost())
    got = cost_from_rows(np.array(rows), np.array(flows))
    np.testing.assert_array_equal(got, costs)
    # odd rows too: zeros, negatives, a NaN (it stays in its own row)
    rng = np.random.default_rng(3)
    x = rng.normal(0.0, 50.0, (25, 41))
    x[3] = 0.0
    x[7, 30] = np.nan
    f = rng.uniform(-10.0, 300.0, 25)
    want = [cost_from_measurements(x[i], float(f[i])) for i in range(25)]
    np.testing.assert_array_equal(cost_from_rows(x, f), want)
    assert np.isnan(want[7]) and np.isfinite(np.delete(want, 7)).all()


def test_cost_rows_refuse_a_flow_per_row_mismatch():
    with pytest.raises(PlantInputError, match="expected 3 values, got 2"):
        cost_from_rows(np.zeros((3, 41)), np.zeros(2))
