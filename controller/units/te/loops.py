"""The inner loops of the TE cascade: what the plant side runs under the supervisory
controller, at the plant's 1.8 s Euler step (seed Table 7.10, R7.11, with one change).

Used by the controller (:mod:`controller.units.te.control`), by the models of the
cascade the MPC acts on (:mod:`controller.units.te.models`) and by the plant side.
"""

from __future__ import annotations

from plant_sim.tennessee_eastman.regulatory import TABLE_7_10, PILoop

__all__ = ["INNER_LOOPS", "PRESSURE_LOOP"]

#: The inner loops: Table 7.10 (R7.11) with one change, the reactor-temperature
#: gain. As printed (-0.5 %/degC, Ti "i" read as 1 h) the linearized plant with the
#: four loops closed has a growing 3 h oscillation at modes 0 and 2 (eigenvalues
#: +0.35 +- 2.08j and +0.51 +- 2.02j 1/h; with -0.5 %/degC no Ti in 0.02-1 h is
#: stable at both modes) and the nonlinear plant trips on reactor pressure after
#: 40 h (mode 0) and 19 h (mode 2) with all other valves held. -2 %/degC with
#: Ti = 0.5 h makes the linearizations Hurwitz at modes 0, 2 and 3, as the seed
#: reports for its loops (R7.10). The three level loops are exactly Table 7.10.
#: A fifth inner loop, reactor pressure -> purge (XMV 6), whose set point the core
#: writes in place of the purge valve (see :mod:`controller.units.te.control`, "Pressure").
PRESSURE_LOOP = PILoop("reactor pressure", cv=7, mv=6, gain=-0.15, ti_h=0.5)
INNER_LOOPS = ((PILoop("reactor temperature", cv=9, mv=10, gain=-2.0, ti_h=0.5),)
               + TABLE_7_10[1:] + (PRESSURE_LOOP,))
