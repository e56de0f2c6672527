"""Operator control, the pure part (controller.operator_modes, controller.units.operator):
controller modes, per-variable modes, ramped limits by hand, validation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.interfaces import ControlDecision
from controller.operator_modes import (
    OperatorError,
    OperatorState,
    RampedLimit,
    UnknownVariable,
    VariableCommand,
    VariableSpec,
)
from controller.units.operator import OperatedController

SPECS = (
    VariableSpec("T", "cv", -math.inf, 170.0, 0.0, 170.0, ("auto", "off"), True, True),
    VariableSpec("F", "cv", note="measured only"),
    VariableSpec("V1", "mv", 0.0, 100.0, 0.0, 100.0, ("auto", "manual", "off"), True, True),
    VariableSpec("V2", "mv", 0.0, 100.0, 0.0, 100.0, ("auto", "manual", "off"), True, True),
)


def state() -> OperatorState:
    return OperatorState(SPECS)


def test_a_high_limit_ramps_at_its_rate_by_hand():
    # 100 -> 60 at 20 %/h from t = 1 h: 100, 90, 80, 70, 60, 60 at 1, 1.5, 2, 2.5, 3, 5 h
    r = RampedLimit(100.0, 60.0, 1.0, 20.0)
    assert [r.at(t) for t in (0.0, 1.0, 1.5, 2.0, 2.5, 3.0, 5.0)] == \
        [100.0, 100.0, 90.0, 80.0, 70.0, 60.0, 60.0]
    # a low limit raised 10 -> 16 at 4 per h: 12 after half an hour
    assert RampedLimit(10.0, 16.0, 0.0, 4.0).at(0.5) == 12.0
    assert RampedLimit(10.0, 16.0, 0.0).at(0.0) == 16.0  # no rate: at once


def test_a_tightened_limit_starts_where_it_would_bind():
    # the valve's own high limit is 100; the value 95: the new limit 60 starts at 95
    s = state().command("V1", VariableCommand(hi=60.0, ramp_per_h=20.0), 1.0, current=95.0)
    assert [s.effective_limits("V1", t)[1] for t in (1.0, 1.5, 2.0, 2.75, 4.0)] == \
        [95.0, 85.0, 75.0, 60.0, 60.0]
    # relaxed half way (85 at 1.5 h) to 90: from where it is, at the same rate
    s = s.command("V1", VariableCommand(hi=90.0), 1.5, current=84.0)
    assert [s.effective_limits("V1", t)[1] for t in (1.5, 1.75, 2.0, 3.0)] == \
        [85.0, 90.0, 90.0, 90.0]
    # tightened with the value inside the new limit already: at once
    s = s.command("V1", VariableCommand(hi=70.0), 2.0, current=40.0)
    assert s.effective_limits("V1", 2.0) == (0.0, 70.0)
    # relaxed from a limit in force: ramps up from it
    s = s.command("V1", VariableCommand(hi=80.0, ramp_per_h=4.0), 2.0, current=40.0)
    assert s.effective_limits("V1", 3.0) == (0.0, 74.0)


def test_mv_modes_manual_holds_the_value_off_the_last_one():
    s = state().command("V1", VariableCommand(mode="manual", value=42.0), 0.0, current=30.0)
    assert (s.control("V1").mode, s.control("V1").value) == ("manual", 42.0)
    s = s.command("V1", VariableCommand(mode="manual"), 0.0, current=30.0)
    assert s.control("V1").value == 42.0  # manual again: the operator's value stays
    s = s.command("V2", VariableCommand(mode="off"), 0.0, current=55.5)
    assert (s.control("V2").mode, s.control("V2").value) == ("off", 55.5)
    s = s.command("V1", VariableCommand(mode="auto"), 0.0, current=42.0)
    assert (s.control("V1").mode, s.control("V1").value) == ("auto", None)
    # manual without a value holds the current one
    s = s.command("V1", VariableCommand(mode="manual"), 0.0, current=12.5)
    assert s.control("V1").value == 12.5
    assert [s.variable_mode(n) for n in ("T", "F", "V1", "V2")] == ["auto", None, "manual",
                                                                     "off"]


def test_controller_mode_transitions():
    s = state()
    assert s.mode == "on"
    for m in ("warm", "off", "on", "off", "warm", "on"):
        s = s.with_mode(m)
        assert s.mode == m
    with pytest.raises(OperatorError, match="mode"):
        s.with_mode("auto")


@pytest.mark.parametrize("name, cmd, match", [
    ("V1", {"lo": 70.0, "hi": 60.0}, "lo 70 above hi 60"),
    ("V1", {"hi": 120.0}, "outside V1's engineering range"),
    ("V1", {"mode": "manual", "value": -1.0}, "outside"),
    ("V1", {"value": 5.0}, "needs mode 'manual'"),
    ("T", {"mode": "manual"}, "cannot be 'manual'"),
    ("T", {"hi": 180.0}, "outside"),
    ("F", {"mode": "off"}, "measured only"),
    ("F", {"lo": 1.0}, "no operator limits"),
    ("V1", {"ramp_per_h": 0.0}, "ramp_per_h"),
])
def test_bad_commands_are_refused_with_a_message(name, cmd, match):
    with pytest.raises(OperatorError, match=match) as err:
        state().command(name, VariableCommand.from_args(cmd), 0.0, current=50.0)
    assert err.value.status == 422


@pytest.mark.parametrize("args, match", [
    ({}, "nothing to change"), ({"mode": "on"}, "mode: expected"),
    ({"lo": float("nan")}, "finite"), ({"hi": float("inf")}, "finite"),
    ({"value": True}, "expected a number"), ({"value": "1"}, "expected a number"),
    ({"speed": 1.0}, "unknown field"), ([], "expected an object"),
])
def test_malformed_command_arguments(args, match):
    with pytest.raises(OperatorError, match=match):
        VariableCommand.from_args(args)


def test_unknown_variable_is_a_404():
    with pytest.raises(UnknownVariable) as err:
        state().command("XMV99", VariableCommand(mode="auto"), 0.0, None)
    assert err.value.status == 404


def test_checkpoint_round_trip_keeps_ramps_and_modes():
    s = (state().with_mode("warm")
         .command("V1", VariableCommand(mode="manual", value=42.0), 0.0, 30.0)
         .command("T", VariableCommand(hi=150.0, ramp_per_h=10.0), 1.0, 165.0))
    back = state().restore(s.checkpoint())
    assert back.mode == "warm" and back.control("V1") == s.control("V1")
    assert back.effective_limits("T", 2.0) == (-math.inf, 155.0), back.control("T")
    with pytest.raises(ValueError):
        state().restore({"mode": "on", "variables": [{"name": "nope"}]})


class Recorder:
    """A controller that asks for u = 10 + k and records what it is told."""

    def __init__(self):
        self.tracked, self.aligned, self.views, self.steps = [], [], [], 0

    def step(self, k, t, y, reference):
        self.steps += 1
        return ControlDecision(u=np.array([10.0 + k, 20.0 + k]))

    def set_operator(self, view):
        self.views.append(view)

    def applied(self, u):
        self.tracked.append(np.asarray(u).copy())

    def align(self, u):
        self.aligned.append(np.asarray(u).copy())

    def checkpoint(self):
        return {}

    def restore(self, state):
        pass


def operated():
    inner = Recorder()
    op = OperatedController(inner, SPECS, ("T", "F"), ("V1", "V2"), time_unit_s=3600.0)
    return inner, op


def test_off_computes_nothing_warm_writes_nothing_and_tracks_the_plant():
    inner, op = operated()
    applied = np.array([1.0, 2.0])
    op.set_state(op.state.with_mode("off"))
    assert op.step(0, 0.0, [0, 0], None, applied) is None and inner.steps == 0
    op.set_state(op.state.with_mode("warm"))
    dec = op.step(1, 0.01, [0, 0], None, applied)
    # leaving off takes over the plant's move; warm reports the computed move, the
    # applied one stays and the controller is told so
    assert len(inner.aligned) == 1 and np.array_equal(inner.aligned[0], applied)
    assert np.array_equal(dec.u, applied) and np.array_equal(dec.extra["computed_u"], [11, 21])
    assert np.array_equal(inner.tracked[-1], applied) and not op.writes
    op.set_state(op.state.with_mode("on"))
    dec = op.step(2, 0.02, [0, 0], None, applied)
    assert np.array_equal(dec.u, [12.0, 22.0]) and op.writes
    assert len(inner.aligned) == 1  # warm -> on needs no take-over: it tracked


def test_held_and_limited_mvs_are_written_exactly_and_the_controller_told():
    inner, op = operated()
    st = op.state.command("V1", VariableCommand(mode="manual", value=33.3), 0.0, 10.0)
    st = st.command("V2", VariableCommand(hi=21.0), 0.0, 20.0)
    op.set_state(st)
    dec = op.step(5, 0.0, [0, 0], None, np.array([10.0, 20.0]))
    assert np.array_equal(dec.u, [33.3, 21.0])
    assert np.array_equal(inner.tracked[-1], [33.3, 21.0])
    v = inner.views[-1]
    assert v.mv_mode == ("manual", "auto") and v.mv_held.tolist() == [True, False]
    assert v.mv_hi[1] == 21.0 and v.cv_on.tolist() == [True, True]


def test_the_status_text_view_shows_the_mode_and_held_variables():
    from services.cli.operator import STATUS_WIDTH, status_lines

    var = {"tag": "", "description": "", "unit": "%", "value": 30.0, "target": None,
           "lo": 0.0, "hi": 100.0, "at_limit": None}
    st = {"unit": "te", "plant": "te", "sample": 5, "process_time_s": 180.0,
          "budget_ms": 18.0, "deadline_misses": 0, "fallback_moves": 0,
          "controller_mode": "warm", "controller_status": "solved", "alarms": [],
          "variables": [{**var, "name": "XMV3", "kind": "mv", "mode": "manual",
                         "target": 30.0},
                        {**var, "name": "XMV4", "kind": "mv", "mode": "off"},
                        {**var, "name": "XMV5", "kind": "mv", "mode": "auto"}]}
    lines = status_lines(st)
    assert lines[1].startswith("controller WARM solved")
    flags = {ln.split()[0]: ln.split()[-1] for ln in lines if ln.startswith("XMV")}
    assert flags == {"XMV3": "MAN", "XMV4": "OFF", "XMV5": "%"}
    assert all(len(ln) <= STATUS_WIDTH for ln in lines)


def test_an_accepted_action_goes_to_the_nodes_event_log_where_it_has_one():
    from services.nodes.operator_commands import record_action

    class Node:
        def __init__(self):
            self.calls = []

        def record_action(self, what, detail, identity):
            self.calls.append((what, detail, identity))
            return "503" if detail.get("mode") == "off" else None

    node = Node()
    assert record_action(node, {"action": "mode", "mode": "warm", "previous": "on"},
                         "operator") is None
    assert node.calls == [("mode", {"mode": "warm", "previous": "on"}, "operator")]
    # the log's refusal is the answer; without an identity the action is anonymous
    assert record_action(node, {"action": "mode", "mode": "off"}, None) == "503"
    assert node.calls[-1][2] == "anonymous"
    assert record_action(object(), {"action": "mode", "mode": "on"}, "x") is None  # no log
