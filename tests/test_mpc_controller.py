"""MPCController in closed loop: limits held, offset-free tracking, deadline fallback,
bad input handled at configuration and at run time, filter, bumpless model switching."""

from __future__ import annotations

import numpy as np
import pytest

from controller.interfaces import SampleController
from controller.mpc import (
    FirstOrderFilter,
    LinearModelState,
    MPCController,
    MPCSettings,
    MPCSettingsError,
)

TRACK_ATOL = 1e-3      # steady-state tracking error after settling
LIMIT_TOL = 1e-7       # hard input/rate limits
SOFT_LIMIT_TOL = 1e-3  # soft output limit held when reachable


def plant_model(gain=1.0):
    # Two-input two-output stable plant, discrete, with coupling.
    Phi = np.array([[0.9, 0.05, 0.0], [0.0, 0.8, 0.1], [0.0, 0.0, 0.7]])
    Gamma = np.array([[0.5, 0.0], [0.1, 0.3], [0.0, 0.4]]) * gain
    C = np.array([[1.0, 0.0, 0.0], [0.0, 0.5, 1.0]])
    return Phi, Gamma, C


class Plant:
    def __init__(self, gain=1.0, d=(0.0, 0.0)):
        self.Phi, self.Gamma, self.C = plant_model(gain)
        self.x = np.zeros(3)
        self.d = np.asarray(d, dtype=float)

    def y(self):
        return self.C @ self.x + self.d

    def apply(self, u):
        self.x = self.Phi @ self.x + self.Gamma @ u


def make(settings_kw=None, gain=1.0):
    kw = dict(nu=2, ny=2, P=10, M=4, Xi=[1.0, 1.0], Lambda=[0.1, 0.1],
              u_min=[-1.0, -1.0], u_max=[1.0, 1.0], du_max=[0.2, 0.2],
              budget_ms=1e3)  # generous: these tests are about behaviour, not speed
    kw.update(settings_kw or {})
    s = MPCSettings(**kw)
    src = LinearModelState({"m": plant_model()})
    return MPCController(s, src, u0=np.zeros(2)), Plant(gain=gain, d=(0.3, -0.2))


def run(ctrl, plant, n, reference):
    us, ys, decisions = [], [], []
    for k in range(n):
        y = plant.y()
        dec = ctrl.step(k, float(k), y, reference)
        plant.apply(dec.u)
        us.append(dec.u)
        ys.append(y)
        decisions.append(dec)
    return np.array(us), np.array(ys), decisions


def test_is_a_sample_controller():
    ctrl, _ = make()
    assert isinstance(ctrl, SampleController)


def test_offset_free_tracking_with_model_mismatch_and_limits_held():
    ctrl, plant = make(gain=1.3)  # 30 % gain mismatch and an output offset
    ref = np.array([0.8, -0.5])
    us, ys, decs = run(ctrl, plant, 150, ref)
    np.testing.assert_allclose(ys[-1], ref, atol=TRACK_ATOL)
    assert all(not d.fallback for d in decs)
    assert np.all(us <= 1.0 + LIMIT_TOL) and np.all(us >= -1.0 - LIMIT_TOL)
    du = np.diff(np.vstack([np.zeros(2), us]), axis=0)
    assert np.all(np.abs(du) <= 0.2 + LIMIT_TOL)


def test_soft_output_limit_held_in_closed_loop():
    ctrl, plant = make({"y_max": [0.5, np.inf], "slack_linear": 1e4})
    us, ys, decs = run(ctrl, plant, 150, np.array([0.9, 0.0]))
    assert np.max(ys[:, 0]) <= 0.5 + SOFT_LIMIT_TOL
    assert ys[-1, 0] == pytest.approx(0.5, abs=SOFT_LIMIT_TOL)


def test_soft_limits_feasible_from_any_state():
    """Start far outside the soft output limits with tight inputs: always a solution."""
    rng = np.random.default_rng(3)
    for _ in range(10):
        ctrl, plant = make({"y_min": [-0.1, -0.1], "y_max": [0.1, 0.1], "du_max": [0.01, 0.01]})
        plant.x = rng.normal(size=3) * 10
        _, _, decs = run(ctrl, plant, 5, rng.normal(size=2))
        assert all(d.status == "solved" for d in decs)
        assert all(d.extra["slack"] >= 0 for d in decs)


def test_time_varying_reference_is_used_over_the_horizon():
    ctrl, plant = make()
    P = 10
    ramp = np.outer(np.linspace(0.01, 0.1, P), [1.0, 0.0])
    flat = np.tile(ramp[0], (P, 1))
    d1 = make()[0].step(0, 0.0, np.zeros(2), ramp)
    d2 = make()[0].step(0, 0.0, np.zeros(2), flat)
    assert np.all(np.abs(d1.u) < 0.2) and np.all(np.abs(d2.u) < 0.2)  # rates not saturated
    assert not np.allclose(d1.u, d2.u)


def test_too_small_budget_applies_the_previous_plan_and_recovers():
    ctrl, plant = make()
    ref = np.array([0.8, -0.5])
    d0 = ctrl.step(0, 0.0, plant.y(), ref)
    assert d0.status == "solved" and not d0.fallback
    plan = ctrl.plan.copy()
    plant.apply(d0.u)

    real_clock = ctrl.clock
    ticks = iter(np.arange(0.0, 1e4, 5.0))  # every clock read advances 5 s
    ctrl.clock = lambda: next(ticks)
    u_prev = d0.u
    for i in (1, 2):
        d = ctrl.step(i, float(i), plant.y(), ref)
        assert d.fallback and d.status == "deadline"
        np.testing.assert_allclose(d.u, np.clip(u_prev + plan[i], -1, 1), atol=1e-12)
        assert d.alarms
        u_prev = d.u
        plant.apply(d.u)
    assert ctrl.counters["deadline"] == 2 and ctrl.counters["fallback"] == 2
    # The plan is used up after M moves: then the input is held.
    for i in (3, 4, 5):
        d = ctrl.step(i, float(i), plant.y(), ref)
        plant.apply(d.u)
    np.testing.assert_allclose(d.u, ctrl.u)
    ctrl.clock = real_clock
    d = ctrl.step(6, 6.0, plant.y(), ref)
    assert d.status == "solved" and not d.fallback
    assert ctrl.counters["fallback"] == 5


def test_tiny_budget_setting_triggers_fallback_every_sample_and_the_loop_carries_on():
    ctrl, plant = make({"budget_ms": 1e-9})
    us, ys, decs = run(ctrl, plant, 20, np.array([0.5, 0.5]))
    assert all(d.fallback and d.status == "deadline" for d in decs)
    assert ctrl.counters["deadline"] == 20
    np.testing.assert_allclose(us, 0.0)  # no previous plan: hold the initial input


@pytest.mark.parametrize("bad", [[np.nan, 0.0], [np.inf, 0.0], [1.0], "x"])
def test_invalid_measurement_is_a_safe_action(bad):
    ctrl, plant = make()
    ref = np.array([0.8, -0.5])
    d0 = ctrl.step(0, 0.0, plant.y(), ref)
    d1 = ctrl.step(1, 1.0, bad, ref)
    assert d1.fallback and d1.status in ("invalid_measurement", "error")
    np.testing.assert_allclose(d1.u, np.clip(d0.u + ctrl.plan[1], -1, 1))
    d2 = ctrl.step(2, 2.0, plant.y(), ref)
    assert d2.status == "solved"


def test_nan_reference_is_a_safe_action():
    ctrl, plant = make()
    d0 = ctrl.step(0, 0.0, plant.y(), np.array([0.8, -0.5]))
    d1 = ctrl.step(1, 1.0, plant.y(), np.array([np.nan, 0.0]))
    assert d1.fallback and d1.status == "invalid_reference"
    assert np.all(np.isfinite(d1.u)) and np.all(np.abs(d1.u - d0.u) <= 0.2 + LIMIT_TOL)


def test_infeasible_user_bounds_rejected_at_configuration():
    with pytest.raises(MPCSettingsError, match="u_min/u_max"):
        make({"u_min": [0.5, -1.0], "u_max": [0.0, 1.0]})


def test_first_order_filter_matches_closed_form():
    f = FirstOrderFilter(0.2, y0=[0.0])
    out = [f.update([1.0])[0] for _ in range(30)]
    k = np.arange(1, 31)
    np.testing.assert_allclose(out, 1 - 0.8 ** k, rtol=1e-12)
    # A NaN sample leaves the state unchanged.
    assert f.update([np.nan])[0] == pytest.approx(out[-1])


def test_model_switch_is_bumpless_and_needs_no_rebuild():
    Phi, Gamma, C = plant_model()
    models = {"a": (Phi, Gamma, C), "b": (Phi, Gamma * 1.2, C)}
    s = MPCSettings(nu=2, ny=2, P=10, M=4, Lambda=[0.1, 0.1], du_max=[0.2, 0.2], budget_ms=1e3)
    src = LinearModelState(models)
    ctrl = MPCController(s, src, u0=np.zeros(2))
    for key, (P_, G_, C_) in models.items():
        ctrl.prepare(key, P_, G_, C_)
    assert ctrl.counters["rebuilds"] == 2
    plant = Plant()
    ref = np.array([0.5, 0.2])
    us = []
    for k in range(120):
        if k % 10 == 0:
            src.select("b" if src.active == "a" else "a")
        d = ctrl.step(k, float(k), plant.y(), ref)
        assert d.status == "solved"
        plant.apply(d.u)
        us.append(d.u)
    assert ctrl.counters["rebuilds"] == 2  # switching reused the cached formulations
    np.testing.assert_allclose(plant.y(), ref, atol=TRACK_ATOL)
    assert np.max(np.abs(np.diff(us, axis=0))) <= 0.2 + LIMIT_TOL


def test_checkpoint_restore_resumes_identically():
    ctrl, plant = make()
    ref = np.array([0.8, -0.5])
    run(ctrl, plant, 5, ref)
    state = ctrl.checkpoint()
    ctrl2, _ = make()
    ctrl2.restore(state)
    y = plant.y()
    np.testing.assert_allclose(ctrl.step(5, 5.0, y, ref).u, ctrl2.step(5, 5.0, y, ref).u,
                               atol=1e-9)


def test_measured_disturbance_feedforward_reduces_the_upset():
    Phi, Gamma, C = plant_model()
    Gd = np.array([[0.3], [0.2], [0.1]])
    s = MPCSettings(nu=2, ny=2, P=10, M=4, Lambda=[0.05, 0.05], budget_ms=1e3)
    peaks = {}
    for ff in (False, True):
        src = LinearModelState({"m": (Phi, Gamma, C, Gd if ff else None)})
        ctrl = MPCController(s, src, u0=np.zeros(2))
        x = np.zeros(3)
        d = np.zeros(1)
        dev = []
        for k in range(150):
            d = np.array([1.0]) if k >= 20 else np.zeros(1)
            y = C @ x
            if ff:
                ctrl.set_measured_disturbance(d)
            dec = ctrl.step(k, float(k), y, np.zeros(2))
            assert dec.status == "solved"
            x = Phi @ x + Gamma @ dec.u + Gd @ d
            dev.append(np.abs(C @ x))
        peaks[ff] = float(np.max(dev))
        np.testing.assert_allclose(C @ x, 0.0, atol=TRACK_ATOL)  # both reject it in the end
    assert peaks[True] < 0.5 * peaks[False]


def test_input_outside_hard_limits_at_run_time_is_brought_back_and_loop_recovers():
    """u(k-1) above u_max with a rate limit: the QP is infeasible; the documented safe
    action holds the input clipped into its hard range, and the next sample solves."""
    ctrl, plant = make()
    ctrl.u = np.array([1.5, 0.0])  # u_max = 1, du_max = 0.2: unreachable in one move
    d0 = ctrl.step(0, 0.0, plant.y(), np.array([0.5, 0.0]))
    assert d0.fallback and d0.status == "infeasible" and d0.alarms
    np.testing.assert_allclose(d0.u, [1.0, 0.0])
    plant.apply(d0.u)
    d1 = ctrl.step(1, 1.0, plant.y(), np.array([0.5, 0.0]))
    assert d1.status == "solved" and np.all(d1.u <= 1.0 + LIMIT_TOL)


def test_invalid_measurement_keeps_the_model_state_in_step_with_time():
    ctrl, plant = make()
    Phi, Gamma, _ = plant_model()
    ref = np.array([0.5, 0.2])
    x_model = np.zeros(3)
    u_applied = []
    for k in range(12):
        y = [np.nan, 0.0] if k == 6 else plant.y()
        d = ctrl.step(k, float(k), y, ref)
        plant.apply(d.u)
        u_applied.append(d.u)
    for u in u_applied[:-1]:  # the state at the last sample has seen all but the last u
        x_model = Phi @ x_model + Gamma @ u
    np.testing.assert_allclose(ctrl.source.x["m"], x_model, atol=1e-12)


def test_set_input_target_moves_toward_the_target_by_the_closed_form():
    # Xi = 0, M = 1, no active limit: the cost is Λ Δu² + W (u(k-1) + Δu − u_t)², so
    # Δu = W (u_t − u(k-1)) / (Λ + W) per input (closed form, independent of the QP).
    lam, w = np.array([1.0, 1.0]), np.array([1.0, 3.0])
    ctrl, plant = make({"Xi": [0.0, 0.0], "M": 1, "Lambda": lam, "du_max": [1.0, 1.0],
                        "u_target_weight": w})
    target = np.array([0.3, -0.2])
    ctrl.set_input_target(target)
    dec = ctrl.step(0, 0.0, plant.y(), np.zeros(2))
    np.testing.assert_allclose(dec.u, w * target / (lam + w), atol=LIMIT_TOL)
    # the target is part of the checkpoint
    twin, _ = make({"Xi": [0.0, 0.0], "M": 1, "Lambda": lam, "du_max": [1.0, 1.0],
                    "u_target_weight": w})
    twin.restore(ctrl.checkpoint())
    np.testing.assert_array_equal(twin.u_target, target)


@pytest.mark.parametrize("bad", [[0.1], [0.1, np.nan], [0.1, np.inf], "x"])
def test_set_input_target_rejects_bad_values_and_keeps_the_target(bad):
    ctrl, _ = make({"u_target": [0.5, 0.5], "u_target_weight": [1.0, 1.0]})
    with pytest.raises(ValueError, match="u_target"):
        ctrl.set_input_target(bad)
    np.testing.assert_array_equal(ctrl.u_target, [0.5, 0.5])


def test_predicted_outputs_of_the_plan_are_what_a_matched_plant_does_under_it():
    """predicted() (made on request, not in the sample) is the plan's output trajectory:
    a plant equal to the model, given the plan's moves and then held, follows it."""
    ctrl, plant = make()
    assert ctrl.predicted() is None  # no optimal solve yet
    run(ctrl, plant, 3, np.array([0.8, -0.5]))
    pred = ctrl.predicted()
    s = ctrl.settings
    assert pred.shape == (s.P, s.ny)
    u, ys = ctrl.u.copy(), [plant.y()]  # run() applied this sample's move: y(k+1)
    for j in range(1, s.P):
        u = u + (ctrl.plan[j] if j < s.M else 0.0)
        plant.apply(u)
        ys.append(plant.y())
    np.testing.assert_allclose(np.array(ys), pred, atol=1e-9)
    # a restored controller has no plan basis: nothing is predicted from a stale one
    ctrl.restore(ctrl.checkpoint())
    assert ctrl.predicted() is None
