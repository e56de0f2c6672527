"""Behaviour of the TE simulator: noise and draws, analyzers, valves, inputs, cost, modes."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from plant_sim import get_plant
from plant_sim.base import PlantInputError
from plant_sim.tennessee_eastman import SimSettings, TennesseeEastman, TESimulator
from plant_sim.tennessee_eastman.batch import Scenario, run_batch

REF = Path(__file__).resolve().parent / "data" / "te_reference"  # origin: its README.md
T0_RTOL = 1e-12
COST_TOL = 0.05  # $/h; te.md 9 prints the base cost to 0.1 $/h


def test_noise_does_not_change_the_plant_and_draws_happen_when_off():
    # Open loop, noise enters only the measurements; the generator advances the same
    # way with noise off, so even a random disturbance (IDV 8, which draws from the
    # same stream) gives identical states.
    for idv in (None, 8):
        sims = []
        for noise in (False, True):
            s = TESimulator(noise=noise)
            if idv:
                s.set_idv(idv, True, at_h=0.0)
            s.run_steps(800)
            sims.append(s)
        off, on = sims
        np.testing.assert_array_equal(off.x, on.x)
        assert off.generator_state == on.generator_state
        assert not np.array_equal(off.xmeas, on.xmeas)


def test_noise_is_reproducible_per_seed_and_differs_between_seeds():
    a = TESimulator(noise=True, seed=12345)
    b = TESimulator(noise=True, seed=12345)
    c = TESimulator(noise=True, seed=54321)
    ra, rb, rc = (s.run_steps(50, record_every=1) for s in (a, b, c))
    np.testing.assert_array_equal(ra, rb)
    assert not np.array_equal(ra[1:, 1:23], rc[1:, 1:23])
    # no noise at t = 0 (te.md 4)
    np.testing.assert_array_equal(ra[0, 1:42], TESimulator().run_steps(1, record_every=1)[0, 1:42])


def test_analyzer_first_samples_at_steps_201_and_500():
    # te.md 10: gas period is float32(0.1) accumulated in double -> first sample at
    # step 201; product analyzer (0.25 h exact) at step 500. With noise on, the
    # sampled output changes exactly there.
    rows = TESimulator(noise=True).run_steps(520, record_every=1)
    gas = rows[:, 1 + 22]  # XMEAS23
    prod = rows[:, 1 + 36]  # XMEAS37
    assert np.flatnonzero(np.diff(gas))[0] + 1 == 201
    assert np.flatnonzero(np.diff(prod))[0] + 1 == 500


def test_noise_free_analyzer_reports_the_composition_one_period_earlier():
    rows = TESimulator().run_steps(420, record_every=1)
    plant = TennesseeEastman()
    captured = plant.outputs(rows[201, 54:104], rows[201, 42:54])[22:36]
    # the second gas sample (after 0.2 h in float32 steps) shows what the first captured
    k2 = np.flatnonzero(np.diff(rows[:, 1 + 22]))[0] + 1
    assert 399 <= k2 <= 402
    np.testing.assert_array_equal(rows[k2, 23:37], captured)


def test_xmv_above_100_is_clipped_in_the_valve_not_in_the_xmv():
    sim = TESimulator()
    x0 = sim.x.copy()
    xmv = sim.xmv
    xmv[0] = 150.0
    sim.step(xmv)
    assert sim.xmv[0] == 150.0
    # valve 1 moves towards 100 % with its 8 s lag (te.md 2)
    expected_rate = (100.0 - x0[38]) / (8.0 / 3600.0)
    assert sim.derivative[38] == pytest.approx(expected_rate, rel=1e-12)


def test_bad_inputs_are_rejected_with_the_field_named():
    sim = TESimulator()
    xmv = sim.xmv
    xmv[4] = math.nan
    with pytest.raises(PlantInputError, match=r"XMV\(5\)"):
        sim.step(xmv)
    with pytest.raises(PlantInputError, match="xmv"):
        sim.set_xmv(np.zeros(11))
    with pytest.raises(PlantInputError, match=r"IDV\(21\)"):
        sim.set_idv(21)
    with pytest.raises(PlantInputError, match=r"IDV\(0\)"):
        sim.set_idv(0)
    for dt in (0.0, -1.8, math.nan):
        with pytest.raises(PlantInputError, match="dt"):
            TESimulator(dt_s=dt)
    with pytest.raises(PlantInputError, match="mode.*base, 1, 2"):
        TESimulator(mode="7")
    with pytest.raises(PlantInputError, match="literals"):
        SimSettings(literals="quad")
    with pytest.raises(PlantInputError, match="seed"):
        SimSettings(seed=-1)


def test_base_case_operating_cost():
    sim = TESimulator()
    sim.step()
    assert sim.cost() == pytest.approx(170.6, abs=COST_TOL)  # te.md 9


def test_time_accumulates_like_the_driver():
    sim = TESimulator(dt_s=1.8)
    sim.run_steps(20)
    t = 0.0
    for _ in range(20):
        t += 1.8 / 3600.0
    assert sim.time == t == 0.010000000000000005


def test_registry_plant_rhs_and_outputs_equal_reference_t0():
    c = np.loadtxt(REF / "c_deriv_t0.csv", delimiter=",", skiprows=1)
    d = np.loadtxt(REF / "d_xmeas_t0.csv", delimiter=",", skiprows=1)
    plant = get_plant("te")
    op = plant.operating_point("mode0")
    np.testing.assert_array_equal(op.x, c[:, 1])
    rhs = plant.rhs(0.0, op.x, op.u, op.d)
    assert np.all(np.abs(rhs - c[:, 2]) <= T0_RTOL * (np.abs(c[:, 2]) + np.abs(c[:, 1])))
    np.testing.assert_allclose(plant.outputs(op.x, op.u), d[:, 1], rtol=T0_RTOL, atol=0)


def test_modes_start_from_ricker_states():
    plant = get_plant("te")
    assert list(plant.operating_points) == [f"mode{i}" for i in range(7)]
    # Ricker 1995 (facts CSV): mode 3 reactor cooling-water outlet 101.8799 degC, XMV12 100 %
    sim = TESimulator(mode="3")
    assert sim.x[36] == 101.8799
    assert sim.xmv[11] == 100.0
    sim.step()
    assert sim.xmeas[20] == 101.8799  # XMEAS21 is state 37


def test_batch_equals_single_runs_and_threads_equal_serial():
    scenarios = [Scenario(seed=777, noise=True, idv={8: 0.0, 6: 0.2}),
                 Scenario(noise=False, xmv_profile=[(0.05, [60.0] * 12)]),
                 Scenario(seed=4242, noise=True, mode="2", idv={13: 0.1})]
    hours = 0.3
    thr = run_batch(scenarios, hours, record_every_steps=20, backend="threads")
    ser = run_batch(scenarios, hours, record_every_steps=20, backend="serial")
    for a, b in zip(thr, ser, strict=True):
        np.testing.assert_array_equal(a.rows, b.rows)
        np.testing.assert_array_equal(a.x, b.x)
    for sc, res in zip(scenarios, thr, strict=True):
        sim = TESimulator(seed=sc.seed, noise=sc.noise, mode=sc.mode)
        for k, t in sc.idv.items():
            sim.set_idv(k, True, at_h=t)
        rows = sim.run_steps(int(round(hours / sim.dt_h)), record_every=20, stop_on_trip=True,
                             xmv_schedule=sc.xmv_profile)
        np.testing.assert_array_equal(rows, res.rows)
        np.testing.assert_array_equal(sim.x, res.x)
    assert thr[1].rows[-1, 42] == 60.0


def test_batch_rejects_bad_scenarios():
    with pytest.raises(PlantInputError, match=r"IDV\(25\)"):
        Scenario(idv={25: 0.0})
    with pytest.raises(PlantInputError, match="mode"):
        Scenario(mode="9")
    with pytest.raises(PlantInputError, match="dt"):
        run_batch([Scenario()], 1.0, dt_s=0.0)


def test_step_h_reproduces_the_demo_driver_single_precision_step():
    # temain.f: DELTAT = 1. / 3600. is folded in float32
    demo = float(np.float32(1.0) / np.float32(3600.0))
    sim = TESimulator(step_h=demo)
    sim.run_steps(3)
    assert sim.dt_h == demo != 1.0 / 3600.0
    assert sim.time == demo + demo + demo
    with pytest.raises(PlantInputError, match="step_h"):
        SimSettings(step_h=0.0)
