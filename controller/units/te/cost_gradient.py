"""The Downs & Vogel operating cost's steady-state gradient in the TE core's handles.

The economic term of the core's steady-state targets (:mod:`controller.units.te.targets`)
is the Downs & Vogel operating cost linearized at the grade's steady state,
``c_u = dJ/du`` in $/h per handle unit. The five-CV models the MPC runs on carry no
cost, so the gradient is measured on the plant: the grade plan alone (strategy
``"plan"``) held at the grade for 40 h, noise off, once as planned and once with one
handle moved; the cost is the plant's (:meth:`TESimulator.cost`), the mean over the
last 16 h, when every loop has settled. The G mol% ratio loop is closed in both runs
(G unchanged to 0.01 mol%); the plan alone has no production trim, and its production
rose 0.1-0.5 % with the pressure, so the gradient is that along the grade's
specifications to within that. In the MPC strategies the production trim holds
production too (mode 0 at 2800 kPa: 22.91 against 22.95 m³/h at 2705).

Only the reactor-pressure set point P_r* is priced: it is the one handle the targets
may move (:class:`~controller.units.te.targets.CoreTargetSettings` ``band``); the
others have gradient 0 here.

Measured (this plant, 1.8 s Euler step, noise off), $/h, and the gradient as the
secant over the move::

    grade   P_r* plan   moved to   cost plan   cost moved   dJ/dP_r* ($/h per kPa)
    mode0   2705        2800       170.63      144.64       -0.274
    mode1   2800        2850       114.31      109.55       -0.095
    mode2   2800        2850       181.09      169.94       -0.223
    mode3   2800        2850        43.93       42.87       -0.021

The cost falls with the pressure at every grade (a higher partial pressure of the
reactants makes the same product with less purge loss). The plant punishes pressure
past about 2850 kPa: at 2895 kPa set point modes 1 and 2 reached the high-pressure
override and tripped within 10 h, so the targets take the gain only up to
:attr:`~controller.units.te.targets.CoreTargetSettings.economic_pressure_max`
(2800 kPa, the limit of Ricker's optimization, where modes 1-3 already sit).
A grade without a measured gradient (modes 4-6) has none: the targets keep its plan.
"""

from __future__ import annotations

from functools import cache

import numpy as np

__all__ = ["PRESSURE_COST_GRADIENT", "cost_gradient"]

#: dJ/dP_r*, $/h per kPa, per grade (module table).
PRESSURE_COST_GRADIENT = {"mode0": -0.274, "mode1": -0.095, "mode2": -0.223, "mode3": -0.021}

_P_INDEX = 2  # P_r* among the core handles (XMV 3, XMV 4, P_r*, T_r*, XMV 11)


@cache
def cost_gradient(grade: str) -> np.ndarray:
    """The operating cost's gradient in the five core handles at ``grade``, $/h per
    handle unit (% for the valves, kPa for P_r*, degC for T_r*), shape (5,), read-only
    (one array per grade, asked for every sample); zeros for a grade without a
    measured gradient."""
    c = np.zeros(5)
    c[_P_INDEX] = PRESSURE_COST_GRADIENT.get(grade, 0.0)
    c.setflags(write=False)
    return c
