"""Aborting a TE transition: every strategy goes on controlling toward the held set points.

Offline first (the TE service controller alone, each strategy), then over the real
nodes (plant and controller nodes on real Zenoh): abort a running transition, see
the samples advance with no failed sample, then start a new transition that runs.
Also: a controller whose step raises is counted and reported as failed, the move is
held, and its traceback is logged once, not every sample.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np
import pytest
from test_service_loop import Harness

from controller.units.config import build_plant, grade_setpoints
from controller.units.te.grades import Leg, TransitionPlan
from controller.units.te.service import HeldPlan, TEServiceController
from controller.units.te.structure import te_mv_names
from services.registry import get_unit

pytestmark = pytest.mark.realtime

STRATEGIES = ("ssmpc", "fixed", "pi", "decentralized")
HOURS = 3600.0


def test_held_plan_answers_with_the_plans_shapes_and_holds_its_values():
    plan = TransitionPlan("mode0", (Leg(1.0, "mode2"),))
    held = HeldPlan(plan, 2.0)
    times = np.array([2.0, 2.5, 9.0])
    for name in ("xmeas_ref", "xmv_ref"):
        live, frozen = getattr(plan, name), getattr(held, name)
        assert np.shape(frozen(3.0)) == np.shape(live(3.0))
        assert np.shape(frozen(times)) == np.shape(live(times))
        # every row is the plan's value at the hold time, whatever time is asked
        np.testing.assert_array_equal(frozen(times), np.tile(live(2.0), (3, 1)))
        assert not np.allclose(live(9.0), live(2.0))  # the live plan moves on meanwhile
    assert held.d_fraction_ref(7.0) == plan.d_fraction_ref(2.0)


def _te_service(strategy):
    cfg = replace(get_unit("te"), strategy=strategy)
    g = grade_setpoints(cfg, None)
    mvs = te_mv_names(cfg)
    return TEServiceController(strategy, "mode0", mvs, cfg.sample_period_s / HOURS,
                               g["mode0"]["mv"]), g["mode0"]["setpoints"]


@pytest.mark.parametrize("strategy", STRATEGIES)
def test_every_strategy_steps_after_an_abort_and_a_new_transition(strategy):
    ctl, y0 = _te_service(strategy)
    y = np.asarray(y0, dtype=float)
    dt = 36.0
    k = 0

    def run(n):
        nonlocal k
        for _ in range(n):
            dec = ctl.step(k, k * dt, y, None)
            ctl.finish_sample()
            assert dec.status != "failed" and np.all(np.isfinite(dec.u)), dec
            k += 1
        return dec

    run(3)
    ctl.on_transition("running", "mode2", k * dt)
    run(3)
    ctl.on_transition("aborted", "mode2", k * dt)
    held = run(5)
    again = run(2)
    # held references: the set points the controller writes no longer move with time
    sp = [i for i, n in enumerate(ctl.mvs) if n.endswith("_level_sp")]
    assert sp
    np.testing.assert_allclose(held.u[sp], again.u[sp], rtol=0, atol=1e-9)
    ctl.on_transition("running", "mode3", k * dt)
    run(3)


@pytest.mark.integration
@pytest.mark.timeout(240)
@pytest.mark.parametrize("strategy", STRATEGIES)
def test_abort_then_new_transition_over_the_real_nodes(tmp_path, strategy):
    h = Harness(tmp_path, unit="te", speed=2_000.0, telemetry=False, strategy=strategy)
    try:
        h.wait_samples(5, timeout=90)
        tid = h.query("transition", {"op": "create", "grade": "mode2"}).data["id"]
        h.wait_samples(20, timeout=60)
        assert h.query("transition", {"op": "abort", "id": tid}).code == 200
        st0 = h.query("status").data
        h.wait_samples(30, timeout=60)
        st = h.query("status").data
        assert st["sample"] > st0["sample"]
        assert st["failed_samples"] == 0
        assert st["controller_status"] != "failed"
        assert not any("failed" in a for a in st["alarms"]), st["alarms"]
        assert h.query("transition", {"op": "get", "id": tid}).data["state"] == "aborted"
        # a new transition after the abort runs and the loop keeps stepping
        tid2 = h.query("transition", {"op": "create", "grade": "mode3"}).data["id"]
        h.wait_samples(30, timeout=60)
        v = h.query("transition", {"op": "get", "id": tid2}).data
        assert v["state"] == "running"
        st = h.query("status").data
        assert st["failed_samples"] == 0 and st["controller_status"] != "failed"
    finally:
        h.close()


class _Broken:
    """A controller whose step always raises (a bug in a unit's controller)."""

    def __init__(self, cfg):
        self.u = np.asarray(grade_setpoints(cfg, build_plant(cfg))[cfg.initial_grade]["mv"],
                            float)

    def step(self, k, t, y, reference):
        raise IndexError("invalid index to scalar variable")

    def align(self, u):
        self.u = np.asarray(u, float)

    def checkpoint(self):
        return {}

    def restore(self, state):
        pass


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_a_failing_step_is_counted_held_and_logged_once(tmp_path, caplog):
    caplog.set_level(logging.ERROR, logger="ssmpc.controller")
    h = Harness(tmp_path, unit="cstr", speed=100.0, telemetry=False,
                controller_factory=_Broken)
    try:
        h.wait_samples(30, timeout=60)
        st = h.query("status").data
        assert st["failed_samples"] >= 30
        assert st["controller_status"] == "failed"
        assert st["fallback_moves"] >= st["failed_samples"] - 1
        assert any("failed" in a and "IndexError" in a for a in st["alarms"])
        # the plant holds the last move: the controller's held move reaches it
        u0 = grade_setpoints(h.cfg, build_plant(h.cfg))[h.cfg.initial_grade]["mv"]
        np.testing.assert_allclose(list(st["mv"].values()), u0)
    finally:
        h.close()
    tracebacks = [r for r in caplog.records if r.exc_info and "controller step failed"
                  in r.getMessage()]
    assert len(tracebacks) == 1
