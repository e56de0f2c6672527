"""Decentralized PI baseline for the Tennessee Eastman grade changes (non-MPC comparison).

Same plant, same inner layer (Table 7.10 loops at the Euler step), same supervisory
pieces as the MPC strategies (grade references, D/E ratio for G mol%, XMV(5)/XMV(9)
ramps); only the five MPC handles are driven differently. The structure is the
simplest multiloop one that holds the original plant (after Ricker 1996 and
McAvoy & Ye 1994, reduced):

========================  =======================  ===========================
controlled variable       manipulated variable     note
========================  =======================  ===========================
reactor pressure XMEAS 7  purge valve XMV 6        inner loop (te_control)
separator temp XMEAS 11   condenser CW XMV 11
A in reactor feed XMEAS 23  A feed XMV 3           keeps A/C in balance
product flow XMEAS 17     A+C feed XMV 4           plus grade feedforward
reactor temperature       reactor temperature SP   grade reference (Table 7.3)
========================  =======================  ===========================

Each loop is a velocity PI at the supervisory sample with the grade's valve
feedforward added as increments, ``u_k = u_{k-1} + Δff_k + Kc (Δe_k + dt/Ti e_k)``,
``e = reference - measurement``; a limited output does not wind up.
Stripper temperature and pressure and separator pressure are left free (they
are not independent of reactor pressure with these handles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.readback import finite_number, finite_vector

__all__ = ["PILoopSpec", "PI_BASELINE_LOOPS", "PRODUCTION_LOOP", "VelocityPI"]


@dataclass(frozen=True)
class PILoopSpec:
    """One supervisory PI loop.

    Parameters
    ----------
    name : str
    cv : int
        XMEAS number (1-based) of the controlled variable.
    output : int
        Index of the core output it drives: 0 XMV3, 1 XMV4, 2 XMV6, 3 Tr*, 4 XMV11.
    gain : float
        Controller gain, output units per CV unit (sign: ``e = r - y``).
    ti_h : float
        Integral time, h (> 0).
    """

    name: str
    cv: int
    output: int
    gain: float
    ti_h: float

    def __post_init__(self) -> None:
        if not 1 <= self.cv <= 41:
            raise ValueError(f"cv: XMEAS number must be 1..41, got {self.cv!r}")
        if not 0 <= self.output <= 4:
            raise ValueError(f"output: core output index must be 0..4, got {self.output!r}")
        if not math.isfinite(self.gain):
            raise ValueError(f"gain: must be finite, got {self.gain!r}")
        if not (math.isfinite(self.ti_h) and self.ti_h > 0):
            raise ValueError(f"ti_h: must be > 0 h, got {self.ti_h!r}")


#: Production (stripper underflow XMEAS 17, m3/h) -> A+C feed XMV 4, on top of the
#: grade feedforward: keeps the product flow when a feed is lost (IDV 6).
PRODUCTION_LOOP = PILoopSpec("production -> A+C feed", cv=17, output=1, gain=1.0, ti_h=2.0)

#: The baseline's loops (tuned on this port; see the module docstring).
PI_BASELINE_LOOPS = (
    PRODUCTION_LOOP,
    PILoopSpec("separator temperature -> condenser CW", cv=11, output=4, gain=-2.0, ti_h=0.5),
    PILoopSpec("A in reactor feed -> A feed", cv=23, output=0, gain=2.0, ti_h=1.0),
)


class VelocityPI:
    """Velocity-form PI loops on the five core outputs with feedforward increments.

    Parameters
    ----------
    loops : sequence of PILoopSpec
    dt_h : float
        Sample time, h.
    u_min, u_max : array_like, shape (5,)
        Output limits.
    """

    def __init__(self, loops, dt_h: float, u_min, u_max) -> None:
        self.loops = tuple(loops)
        self.dt_h = float(dt_h)
        self.u_min = np.asarray(u_min, dtype=float)
        self.u_max = np.asarray(u_max, dtype=float)
        self.e_prev = np.full(len(self.loops), np.nan)
        self.u: np.ndarray | None = None
        self.ff_prev: np.ndarray | None = None

    def step(self, xmeas, ref_xmeas, ff) -> np.ndarray:
        """One sample.

        Parameters
        ----------
        xmeas : array_like, shape (41,)
            Measurements.
        ref_xmeas : array_like, shape (41,)
            Their references (grade trajectory).
        ff : array_like, shape (5,)
            Feedforward of the five outputs (grade trajectory); a loop-free output
            follows it exactly.
        """
        ff = np.asarray(ff, dtype=float)
        if self.u is None:
            self.u = ff.copy()
        if self.ff_prev is None:  # after start(): no feedforward move on the first sample
            self.ff_prev = ff.copy()
        u = self.u + (ff - self.ff_prev)
        self.ff_prev = ff.copy()
        for i, lp in enumerate(self.loops):
            e = float(ref_xmeas[lp.cv - 1] - xmeas[lp.cv - 1])
            if not math.isfinite(e):
                continue
            if not math.isfinite(self.e_prev[i]):
                self.e_prev[i] = e
            u[lp.output] += lp.gain * ((e - self.e_prev[i]) + self.dt_h / lp.ti_h * e)
            self.e_prev[i] = e
        self.u = np.clip(u, self.u_min, self.u_max)
        return self.u.copy()

    def start(self, u0) -> None:
        """Bumpless start from the outputs in force."""
        self.u = np.asarray(u0, dtype=float).copy()

    def applied(self, u) -> None:
        """The plant got ``u`` instead of the last outputs (a missed deadline): the
        velocity form goes on from it (clipped to the limits); before the first sample
        there is nothing to go on from."""
        if self.u is not None:
            self.u = np.clip(np.asarray(u, dtype=float), self.u_min, self.u_max)

    def checkpoint(self) -> dict[str, Any]:
        return {"u": None if self.u is None else self.u.tolist(),
                "ff_prev": None if self.ff_prev is None else self.ff_prev.tolist(),
                "e_prev": [None if not math.isfinite(v) else v for v in self.e_prev]}

    def restore(self, state: dict[str, Any]) -> None:
        """Take the outputs, the feedforward and the loops' previous errors back.

        Raises
        ------
        ValueError
            When the outputs and the feedforward are not both absent or both finite
            vectors of the outputs' length, or the errors are not one finite number or
            None per loop: the outputs are this controller's state, so a damaged one
            refuses the checkpoint rather than start from a guess.
        """
        n = self.u_min.size
        u, ff = state["u"], state["ff_prev"]
        if (u is None) != (ff is None):
            raise ValueError("PI baseline: outputs and feedforward go together")
        if u is not None:
            u = finite_vector(u, n, "PI baseline: outputs")
            ff = finite_vector(ff, n, "PI baseline: feedforward")
        e = state["e_prev"]
        if not isinstance(e, list) or len(e) != len(self.loops) or not all(
                v is None or finite_number(v) for v in e):
            raise ValueError(f"PI baseline: expected {len(self.loops)} previous errors "
                             "(finite numbers or None)")
        self.u, self.ff_prev = u, ff
        self.e_prev = np.array([np.nan if v is None else float(v) for v in e])
