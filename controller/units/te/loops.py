"""The inner loops of the TE cascade: what the plant side runs under the supervisory
controller, at the plant's 1.8 s Euler step (seed Table 7.10, R7.11, with the reactor
temperature cascaded over the coolant outlet temperature), and the loops the core's
models are linearized with.

Used by the controller (:mod:`controller.units.te.control`), by the models of the
cascade the MPC acts on (:mod:`controller.units.te.models`) and by the plant side.
"""

from __future__ import annotations

from dataclasses import replace

from controller.units.te.published_loops import published_cascade
from plant_sim.tennessee_eastman.regulatory import TABLE_7_10, PILoop

__all__ = ["DEFAULT_TUNING", "E_LIMITED_LEVEL_GAIN", "INNER_LOOPS", "LOOP_TUNING_SETS",
           "MODEL_LOOPS", "PRESSURE_LOOP", "PUBLISHED_TEMPERATURE_CASCADE",
           "REACTOR_TEMPERATURE_CASCADE", "STEADY_LEVEL_GAIN", "tuning_gains"]

#: A fifth inner loop, reactor pressure -> purge (XMV 6), whose set point the core
#: writes in place of the purge valve (see :mod:`controller.units.te.control`, "Pressure").
#: Measured at -0.45 %/kPa (``docs/te_matrix.md``, "the pressure loop three times as
#: strong"): G's deviation lower under IDV 8, 17 and 20, 1 -> 0 slower (2.8 -> 5.1 h, the
#: purge at 99 % while P_r* falls), the guards tuned on this gain; not taken. The same
#: gain at a steady grade only, on the error's fast changes, from the controller's side
#: through the set point: :mod:`controller.units.te.pressure_gain` (on by default).
PRESSURE_LOOP = PILoop("reactor pressure", cv=7, mv=6, gain=-0.15, ti_h=0.5)

#: The loops the core's models are linearized with (:mod:`controller.units.te.models`):
#: Table 7.10 (R7.11) with one change, the reactor-temperature gain, and the pressure
#: loop. As printed (-0.5 %/degC, Ti "i" read as 1 h) the linearized plant with the four
#: loops closed has a growing 3 h oscillation at modes 0 and 2 (eigenvalues +0.35 +-
#: 2.08j and +0.51 +- 2.02j 1/h; with -0.5 %/degC no Ti in 0.02-1 h is stable at both
#: modes) and the nonlinear plant trips on reactor pressure after 40 h (mode 0) and
#: 19 h (mode 2) with all other valves held. -2 %/degC with Ti = 0.5 h makes the
#: linearizations Hurwitz at modes 0, 2 and 3, as the seed reports for its loops
#: (R7.10). The three level loops are exactly Table 7.10.
MODEL_LOOPS = ((PILoop("reactor temperature", cv=9, mv=10, gain=-2.0, ti_h=0.5),)
               + TABLE_7_10[1:] + (PRESSURE_LOOP,))

#: The reactor temperature over the reactor coolant outlet temperature (XMEAS 21), as
#: the decentralized structure closes it (``temain_mod.f``, Lyman & Georgakis; its loops
#: 18 and 10, :mod:`controller.units.te.published_loops`: 28.3 degC of coolant set point
#: per degC, reset 982 s; -1.04 % of valve per degC, reset 1452 s). It holds the reactor
#: temperature within 0.08 degC under IDV(11) (the -2 %/degC loop 1.66,
#: `tests/test_te_regulatory.py`). The baseline ``decentralized`` runs it.
PUBLISHED_TEMPERATURE_CASCADE = published_cascade(18, 10)

#: The cascade the plant side runs under the supervisory controller: the published one
#: with the primary's gain at 10 degC of coolant set point per degC instead of 28.3 (the
#: secondary and both resets as published). Measured (``ssmpc`` and ``fixed``, seeds
#: 1-3, 48 h; ``docs/te_matrix.md``, "The primary's gain") on ten cases
#: of the acceptance matrix (the legs out of mode 3, 1 -> 0, 2 -> 0, IDV 11, 12, 17 and
#: 20 at mode 0, IDV(13) at mode 2): with the primary at 15 degC/degC ``fixed`` tripped
#: under IDV(13) at mode 2 (seed 2), at 20 and 28.3 both strategies tripped 3 -> 2 on
#: every seed (reactor pressure, 3-4.5 h); at 10 none did, nor anywhere in the whole
#: matrix.
REACTOR_TEMPERATURE_CASCADE = replace(PUBLISHED_TEMPERATURE_CASCADE, gain=10.0)

#: The inner loops the plant side runs: the reactor-temperature cascade above, the
#: three level loops of Table 7.10 and the pressure loop. The core's models keep the
#: single temperature loop of :data:`MODEL_LOOPS`: any loop with integral action holds
#: the reactor temperature at T_r* at a steady state, so the models' steady-state gains
#: are the cascade's; their temperature dynamics are slower than the cascade's. The
#: cascade's own reduced models carry its fast modes (-30 +- 244j 1/h at mode 2 with the
#: published tuning), and with them ``fixed`` tripped 0 -> 2 0.7 h after the request.
INNER_LOOPS = (REACTOR_TEMPERATURE_CASCADE,) + MODEL_LOOPS[1:]

#: The reactor level loop's gain at a steady grade, % of D valve per % of level: three
#: eighths of Table 7.10's 4, beside the reactor-feed balance on the A+C feed
#: (:mod:`controller.units.te.feed_balance`), which holds the reactor feed's A + C on
#: its fast changes while the level's loop moves D less. At 1 %/% the level left its
#: grade's 1 % band for two hours after a grade change (see
#: :mod:`controller.units.te.loop_tuning`): the old gain's answer to the level's noise
#: stood at the switch. With the switch re-basing the loop
#: (:meth:`plant_sim.tennessee_eastman.regulatory.RegulatoryLayer.set_gains`) 1 %/% no
#: longer does (0 -> 1 and 1 -> 0 at grade after 2.7-3.1 h on seeds 1-3), but it was not
#: taken: in the acceptance matrix (seeds 1-3) G's deviation under IDV(20) at mode 0
#: 0.513 -> 0.511 mol %, under IDV(13) 0.814 -> 0.822 (the decentralized structure's
#: 0.824) and under IDV(8) 0.507 -> 0.511; on seeds 1-9 IDV(20) at mode 0 0.521 -> 0.517.
STEADY_LEVEL_GAIN = 1.5

#: The reactor level loop's gain at a steady grade whose E feed valve stands near its
#: range (mode 2), % of D valve per % of level: an eighth of Table 7.10's 4 (see
#: :mod:`controller.units.te.loop_tuning`).
E_LIMITED_LEVEL_GAIN = 0.5

#: The plant side's named tuning sets (set name -> loop name -> gain; a cascaded loop's
#: primary). A loop a set does not name runs its gain of :data:`INNER_LOOPS`. The
#: supervisory controller selects one each sample (:mod:`controller.units.te.loop_tuning`):
#: ``"grade_change"``, the gains every grade change was tuned with; ``"steady"``, the
#: reactor temperature's primary at its published 28.3 degC/degC and the reactor level's
#: loop at :data:`STEADY_LEVEL_GAIN`; ``"steady_e_limited"``, the primary as published
#: and the level's loop at :data:`E_LIMITED_LEVEL_GAIN`.
LOOP_TUNING_SETS = {
    "grade_change": {},
    "steady": {REACTOR_TEMPERATURE_CASCADE.name: PUBLISHED_TEMPERATURE_CASCADE.gain,
               MODEL_LOOPS[1].name: STEADY_LEVEL_GAIN},
    "steady_e_limited": {REACTOR_TEMPERATURE_CASCADE.name: PUBLISHED_TEMPERATURE_CASCADE.gain,
                         MODEL_LOOPS[1].name: E_LIMITED_LEVEL_GAIN},
}

#: The tuning set the plant side runs when it hears no selection (a controller lost,
#: held or of an older version): the grade changes' gains, safe through a grade change.
DEFAULT_TUNING = "grade_change"


def tuning_gains(loops, name: str) -> tuple[float, ...]:
    """The gains of ``loops`` under tuning set ``name``, one per loop.

    Raises
    ------
    ValueError
        ``name`` is not a set of :data:`LOOP_TUNING_SETS` (the known ones are named).
    """
    if name not in LOOP_TUNING_SETS:
        raise ValueError(f"tuning: unknown tuning set {name!r}; known: "
                         f"{', '.join(LOOP_TUNING_SETS)}")
    chosen = LOOP_TUNING_SETS[name]
    return tuple(float(chosen.get(lp.name, lp.gain)) for lp in loops)
