"""Bookkeeping after the move (``finish_sample``): the moves must not depend on it.

A real-time node sends the move first and then runs the sample's bookkeeping (the
shared state's advance, the covariance steps, the next QP build); offline runners
call it at once, and a controller whose caller never calls it runs it itself at the
next step. All three must give the same moves, bit for bit.
"""

import json

import numpy as np
import pytest

from controller.adaptation import NLSSettings, NormalizedLeastSquares

G_D = 0.01  # per-sample gain of every estimator here


def _estimator(n: int) -> NormalizedLeastSquares:
    """An estimator of n parameters from zero, default settings."""
    return NormalizedLeastSquares(NLSSettings(), np.zeros(n), G_D)


@pytest.mark.parametrize("n", [12, 213])  # dense covariance / implicit c I - V V'
def test_deferred_covariance_step_equals_the_immediate_one(n):
    rng = np.random.default_rng(7)
    a = _estimator(n)
    b = _estimator(n)
    theta = rng.standard_normal(n)
    for k in range(120):
        W = rng.standard_normal((5, n))
        y = W @ theta
        ra = a.update(W, y)
        rb = b.update(W, y, defer=True)
        np.testing.assert_array_equal(ra.error, rb.error)
        np.testing.assert_array_equal(a.p, b.p)
        if k % 7 == 0:
            b.commit()
            b.commit()  # idempotent
    assert a.n_resets >= 2  # the floor rule (lambda_min(P) > 1) was exercised
    np.testing.assert_array_equal(a.P, b.P)  # reading P commits
    assert a.counters() == b.counters()
    assert a.reset_reasons == b.reset_reasons


def test_checkpoint_commits_a_pending_step():
    rng = np.random.default_rng(1)
    n = 213
    a = _estimator(n)
    W, y = rng.standard_normal((5, n)), rng.standard_normal(5)
    a.update(W, y, defer=True)
    twin = _estimator(n)
    twin.restore(json.loads(json.dumps(a.checkpoint())))
    ref = _estimator(n)
    ref.update(W, y)
    np.testing.assert_array_equal(twin.P, ref.P)


def _te_moves(finish: bool, n: int = 160):
    from test_te_control_mpc import apply_decision

    from controller.units.te.control import TEMPCOptions, make_te_controller
    from controller.units.te.grades import Leg, TransitionPlan
    from plant_sim.tennessee_eastman import TESimulator
    from plant_sim.tennessee_eastman.regulatory import RegulatoryLayer

    # the adaptive gain of 10 1/h (the product's is 1): its Θ moves enough within the
    # run for the law to refresh the adaptive model's form several times
    ctl, spec = make_te_controller("ssmpc", TransitionPlan("mode0", (Leg(0.2, "mode2"),)),
                                   realtime=False,  # no wall-clock budget: a loaded machine
                                   # would take the fallback move and the moves would
                                   # differ by timing, not by design
                                   mpc=TEMPCOptions(nls_gain=10.0))
    sim = TESimulator()
    reg = RegulatoryLayer(sim, loops=spec.loops)
    law = ctl.core.law
    moves, rebuild_in_step = [], 0
    for k in range(n):
        before = law.mpc.counters["rebuilds"]
        dec = ctl.step(k, sim.time, sim.xmeas, None)
        if k > 0:  # sample 0 makes the adaptive model's first form
            rebuild_in_step += law.mpc.counters["rebuilds"] - before
        if finish:
            ctl.finish_sample()
        moves.append(np.concatenate([dec.u, dec.extra["setpoints"]]))
        apply_decision(spec, sim, reg, dec)
    return np.array(moves), rebuild_in_step, law.source.refreshes


def test_te_moves_do_not_depend_on_when_the_bookkeeping_runs():
    eager, rebuilds_eager, refreshes = _te_moves(True)
    lazy, _, _ = _te_moves(False)
    np.testing.assert_array_equal(eager, lazy)
    assert np.all(np.isfinite(eager[:, [2, 3, 10]]))
    # with the bookkeeping run between samples the adaptive model's refreshes (when its
    # Θ has moved by more than the law's refresh_tol) are built there, not inside a step
    assert refreshes >= 3
    assert rebuilds_eager == 0


PREPARED_RTOL = 1e-10  # P W' summed in another order: round-off only


@pytest.mark.parametrize("n", [12, 213])  # dense covariance / implicit c I - V V'
def test_prepared_update_equals_the_update_on_the_full_regressor(n):
    """``prepare(W_base, d)`` then ``update_prepared(y)`` is ``update(W_base + y d', y)``."""
    rng = np.random.default_rng(11)
    a = _estimator(n)
    b = _estimator(n)
    theta = rng.standard_normal(n)
    d = np.zeros(n)
    d[3:7] = rng.standard_normal(4)  # the hold's columns
    for k in range(120):
        W_base = rng.standard_normal((5, n))
        y = W_base @ theta + 0.01 * rng.standard_normal(5)
        b.prepare(W_base, d if k % 2 else None)
        W = W_base + np.outer(y, d) if k % 2 else W_base
        ra = a.update(W, y, defer=True)
        rb = b.update_prepared(y, defer=True)
        np.testing.assert_allclose(rb.error, ra.error, rtol=PREPARED_RTOL, atol=1e-12)
        np.testing.assert_allclose(b.p, a.p, rtol=PREPARED_RTOL, atol=1e-12)
        assert (ra.updated, ra.reset, ra.reason) == (rb.updated, rb.reset, rb.reason)
    assert a.n_resets >= 2 and a.reset_reasons == b.reset_reasons
    np.testing.assert_allclose(b.P, a.P, rtol=1e-8, atol=1e-10)


def test_a_covariance_change_discards_the_preparation():
    rng = np.random.default_rng(2)
    est = _estimator(20)
    W = rng.standard_normal((3, 20))
    with pytest.raises(RuntimeError, match="prepare"):
        est.update_prepared(np.ones(3))
    est.prepare(W)
    assert est.prepared
    est.reset_covariance()
    assert not est.prepared
    est.prepare(W)
    est.P = 2.0 * np.eye(20)
    assert not est.prepared
    est.prepare(W)
    est.update(W, np.ones(3))  # an update on another regressor uses it up
    assert not est.prepared


def test_prepared_update_skips_a_non_finite_output_and_keeps_p():
    est = NormalizedLeastSquares(NLSSettings(), np.ones(8), G_D)
    d = np.zeros(8)
    d[2] = 0.5
    est.prepare(np.eye(2, 8), d)
    step = est.update_prepared(np.array([np.inf, 1.0]))
    assert not step.updated and step.reason == "invalid_data"
    np.testing.assert_array_equal(est.p, np.ones(8))
    assert est.n_skipped == 1


def test_te_step_reads_no_covariance_when_the_bookkeeping_ran():
    """After finish_sample the adaptive model's products are ready: the step between
    the measurement and the move does not form P W' (the (213, 213) covariance)."""
    from test_te_control_mpc import apply_decision

    from controller.units.te.control import make_te_controller
    from controller.units.te.grades import TransitionPlan
    from plant_sim.tennessee_eastman import TESimulator
    from plant_sim.tennessee_eastman.regulatory import RegulatoryLayer

    ctl, spec = make_te_controller("ssmpc", TransitionPlan("mode0"), realtime=False)
    sim = TESimulator()
    reg = RegulatoryLayer(sim, loops=spec.loops)
    core = ctl.core
    (j,) = core.adaptive
    est = core.estimators[j]
    calls = []
    original = est.prepare
    est.prepare = lambda *a, **kw: (calls.append(1), original(*a, **kw))[1]
    for k in range(20):
        ctl.finish_sample()
        assert est.prepared or k == 0
        before = len(calls)
        dec = ctl.step(k, sim.time, sim.xmeas, None)
        assert len(calls) == before + (1 if k == 0 else 0)  # sample 0 initializes
        apply_decision(spec, sim, reg, dec)
    assert est.n_updates >= 19


def test_te_step_computes_no_steady_state_when_the_bookkeeping_ran(monkeypatch):
    """The targets' steady state of the active model, due every refresh_samples samples
    for the adaptive model, is computed after the move (CoreTargets.prepare), not in the
    step; the moves are those of the lazy path (test above)."""
    from test_te_control_mpc import apply_decision

    from controller.units.te import targets as te_targets
    from controller.units.te.control import make_te_controller
    from controller.units.te.grades import TransitionPlan
    from plant_sim.tennessee_eastman import TESimulator
    from plant_sim.tennessee_eastman.regulatory import RegulatoryLayer

    ctl, spec = make_te_controller("ssmpc", TransitionPlan("mode0"), realtime=False)
    sim = TESimulator()
    reg = RegulatoryLayer(sim, loops=spec.loops)
    where, phase = [], ["finish"]
    original = te_targets.model_steady_state
    monkeypatch.setattr(te_targets, "model_steady_state",
                        lambda ssm, j: (where.append(phase[0]), original(ssm, j))[1])
    for k in range(35):
        phase[0] = "step"
        dec = ctl.step(k, sim.time, sim.xmeas, None)
        phase[0] = "finish"
        ctl.finish_sample()
        apply_decision(spec, sim, reg, dec)
    assert ctl.core.initialized and where.count("finish") >= 3  # the refreshes, every 10
    assert where.count("step") <= 1  # at most the first sample's (nothing prepared yet)


def test_te_plan_references_are_evaluated_after_the_move_on_the_sample_grid():
    """finish_sample evaluates the next sample's plan references; a step at that time
    (up to the round-off of another clock) uses them, one off the grid evaluates its
    own, and the values are those of the plan at the grid time."""
    from controller.units.te.control import SAMPLE_H, make_te_controller
    from controller.units.te.grades import Leg, TransitionPlan
    from plant_sim.tennessee_eastman import TESimulator

    plan = TransitionPlan("mode0", (Leg(0.05, "mode2"),))
    ctl, _ = make_te_controller("ssmpc", plan, realtime=False)
    y = TESimulator().xmeas
    seen = []
    original = ctl._plan_refs
    ctl._plan_refs = lambda t: (seen.append(t), original(t))[1]
    used = []
    original_ff = ctl._d_share_ff  # the plan's D share, before the MPC strategies' path
    ctl._d_share_ff = lambda ff, t_ref, ym, x: (used.append((ff, ym.copy())),
                                                original_ff(ff, t_ref, ym, x))[1]
    t = 0.0
    for k in range(12):
        ctl.step(k, t, y, None)
        ctl.finish_sample()
        t = (k + 1) * SAMPLE_H * (1.0 + 3e-16 * (-1) ** k)  # another clock's round-off
    # one evaluation per sample: the first at t = 0, then each ahead of its sample
    assert len(seen) == 13
    for k, (ff, ym) in enumerate(used):
        t_grid = seen[k]
        assert abs(t_grid - k * SAMPLE_H) < 1e-12
        # the MPC's own references of the plan (its faster reactor level and temperature)
        np.testing.assert_array_equal(ym, ctl.plan.xmeas_ref(t_grid))
        assert ff == plan.d_fraction_ref(t_grid)
    n = len(seen)
    ctl.step(99, t + 5 * SAMPLE_H, y, None)  # off the grid (a gap): evaluated at its time
    assert len(seen) == n + 1 and seen[-1] == t + 5 * SAMPLE_H
