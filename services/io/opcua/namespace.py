"""The ``urn:ssmpc`` address space of one unit, as a DCS would expose it.

::

    Objects/<unit>/                      (Object, BrowseName <ns>:<unit>)
        Measurements/<CV>                (AnalogItemType, Double, read-only)
            EngineeringUnits             (EUInformation, OPC 10000-8 §5.6.3)
            EURange                      (Range, where the limits are finite)
        Setpoints/<MV>                   (AnalogItemType, Double, controller writes)
        Status/Sample                    (Int64: the plant's sample counter k)
              /ProcessTime               (Double, s)
              /AppliedMoves              (Double[nu]: the MVs acting now)
              /AppliedMoveSeq            (Int64: the move they came from, -1: none)
              /Shutdown                  (Boolean: the plant has tripped)
              /AppliedTuning             (String: the plant loops' tuning set in force, "": none)
              /WatchdogState             (String: "ok" or "shed")
              /ControllerHeartbeat       (UInt32, controller writes)
              /ControllerMode            (String "on" | "warm" | "off", controller writes)
              /AnsweredSample            (Int64: the sample a move answers, controller writes)
              /MoveFallback              (Boolean: the move is a held fallback, controller writes)
              /Tuning                    (String: the plant loops' tuning set for the move,
                                          "": the plant's default, controller writes)

Node ids are strings in the ``urn:ssmpc`` namespace: ``<unit>.<Folder>.<name>``
(``cstr.Measurements.y``), so a client that knows the unit needs no browsing; the
namespace index is looked up by its URI.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["CONTROLLER_STATUS", "CONTROLLER_MODES", "PLANT_STATUS", "Variable", "node_name",
           "unit_namespace"]

#: Status variables the plant writes: (name, OPC UA built-in type, description).
PLANT_STATUS = (
    ("Sample", "Int64", "plant sample counter k (one per sample period)"),
    ("ProcessTime", "Double", "process time of the sample, s"),
    ("AppliedMoves", "DoubleArray", "MVs acting over the current sample interval"),
    ("AppliedMoveSeq", "Int64", "sequence number of the move acting now (-1: initial values)"),
    ("Shutdown", "Boolean", "the plant has tripped (interlocks)"),
    ("Incarnation", "String", "this plant run's id (a new one when the plant restarts)"),
    ("AppliedTuning", "String", "tuning set of the plant's own loops in force (empty: the "
     "plant has none)"),
    ("WatchdogState", "String", "controller link: ok, or shed (heartbeat lost: valves held)"),
)
#: Status variables the controller writes (with its moves).
CONTROLLER_STATUS = (
    ("ControllerHeartbeat", "UInt32", "counter the controller advances with every write"),
    ("ControllerMode", "String", "controller mode: on, warm or off"),
    ("AnsweredSample", "Int64", "the plant sample the current set points answer"),
    ("MoveFallback", "Boolean", "the current set points are the controller's held fallback"),
    ("Tuning", "String", "tuning set of the plant's own loops the set points go with "
     "(empty: the plant's default)"),
)
#: The values ``ControllerMode`` may take.
CONTROLLER_MODES = ("on", "warm", "off")


@dataclass(frozen=True)
class Variable:
    """One Measurements or Setpoints variable: name, description, unit, limits."""

    name: str
    description: str
    unit: str
    lo: float
    hi: float


def node_name(unit: str, folder: str, name: str = "") -> str:
    """The string identifier of a node: ``<unit>.<folder>[.<name>]``."""
    return f"{unit}.{folder}.{name}" if name else f"{unit}.{folder}"


def unit_namespace(cfg) -> tuple[list[Variable], list[Variable]]:
    """``(measurements, setpoints)`` of a unit, in the order of its CV and MV vectors,
    with descriptions, engineering units and limits from
    :func:`controller.units.variables.unit_variables`."""
    from controller.units.config import build_plant, unit_info
    from controller.units.variables import unit_variables

    plant = build_plant(cfg)
    info = unit_info(cfg, plant)
    by_name = {(v.kind, v.name): v for v in unit_variables(cfg, plant)}

    def variables(kind, names, units):
        out = []
        for name, unit in zip(names, units):
            v = by_name.get((kind, name))
            out.append(Variable(name, v.description if v else name, v.unit if v else unit,
                                v.lo if v else float("-inf"), v.hi if v else float("inf")))
        return out

    return (variables("cv", info.cv_names, info.cv_units),
            variables("mv", info.mv_names, info.mv_units))
