"""Interlock trips of the open-loop Tennessee Eastman plant (te.md 5, 8, 13).

Trip times are the original program's, measured with a single IDV on from t = 0,
XMVs held at base, 1.8 s Euler step, published build (te.md 5).
"""

from __future__ import annotations

import pytest

from plant_sim.tennessee_eastman import TESimulator

STEP_H = 1.8 / 3600.0
TIME_TOL_H = 1e-9  # trip times are whole steps; this only absorbs time accumulation
MAX_STEPS = 9000  # > 4.06 h

IDV_TRIP_H = {1: 0.4785, 2: 1.6000, 3: 1.0855, 4: 1.0745, 5: 0.9565, 6: 0.4425, 7: 0.3010,
              8: 1.3535, 9: 1.5795, 10: 2.7375, 11: 0.3935, 12: 0.9760, 13: 1.6045,
              14: 4.0570, 15: 4.0570, 16: 1.6935, 17: 2.8755, 18: 2.6210, 19: 4.0570,
              20: 1.2635}


def _trip(idv=None, **kw):
    sim = TESimulator(**kw)
    if idv is not None:
        sim.set_idv(idv, True, at_h=0.0)
    sim.run_steps(MAX_STEPS, stop_on_trip=True)
    return sim


def test_open_loop_base_trips_on_reactor_pressure_after_8114_steps():
    sim = _trip()
    sd = sim.shutdown
    assert sd is not None
    assert sd.reason == "reactor pressure high"
    assert sim.steps == 8114
    assert sd.time_h == pytest.approx(4.0570, abs=TIME_TOL_H)
    assert sd.value > sd.limit == 3000.0


def test_double_literal_build_trips_at_3_584_h():
    assert _trip(literals="double").shutdown.time_h == pytest.approx(3.5840, abs=TIME_TOL_H)


def test_idv6_trips_much_earlier():
    base = _trip().shutdown.time_h
    sd = _trip(6).shutdown
    assert sd.reason == "reactor pressure high"
    assert sd.time_h < base / 5


@pytest.mark.parametrize("k", sorted(IDV_TRIP_H))
def test_idv_trip_time_matches_original(k):
    # exercises every disturbance path and, for the random ones, the draw order
    sd = _trip(k).shutdown
    assert sd.time_h == pytest.approx(IDV_TRIP_H[k], abs=TIME_TOL_H)
    assert sd.reason == "reactor pressure high"


def test_plant_stays_frozen_after_trip():
    sim = _trip(6)
    x = sim.x.copy()
    sim.run_steps(50)
    assert (sim.x == x).all()
    assert sim.shutdown.time_h == pytest.approx(IDV_TRIP_H[6], abs=TIME_TOL_H)
