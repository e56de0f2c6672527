"""A unit's operating cost per hour from its measured CVs, and its base case (KPIs).

- TE: the Downs & Vogel operating cost computed from XMEAS 1-41 as the controller
  receives them (:func:`plant_sim.tennessee_eastman.cost.measured_operating_cost`,
  its measured limits there), against Downs & Vogel's base case, 170.6 $/h at mode 0
  (:data:`~plant_sim.tennessee_eastman.cost.BASE_CASE_COST_USD_H`, from
  ``docs/facts/te.md`` §9).
- The unit plants (CSTR, bioreactor, two-phase reactor) have no published operating
  cost: :func:`operating_cost` is None for them, and the KPIs report no cost.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["OperatingCost", "operating_cost"]

@dataclass(frozen=True)
class OperatingCost:
    """How one unit's operating cost is read from a sample.

    Attributes
    ----------
    usd_per_h : callable
        ``usd_per_h(y) -> float``: the cost, $/h, from the unit's CV vector ``y``
        (engineering units, shape (ny,)).
    base_usd_h : float
        The unit's base-case cost, $/h.
    base_origin : str
        Where the base-case cost comes from.
    """

    usd_per_h: Callable[[np.ndarray], float]
    base_usd_h: float
    base_origin: str


def operating_cost(cfg) -> OperatingCost | None:
    """The unit's :class:`OperatingCost`, or None when it has none (module notes).

    Parameters
    ----------
    cfg : controller.units.config.UnitConfig
    """
    if cfg.plant != "te":
        return None
    from plant_sim.tennessee_eastman.cost import (
        BASE_CASE_COST_ORIGIN,
        BASE_CASE_COST_USD_H,
        measured_operating_cost,
    )

    # the TE unit's CVs are XMEAS 1-41 in order (controller.units.te.structure checks it)
    def usd_per_h(y) -> float:
        return measured_operating_cost(y)

    return OperatingCost(usd_per_h, BASE_CASE_COST_USD_H, BASE_CASE_COST_ORIGIN)
