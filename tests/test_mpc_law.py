"""MPCLaw / SharedStateSource on a StateSharedModel: the adaptive model's discrete form is
the shared state's own recursion; fixed models use the exact prediction form; no rebuild
on switching; the law never raises."""

from __future__ import annotations

import numpy as np

from controller.mpc import MPCSettings
from controller.mpc.law import MPCLaw, SharedStateSource
from controller.state_shared import ModelSpec, StateSharedModel

RECURSION_RTOL = 1e-10


def small_ssm(rng):
    a, m = (2.0, 3.0), 2  # omega = s^2 + 3 s + 2
    ssm = StateSharedModel(a, m, 0.1)
    for j, kind in enumerate(("fixed", "fixed", "adaptive")):
        p = 0.05 * rng.standard_normal(ssm.n_params + m)
        theta, bias = ssm.theta_from_params(p)
        ssm.add_model(ModelSpec(f"M{j}", theta, bias, kind))
    return ssm


def test_discrete_form_reproduces_the_shared_state_recursion():
    rng = np.random.default_rng(1)
    ssm = small_ssm(rng)
    ssm.initialize(np.zeros(2), np.zeros(2))
    src = SharedStateSource()
    src.ssm = ssm
    Phi, Gamma, C = src._discrete_form(2)
    b = ssm.bias(2)
    for _ in range(5):
        ssm.update(rng.standard_normal(2), rng.standard_normal(2))
    n = ssm.n
    u = rng.standard_normal(2)
    y = C @ n + b  # the model's own output, held over the sample
    ssm.update(u, y)
    # Φ n + Γ u plus the bias path [0; Gd b] equals the recursion's next state.
    expected = Phi @ n + Gamma @ u
    nm = ssm.Fd.shape[0]
    expected[nm:] += ssm.Gd @ b
    np.testing.assert_allclose(ssm.n, expected, rtol=RECURSION_RTOL, atol=1e-12)


def test_law_switches_models_without_rebuilds_and_never_raises():
    rng = np.random.default_rng(2)
    ssm = small_ssm(rng)
    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)
    law = MPCLaw(s)
    law.prepare(ssm)
    builds = law.mpc.counters["rebuilds"]
    u = np.zeros(2)
    ssm.initialize(u, np.zeros(2))
    law.reset(u, np.zeros(2))
    for k in range(30):
        y = ssm.estimates()[0]
        u, info = law.compute(k, k // 3 % 3, ssm, y, np.ones((8, 2)) * 0.1, u)
        assert info["status"] == "solved"
        ssm.update(u, y)
    # Fixed models are built once; the adaptive one (its Θ unchanged here) only when its
    # refreshed form differs.
    assert law.mpc.counters["rebuilds"] == builds
    # Bad measurement: a flagged fallback, not an exception.
    u2, info = law.compute(30, 0, ssm, [np.nan, 0.0], np.zeros((8, 2)), u)
    assert info["fallback"] and np.all(np.isfinite(u2))


def test_mpc_law_inside_the_multiple_model_controller_with_restart():
    from controller.multimodel import MultiModelController

    rng = np.random.default_rng(3)
    ssm = small_ssm(rng)
    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)
    ctrl = MultiModelController(ssm, MPCLaw(s), u0=np.zeros(2))
    ref = np.full((8, 2), 0.2)
    plant = small_ssm(np.random.default_rng(3))  # same models: model 0 is the plant
    plant.initialize(np.zeros(2), np.zeros(2))
    for k in range(40):
        y = plant.estimates()[0]
        dec = ctrl.step(k, 0.1 * k, y, ref)
        assert dec.status == "solved" and not dec.fallback
        plant.update(dec.u, y)
    state = ctrl.checkpoint()
    twin = MultiModelController(small_ssm(np.random.default_rng(3)), MPCLaw(s),
                                u0=np.zeros(2))
    twin.restore(state)
    y = plant.estimates()[0]
    np.testing.assert_allclose(ctrl.step(40, 4.0, y, ref).u, twin.step(40, 4.0, y, ref).u,
                               atol=1e-9)


RESTORE_ATOL = 1e-12  # restored law vs the original, same data (JSON round trip is exact)


def _drive_adaptive(law, ssm, rng, k0, n, u):
    """n samples with the adaptive model (index 2) active and its Θ changing."""
    out = []
    for k in range(k0, k0 + n):
        p = ssm.params_from_theta(ssm.theta(2), ssm.bias(2))
        ssm.set_params(2, p + 1e-3 * rng.standard_normal(p.size))
        y = ssm.estimates()[0]
        u, info = law.compute(k, 2, ssm, y, np.full((8, 2), 0.1), u)
        assert info["status"] == "solved"
        out.append(u)
        ssm.update(u, y)
    return np.array(out), u


def test_checkpoint_keeps_the_adaptive_forms():
    import json

    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)

    def run(restore_phase: bool):
        rng = np.random.default_rng(4)
        ssm = small_ssm(rng)
        ssm.initialize(np.zeros(2), np.zeros(2))
        law = MPCLaw(s, refresh_tol=0.03)  # Θ moves ~2 % a sample: a refresh every few
        law.prepare(ssm)
        law.reset(np.zeros(2), np.zeros(2))
        _, u = _drive_adaptive(law, ssm, rng, 0, 7, np.zeros(2))  # a form some samples old
        state = json.loads(json.dumps(law.checkpoint()))
        if not restore_phase:  # a checkpoint without the forms (an older one)
            state["source"] = {"n_prev": state["source"]["n_prev"]}
        twin = MPCLaw(s, refresh_tol=0.03)
        twin.prepare(ssm)
        twin.restore(state)
        ss = ssm.checkpoint()
        a, _ = _drive_adaptive(law, ssm, np.random.default_rng(5), 7, 8, u)
        ssm.restore(ss)
        b, _ = _drive_adaptive(twin, ssm, np.random.default_rng(5), 7, 8, u)
        return np.max(np.abs(a - b))

    assert run(True) <= RESTORE_ATOL
    # the check can fail: without the forms the restored law predicts with today's Θ
    assert run(False) > RESTORE_ATOL


def test_rebuild_only_between_samples_and_only_when_theta_moved_past_the_tolerance():
    """finish_sample rebuilds the adaptive model's QP when its Θ moved by more than
    refresh_tol (relative, Frobenius) since its form was made; compute never builds."""
    rng = np.random.default_rng(6)
    ssm = small_ssm(rng)
    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)
    tol = 1e-3
    law = MPCLaw(s, refresh_tol=tol, min_refresh_samples=1)
    law.prepare(ssm)
    u = np.zeros(2)
    ssm.initialize(u, np.zeros(2))
    law.reset(u, np.zeros(2))
    theta0 = ssm.theta(2).copy()
    direction = rng.standard_normal(theta0.shape[0])[:, None] * np.ones((1, 2))
    nm = ssm.Fd.shape[0]
    direction[nm:] = 0.0  # move Θ1 only (Θ2 keeps its block structure)
    direction *= np.linalg.norm(theta0) / np.linalg.norm(direction)
    built_in_compute = 0
    expected = 0
    for k, rel in enumerate([0.2, 0.5, 0.9, 1.5, 1.6, 3.0, 3.2, 2.1, 0.0]):
        ssm.set_theta(2, theta0 + rel * tol * direction)
        before = law.mpc.counters["rebuilds"]
        y = ssm.estimates()[0]
        u, info = law.compute(k, 2, ssm, y, np.full((8, 2), 0.1), u)
        assert info["status"] == "solved"
        built_in_compute += law.mpc.counters["rebuilds"] - before
        ssm.update(u, y)
        made = law.source._snap[2][2].T  # Θ the current form was made from
        moved = np.linalg.norm(ssm.theta(2) - made) / np.linalg.norm(made)
        before = law.mpc.counters["rebuilds"]
        law.finish_sample(ssm, 2)
        rebuilt = law.mpc.counters["rebuilds"] - before
        assert rebuilt == (1 if moved > tol else 0), (k, moved)
        expected += moved > tol
    assert built_in_compute == 0
    assert expected >= 3  # 0 -> 1.5 tol, 1.5 -> 3.0 tol, 3.2 -> 2.1 tol, 2.1 -> 0 tol


def test_refreshes_of_a_fast_adapting_model_are_spaced_by_min_refresh_samples():
    rng = np.random.default_rng(7)
    ssm = small_ssm(rng)
    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)
    law = MPCLaw(s, refresh_tol=1e-6, min_refresh_samples=4)
    law.prepare(ssm)
    u = np.zeros(2)
    ssm.initialize(u, np.zeros(2))
    law.reset(u, np.zeros(2))
    rebuilt_at = []
    for k in range(20):
        p = ssm.params_from_theta(ssm.theta(2), ssm.bias(2))
        ssm.set_params(2, p + 1e-2 * rng.standard_normal(p.size))  # moves every sample
        y = ssm.estimates()[0]
        u, _ = law.compute(k, 2, ssm, y, np.full((8, 2), 0.1), u)
        ssm.update(u, y)
        before = law.mpc.counters["rebuilds"]
        law.finish_sample(ssm, 2)
        if law.mpc.counters["rebuilds"] > before:
            rebuilt_at.append(k)
    assert len(rebuilt_at) >= 4
    assert np.all(np.diff(rebuilt_at) == 4)  # every 4th sample, never closer


def test_a_rebuild_between_samples_sets_the_solver_up_there_too():
    """With setup_ahead (the default) the QP rebuilt in finish_sample has its DAQP
    workspace made there, so the next sample only solves; without, the solve makes it."""
    s = MPCSettings(nu=2, ny=2, P=8, M=3, Lambda=[0.1, 0.1], du_max=[0.5, 0.5],
                    budget_ms=1e3)
    made = {}
    for ahead in (True, False):
        rng = np.random.default_rng(6)
        ssm = small_ssm(rng)
        law = MPCLaw(s, refresh_tol=0.0, min_refresh_samples=1, setup_ahead=ahead)
        law.prepare(ssm)
        ssm.initialize(np.zeros(2), np.zeros(2))
        law.reset(np.zeros(2), np.zeros(2))
        _drive_adaptive(law, ssm, rng, 0, 1, np.zeros(2))
        p = ssm.params_from_theta(ssm.theta(2), ssm.bias(2))
        ssm.set_params(2, p + 1e-3 * rng.standard_normal(p.size))  # Θ moved: stale
        before = law.mpc.counters["rebuilds"]
        law.finish_sample(ssm, 2)
        assert law.mpc.counters["rebuilds"] == before + 1
        made[ahead] = law.mpc._solvers[2][1]._model is not None
    assert made == {True: True, False: False}


SETUP_AHEAD_MOVES_ATOL = 1e-9  # valve %, the two-phase closed loop with/without


def test_solver_set_up_ahead_keeps_the_two_phase_moves():
    """The chapter-6 reactor in closed loop (adaptive model's QP rebuilt between
    samples) moves the same with the solver set up at the rebuild as in the sample."""
    import functools

    import controller.units.two_phase_reactor as tp

    runs = {}
    for ahead in (True, False):
        law = functools.partial(MPCLaw, setup_ahead=ahead)
        orig = tp.MPCLaw
        tp.MPCLaw = law
        try:
            runs[ahead] = tp.run_reactor(tp.ReactorCase())
        finally:
            tp.MPCLaw = orig
    assert runs[True].counters["mpc_rebuilds"] >= 1
    assert not runs[True].fallback.any()
    np.testing.assert_allclose(runs[True].u, runs[False].u, rtol=0,
                               atol=SETUP_AHEAD_MOVES_ATOL)
