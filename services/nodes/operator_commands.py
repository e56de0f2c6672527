"""The controller node's operator commands: ``cmd/mode`` and ``cmd/variable`` (REST
``PUT .../mode`` and ``PATCH .../variables/{name}``).

``mode``: ``args = {"mode": "off"|"warm"|"on"}``. ``variable``: ``args = {"name": ...,
"mode"?, "value"?, "lo"?, "hi"?, "ramp_per_h"?}``
(:class:`controller.operator_modes.VariableCommand`). Both may carry the
identity that made the action as ``"identity"`` (at most 128 printable characters).

A command is validated against the unit's variables (unknown variable 404, anything
else that cannot be applied 422 with a message; ``off`` or ``warm`` while a transition
is under way 409: nobody would move the plant along it, abort it first), takes
effect at the next sample (:class:`controller.units.operator.OperatedController`
reads its state once per sample) and is committed with a checkpoint before it is
acknowledged; a store that cannot commit puts the previous settings back and answers
503. Every accepted action goes to :func:`record_action` and the recording's event
log.
"""

from __future__ import annotations

import logging
import math

from controller.operator_modes import OperatorError, VariableCommand
from services.io.messages import Reply

__all__ = ["handle", "publish_mode", "record_action", "variable_view"]

log = logging.getLogger("ssmpc.controller")

#: Longest identity stored with an action, characters.
IDENTITY_MAX = 128


def record_action(node, action: dict, identity: str | None):
    """The one place an accepted operator action goes to the durable event log.

    The node's ``record_action(what, detail, identity)`` where it has one (it commits
    the event before the action is acknowledged and answers a :class:`Reply` 503 when
    the store cannot); until then a no-op. ``action``: ``{"action": "mode"|"variable",
    ...the command...}``.

    Returns
    -------
    Reply or None
        The reply to send instead of the acknowledgement, None once recorded.
    """
    recorder = getattr(node, "record_action", None)
    if not callable(recorder):
        return None
    detail = {k: v for k, v in action.items() if k != "action"}
    return recorder(action["action"], detail, identity or "anonymous")


class Conflict(OperatorError):
    """A command the unit's state refuses now (409)."""

    status = 409


def publish_mode(node) -> None:
    """Tell the plant link the controller mode, where it reports one (the OPC UA link
    writes it to the DCS's ``Status/ControllerMode`` with its heartbeat)."""
    link = getattr(node, "plant_link", None)
    if link is not None and hasattr(link, "controller_mode"):
        link.controller_mode = node.operated.mode


def _identity(args: dict) -> str | None:
    who = args.get("identity")
    if who is None:
        return None
    if not (isinstance(who, str) and 0 < len(who) <= IDENTITY_MAX and who.isprintable()):
        raise OperatorError(f"identity: expected 1..{IDENTITY_MAX} printable characters")
    return who


def variable_view(node, name: str) -> dict:
    """One entry of the status's ``variables`` (call with the node's lock held)."""
    for v in node._variables_view():
        if v["name"] == name:
            return v
    raise KeyError(name)


def _current(node, name: str) -> float | None:
    """The variable's value now: a CV's measurement, an MV's applied value."""
    info = node.info
    if name in info.mv_names:
        x = float(node.u_last[info.mv_names.index(name)])
    elif name in info.cv_names:
        x = float(node.y[info.cv_names.index(name)])
    else:
        return None
    return x if math.isfinite(x) else None


def handle(node, action: str, args: dict) -> Reply:
    """Apply one operator command on ``node`` (a :class:`~services.nodes.controller.
    ControllerNode`); the reply's data: ``mode`` the controller mode, ``variable`` the
    variable's status entry."""
    try:
        by = _identity(args)
        op = node.operated
        with node._lock:
            old = op.state
            if action == "mode":
                unknown = sorted(set(args) - {"mode", "identity"})
                if unknown:
                    raise OperatorError(f"{unknown[0]}: unknown field (known: mode)")
                mode = args.get("mode")
                new = old.with_mode(mode if isinstance(mode, str) else "")
                tm = node.tm
                under_way = ([tm.active] if tm.active is not None and not tm.active.terminal
                             else []) + list(tm.queued)
                if new.mode != "on" and under_way:
                    raise Conflict(f"mode: transition {under_way[0].id} to "
                                   f"{under_way[0].grade} is {under_way[0].state}; abort "
                                   f"it before the controller goes {new.mode}")
                record = {"action": "mode", "mode": new.mode, "previous": old.mode}
            else:
                name = args.get("name")
                if not isinstance(name, str):
                    raise OperatorError("name: expected a variable name")
                fields = {k: v for k, v in args.items() if k not in ("name", "identity")}
                cmd = VariableCommand.from_args(fields)
                new = old.command(name, cmd, node.t / 3600.0, _current(node, name))
                record = {"action": "variable", "name": name,
                          **{k: v for k, v in fields.items() if v is not None}}
            op.set_state(new)
    except OperatorError as exc:
        return Reply(exc.status, error=str(exc))
    before = node.store_error
    node.checkpoint(wait=True)  # committed before it is acknowledged
    if node.store_error is not before:  # this checkpoint failed (a new reason)
        with node._lock:
            if op.state is new:
                op.set_state(old)
        return Reply(503, error=f"store: cannot commit; the {action} command was not "
                                f"applied ({node.store_error})")
    node._store_ok()
    refused = record_action(node, record, by)
    if refused is not None:  # the event log cannot commit it: not applied either
        with node._lock:
            if op.state is new:
                op.set_state(old)
        node.checkpoint(wait=True)  # the old settings on disk again (as far as it can)
        return refused
    publish_mode(node)
    text = (f"operator: mode {old.mode} -> {new.mode}" if action == "mode" else
            "operator: " + " ".join(f"{k}={v}" for k, v in record.items()
                                    if k != "action"))
    if by:
        text += f" (by {by})"
    log.info("%s", text)  # the recording's event log has it from record_action
    with node._lock:
        if action == "mode":
            return Reply(200, {"unit": node.cfg.unit, "mode": new.mode,
                               "previous": old.mode})
        return Reply(200, variable_view(node, record["name"]))
