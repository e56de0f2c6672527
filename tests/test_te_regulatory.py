"""TE regulatory layer (seed Table 7.10, R7.11)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.units.te.loops import MODEL_LOOPS, PUBLISHED_TEMPERATURE_CASCADE
from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import TESimulator
from plant_sim.tennessee_eastman.regulatory import (
    TABLE_7_10,
    PILoop,
    RegulatoryLayer,
    SecondaryLoop,
    ValveOverride,
)

LEVEL_BAND = 2.0  # R7.11: levels within +-2 % for 24 h
MODE0_SP = (120.4, 75.0, 50.0, 50.0)  # seed Table 7.3, mode 0: Tr degC, reactor/sep/strip level %
STEPS_PER_H = 2000


def test_table_7_10_loops_hold_mode0_levels_for_24_h():
    sim = TESimulator()
    reg = RegulatoryLayer(sim, setpoints=MODE0_SP)
    rows = reg.run_steps(24 * STEPS_PER_H, record_every=20, stop_on_trip=True)
    assert sim.shutdown is None  # open loop, the same plant trips at 4.06 h
    assert rows[-1, 0] == pytest.approx(24.0 - 0.01)
    for col, sp in ((8, 75.0), (12, 50.0), (15, 50.0)):
        assert np.max(np.abs(rows[:, col] - sp)) <= LEVEL_BAND


def test_first_pi_move_is_the_integral_action_only():
    sim = TESimulator()
    e0 = 2.0
    sp = sim.initial_xmeas[[8, 7, 11, 14]].copy()
    sp[3] += e0  # stripper level 2 % above its measurement
    reg = RegulatoryLayer(sim, setpoints=sp)
    xmv8 = sim.xmv[7]
    reg.run_steps(1)
    gain, ti = -1.5, 1.0  # Table 7.10, stripper loop
    expected = xmv8 + gain * (sim.dt_h / ti * e0)
    assert sim.xmv[7] == pytest.approx(expected, abs=1e-12)


def test_saturated_output_leaves_the_limit_when_the_error_turns():
    # a loop whose MV (agitator) barely moves its CV (reactor temperature): the
    # integral drives the output into the 100 % limit, where it must not wind up
    sim = TESimulator()
    loop = (PILoop("test", cv=9, mv=12, gain=-1.0, ti_h=1.0),)
    reg = RegulatoryLayer(sim, loops=loop, setpoints=[0.0])  # e = -120 degC
    reg.run_steps(2000)
    assert sim.xmv[11] == 100.0
    reg.set_setpoints([sim.xmeas[8] + 0.5])  # error turns positive
    reg.run_steps(1)
    assert sim.xmv[11] < 100.0  # no wound-up integral to unwind first


def test_bad_loop_settings_are_rejected():
    with pytest.raises(PlantInputError, match="ti_h"):
        PILoop("x", cv=8, mv=1, gain=1.0, ti_h=0.0)
    with pytest.raises(PlantInputError, match="cv"):
        PILoop("x", cv=42, mv=1, gain=1.0, ti_h=1.0)
    reg = RegulatoryLayer(TESimulator())
    with pytest.raises(PlantInputError, match="reactor level"):
        reg.set_setpoints([120.0, math.nan, 50.0, 50.0])
    assert len(TABLE_7_10) == 4


SINGLE_TEMPERATURE = MODEL_LOOPS[0]  # the -2 %/degC loop on the cooling water


def _temperature_under_idv11(first: PILoop) -> np.ndarray:
    sim = TESimulator()
    sim.set_idv(11)  # random variation of the reactor cooling water's inlet temperature
    reg = RegulatoryLayer(sim, loops=(first,) + TABLE_7_10[1:], setpoints=MODE0_SP)
    rows = reg.run_steps(6 * STEPS_PER_H, record_every=20, stop_on_trip=True)
    assert sim.shutdown is None
    return rows[rows[:, 0] >= 1.0, 9]


def test_a_cascaded_temperature_loop_meets_the_cooling_waters_variation():
    # measured: 0.08 degC against 1.66 with the single -2 %/degC loop on the same draws
    single, cascade = (_temperature_under_idv11(lp)
                       for lp in (SINGLE_TEMPERATURE, PUBLISHED_TEMPERATURE_CASCADE))
    assert np.std(cascade) < 0.15 < 1.0 < np.std(single)
    assert abs(np.mean(cascade) - MODE0_SP[0]) < 0.05


def test_a_cascaded_loop_keeps_one_set_point_per_loop_and_moves_its_secondary():
    sim = TESimulator()
    reg = RegulatoryLayer(sim, loops=(PUBLISHED_TEMPERATURE_CASCADE,) + TABLE_7_10[1:],
                          setpoints=MODE0_SP)
    assert reg.setpoints.shape == (4,)
    # the secondary starts at its measurement: closing the cascade is bumpless
    np.testing.assert_allclose(reg.secondary_setpoints, sim.initial_xmeas[[20]])
    reg.run_steps(STEPS_PER_H)
    coolant_sp = reg.secondary_setpoints[0]
    reg.set_setpoints((MODE0_SP[0] + 1.0,) + MODE0_SP[1:])
    rows = reg.run_steps(STEPS_PER_H, record_every=20)
    # a warmer reactor asks for warmer coolant, and gets it
    assert reg.secondary_setpoints[0] > coolant_sp + 0.3
    assert np.max(np.abs(rows[rows[:, 0] >= 1.5, 9] - (MODE0_SP[0] + 1.0))) < 0.05
    np.testing.assert_allclose(reg.setpoints, (MODE0_SP[0] + 1.0,) + MODE0_SP[1:])


def test_a_cascaded_loop_is_validated():
    with pytest.raises(PlantInputError, match="cv"):
        SecondaryLoop("x", cv=0, gain=1.0, ti_h=1.0)
    with pytest.raises(PlantInputError, match="ti_h"):
        SecondaryLoop("x", cv=21, gain=1.0, ti_h=-1.0)
    override = ValveOverride(cv=7, high=2950.0, release=2900.0, low=2000.0,
                             restart_output=40.0, restart_setpoint=120.4)
    with pytest.raises(PlantInputError, match="secondary"):
        PILoop("reactor temperature", cv=9, mv=10, gain=28.3, ti_h=0.3, override=override,
               secondary=PUBLISHED_TEMPERATURE_CASCADE.secondary)
