"""Transition state machine, first-order reference, progress, ISE, ETA (closed forms)."""

import math

import numpy as np
import pytest

from services.transitions import ConflictError, TransitionManager, UnknownTransition

TS = 0.1
GRADES = {"A": [1.0, 10.0], "B": [2.0, 10.0]}


def _tm(**kw):
    args = dict(unit="u", grades=GRADES, scales=[1.0, 5.0], initial_grade="A",
                sample_period_s=TS, default_duration_s=4.0, settle_tolerance=0.02,
                settle_samples=3)
    args.update(kw)
    return TransitionManager(**args)


def test_reference_is_first_order_reaching_98_percent_at_duration():
    tm = _tm()
    tr = tm.request("B", t=0.0)
    tm.update(0.0, [1.0, 10.0])  # pending -> running at t0 = 0
    assert tr.state == "running"
    tau = 4.0 / 4
    for t in (0.0, 0.5, 1.0, 4.0):
        expected = 2.0 + (1.0 - 2.0) * math.exp(-t / tau)
        assert tm.reference_at(t)[0, 0] == pytest.approx(expected, rel=1e-12)
        assert tm.reference_at(t)[0, 1] == 10.0
    assert (tm.reference_at(4.0)[0, 0] - 1.0) / (2.0 - 1.0) == pytest.approx(1 - math.exp(-4))
    horizon = tm.reference_at(1.0, horizon=3)
    assert horizon.shape == (3, 2)
    assert horizon[2, 0] == pytest.approx(2.0 - math.exp(-(1.0 + 2 * TS) / tau))


def test_settles_after_duration_when_in_band_and_records_ise():
    tm = _tm()
    tr = tm.request("B", t=0.0)
    states = []
    k = 0
    while not tr.terminal and k < 200:
        t = k * TS
        y = tm.reference_at(t)[0] + np.array([0.01, 0.0])  # constant error 0.01 on CV 0
        states += [s for _, s in tm.update(t, y)]
        k += 1
    assert states == ["running", "settled"]
    assert tr.progress == 1.0 and tm.grade == "B"
    assert tr.ended_t >= 4.0
    # ISE = sum (0.01 / scale)^2 * Ts over the samples
    assert tr.ise == pytest.approx(tr.samples * 0.01 ** 2 * TS, rel=1e-9)
    np.testing.assert_allclose(tm.reference_at(100.0)[0], GRADES["B"])


def test_conflict_unknown_grade_and_bad_duration():
    tm = _tm()
    tm.request("B", t=0.0)
    with pytest.raises(ConflictError):
        tm.request("A", t=0.1)
    tm2 = _tm()
    with pytest.raises(UnknownTransition, match="grade"):
        tm2.request("Z", t=0.0)
    with pytest.raises(ValueError, match="duration"):
        tm2.request("B", t=0.0, duration_s=-1.0)


def test_abort_holds_the_set_points_of_that_moment():
    tm = _tm()
    tr = tm.request("B", t=0.0)
    tm.update(0.0, [1.0, 10.0])
    r_mid = tm.reference_at(1.0)[0].copy()
    tm.abort(tr.id, 1.0)
    assert tr.state == "aborted" and tm.grade is None
    np.testing.assert_allclose(tm.reference_at(50.0)[0], r_mid)
    assert tr.eta_s(2.0) is None
    tm.request("A", t=2.0)  # a new one is allowed after the abort
    with pytest.raises(UnknownTransition):
        tm.abort("nope", 2.0)


def test_progress_and_eta():
    tm = _tm()
    tr = tm.request("B", t=0.0)
    tm.update(0.0, [1.0, 10.0])
    tm.update(1.0, [1.25, 10.0])
    assert tr.progress == pytest.approx(0.25)
    assert tr.eta_s(1.0) == pytest.approx(3.0)
    view = tr.view(1.0, speed=10.0)
    assert view["eta_wall_s"] == pytest.approx(0.3)


def test_times_out_to_failed():
    tm = _tm(timeout_factor=2.0)
    tr = tm.request("B", t=0.0)
    t, k = 0.0, 0
    while not tr.terminal:
        t = k * TS
        tm.update(t, [1.0, 10.0])  # output never moves
        k += 1
    assert tr.state == "failed" and t > 8.0


def test_checkpoint_restore_resumes_the_running_transition():
    tm = _tm()
    tr = tm.request("B", t=0.0)
    tm.update(0.0, [1.0, 10.0])
    tm.update(0.1, [1.05, 10.0])
    cp = tm.checkpoint()
    tm2 = _tm()
    tm2.restore(cp)
    assert tm2.active.id == tr.id and tm2.active.state == "running"
    np.testing.assert_allclose(tm2.reference_at(0.7), tm.reference_at(0.7))


def test_queued_transition_starts_when_the_first_ends():
    tm = _tm()
    first = tm.request("B", t=0.0)
    second = tm.request("A", t=0.0, queue=True)
    assert second.state == "pending" and second.detail == "queued"
    assert tm.find(second.id) is second
    states = []
    k = 0
    while not second.terminal and k < 1000:
        t = k * TS
        y = tm.reference_at(t)[0]  # perfect tracking
        states += [(tr.id, s) for tr, s in tm.update(t, y)]
        k += 1
    assert states == [(first.id, "running"), (first.id, "settled"), (second.id, "running"),
                      (second.id, "settled")]
    assert second.from_grade == "B" and tm.grade == "A"
    assert second.started_t >= first.ended_t


def test_aborting_a_queued_transition_removes_it():
    tm = _tm()
    tm.request("B", t=0.0)
    q = tm.request("A", t=0.0, queue=True)
    tm.abort(q.id, 0.5)
    assert q.state == "aborted" and tm.queued == []
    assert tm.active.state == "pending"  # the first one is untouched
    cp = tm.checkpoint()
    tm2 = _tm()
    tm2.restore(cp)
    assert tm2.queued == [] and tm2.active.id == tm.active.id
