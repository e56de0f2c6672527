"""The inner loops of the TE cascade: what the plant side runs under the supervisory
controller, at the plant's 1.8 s Euler step (seed Table 7.10, R7.11, with one change).

Used by the controller (:mod:`controller.units.te.control`), by the models of the
cascade the MPC acts on (:mod:`controller.units.te.models`) and by the plant side.
"""

from __future__ import annotations

from plant_sim.tennessee_eastman.regulatory import TABLE_7_10, PILoop, SecondaryLoop

__all__ = ["INNER_LOOPS", "PRESSURE_LOOP", "PUBLISHED_TEMPERATURE_CASCADE"]

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

#: The reactor temperature over the reactor coolant outlet temperature (XMEAS 21), as
#: the decentralized structure closes it (``temain_mod.f``, Lyman & Georgakis; its loops
#: 18 and 10 with 150 degC spans: 2.83 x 10 %/% = 28.3 degC of coolant set point per
#: degC, reset 982 s; -0.156 x 10 %/% = -1.04 % of valve per degC, reset 1452 s).
#: Measured, not in :data:`INNER_LOOPS`: it holds the reactor temperature within 0.08
#: degC under IDV(11) (the -2 %/degC loop 1.66, `tests/test_te_regulatory.py`), and with
#: the MPC it brought G's deviation under IDV(11) at mode 0 to 0.506 mol %
#: (decentralized 0.504); but the cascade's reduced models carry its fast modes
#: (-30 +- 244j 1/h at mode 2), and with them `fixed` tripped 0 -> 2 0.7 h after the
#: request (docs/te_matrix.md, "The reactor temperature's inner loop").
PUBLISHED_TEMPERATURE_CASCADE = PILoop(
    "reactor temperature", cv=9, mv=10, gain=28.3, ti_h=982.0 / 3600.0,
    secondary=SecondaryLoop("reactor coolant outlet temperature", cv=21,
                            gain=-0.156 * 10.0 / 1.5, ti_h=1452.0 / 3600.0))
