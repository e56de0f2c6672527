"""Zenoh key expressions of ssmpc: ``ssmpc/<unit>/...``.

=========================================  =========================================
``ssmpc/<unit>/meas``                      plant → controller, one :class:`Measurement` per sample
``ssmpc/<unit>/mv``                        controller → plant, :class:`MVMessage`
``ssmpc/<unit>/status``                    controller status (JSON), every N samples
``ssmpc/<unit>/cmd/<action>[/<id>]``       queries to the controller (status, grades, transitions)
``ssmpc/<unit>/plant/cmd/<action>``        queries to the plant node (status, disturbance)
``ssmpc/<unit>/alive/<role>``              liveliness tokens, role ``plant`` or ``controller``
=========================================  =========================================
"""

from __future__ import annotations

from controller.units.config import UNIT_NAME_RE, check_unit_name

__all__ = [
    "ROOT",
    "ROLES",
    "UNIT_NAME_RE",
    "check_unit_name",
    "meas",
    "mv",
    "status",
    "cmd",
    "cmd_all",
    "plant_cmd",
    "plant_cmd_all",
    "alive",
    "alive_all",
    "parse_alive",
]

ROOT = "ssmpc"
ROLES = ("plant", "controller")
def meas(unit: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/meas"


def mv(unit: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/mv"


def status(unit: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/status"


def cmd(unit: str, action: str, *rest: str) -> str:
    parts = [ROOT, check_unit_name(unit), "cmd", action, *rest]
    return "/".join(parts)


def cmd_all(unit: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/cmd/**"


def plant_cmd(unit: str, action: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/plant/cmd/{action}"


def plant_cmd_all(unit: str) -> str:
    return f"{ROOT}/{check_unit_name(unit)}/plant/cmd/**"


def alive(unit: str, role: str) -> str:
    if role not in ROLES:
        raise ValueError(f"role: expected one of {ROLES}, got {role!r}")
    return f"{ROOT}/{check_unit_name(unit)}/alive/{role}"


def alive_all(unit: str | None = None) -> str:
    return f"{ROOT}/{'*' if unit is None else check_unit_name(unit)}/alive/*"


def parse_alive(key: str) -> tuple[str, str] | None:
    """``ssmpc/<unit>/alive/<role>`` → ``(unit, role)``; anything else → None."""
    parts = str(key).split("/")
    if len(parts) == 4 and parts[0] == ROOT and parts[2] == "alive" and parts[3] in ROLES:
        return parts[1], parts[3]
    return None
