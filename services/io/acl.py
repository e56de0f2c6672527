"""The access-control list of the ssmpc router: what each identity may do, by key.

Zenoh 1.x access control (the router's ``access_control`` block: ``rules``,
``subjects``, ``policies``, ``default_permission``) filters every message a router
receives from a session (``ingress``) or sends to it (``egress``), by message kind
and key expression, for the subject the session authenticated as (the user names
of :mod:`services.io.mesh_auth`). Everything not allowed here is denied. A path
from one node to another is allowed on both ends: the sender's ingress and the
receiver's egress.

=============  ========================================================================
identity       may (``<u>`` any unit)
=============  ========================================================================
plant          put ``ssmpc/<u>/meas``; receive ``ssmpc/<u>/mv``; serve
               ``ssmpc/<u>/plant/cmd/**``; hold ``ssmpc/<u>/alive/plant``; follow the
               controller's liveliness
controller     put ``ssmpc/<u>/mv`` and ``ssmpc/<u>/status``; receive
               ``ssmpc/<u>/meas``; serve ``ssmpc/<u>/cmd/**``; hold
               ``ssmpc/<u>/alive/controller``; follow the plant's liveliness
api, cli       query ``ssmpc/<u>/cmd/**`` and ``ssmpc/<u>/plant/cmd/**``; follow every
               liveliness token and the status
=============  ========================================================================

So a session of another identity cannot move a plant, feed a controller
measurements, command either node, or hold a plant's or controller's liveliness
token (it cannot impersonate a unit to the api). A session that did not
authenticate cannot join at all (the router's user/password dictionary).

The ACL is the enforcement point of these rules: a node in ``ssmpc up`` is a Zenoh
client whose only link is to the router, and Zenoh does not tell a query handler
which identity sent the query (a query's ``source_info`` is written by its sender),
so the handler has nothing trustworthy to check beyond what the router let through.
"""

from __future__ import annotations

from services.io.keys import ROOT
from services.io.mesh_auth import ROLES, user_name

__all__ = ["access_control", "RULES_BY_ROLE"]

_ANY = f"{ROOT}/*"
MEAS = f"{_ANY}/meas"
MV = f"{_ANY}/mv"
STATUS = f"{_ANY}/status"
CMD = f"{_ANY}/cmd/**"
PLANT_CMD = f"{_ANY}/plant/cmd/**"
ALIVE_PLANT = f"{_ANY}/alive/plant"
ALIVE_CONTROLLER = f"{_ANY}/alive/controller"
ALIVE_ANY = f"{_ANY}/alive/*"

# (rule id, flow, messages, key expressions)
_RULES = {
    "meas-put": ("ingress", ["put"], [MEAS]),
    "meas-receive": ("egress", ["put"], [MEAS]),
    "meas-subscribe": ("ingress", ["declare_subscriber"], [MEAS]),
    "meas-matching": ("egress", ["declare_subscriber"], [MEAS]),
    "mv-put": ("ingress", ["put"], [MV, STATUS]),
    "mv-receive": ("egress", ["put"], [MV]),
    "mv-subscribe": ("ingress", ["declare_subscriber"], [MV]),
    "mv-matching": ("egress", ["declare_subscriber"], [MV, STATUS]),
    "cmd-serve": ("ingress", ["declare_queryable", "reply"], [CMD]),
    "cmd-receive": ("egress", ["query"], [CMD]),
    "plant-cmd-serve": ("ingress", ["declare_queryable", "reply"], [PLANT_CMD]),
    "plant-cmd-receive": ("egress", ["query"], [PLANT_CMD]),
    "command": ("ingress", ["query"], [CMD, PLANT_CMD]),
    "command-answers": ("egress", ["reply", "declare_queryable"], [CMD, PLANT_CMD]),
    "alive-plant": ("ingress", ["liveliness_token"], [ALIVE_PLANT]),
    "alive-controller": ("ingress", ["liveliness_token"], [ALIVE_CONTROLLER]),
    "watch-controller": ("ingress", ["declare_liveliness_subscriber", "liveliness_query"],
                         [ALIVE_CONTROLLER]),
    "see-controller": ("egress", ["liveliness_token", "reply"], [ALIVE_CONTROLLER]),
    "watch-plant": ("ingress", ["declare_liveliness_subscriber", "liveliness_query"],
                    [ALIVE_PLANT]),
    "see-plant": ("egress", ["liveliness_token", "reply"], [ALIVE_PLANT]),
    "watch-all": ("ingress", ["declare_liveliness_subscriber", "liveliness_query",
                              "declare_subscriber"], [ALIVE_ANY, STATUS]),
    "see-all": ("egress", ["liveliness_token", "reply", "put"], [ALIVE_ANY, STATUS]),
}

#: The rules each identity is given (everything else is denied).
RULES_BY_ROLE = {
    "plant": ("meas-put", "meas-matching", "mv-subscribe", "mv-receive", "plant-cmd-serve",
              "plant-cmd-receive", "alive-plant", "watch-controller", "see-controller"),
    "controller": ("mv-put", "mv-matching", "meas-subscribe", "meas-receive", "cmd-serve",
                   "cmd-receive", "alive-controller", "watch-plant", "see-plant"),
    "api": ("command", "command-answers", "watch-all", "see-all"),
    "cli": ("command", "command-answers", "watch-all", "see-all"),
}


def access_control() -> dict:
    """The router's ``access_control`` block (JSON-able ``dict``), default deny."""
    assert set(RULES_BY_ROLE) == set(ROLES)
    rules = [{"id": rid, "permission": "allow", "flows": [flow], "messages": list(msgs),
              "key_exprs": list(kes)} for rid, (flow, msgs, kes) in _RULES.items()]
    subjects = [{"id": role, "usernames": [user_name(role)]} for role in ROLES]
    policies = [{"id": f"{role}-policy", "subjects": [role], "rules": list(RULES_BY_ROLE[role])}
                for role in ROLES]
    return {"enabled": True, "default_permission": "deny", "rules": rules,
            "subjects": subjects, "policies": policies}
