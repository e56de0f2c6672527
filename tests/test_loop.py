"""Closed-loop runner + multiple-model controller on linear plants (fast, exact ZOH)."""

import json

import control as ct
import numpy as np
import pytest
import scipy.linalg

from controller.adaptation import NLSSettings
from controller.hinf import HInfLaw, HInfWeights
from controller.interfaces import SampleController
from controller.loop import ise, run_closed_loop, settling_time
from controller.mrac import MRACLaw
from controller.multimodel import HoldLaw, MultiModelController, MultiModelSettings
from controller.reference import ReferenceTrajectory, SetpointSchedule
from controller.state_shared import ModelSpec, StateSharedModel
from controller.switching import IndexSettings

DT = 0.05
A_POLY = [1.0, 1.0]  # the seed's F = [[0, 1], [-1, -1]] (§5.2.3)
TRUE = ([0.3, 0.3 * 1.2440], [1.0, 1.1605, 0.2337])  # Table 5.3 OPI
WRONG = ([0.3, 0.3 * 4.9310], [1.0, 2.1493, 2.3286])  # Table 5.3 OPII
U0, Y0 = 0.4, 1.3
TRACK_TOL = 0.02  # ±2 % band of the seed's checks (R5.5)


def _ss(tf):
    sys = ct.ss(ct.tf(*tf))
    return np.asarray(sys.A), np.asarray(sys.B), np.asarray(sys.C)


def _linear_plant(tf):
    A, B, C = _ss(tf)
    n = A.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n], M[:n, n:] = A * DT, B * DT
    E = scipy.linalg.expm(M)
    Ad, Bd = E[:n, :n], E[:n, n:]

    def step(x, u, t, dt):
        return Ad @ x + Bd[:, 0] * (u[0] - U0)

    def measure(x, t):
        return C @ x + Y0

    return step, measure, np.zeros(n)


def _model(name, tf, kind="fixed"):
    A, B, C = _ss(tf)
    spec = StateSharedModel.model_from_linear(name, A, B, C, [U0], [Y0], A_POLY)
    return ModelSpec(name, spec.theta, spec.bias, kind)


def _controller(law, models, kinds, initial=0, dwell=0.5, nls=None, **settings):
    ssm = StateSharedModel(A_POLY, 1, DT, models)
    s = MultiModelSettings(nls or NLSSettings(kappa=10, gain=3.0, rate=1.0),
                           IndexSettings(1.0, 0.1, 0.5, dwell), **settings)
    return MultiModelController(ssm, law, [U0], s, kinds=kinds, initial_model=initial)


def _hinf():
    return HInfLaw(HInfWeights.seed_cstr(a=3.0), DT, resynthesis_threshold=0.2)


def test_controller_implements_the_sample_controller_protocol():
    ctl = _controller(_hinf(), [_model("M1", TRUE)], ["fixed"])
    assert isinstance(ctl, SampleController)


def test_switches_to_the_true_model_and_tracks_a_step():
    step, measure, x0 = _linear_plant(TRUE)
    ctl = _controller(_hinf(), [_model("wrong", WRONG), _model("true", TRUE)],
                      ["fixed", "fixed"], initial=0)
    ref = ReferenceTrajectory(SetpointSchedule.step(Y0, 2.0, 1.0), 2.0, DT)
    res = run_closed_loop(step, measure, x0, ctl, ref, 30.0)
    assert res.completed
    assert res.final_model() == "true"
    assert abs(res.y[-1, 0] - 2.0) <= TRACK_TOL * 2.0
    assert not np.isnan(settling_time(res.t, res.y[:, 0], 2.0, TRACK_TOL * 2.0))
    # the switch is bumpless: the move at the switching sample equals the previous one
    k_sw = np.flatnonzero(np.diff(res.active))
    assert k_sw.size >= 1
    for k in k_sw + 1:
        assert res.u[k, 0] == pytest.approx(res.u[k - 1, 0], abs=1e-12)
    # and the output changes no more at a switch than its largest one-sample change
    dy = np.abs(np.diff(res.y[:, 0]))
    assert np.all(dy[k_sw] <= dy.max())


def test_dwell_time_is_respected_in_closed_loop():
    step, measure, x0 = _linear_plant(TRUE)
    models = [_model("M1", TRUE), _model("M2", WRONG), _model("M3", TRUE, "adaptive"),
              _model("M4", TRUE, "adaptive")]
    ctl = _controller(_hinf(), models, ["fixed", "fixed", "free-running", "re-initialized"],
                      dwell=1.0)
    ref = ReferenceTrajectory(SetpointSchedule.pulses(Y0, 1.8, 2.0, 4.0, 8.0, 2), 1.0, DT)
    res = run_closed_loop(step, measure, x0, ctl, ref, 20.0)
    k_sw = np.flatnonzero(np.diff(res.active))
    if k_sw.size > 1:
        assert np.diff(k_sw).min() >= ctl.switcher.dwell_samples
    assert res.completed and np.all(np.isfinite(res.u))


def test_adaptive_model_learns_a_plant_between_the_fixed_models():
    # plant between the two fixed models, exciting random set points, exact RLS tuning
    # (gain * dt = rate, large kappa, low floor): the free-running model ends best and
    # its DC gain is the plant's
    plant_tf = ([0.3, 0.3 * 2.5], [1.0, 1.6, 1.0])
    step, measure, x0 = _linear_plant(plant_tf)
    models = [_model("M1", TRUE), _model("M2", WRONG), _model("M3", TRUE, "adaptive")]
    nls = NLSSettings(kappa=1000.0, gain=1.0 / DT, rate=1.0, eig_floor=1e-3)
    ctl = _controller(_hinf(), models, ["fixed", "fixed", "free-running"], nls=nls)
    levels = Y0 + 0.3 * np.random.default_rng(0).standard_normal(30)
    sched = SetpointSchedule.sequence(levels, np.arange(30.0))
    res = run_closed_loop(step, measure, x0, ctl, ReferenceTrajectory(sched, 0.2, DT), 30.0)
    assert res.completed
    assert np.argmin(res.J[-1]) == 2
    th = ctl.ssm.theta(2)[:, 0]
    dc_adapted = th[0] / (A_POLY[0] - th[2])
    assert dc_adapted == pytest.approx(0.3 * 2.5 / 1.0, rel=0.01)


def test_nan_measurement_is_skipped_with_an_alarm_and_nothing_goes_nan():
    step, measure, x0 = _linear_plant(TRUE)
    models = [_model("M1", TRUE), _model("M3", TRUE, "adaptive")]
    ctl = _controller(_hinf(), models, ["fixed", "free-running"])
    bad = {40, 41, 90}

    def fault(k, y):
        return np.full_like(y, np.nan) if k in bad else y

    ref = ReferenceTrajectory(SetpointSchedule.step(Y0, 1.8, 1.0), 1.0, DT)
    res = run_closed_loop(step, measure, x0, ctl, ref, 8.0, fault=fault)
    assert res.completed
    for k in bad:
        assert res.fallback[k] and res.status[k] == "invalid_measurement"
        assert res.u[k, 0] == res.u[k - 1, 0]
    assert ctl.counters()["invalid_measurements"] == len(bad)
    assert sum("invalid measurement" in a for _, a in res.alarms) == len(bad)
    assert np.all(np.isfinite(ctl.ssm.n)) and np.all(np.isfinite(res.J))
    assert np.all(np.isfinite(ctl.estimators[1].p))
    assert abs(res.y[-1, 0] - 1.8) < TRACK_TOL * 1.8


def test_bad_measurement_before_initialization_holds_the_input():
    ctl = _controller(_hinf(), [_model("M1", TRUE)], ["fixed"])
    dec = ctl.step(0, 0.0, np.array([np.nan]), np.array([[Y0]]))
    assert dec.fallback and dec.u[0] == U0
    dec = ctl.step(1, DT, np.array([1.0, 2.0]), np.array([[Y0]]))  # wrong length
    assert dec.status == "invalid_measurement"


def test_checkpoint_restore_resumes_bumplessly():
    step, measure, x0 = _linear_plant(TRUE)
    models = [_model("M1", TRUE), _model("M2", WRONG), _model("M3", TRUE, "adaptive")]
    kinds = ["fixed", "fixed", "free-running"]
    a = _controller(_hinf(), models, kinds)
    sched = SetpointSchedule.step(Y0, 1.7, 0.5)
    ra = ReferenceTrajectory(sched, 1.0, DT)
    x = x0
    for k in range(60):  # run half-way by hand
        y = measure(x, k * DT)
        dec = a.step(k, k * DT, y, ra.horizon(1))
        x = step(x, dec.u, k * DT, DT)
        ra.advance()
    state = json.loads(json.dumps(a.checkpoint()))
    b = _controller(_hinf(), [_model("M1", TRUE), _model("M2", WRONG),
                              _model("M3", TRUE, "adaptive")], kinds)
    b.restore(state)
    rb = ReferenceTrajectory(sched, 1.0, DT)
    rb.restore(ra.checkpoint())
    xb = x.copy()
    for k in range(60, 120):
        ya, yb = measure(x, k * DT), measure(xb, k * DT)
        da = a.step(k, k * DT, ya, ra.horizon(1))
        db = b.step(k, k * DT, yb, rb.horizon(1))
        assert db.u[0] == pytest.approx(da.u[0], rel=1e-9, abs=1e-12)
        assert db.active_model == da.active_model
        x, xb = step(x, da.u, 0, DT), step(xb, db.u, 0, DT)
        ra.advance()
        rb.advance()


def test_mrac_follows_the_reference_model_on_the_true_plant():
    step, measure, x0 = _linear_plant(TRUE)
    ctl = _controller(MRACLaw(DT), [_model("M1", TRUE)], ["fixed"])
    ref = ReferenceTrajectory(SetpointSchedule.step(Y0, 2.0, 1.0), 0.0, DT)
    res = run_closed_loop(step, measure, x0, ctl, ref, 12.0)
    # reference model 1/(s+1) driven by the same sampled r
    ym = np.empty_like(res.t)
    ym[0] = Y0
    for k in range(1, res.t.size):
        ym[k] = np.exp(-DT) * ym[k - 1] + (1 - np.exp(-DT)) * res.setpoint[k - 1, 0]
    # the discrete filters approximate the continuous law: error small, not zero
    assert np.max(np.abs(res.y[:, 0] - ym)) < 0.02
    assert abs(res.y[-1, 0] - 2.0) < 1e-3


def test_plant_failure_ends_the_run_without_raising():
    step, measure, x0 = _linear_plant(TRUE)
    ctl = _controller(_hinf(), [_model("M1", TRUE)], ["fixed"])

    def failing(x, u, t, dt):
        if t > 1.0:
            raise RuntimeError("integrator failed")
        return step(x, u, t, dt)

    res = run_closed_loop(failing, measure, x0, ctl,
                          ReferenceTrajectory(SetpointSchedule.constant(Y0), 0.0, DT), 5.0)
    assert not res.completed and "integrator failed" in res.stop_reason
    assert res.t[-1] == pytest.approx(1.0 + DT, abs=1e-9)


def test_ise_and_settling_time_closed_forms():
    t = np.arange(0, 10, 0.01)
    y = 1 - np.exp(-t)
    # rectangle rule: dt sum exp(-2 t_k) is a geometric series
    dt = 0.01
    expected = dt * (1 - np.exp(-2 * 10.0)) / (1 - np.exp(-2 * dt))
    assert ise(t, y, np.ones_like(t)) == pytest.approx(expected, rel=1e-9)
    assert settling_time(t, y, 1.0, 0.02) == pytest.approx(np.log(50), abs=0.011)


def test_non_square_model_validates_outputs_by_their_own_count():
    # two inputs, one output: y has length p = 1, u has length m = 2
    theta = np.zeros((2 * 2 + 2, 1))  # n = 2: n(m + p) = 6 rows, p = 1 column
    theta[0, 0], theta[2, 0] = 0.3, 0.1
    ssm = StateSharedModel(A_POLY, 2, DT, [ModelSpec("M", theta, np.zeros(1))], p=1)
    ctl = MultiModelController(ssm, HoldLaw(), [0.5, 0.5], kinds=["fixed"])
    dec = ctl.step(0, 0.0, np.array([1.0]), np.array([[1.0]]))
    assert dec.status == "solved" and dec.u.shape == (2,)
    dec = ctl.step(1, DT, np.array([1.0, 2.0]), np.array([[1.0]]))
    assert dec.status == "invalid_measurement"


class _SlackLaw(HoldLaw):
    """Holds u and reports a soft-constraint slack (an MPC law's ``info["slack"]``)."""

    slack = 0.25

    def compute(self, k, model, ssm, y, reference, u_last):
        return u_last, {"status": "solved", "slack": self.slack}


def test_law_slack_and_status_are_in_the_decision():
    ctl = _controller(_SlackLaw(), [_model("M1", TRUE)], ["fixed"])
    dec = ctl.step(0, 0.0, [Y0], [[Y0]])
    assert dec.extra["constraint_slack"] == _SlackLaw.slack
    assert dec.extra["law_status"] == "solved"
    # a law without a soft constraint: None, not a made-up zero
    ctl = _controller(HoldLaw(), [_model("M1", TRUE)], ["fixed"])
    assert ctl.step(0, 0.0, [Y0], [[Y0]]).extra["constraint_slack"] is None


def _reinit_controller(order):
    """Fixed M1 (TRUE), fixed M2 (WRONG) and a re-initialized model starting at WRONG,
    in the given slot order; at a steady state (y = Y0, u = U0) every model's error is
    0, so nothing adapts and J is exactly what the test sets."""
    specs = {"M1": (_model("M1", TRUE), "fixed"), "M2": (_model("M2", WRONG), "fixed"),
             "R": (_model("R", WRONG, "adaptive"), "re-initialized")}
    ctl = _controller(HoldLaw(), [specs[n][0] for n in order], [specs[n][1] for n in order])
    return ctl, {n: i for i, n in enumerate(order)}


@pytest.mark.parametrize("order", [("M1", "M2", "R"), ("R", "M1", "M2")])
def test_reinitialization_only_when_a_fixed_model_is_strictly_better(order):
    ctl, idx = _reinit_controller(order)
    wrong = ctl.params(idx["R"]).copy()
    J = np.zeros(3)
    ctl.index.update = lambda errors: J.copy()  # the rule under test reads J only
    # a tie between the best fixed model and the adaptive one: the adaptive model
    # keeps its own parameters (whatever the slot order)
    J[[idx["M1"], idx["M2"], idx["R"]]] = [1.0, 2.0, 1.0]
    for k in range(3):
        ctl.step(k, k * DT, [Y0], [[Y0]])
    assert ctl.n_reinit == 0
    np.testing.assert_array_equal(ctl.params(idx["R"]), wrong)
    # the best fixed model strictly better: the adaptive model takes its parameters
    J[idx["M1"]] = 0.5
    ctl.step(3, 3 * DT, [Y0], [[Y0]])
    assert ctl.n_reinit == 1
    np.testing.assert_array_equal(ctl.params(idx["R"]), ctl.params(idx["M1"]))
    # a fixed model better than the adaptive one but not the best fixed one: the best
    J[[idx["M1"], idx["M2"], idx["R"]]] = [0.7, 0.4, 1.0]
    ctl.step(4, 4 * DT, [Y0], [[Y0]])
    assert ctl.n_reinit == 2
    np.testing.assert_array_equal(ctl.params(idx["R"]), ctl.params(idx["M2"]))


def test_hold_law_keeps_the_last_move_while_models_adapt():
    law = HoldLaw()
    u_last = np.array([0.3, -1.2])
    u, info = law.compute(0, 0, None, np.zeros(1), np.zeros((1, 1)), u_last)
    assert info["status"] == "solved"
    np.testing.assert_array_equal(u, u_last)
    assert law.checkpoint() == {}
