"""Bumpless resume of the multiple-model controller from a stale checkpoint.

A restarted controller node restores a checkpoint that may be many samples old and
then takes over the move the plant holds (``MultiModelController.align``). The loops
here run the unit controllers of :mod:`services.registry` on their plants sample by
sample (no Zenoh): checkpoint, run on, restore the old checkpoint, align to the move
now held, and compare the moves that follow with the held move itself (the
independent reference) and with the size of the moves before the restart.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

from controller.hinf import DiscreteController, equilibrium_state
from controller.units.config import build_plant, grade_setpoints
from services.nodes.plant import ODERunner
from services.registry import build_controller, get_unit

FIRST_MOVE_TOL = 1e-9  # the first move after the take-over is the held move (round-off)
KICK_FACTOR = 2.0  # later moves: at most this many times the largest move before the kill
N_BEFORE = 20  # samples before the (stale) checkpoint
N_AFTER_MOVES = 12  # moves checked after the restart


class _Loop:
    """A unit controller on its plant, sampled by hand."""

    def __init__(self, unit: str, controller: str | None = None):
        cfg = get_unit(unit)
        if controller is not None:
            cfg = replace(cfg, controller=controller)
        self.cfg = cfg
        plant = build_plant(cfg)
        grades = grade_setpoints(cfg, plant)
        self.ctl = build_controller(cfg, plant, grades=grades)
        self.run = ODERunner(cfg, plant)
        target = next(g for g in grades if g != cfg.initial_grade)  # a grade transition
        rows = getattr(self.ctl, "horizon", 1)
        self.reference = np.tile(np.asarray(grades[target]["setpoints"], float), (rows, 1))
        self.moves: list[np.ndarray] = []
        self.k = 0

    def sample(self):
        dec = self.ctl.step(self.k, self.k * self.cfg.sample_period_s, self.run.y(),
                            self.reference)
        self.run.advance(dec.u, self.cfg.sample_period_s)
        self.moves.append(np.asarray(dec.u, float).copy())
        self.k += 1
        return dec

    def stale_restart(self, n_lost: int, align: bool = True) -> np.ndarray:
        """Checkpoint, run ``n_lost`` samples, restore the checkpoint, take over the held
        move; returns the held move."""
        for _ in range(N_BEFORE):
            self.sample()
        stale = json.loads(json.dumps(self.ctl.checkpoint()))  # as stored on disk
        for _ in range(n_lost):
            self.sample()
        held = self.moves[-1].copy()
        self.ctl.restore(stale)
        if align:
            self.ctl.align(held)
        return held

    def largest_recent_step(self, n: int = 20) -> np.ndarray:
        return np.max(np.abs(np.diff(np.array(self.moves[-n:]), axis=0)), axis=0)


@pytest.mark.parametrize("n_lost", [30, 60])
def test_hinf_resumes_from_the_held_move_without_a_kick(n_lost):
    loop = _Loop("cstr", "hinf")
    held = loop.stale_restart(n_lost)
    normal = loop.largest_recent_step()
    first = loop.sample()
    assert not first.fallback
    np.testing.assert_allclose(first.u, held, rtol=0, atol=FIRST_MOVE_TOL)
    for _ in range(N_AFTER_MOVES):
        loop.sample()
    after = np.abs(np.diff(np.array(loop.moves[-N_AFTER_MOVES - 2:]), axis=0))
    assert np.all(after <= KICK_FACTOR * normal), (after.ravel(), normal)


@pytest.mark.parametrize("change_at", [1, 3])
def test_hinf_controller_change_soon_after_the_take_over_does_not_kick(change_at):
    """A new controller (switch or re-synthesis) before a full error history exists."""
    loop = _Loop("cstr", "hinf")
    held = loop.stale_restart(30)
    normal = loop.largest_recent_step()
    for _ in range(change_at):
        loop.sample()
    law = loop.ctl.law
    changes = law.n_controller_changes
    law._designs.pop(loop.ctl.active)  # forces a fresh synthesis: a new controller object
    for _ in range(N_AFTER_MOVES):
        loop.sample()
    assert law.n_controller_changes > changes
    moves = np.array([held, *loop.moves[-N_AFTER_MOVES - change_at:]])
    after = np.abs(np.diff(moves, axis=0))
    assert np.all(after <= KICK_FACTOR * normal), (after.ravel(), normal)


def test_hinf_stale_restart_without_align_bumps():
    """The gap this fixes: the stale checkpoint's controller state alone moves far."""
    loop = _Loop("cstr", "hinf")
    held = loop.stale_restart(30, align=False)
    normal = loop.largest_recent_step()
    moves = [loop.sample().u for _ in range(3)]
    assert np.max(np.abs(np.array(moves) - held)) > 5 * normal


@pytest.mark.parametrize("n_lost", [30, 60])
def test_mrac_resumes_from_the_held_move(n_lost):
    loop = _Loop("cstr", "mrac")
    held = loop.stale_restart(n_lost)
    first = loop.sample()
    assert not first.fallback
    np.testing.assert_allclose(first.u, held, rtol=0, atol=FIRST_MOVE_TOL)


def test_mrac_reset_alone_is_not_bumpless():
    """Filters at steady state (a plain reset) do not give the held move back."""
    loop = _Loop("cstr", "mrac")
    held = loop.stale_restart(30, align=False)
    loop.ctl.initialized = False  # re-initialize at (u_last, y) without the take-over
    loop.ctl.u_last = held.copy()
    normal = loop.largest_recent_step()
    first = loop.sample()
    assert np.max(np.abs(first.u - held)) > 5 * normal.max()


def test_mpc_resumes_within_its_move_limit():
    """Delta-u MPC: the first move after the take-over is within du_max of the held one."""
    loop = _Loop("two_phase_reactor")
    held = loop.stale_restart(30)
    du_max = np.asarray(loop.ctl.law.mpc.settings.du_max, float)
    first = loop.sample()
    assert not first.fallback
    assert np.all(np.abs(first.u - held) <= du_max + FIRST_MOVE_TOL), (first.u, held)


def test_align_validates_the_move():
    loop = _Loop("cstr", "hinf")
    with pytest.raises(ValueError, match="u:"):
        loop.ctl.align([1.0, 2.0])
    with pytest.raises(ValueError, match="u:"):
        loop.ctl.align([np.nan])


def _pi_with_lag(dt=0.1):
    """States (integrator of e, first-order lag 1/(s+2) of e); u = x_int + 3 x_lag + 0.5 e."""
    Ac = np.array([[0.0, 0.0], [0.0, -2.0]])
    import scipy.linalg
    A = scipy.linalg.expm(Ac * dt)
    B = np.array([[dt], [(1 - np.exp(-2 * dt)) / 2]])
    return DiscreteController(A, B, np.array([[1.0, 3.0]]), np.array([[0.5]]), dt)


def test_equilibrium_state_constant_error_settles_all_but_the_integrator():
    ctrl = _pi_with_lag()
    e = 0.7
    a, b = equilibrium_state(ctrl, e)
    # closed forms: the lag at its steady state e/2, the integrator at 0 ramping by dt*e
    np.testing.assert_allclose(a, [0.0, e / 2], atol=1e-12)
    np.testing.assert_allclose(b, [ctrl.dt * e, 0.0], atol=1e-12)
    x = a.copy()
    for _ in range(20):  # simulated: the lag stays put
        x = ctrl.A @ x + ctrl.B[:, 0] * e
    assert x[1] == pytest.approx(e / 2, abs=1e-12)


def test_equilibrium_state_on_a_ramp_matches_simulation():
    ctrl = _pi_with_lag()
    e, s = 0.7, -0.05
    a, b = equilibrium_state(ctrl, e, s)
    x = np.zeros(2)
    x_long = np.zeros(2)
    # independent reference: a long simulation of the ramp, whose lag has settled
    n = 400
    for k in range(-n, 0):
        x_long = ctrl.A @ x_long + ctrl.B[:, 0] * (e + k * s)
    x = a
    assert x[1] == pytest.approx(x_long[1], abs=1e-9)
    x_next = ctrl.A @ x + ctrl.B[:, 0] * e
    np.testing.assert_allclose(x_next - x, b, atol=1e-9)


@pytest.mark.parametrize("law", ["hinf", "mrac"])
def test_a_take_over_survives_a_checkpoint_before_the_next_sample(law):
    loop = _Loop("cstr", law)
    held = loop.stale_restart(30)
    state = json.loads(json.dumps(loop.ctl.checkpoint()))
    other = _Loop("cstr", law)
    other.run = loop.run  # the same plant, now driven by the restored controller
    other.k = loop.k
    other.ctl.restore(state)
    first = other.sample()
    np.testing.assert_allclose(first.u, held, rtol=0, atol=FIRST_MOVE_TOL)
