"""TE strategy "plan" (the grade plan's feedforward alone) and run_te's seed and IDV-off options."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.control import make_te_controller, plant_seed_for, run_te
from controller.units.te.grades import Leg, TransitionPlan, grade
from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED


def test_plan_strategy_moves_the_five_handles_along_the_plan_alone():
    plan = TransitionPlan("mode0", (Leg(0.0, "mode2"),))   # tau 3 h toward mode 2
    ctl, spec = make_te_controller("plan", plan)
    xmeas = TESimulator().xmeas                          # 2705 kPa: no override
    dec = ctl.step(0, 0.0, xmeas, None)
    assert dec.active_model == -1 and dec.model_names == () and not dec.fallback
    m0 = grade("mode0").xmv
    assert dec.u[2] == pytest.approx(m0[2]) and dec.u[3] == pytest.approx(m0[3])
    assert dec.u[10] == pytest.approx(m0[10])
    sp = dec.extra["setpoints"]                           # T_r*, levels, P_r*
    assert sp[0] == pytest.approx(120.4) and sp[4] == pytest.approx(2705.0)  # Table 7.3 mode 0
    # one time constant later: 63 % of the way (Table 7.3: T_r 120.4 -> 124.2 degC,
    # P_r 2705 -> 2800 kPa), whatever the measurements say (no feedback core; a
    # pressure below the set point would only cap P_r* 10 kPa above it)
    xmeas = xmeas.copy()
    xmeas[6] = 2790.0
    dec = ctl.step(300, 3.0, xmeas, None)
    sp = dec.extra["setpoints"]
    assert sp[0] == pytest.approx(124.2 - 3.8 * math.exp(-1.0), abs=1e-9)
    assert sp[4] == pytest.approx(2800.0 - 95.0 * math.exp(-1.0), abs=1e-9)
    m2 = grade("mode2").xmv
    assert dec.u[2] == pytest.approx(m2[2] + (m0[2] - m2[2]) * math.exp(-1.0))


def test_plan_strategy_closed_loop_holds_the_base_case():
    r = run_te("plan", TransitionPlan("mode0"), 1.0)
    assert r.shutdown is None and r.xmeas.shape == (100, 41)
    assert np.all(r.active == -1)
    assert abs(r.xmeas[-1, 6] - 2705.0) < 50.0


def test_run_te_default_plant_seed_is_the_original_and_a_seed_changes_the_noise():
    plan = TransitionPlan("mode0")
    default = run_te("pi", plan, 0.3, noise=True)
    original = run_te("pi", plan, 0.3, noise=True, plant_seed=ORIGINAL_SEED)
    other = run_te("pi", plan, 0.3, noise=True, plant_seed=plant_seed_for(2))
    assert np.array_equal(default.xmeas, original.xmeas)
    assert not np.array_equal(default.xmeas[5:], other.xmeas[5:])


def test_plant_seeds_of_neighbouring_noise_seeds_are_distinct_odd_integers():
    seeds = [plant_seed_for(s) for s in range(100)]
    assert len(set(seeds)) == 100
    assert all(s == int(s) and int(s) % 2 == 1 and 0 < s < 2**32 for s in seeds)


def test_run_te_switches_an_idv_off_at_its_off_time():
    plan = TransitionPlan("mode0")
    on = run_te("pi", plan, 1.0, idv={1: 0.1})
    on_off = run_te("pi", plan, 1.0, idv={1: 0.1}, idv_off={1: 0.5})
    before = on.t < 0.5
    assert np.array_equal(on.xmeas[before], on_off.xmeas[before])
    assert not np.array_equal(on.xmeas[~before], on_off.xmeas[~before])
    assert on_off.meta["idv_off"] == {1: 0.5}
