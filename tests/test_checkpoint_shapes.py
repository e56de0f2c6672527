"""A checkpoint with an entry of the wrong shape: the restore either refuses it with one
of the errors the controller node turns into "the checkpoint does not fit"
(:data:`services.nodes.controller.CHECKPOINT_MISFIT`, ``error:`` at start), or takes it
and what was restored goes on working: the controller's next sample gives finite moves,
the transition manager's next samples run. Never an error the node does not expect,
never a piece that restores and then fails every sample.

Every mapping entry of the checkpoint, at any depth (and in lists of mappings), is
replaced in turn by a value of another JSON type, a negative number or a boolean: the
TE service controller of each strategy after a few samples at mode 0, the unit
controllers of the other units, and the transition manager with a transition running
and one queued. The whole node's start on such a checkpoint:
``tests/test_store_integrity.py``.
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from controller.units.te.service import TEServiceController
from controller.units.te.structure import te_mv_names
from services.nodes.controller import CHECKPOINT_MISFIT
from services.registry import build_controller, build_plant, get_unit, grade_setpoints
from services.transitions import TransitionManager

#: The values each entry is replaced by.
WRONG = ("x", [1, 2], {"a": 1}, None, -1.5, True)
SAMPLE_S = 36.0


def _paths(obj, prefix=()):
    """The key paths of every mapping entry of ``obj`` (also in lists), depth first."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield (*prefix, k)
            yield from _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            if isinstance(v, dict):
                yield from _paths(v, (*prefix, i))


def _copy(state):
    return json.loads(json.dumps(state))


def _damaged(good: dict, path, value) -> dict:
    state = _copy(good)
    node = state
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return state


def _fuzz(good: dict, restore, use) -> tuple[int, int, list]:
    """Restore every damaged variant of ``good`` with ``restore`` (then ``good`` again)
    and ``use`` what a taken one restored. Returns (refused, taken, failures)."""
    refused = taken = 0
    failures = []
    for path in _paths(good):
        for value in WRONG:
            try:
                restore(_damaged(good, path, value))
            except CHECKPOINT_MISFIT:
                refused += 1
                restore(_copy(good))
                continue
            except Exception as exc:  # what the node would not turn into a store error
                failures.append(("restore", path, value, repr(exc)))
                restore(_copy(good))
                continue
            taken += 1
            try:
                use()
            except Exception as exc:
                failures.append(("use", path, value, repr(exc)))
            restore(_copy(good))
    return refused, taken, failures


def _steps_finite(ctl, k, t, y, reference):
    def use():
        u = np.asarray(ctl.step(k, t, y, reference).u, dtype=float)
        if not np.all(np.isfinite(u)):
            raise AssertionError("moves not finite")
    return use


@pytest.mark.parametrize("strategy", ["ssmpc", "fixed", "pi", "decentralized"])
def test_a_damaged_te_controller_entry_is_refused_or_restores_one_that_steps(strategy):
    cfg = replace(get_unit("te"), strategy=strategy)
    g = grade_setpoints(cfg, None)
    ctl = TEServiceController(strategy, "mode0", te_mv_names(cfg), SAMPLE_S / 3600.0,
                              g["mode0"]["mv"])
    y = np.asarray(g["mode0"]["setpoints"], dtype=float)
    for k in range(5):
        ctl.step(k, k * SAMPLE_S, y, None)
    refused, taken, failures = _fuzz(_copy(ctl.checkpoint()), ctl.restore,
                                     _steps_finite(ctl, 5, 5 * SAMPLE_S, y, None))
    assert not failures, failures[:10]
    assert refused > 0 and taken > 0  # both policies are exercised


@pytest.mark.parametrize("unit, controller", [
    ("cstr", "pi"), ("cstr", "hold"), ("cstr", "hinf"), ("cstr", "mrac"),
    ("bioreactor", "hinf"), ("two_phase_reactor", "ssmpc"), ("two_phase_reactor", "pi"),
    ("two_phase_reactor", "hold")])
def test_a_damaged_unit_controller_entry_is_refused_or_restores_one_that_steps(
        unit, controller):
    cfg = replace(get_unit(unit), controller=controller)
    plant = build_plant(cfg)
    grades = grade_setpoints(cfg, plant)
    ctl = build_controller(cfg, plant)
    y = np.asarray(grades[cfg.initial_grade]["setpoints"], dtype=float)
    dt = cfg.sample_period_s
    for k in range(5):
        ctl.step(k, k * dt, y, y)
    refused, taken, failures = _fuzz(_copy(ctl.checkpoint()), ctl.restore,
                                     _steps_finite(ctl, 5, 5 * dt, y, y))
    assert not failures, failures[:10]
    assert refused > 0


def _transitions():
    return TransitionManager("u", {"A": [1.0, 2.0], "B": [3.0, 1.0]}, [1.0, 1.0], "A",
                             sample_period_s=1.0, default_duration_s=10.0, max_queued=3)


def test_a_damaged_transition_entry_is_refused_or_restores_transitions_that_run():
    tm = _transitions()
    tm.request("B", 0.0)
    tm.update(0.0, [1.0, 2.0])
    tm.update(1.0, [1.5, 2.0])
    tm.request("A", 2.0, queue=True)
    good = _copy(tm.checkpoint())
    assert good["active"]["state"] == "running" and len(good["queued"]) == 1
    box = {}

    def restore(state):
        box["tm"] = _transitions()
        box["tm"].restore(state)

    def use():
        t = box["tm"]
        for k in range(40):  # to the end of the running one and through the queued one
            t.update(2.0 + k, [2.0, 1.5])
            t.reference_at(2.0 + k, 3)
            for tr in ([t.active] if t.active else []) + t.queued:
                json.dumps(tr.view(2.0 + k, 1.0))

    refused, taken, failures = _fuzz(good, restore, use)
    assert not failures, failures[:10]
    assert refused > 0 and taken > 0


@pytest.mark.parametrize("end", ["aborted while waiting", "failed while waiting",
                                 "aborted", "settled"])
def test_transitions_that_ended_restore_as_they_were(end):
    """A checkpoint whose transition ended, before or after it started, restores as it
    was written (the checks above refuse damaged records, not these)."""
    tm = _transitions()
    tr = tm.request("B", 0.0)
    if end == "aborted while waiting":
        tm.abort(tr.id, 0.5)
    elif end == "failed while waiting":
        tm.fail(0.5, "plant shut down")
    else:
        tm.update(0.0, [1.0, 2.0])
        if end == "aborted":
            tm.abort(tr.id, 1.0)
        else:
            for k in range(1, 40):
                tm.update(float(k), [3.0, 1.0])
    assert tm.active.state == end.split()[0]
    state = _copy(tm.checkpoint())
    again = _transitions()
    again.restore(state)
    assert again.checkpoint() == state
    assert again.active.state == end.split()[0]
