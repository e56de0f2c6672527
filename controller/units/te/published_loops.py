"""The loops of ``temain_mod.f`` as published: the decentralized TE control structure of
Lyman & Georgakis (1995) in the closed-loop driver of Russell, Chiang & Braatz (2000).

One table, :data:`TEMAIN_MOD_LOOPS`, in the source's own units (errors in % of the CV's
span, outputs in % of a valve or of the inner CV's span), and the conversion to
engineering units (:func:`gain_eu`). The baseline ``decentralized``
(:mod:`controller.units.te.decentralized`) runs the whole structure; the plant side of the
other strategies borrows its reactor-temperature cascade (:func:`published_cascade`,
:mod:`controller.units.te.loops`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from plant_sim.tennessee_eastman.regulatory import PILoop, SecondaryLoop, ValveOverride

__all__ = ["PublishedLoop", "TEMAIN_MOD_LOOPS", "LOOP_BY_NUMBER", "PURGE_OVERRIDE", "gain_eu",
           "published_cascade"]


@dataclass(frozen=True)
class PublishedLoop:
    """One loop of ``temain_mod.f`` as published (its units, not this project's).

    Parameters
    ----------
    number : int
        The source's loop (subroutine) number.
    name : str
    cv : int
        Controlled XMEAS number.
    xmv : int or None
        Manipulated XMV number; None for an outer loop.
    inner : int or None
        Number of the loop whose set point an outer loop writes.
    gain : float
        ``Kc`` on errors in % of ``span`` (output in % of the output's span).
    ti_s : float
        Reset time, s; ``math.inf``: proportional only.
    span : float
        The CV's span in the error scaling, CV units per 100 %.
    sample_s : float
        Execution period, s.
    setpoint : float
        Base-case set point, CV units.
    """

    number: int
    name: str
    cv: int
    xmv: int | None
    inner: int | None
    gain: float
    ti_s: float
    span: float
    sample_s: float
    setpoint: float

    def __post_init__(self) -> None:
        if (self.xmv is None) == (self.inner is None):
            raise ValueError(f"loop {self.number}: exactly one of xmv and inner")
        if not 1 <= self.cv <= 41:
            raise ValueError(f"loop {self.number}: cv must be an XMEAS number 1..41")
        if not (self.ti_s > 0 and self.span > 0 and self.sample_s > 0):
            raise ValueError(f"loop {self.number}: ti_s, span and sample_s must be > 0")

    @property
    def ti_h(self) -> float:
        """Reset time, h (``math.inf``: proportional only)."""
        return self.ti_s / 3600.0


_P = math.inf
#: The loops of ``temain_mod.f`` (set points lines 246-312, gains and reset times
#: there, errors and outputs in the loop subroutines, execution order and samples
#: in the main loop, lines 369-394).
TEMAIN_MOD_LOOPS = (
    PublishedLoop(1, "D feed", 2, 1, None, 1.0, _P, 5811.0, 3.0, 3664.0),
    PublishedLoop(2, "E feed", 3, 2, None, 1.0, _P, 8354.0, 3.0, 4509.3),
    PublishedLoop(3, "A feed", 1, 3, None, 1.0, _P, 1.017, 3.0, 0.25052),
    PublishedLoop(4, "A and C feed", 4, 4, None, 1.0, _P, 15.25, 3.0, 9.3477),
    PublishedLoop(5, "recycle flow", 5, 5, None, -0.083, 1.0, 53.0, 3.0, 26.902),
    PublishedLoop(6, "purge rate", 10, 6, None, 1.22, _P, 1.0, 3.0, 0.33712),
    PublishedLoop(7, "separator level", 12, 7, None, -2.06, _P, 70.0, 3.0, 50.0),
    PublishedLoop(8, "stripper level", 15, 8, None, -1.62, _P, 70.0, 3.0, 50.0),
    PublishedLoop(9, "stripper steam", 19, 9, None, 0.41, _P, 460.0, 3.0, 230.31),
    PublishedLoop(10, "reactor coolant outlet temperature", 21, 10, None, -0.156 * 10.0,
                  1452.0, 150.0, 3.0, 94.599),
    PublishedLoop(11, "production", 17, 11, None, 1.09, 2600.0, 46.0, 3.0, 22.949),
    PublishedLoop(16, "stripper temperature", 18, None, 9, 1.69 / 10.0, 236.0, 130.0, 3.0,
                  65.731),
    PublishedLoop(17, "reactor level", 8, None, 4, 11.1 / 10.0, 3168.0, 50.0, 3.0, 75.0),
    PublishedLoop(18, "reactor temperature", 9, None, 10, 2.83 * 10.0, 982.0, 150.0, 3.0,
                  120.40),
    PublishedLoop(13, "A in reactor feed", 23, None, 3, 18.0, 3168.0, 100.0, 360.0, 32.188),
    PublishedLoop(14, "D in reactor feed", 26, None, 1, 8.3, 3168.0, 100.0, 360.0, 6.8820),
    PublishedLoop(15, "E in reactor feed", 27, None, 2, 2.37, 5069.0, 100.0, 360.0, 18.776),
    PublishedLoop(19, "B in purge", 30, None, 6, -83.2 / 5.0 / 3.0, 6336.0, 26.0, 360.0,
                  13.823),
    PublishedLoop(20, "E in product", 38, None, 16, -16.3 / 5.0, 12408.0, 1.6, 900.0,
                  0.83570),
)
#: The published loops by their number.
LOOP_BY_NUMBER = {lp.number: lp for lp in TEMAIN_MOD_LOOPS}

#: Loop 6's override on the separator pressure (source lines 710-727).
PURGE_OVERRIDE = ValveOverride(cv=13, high=2950.0, release=2633.7, low=2300.0,
                               restart_output=40.060, restart_setpoint=0.33712)


def _out_span(lp: PublishedLoop) -> float:
    return 100.0 if lp.inner is None else LOOP_BY_NUMBER[lp.inner].span


def gain_eu(lp: PublishedLoop) -> float:
    """Gain in engineering units: % of valve (or inner CV units) per CV unit."""
    return lp.gain * _out_span(lp) / lp.span


def published_cascade(primary: int, secondary: int) -> PILoop:
    """Two published loops as one plant-side cascade: loop ``primary`` writes the set
    point of loop ``secondary``, which drives its valve.

    Parameters
    ----------
    primary, secondary : int
        The source's loop numbers; ``secondary`` must be the loop whose set point
        ``primary`` writes, and drive a valve.

    Returns
    -------
    PILoop
        The primary on its CV and the secondary's valve, gains in engineering units
        (:func:`gain_eu`), reset times in h.
    """
    outer, inner = LOOP_BY_NUMBER[primary], LOOP_BY_NUMBER[secondary]
    if outer.inner != secondary or inner.xmv is None:
        raise ValueError(f"loop {primary} does not write the set point of a valve loop "
                         f"{secondary}")
    return PILoop(outer.name, cv=outer.cv, mv=inner.xmv, gain=gain_eu(outer),
                  ti_h=outer.ti_h,
                  secondary=SecondaryLoop(inner.name, cv=inner.cv, gain=gain_eu(inner),
                                          ti_h=inner.ti_h))
