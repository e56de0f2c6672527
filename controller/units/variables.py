"""The unit's variables as an operator reads them: tag, description, engineering unit, limits.

One :class:`VariableInfo` per controlled variable (CV), manipulated variable (MV) and
disturbance variable (DV) of a unit. The limits are the ones the controller works
to, in engineering units:

- TE CVs (XMEAS, Downs & Vogel 1993, Table 4/5 tags and units): the alarm limits the
  TE controller reports against, set below the interlocks
  (:data:`controller.units.te.control.ALARM_LIMITS`: reactor pressure 2950 kPa for
  the 3000 kPa trip, reactor temperature 170 °C for 175 °C, levels 10-90 %); the
  other XMEAS have none (±inf).
- TE MVs: the valves (XMV, 0-100 %) and the inner loops' set points, limited to the
  supervisory controller's ranges (reactor temperature
  :data:`~controller.units.te.control.TR_LIMITS`, reactor pressure
  :data:`~controller.units.te.control.PR_LIMITS`) and the levels to their alarm band.
- Unit plants: the plant's own physical bounds (:mod:`plant_sim`); the SISO units'
  input the range the chapter-5 laws work to (:func:`controller.units.siso.input_limits`).

:func:`at_limit` says which limit a value sits at (within :data:`AT_LIMIT_FRACTION`
of the range, or beyond it); :func:`at_limit_flags` says it for a whole vector at once
(the KPIs' constraint activity, every sample).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["AT_LIMIT_FRACTION", "VariableInfo", "at_limit", "at_limit_flags", "flags_at",
           "limit_thresholds", "unit_variables"]

#: A value within this fraction of its range from a limit is "at" it (0.5 %).
AT_LIMIT_FRACTION = 0.005


@dataclass(frozen=True)
class VariableInfo:
    """Static facts of one variable.

    Attributes
    ----------
    name : str
        Name on the wire (``XMEAS7``, ``reactor_pressure_sp``, ``y``).
    tag : str
        Plant tag (``XMEAS 7``; a set point: ``XMEAS 7 SP``).
    description : str
    unit : str
        Engineering unit (``kPa gauge``, ``%``, ``degC``).
    kind : str
        ``"cv"``, ``"mv"`` or ``"dv"``.
    lo, hi : float
        Limits in ``unit`` (±inf: none).
    """

    name: str
    tag: str
    description: str
    unit: str
    kind: str
    lo: float
    hi: float

    def as_dict(self) -> dict:
        return {"name": self.name, "tag": self.tag, "description": self.description,
                "unit": self.unit, "kind": self.kind, "lo": _num(self.lo), "hi": _num(self.hi)}


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def at_limit(value: float | None, lo: float, hi: float) -> str | None:
    """``"lo"``, ``"hi"`` or None: the limit ``value`` sits at or beyond.

    With both limits finite "at" means within :data:`AT_LIMIT_FRACTION` of the range;
    with one limit, within that fraction of the limit's magnitude (or 1e-9).
    """
    if value is None or not math.isfinite(value):
        return None
    if math.isfinite(lo) and math.isfinite(hi):
        tol = AT_LIMIT_FRACTION * (hi - lo)
    else:
        finite = [abs(x) for x in (lo, hi) if math.isfinite(x)]
        tol = AT_LIMIT_FRACTION * max(finite + [1e-9 / AT_LIMIT_FRACTION])
    if math.isfinite(hi) and value >= hi - tol:
        return "hi"
    if math.isfinite(lo) and value <= lo + tol:
        return "lo"
    return None


def limit_thresholds(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Where "at a limit" starts for each variable (:func:`at_limit`'s tolerance taken
    off): a value at or below ``lo_at`` is at its low limit, at or above ``hi_at`` at its
    high one (±inf: the variable has no such limit).

    Parameters
    ----------
    lo, hi : array_like, shape (n,)
        Limits in engineering units (±inf: none).

    Returns
    -------
    lo_at, hi_at : ndarray, shape (n,)
    """
    lo = np.asarray(lo, dtype=float)
    hi = np.asarray(hi, dtype=float)
    f_lo, f_hi = np.isfinite(lo), np.isfinite(hi)
    with np.errstate(invalid="ignore"):
        one = np.maximum(np.where(f_lo, np.abs(lo), 0.0), np.where(f_hi, np.abs(hi), 0.0))
        tol = np.where(f_lo & f_hi, AT_LIMIT_FRACTION * (hi - lo),
                       np.maximum(AT_LIMIT_FRACTION * one, 1e-9))
        return (np.where(f_lo, lo + tol, -np.inf), np.where(f_hi, hi - tol, np.inf))


def flags_at(values, lo_at, hi_at) -> tuple[np.ndarray, np.ndarray]:
    """Which ``values`` sit at their low / high limit, given :func:`limit_thresholds`
    (a non-finite value at neither; high wins where both would).

    Returns
    -------
    at_lo, at_hi : ndarray of bool, shape (n,)
    """
    x = np.asarray(values, dtype=float)
    finite = np.isfinite(x)
    at_hi = (x >= hi_at) & finite
    return (x <= lo_at) & finite & ~at_hi, at_hi


def at_limit_flags(values, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Vector form of :func:`at_limit`: which of ``values`` sit at their low, which at
    their high limit (:func:`limit_thresholds`, :func:`flags_at`).

    Parameters
    ----------
    values, lo, hi : array_like, shape (n,)
        Values and limits in engineering units (±inf: no limit).

    Returns
    -------
    at_lo, at_hi : ndarray of bool, shape (n,)
    """
    return flags_at(values, *limit_thresholds(lo, hi))


def _te_variables(cfg, plant) -> tuple[VariableInfo, ...]:
    from controller.units.te.control import ALARM_LIMITS, PR_LIMITS, TR_LIMITS
    from controller.units.te.structure import te_mv_names, te_setpoint_name, te_structure

    out = []
    for name in cfg.cvs:
        i = int(name[5:])
        var = plant.output_vars[i - 1]
        lo, hi = ALARM_LIMITS.get(i, (-math.inf, math.inf))
        out.append(VariableInfo(name, f"XMEAS {i}", var.description, var.unit, "cv", lo, hi))
    loops, _ = te_structure(cfg.strategy)
    by_sp = {te_setpoint_name(lp): lp for lp in loops}
    for name in te_mv_names(cfg):
        if name in by_sp:
            lp = by_sp[name]
            var = plant.output_vars[lp.cv - 1]
            if lp.cv == 9:
                lo, hi = TR_LIMITS
            elif lp.cv == 7:
                lo, hi = PR_LIMITS
            else:
                lo, hi = ALARM_LIMITS.get(lp.cv, (var.lower, var.upper))
            acts_on = (f"loop on XMV {lp.mv}" if hasattr(lp, "mv")
                       else f"cascade to the {lp.inner} loop")
            out.append(VariableInfo(name, f"XMEAS {lp.cv} SP",
                                    f"{var.description} set point ({acts_on})",
                                    var.unit, "mv", lo, hi))
        else:
            i = int(name[3:])
            var = plant.input_vars[i - 1]
            out.append(VariableInfo(name, f"XMV {i}", var.description, var.unit, "mv",
                                    var.lower, var.upper))
    return tuple(out)


def unit_variables(cfg, plant) -> tuple[VariableInfo, ...]:
    """Every CV, MV and DV of the unit, in the order of the unit's vectors (CVs, MVs,
    then DVs).

    Parameters
    ----------
    cfg : controller.units.config.UnitConfig
    plant : plant_sim.base.Plant
        The unit's plant (:func:`controller.units.config.build_plant`).
    """
    if cfg.plant == "te":
        return _te_variables(cfg, plant)
    from controller.units.config import cv_indices, mv_indices

    out = []
    for kind, idx, vars_ in (("cv", cv_indices(cfg, plant), plant.output_vars),
                             ("mv", mv_indices(cfg, plant), plant.input_vars),
                             ("dv", range(len(plant.disturbance_vars)), plant.disturbance_vars)):
        for i in idx:
            v = vars_[i]
            lo, hi = v.lower, v.upper
            if kind == "mv" and cfg.controller in ("hinf", "mrac"):
                from controller.units.siso import input_limits

                lo, hi = input_limits(cfg, plant)
            out.append(VariableInfo(v.name, v.name, v.description, v.unit, kind, lo, hi))
    return tuple(out)
