"""The plant side's tuning set, selected by the supervisory controller: the reactor
temperature cascade's primary at the published gain at a steady grade, at the grade
changes' gain otherwise (a guard of the TE cascade's MPC strategies).

The plant side runs the reactor temperature over the coolant outlet temperature
(:data:`controller.units.te.loops.REACTOR_TEMPERATURE_CASCADE`, as Lyman & Georgakis
close it in ``temain_mod.f``) with the primary's gain at 10 degC of coolant set point per
degC instead of the published 28.3: at 20 and 28.3 both MPC strategies tripped 3 -> 2 on
every seed (reactor pressure, 3-4.5 h). At a steady grade the published gain holds the
reactor temperature tighter under a varying heat-transfer coefficient (IDV(17)), and G in
product follows the reaction, which follows the temperature.

Method
    A DCS keeps named tuning sets of its loops and switches between them on an order
    (:data:`controller.units.te.loops.LOOP_TUNING_SETS`: ``"grade_change"``, the gains
    every grade change, guard and model of the cascade was tuned with, and
    ``"steady"``, the primary at its published gain). The supervisory controller
    selects one each sample and sends the selection with its moves; the plant side
    applies it before its next integration step. ``"steady"`` is selected from
    :attr:`LoopTuningSettings.after_h` after the last grade change (and from the start
    of a run without one) while nothing holds the outer loops (the operator's warm, or
    an outer loop's CV off); ``"grade_change"`` otherwise, from the sample a grade
    change is requested. The loops are velocity-form PI (:mod:`plant_sim.
    tennessee_eastman.regulatory`), so a switch moves no valve and no set point: the
    loop acts with the new gain on the error's next changes. The selection is a function
    of the hours since the grade change and of the hold alone, so a restarted controller
    selects what it selected before (nothing to checkpoint). A plant side that hears no
    selection (a lost controller, an older one) runs ``"grade_change"``.

Measured (the acceptance matrix, ``docs/campaigns/te_matrix.json``, and the same cases on
plant seeds 4-9, ``te_matrix_seeds_4_9.json``; noise on, 48 h, onset 2 h; off -> on;
G's standard deviation in product, mol %, and the run's mean cost, $/h)
    ==============  ===============  ===============  ==========================
    case, seeds     G std            $/h              decentralized structure
    ==============  ===============  ===============  ==========================
    IDV(17)@0, 1-3  0.538 -> 0.532   134.75 -> 134.21  0.527, 170.63
    IDV(17)@0, 4-9  0.532 -> 0.528   134.42 -> 134.07  0.524, 170.65
    IDV(14)@2, 1-3  0.502 -> 0.503   180.96 -> 181.25  0.515, 181.16
    IDV(8)@2, 4-9   0.507 -> 0.510   181.76 -> 182.12  0.508, 181.44
    ==============  ===============  ===============  ==========================

    IDV(17) at mode 0 is met within the 1 % of "no worse" on both seed sets (58 of 60
    disturbance cases on each; 57 off), by 0.0004 and 0.0010 mol % (0.5317 against
    0.5321, 0.5279 against 0.5289). IDV(14) (the coolant valve sticks) and IDV(8) at
    mode 2 are dearer than the decentralized structure within the 1 %. Every other case
    within 0.25 $/h (IDV(20) at mode 0 on seeds 1-3 1.2 $/h cheaper) and 0.001 mol %.
    No trip of ``ssmpc`` or ``fixed`` (1332 runs); the transitions' median times as
    off, their costs within 1 $.
    ``ssmpc`` ties ``fixed`` on IDV(17) at mode 0 (0.5317 both): the set is the plant
    side's, not the core's. Run at 20 degC/degC instead of 28.3 (cases without a grade
    change, seeds 1-3): IDV(17) at mode 0 0.533.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from controller.units.te.settings_check import check_finite_fields, check_range

__all__ = ["LoopTuningSettings", "select_tuning"]


@dataclass(frozen=True)
class LoopTuningSettings:
    """When :func:`select_tuning` selects the steady grade's tuning set.

    Parameters
    ----------
    after_h : float
        Hours after a grade change from which the steady set is selected (>= 0).
    """

    after_h: float = 24.0

    def __post_init__(self) -> None:
        check_finite_fields(self, "loop tuning ")
        check_range(self, "after_h", ">= 0", "h", "loop tuning ")


def select_tuning(settings: LoopTuningSettings, since_h: float, held: bool) -> str:
    """The plant side's tuning set for the next interval.

    Parameters
    ----------
    settings : LoopTuningSettings
    since_h : float
        Hours since the last grade change (``inf``: none in this run; NaN counts as a
        grade change in progress).
    held : bool
        The operator holds the outer loops.

    Returns
    -------
    str
        ``"steady"`` or ``"grade_change"`` (names of
        :data:`controller.units.te.loops.LOOP_TUNING_SETS`).
    """
    steady = (not held and not math.isnan(since_h) and since_h >= settings.after_h)
    return "steady" if steady else "grade_change"
