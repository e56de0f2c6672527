"""Steady-state targets on the two-phase reactor's MPC (seed ch. 6 plant, the service's
controller closed loop offline with its plant runner): a pressure set point above the
pressure limit is relaxed, reported, and the loop settles at the targets, which an
independent SciPy solve of the same steady-state problem confirms; the targets follow
the active model; settings and the safe action on bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import minimize

from controller.units.config import build_plant, grade_setpoints
from controller.units.mpc_targets import TargetingLaw, TargetSettings, steady_state_map
from controller.units.operator import operate
from controller.units.two_phase_reactor import (
    CV,
    MV,
    P_LIMIT,
    PRODUCT_TARGETS,
    SEED_TARGETS,
    ReactorCase,
    build,
)
from plant_sim.linearize import linearize
from services.nodes.plant import make_runner
from services.registry import get_unit

pytestmark = pytest.mark.timeout(300)

CFG = get_unit("two_phase_reactor")
PLANT = build_plant(CFG)
GRADES = grade_setpoints(CFG, PLANT)
OPI = np.asarray(GRADES["OPI"]["setpoints"])    # P 2700 kPa, yA3 47 %, F4 100 kmol/h
U_OPI = np.asarray(GRADES["OPI"]["mv"])
DT_H = CFG.sample_period_s / 3600.0
#: A pressure set point above the 2950 kPa limit, with 140 kmol/h of product.
ABOVE_LIMIT = np.array([3000.0, 63.5, 140.0])


def dc_gain(op: str) -> np.ndarray:
    """The plant's own steady-state gain at an operating point (its full linearization,
    -C A^-1 B), MVs x1..x3 to CVs P, yA3, F4."""
    lm = linearize(PLANT, op).select(MV, CV)
    return -lm.C @ np.linalg.solve(lm.A, lm.B)


def closed_loop(targets, setpoint, hours, tau_h=1.0):
    """The service's controller from OPI toward ``setpoint`` on a first-order reference
    (time constant ``tau_h``, as a transition's), the plant integrated between samples."""
    ctl = build(CFG, PLANT, U_OPI, GRADES, targets=targets)
    run = make_runner(CFG)
    P = ctl.horizon
    ys, decs, problems = [], [], []
    for k in range(int(round(hours / DT_H))):
        t_ahead = (k + 1 + np.arange(P)) * DT_H
        ref = setpoint + (OPI - setpoint) * np.exp(-t_ahead / tau_h)[:, None]
        dec = ctl.step(k, run.t, run.y(), ref)
        ctl.finish_sample()
        run.advance(dec.u, CFG.sample_period_s)
        ys.append(run.y())
        decs.append(dec)
        problems.append(getattr(ctl.law, "last_problem", None))
    return ctl, np.array(ys), decs, problems


def scipy_targets(p):
    """The same steady-state problem solved by SciPy (SLSQP), lexicographically: first
    the rank-1 pressure limit's least violation over the valve ranges, then the rank-2
    set points' weighted squared violation with the limit held at that."""
    G, yb, lo, hi = p.gain, p.y_base, p.u_min, p.u_max
    bounds = list(zip(lo, hi))
    u0 = np.clip(p.u0, lo, hi)
    over = minimize(lambda u: max(G[0] @ u + yb[0] - p.y_max[0], 0.0) ** 2, u0,
                    method="SLSQP", bounds=bounds, options={"ftol": 1e-12, "maxiter": 500})
    s1 = max(G[0] @ over.x + yb[0] - p.y_max[0], 0.0)
    w = 1.0 / p.y_scale ** 2
    res = minimize(lambda u: float(np.sum(w * (G @ u + yb - p.y_spec) ** 2)), u0,
                   method="SLSQP", bounds=bounds,
                   constraints=[{"type": "ineq",
                                 "fun": lambda u: p.y_max[0] + s1 - (G[0] @ u + yb[0])}],
                   options={"ftol": 1e-10, "maxiter": 1000})
    assert res.success, res.message
    return res.x, G @ res.x + yb


def test_a_pressure_set_point_above_the_limit_is_relaxed_and_the_loop_settles_there():
    ctl, y, decs, problems = closed_loop(PRODUCT_TARGETS, ABOVE_LIMIT, hours=20.0)
    last = decs[-1].extra["targets"]
    # reported: the P set point relaxed (rank 2), nothing else; an alarm names it
    assert [(r["cv"], r["kind"], r["rank"]) for r in last["relaxed"]] == [("P", "spec", 2)]
    assert any(a.startswith("targets: P set point 3000 kPa") for a in decs[-1].alarms)
    # the targets agree with an independent solve of the same problem ...
    p = problems[-1]
    u_ref, y_ref = scipy_targets(p)
    u_t = np.array([last["mv"][n] for n in MV])
    y_t = np.array([last["cv"][n] for n in CV])
    np.testing.assert_allclose(y_t, y_ref, rtol=1e-6, atol=1e-4)
    np.testing.assert_allclose(u_t, u_ref, rtol=0, atol=1e-3)  # valve %, 1e-5 of range
    assert y_ref[0] == pytest.approx(P_LIMIT, abs=1e-3)  # P at its limit, the others held
    np.testing.assert_allclose(y_ref[1:], ABOVE_LIMIT[1:], atol=1e-4)
    # ... on the active model's gain, the plant's own at OPII (reduced with DC kept)
    assert decs[-1].model_names[decs[-1].active_model] == "OPII"
    np.testing.assert_allclose(p.gain, dc_gain("OPII"), rtol=1e-6, atol=1e-9)
    # the pressure limit holds within 5 kPa (a soft limit: the dynamic response's
    # overshoot), and the plant settles at the targets: P within 0.5 kPa, yA3 (mol %)
    # and F4 (kmol/h) within 0.1 of theirs over the last 2 h
    assert y[:, 0].max() <= P_LIMIT + 5.0
    tail = y[-20:]
    assert np.all(np.abs(tail[:, 0] - y_t[0]) <= 0.5)
    assert np.all(np.abs(tail[:, 1:] - y_t[1:]) <= 0.1)
    # ... and its valves at the MV targets (valve %)
    np.testing.assert_allclose(ctl.u_last, u_t, atol=0.5)
    # the MPC alone trades the unreachable pressure set point against the others by
    # its weights: F4 and yA3 stay off their set points
    _, y_off, decs_off, _ = closed_loop(SEED_TARGETS, ABOVE_LIMIT, hours=20.0)
    assert "targets" not in decs_off[-1].extra
    off = np.abs(y_off[-20:, 1:] - ABOVE_LIMIT[1:]).mean(axis=0)
    on = np.abs(tail[:, 1:] - ABOVE_LIMIT[1:]).mean(axis=0)
    assert np.all(on < 0.5 * off), (on, off)
    assert y_off[-1, 0] == pytest.approx(P_LIMIT, abs=1.0)  # riding the soft limit


def test_set_points_that_need_the_purge_valve_beyond_100_percent():
    """OPII's pressure and F4 with OPI's yA3 of 47 % need x3 past its range: every set
    point is relaxed, the targets put x3 at 100 % and say where the plant settles; the
    MPC alone rides x3 on its hard limit."""
    sp = np.array([2850.0, 47.0, 130.0])
    ctl, y, decs, _ = closed_loop(PRODUCT_TARGETS, sp, hours=20.0)
    last = decs[-1].extra["targets"]
    assert sorted(r["cv"] for r in last["relaxed"]) == ["F4", "P", "yA3"]
    assert last["mv"]["x3"] == pytest.approx(100.0, abs=1e-6)
    y_t = np.array([last["cv"][n] for n in CV])
    np.testing.assert_allclose(y[-10:], np.tile(y_t, (10, 1)), atol=0.15)  # kPa, %, kmol/h
    at_limit = np.mean([d.u[2] >= 100.0 - 1e-9 for d in decs])
    _, _, decs_off, _ = closed_loop(SEED_TARGETS, sp, hours=20.0)
    at_limit_off = np.mean([d.u[2] >= 100.0 - 1e-9 for d in decs_off])
    assert at_limit < 0.1 < 0.5 < at_limit_off, (at_limit, at_limit_off)


def test_the_targets_follow_the_active_model_after_a_switch():
    opii = np.asarray(GRADES["OPII"]["setpoints"])
    ctl, _, decs, problems = closed_loop(PRODUCT_TARGETS, opii, hours=15.0)
    gains = {"OPI": dc_gain("OPI"), "OPII": dc_gain("OPII")}
    names = [d.model_names[d.active_model] for d in decs]
    assert names[0] == "OPI" and names[-1] == "OPII"  # the switch happened
    for name, p in zip(names, problems):
        np.testing.assert_allclose(p.gain, gains[name], rtol=1e-6, atol=1e-9)
    # with the OPII model active, the targets of the OPII set points are OPII's valves
    # once the plant is at the grade (within 2 % of their range at 15 h; the static
    # bias carries what is still moving)
    u_end = np.array([decs[-1].extra["targets"]["mv"][n] for n in MV])
    np.testing.assert_allclose(u_end, GRADES["OPII"]["mv"], atol=2.0)


def test_the_relaxation_reaches_the_operator_through_the_operated_controller():
    inner = build(CFG, PLANT, U_OPI, GRADES)
    op = operate(CFG, PLANT, inner, GRADES)
    run = make_runner(CFG)
    ref = np.tile([3000.0, 47.0, 100.0], (inner.horizon, 1))
    dec = None
    for k in range(3):
        dec = op.step(k, run.t, run.y(), ref, run.u.copy())
        op.finish_sample()
        run.advance(dec.u, CFG.sample_period_s)
    assert dec.extra["targets"]["status"] == "relaxed"
    assert dec.extra["targets"]["cv"]["P"] == pytest.approx(P_LIMIT, abs=1e-3)
    assert any("P set point 3000 kPa" in a and "rank 2" in a for a in dec.alarms)


def test_an_operator_pressure_limit_is_a_rank_1_limit_of_the_targets():
    """The operator's CV limit (through the MPC's operator layer) is what the targets
    hold: the OPI pressure set point of 2700 kPa relaxed to a 2650 kPa limit."""
    from controller.operator_modes import VariableCommand

    inner = build(CFG, PLANT, U_OPI, GRADES)
    op = operate(CFG, PLANT, inner, GRADES)
    op.set_state(op.state.command("P", VariableCommand(hi=2650.0), 0.0, 2700.0))
    run = make_runner(CFG)
    ref = np.tile(OPI, (inner.horizon, 1))
    dec = op.step(0, run.t, run.y(), ref, run.u.copy())
    tg = dec.extra["targets"]
    assert tg["cv"]["P"] == pytest.approx(2650.0, abs=1e-3)
    assert tg["cv"]["F4"] == pytest.approx(100.0, abs=1e-3)
    assert [(r["cv"], r["kind"]) for r in tg["relaxed"]] == [("P", "spec")]


def test_a_limit_back_off_keeps_the_targets_inside_the_limit():
    inner = build(CFG, PLANT, U_OPI, GRADES,
                  targets=TargetSettings(limit_backoff=(10.0, 0.0, 0.0)))
    run = make_runner(CFG)
    dec = inner.step(0, run.t, run.y(), np.tile([3000.0, 47.0, 100.0], (inner.horizon, 1)))
    assert dec.extra["targets"]["cv"]["P"] == pytest.approx(P_LIMIT - 10.0, abs=1e-3)
    assert ("P", "spec") in {(r["cv"], r["kind"]) for r in dec.extra["targets"]["relaxed"]}


def test_a_restored_controller_makes_the_same_moves():
    a, _, _, _ = closed_loop(PRODUCT_TARGETS, ABOVE_LIMIT, hours=1.0)
    state = a.checkpoint()
    assert "targets" in state["law"]
    b = build(CFG, PLANT, U_OPI, GRADES)
    b.restore(state)
    y = np.array([2760.0, 50.0, 110.0])
    ref = np.tile(ABOVE_LIMIT, (a.horizon, 1))
    da, db = a.step(10, 3600.0, y, ref), b.step(10, 3600.0, y, ref)
    np.testing.assert_array_equal(da.u, db.u)
    ta, tb = (dict(d.extra["targets"], solve_ms=None) for d in (da, db))
    assert ta == tb


def test_no_steady_state_or_a_bad_measurement_is_the_documented_safe_action():
    # an integrator (eigenvalue 1) has no steady state
    assert steady_state_map(np.array([[1.0]]), np.array([[1.0]]), np.array([[1.0]])) is None
    assert steady_state_map(np.array([[0.5]]), np.array([[1.0]]), np.array([[1.0]]))[1][0, 0] \
        == pytest.approx(2.0)
    ctl = build(CFG, PLANT, U_OPI, GRADES)
    law = ctl.law
    assert isinstance(law, TargetingLaw)
    y = np.array([2700.0, math.nan, 100.0])
    ref = np.tile(OPI, (ctl.horizon, 1))
    u, info = law.compute(0, 0, ctl.ssm, y, ref, U_OPI)  # never raises
    assert info["targets"]["status"] == "unavailable"
    assert any(a.startswith("targets: not computed") for a in info["alarms"])
    assert np.all(np.isfinite(u))


@pytest.mark.parametrize("kw, field", [
    ({"spec_rank": (2, 0, 2)}, "spec_rank"),
    ({"limit_rank": 1.5}, "limit_rank"),
    ({"input_weight": -1.0}, "input_weight"),
    ({"mv_weight": 0.0}, "mv_weight"),
    ({"report_fraction": math.inf}, "report_fraction"),
    ({"limit_backoff": (10.0, -1.0, 0.0)}, "limit_backoff"),
    ({"enabled": 1}, "enabled"),
])
def test_target_settings_name_the_bad_field(kw, field):
    with pytest.raises(ValueError, match=field):
        TargetSettings(**kw)


def test_reactor_case_checks_its_set_points_and_targets():
    with pytest.raises(ValueError, match="setpoint"):
        ReactorCase(setpoint=(2850.0, 63.5))
    with pytest.raises(ValueError, match="setpoint"):
        ReactorCase(setpoint=(2850.0, math.nan, 130.0))
    with pytest.raises(ValueError, match="targets"):
        ReactorCase(targets=True)
    with pytest.raises(ValueError, match="spec_rank"):
        build(CFG, PLANT, U_OPI, GRADES, targets=TargetSettings(spec_rank=(2, 2)))
