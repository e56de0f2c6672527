"""Tennessee Eastman linear models and their state-shared model (seed ch. 7.4/7.7,
built with the chapter-3 tooling).

Linear model per mode (modes 0, 2, 3: the base case and Ricker's 1995 optima):

1. Jacobian linearization of :class:`plant_sim.tennessee_eastman.TennesseeEastman`
   (50 states, time in h) at the mode's state and XMVs. These states are
   Ricker's steady states, which drift slightly in this code (facts), so the
   linearization point is the tabulated one, not an exact equilibrium.
2. The four regulatory PI loops of Table 7.10 (R7.11) closed in deviation
   variables, ``u = Kc (r - y) + (Kc / Ti) z``, ``z' = r - y``:
   reactor temperature (XMEAS 9) <- reactor cooling water (XMV 10),
   reactor level (XMEAS 8) <- D feed (XMV 1),
   separator level (XMEAS 12) <- separator underflow (XMV 7),
   stripper level (XMEAS 15) <- stripper underflow (XMV 8);
   Ti = 1 h for all four (the reactor-temperature value is OCR-garbled "i").
3. A unity-gain first-order filter on reactor pressure, time constant 1/300 h
   (R7.10). In this port the pressure has no direct feedthrough (D = 0
   already), the filter is kept for fidelity (one state).
4. Inputs (R7.15): XMV 3, XMV 4, XMV 6, the reactor-temperature set point T_r*,
   XMV 11. Outputs: reactor pressure (filtered), separator temperature,
   separator pressure, stripper pressure, stripper temperature.

Measured on this port: the open-loop spectrum at mode 0 spans -1968 to +3.06 1/h
(seed R7.10: -1968 to 3.11). With the four loops closed the model is **not**
Hurwitz at modes 0 and 2 (a complex pair at +0.35 +- 2.08j and +0.51 +- 2.02j
1/h, caused by the reactor-level loop on the D feed; mode 3 is stable), while
the seed reports all eigenvalues negative for its variant (38 states with T_r
as an input). With a tighter temperature loop (-2 %/degC instead of -0.5,
:data:`TE_LOOPS_TIGHT_TR`, close to treating T_r as an input) all three modes
are Hurwitz, as the seed says. Balanced truncation keeps any unstable modes and
reduces the stable part (:func:`controller.linear.balanced_truncation`,
``unstable="keep"``).

Order: with n = 8 (6 stable + 2 unstable states at modes 0 and 2, 8 at mode 3)
the stable parts keep all but Re = 1.7 %, 1.3 %, 0.3 % (eq. 3.22), and the
state-shared form reproduces every reduced model's frequency response to
~1e-10; n = 10 would give Re <= 0.2 % but only 1e-5..1e-7 accuracy of the
coefficient representation, and the seed's n = 40 none at all (see the
numerical limits in :mod:`controller.state_shared`). The state-shared model
has 2nm = 80 states and n(m^2+1) = 208 parameters per model. With
:data:`TE_LOOPS_TIGHT_TR` all three reduced models are stable with Re = 0.99 %,
0.94 %, 0.70 % at n = 8.

In the orthonormal shared-state basis (``basis="orthonormal"``, omega's roots
at the mode-0 model's poles, the unstable pair reflected) the seed's order is
available: at n = 40 (2nm = 400) every mode's reduced model is represented to
7e-13, 2e-11, 1e-10 (measured; |Theta| up to 2e5 for mode 2, whose poles
moved farthest from mode 0's).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from controller.linear import BalancedTruncation, Realization, balanced_truncation
from controller.shared_basis import BASES, SharedBasis, roots_from_poles
from controller.state_shared import ModelSpec, StateSharedModel, designer_polynomial
from controller.units.te.models import ADAPTIVE_MODEL

__all__ = ["TE_LOOPS", "TE_LOOPS_TIGHT_TR", "TE_INPUTS", "TE_OUTPUTS", "TE_MODES", "TEClosedLoop",
           "te_closed_loop", "te_reduced", "te_state_shared_model", "TE_ORDER",
           "TE_DESIGNER_ROOTS"]

#: (XMEAS, XMV, Kc, Ti in h), 1-based, Table 7.10 (R7.11).
TE_LOOPS = ((9, 10, -0.5, 1.0), (8, 1, 4.0, 1.0), (12, 7, -5.0, 1.0), (15, 8, -1.5, 1.0))
#: MPC inputs: XMV numbers, None = reactor-temperature set point (R7.15).
TE_INPUTS = (3, 4, 6, None, 11)
TE_INPUT_NAMES = ("XMV3", "XMV4", "XMV6", "Tr_sp", "XMV11")
#: MPC outputs (XMEAS numbers); the first is filtered.
TE_OUTPUTS = (7, 11, 13, 16, 18)
TE_OUTPUT_NAMES = ("reactor_pressure_f", "separator_temperature", "separator_pressure",
                   "stripper_pressure", "stripper_temperature")
PRESSURE_FILTER_H = 1.0 / 300.0
TE_MODES = ("mode0", "mode2", "mode3")
TE_ORDER = 8
#: roots of omega, 1/h: a geometric spread over the retained poles' range
TE_DESIGNER_ROOTS = tuple(-np.geomspace(0.05, 20.0, TE_ORDER))


@dataclass(frozen=True)
class TEClosedLoop:
    """TE with the regulatory loops closed and the pressure filter, about one mode."""

    mode: str
    model: Realization  # states: 50 plant + 4 PI integrators + 1 filter
    u_op: np.ndarray  # (5,) XMV3, XMV4, XMV6, Tr*, XMV11 at the mode
    y_op: np.ndarray  # (5,) the outputs at the mode
    input_names: tuple[str, ...] = TE_INPUT_NAMES
    output_names: tuple[str, ...] = TE_OUTPUT_NAMES
    time_unit: str = "h"


@lru_cache(maxsize=8)
def _te_linearization(mode: str):
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    plant = get_plant("te")
    return linearize(plant, plant.operating_point(mode))


#: Table 7.10 with a tighter reactor-temperature loop (-2 %/degC): close to the seed's
#: variant with T_r as an input; Hurwitz at modes 0, 2 and 3 (max Re -0.072, -0.072,
#: -0.016 1/h), as R7.10 says of the seed's model.
TE_LOOPS_TIGHT_TR = ((9, 10, -2.0, 1.0),) + TE_LOOPS[1:]


@lru_cache(maxsize=8)
def te_closed_loop(mode: str, loops: tuple = TE_LOOPS) -> TEClosedLoop:
    """Linear TE model about ``mode`` with PI ``loops`` (default Table 7.10) closed.

    ``loops`` holds (XMEAS, XMV, Kc, Ti) tuples; the first must be the reactor
    temperature loop (its set point is an input).
    """
    lm = _te_linearization(mode)
    A, B, C = lm.A, lm.B, lm.C
    nx = A.shape[0]
    if loops[0][0] != 9:
        raise ValueError("loops: the first loop must control the reactor temperature (XMEAS 9)")
    nl = len(loops)
    yl = [lp[0] - 1 for lp in loops]
    ul = [lp[1] - 1 for lp in loops]
    Kc = np.array([lp[2] for lp in loops])
    Ti = np.array([lp[3] for lp in loops])
    CL, BL = C[yl], B[:, ul]
    N = nx + nl + 1
    Acl = np.zeros((N, N))
    Acl[:nx, :nx] = A - BL @ np.diag(Kc) @ CL
    Acl[:nx, nx : nx + nl] = BL @ np.diag(Kc / Ti)
    Acl[nx : nx + nl, :nx] = -CL
    Acl[-1, :nx] = C[TE_OUTPUTS[0] - 1] / PRESSURE_FILTER_H
    Acl[-1, -1] = -1.0 / PRESSURE_FILTER_H
    Bcl = np.zeros((N, len(TE_INPUTS)))
    for j, mv in enumerate(TE_INPUTS):
        if mv is None:  # set-point of loop 0 (reactor temperature)
            Bcl[:nx, j] = BL[:, 0] * Kc[0]
            Bcl[nx, j] = 1.0
        else:
            Bcl[:nx, j] = B[:, mv - 1]
    Ccl = np.zeros((len(TE_OUTPUTS), N))
    Ccl[0, -1] = 1.0
    for i, cv in enumerate(TE_OUTPUTS[1:], start=1):
        Ccl[i, :nx] = C[cv - 1]
    y = lm.y_op
    u_op = np.array([lm.u_op[mv - 1] if mv is not None else y[loops[0][0] - 1]
                     for mv in TE_INPUTS])
    y_op = np.array([y[cv - 1] for cv in TE_OUTPUTS])
    return TEClosedLoop(mode, Realization(Acl, Bcl, Ccl, None), u_op, y_op)


@lru_cache(maxsize=8)
def te_reduced(mode: str, order: int = TE_ORDER, loops: tuple = TE_LOOPS) -> BalancedTruncation:
    """Balanced truncation to ``order`` states (unstable modes kept)."""
    return balanced_truncation(te_closed_loop(mode, loops).model, order=order,
                               unstable="keep")


def te_state_shared_model(dt: float, order: int = TE_ORDER, roots=None,
                          loops: tuple = TE_LOOPS, basis: str = "companion") -> StateSharedModel:
    """State-shared model of R7.15 at a numerically sane order.

    Three fixed models (modes 0, 2, 3, each about its own operating point via
    the bias) and one adaptive slot ("reinit", starting as the mode-0 model).

    Parameters
    ----------
    dt : float
        Sample time in h.
    order : int
        n, the MFD degree (the reduced order of every mode).
    roots : sequence of complex, optional
        Roots of the designer polynomial omega, 1/h (length ``order``). Default:
        :data:`TE_DESIGNER_ROOTS` in the companion basis; in the orthonormal basis
        the mode-0 model's poles, unstable ones reflected
        (:func:`controller.shared_basis.roots_from_poles`).
    loops : tuple
        Regulatory loops (default Table 7.10; :data:`TE_LOOPS_TIGHT_TR` gives
        Hurwitz models at all three modes).
    basis : {"companion", "orthonormal"}
        Coordinates of the shared state. The orthonormal basis represents the
        seed's n = 40 (order 400) to about 1e-11; the companion one only n <= 8.
    """
    if basis not in BASES:
        raise ValueError(f"basis: must be one of {BASES}, got {basis!r}")
    if basis == "companion":
        a = designer_polynomial(TE_DESIGNER_ROOTS if roots is None else roots)
        if a.size != order:
            raise ValueError(f"roots: expected {order} roots (the order), got {a.size}")
    else:
        if roots is None:
            roots = roots_from_poles(te_reduced(TE_MODES[0], order, loops).reduced.poles())
        a = SharedBasis.orthonormal(roots)
        if a.n != order:
            raise ValueError(f"roots: expected {order} roots (the order), got {a.n}")
    ssm = StateSharedModel(a, len(TE_INPUTS), dt)
    for mode in TE_MODES:
        cl = te_closed_loop(mode, loops)
        r = te_reduced(mode, order, loops).reduced
        ssm.add_model(StateSharedModel.model_from_linear(mode, r.A, r.B, r.C, cl.u_op,
                                                         cl.y_op, a))
    first = ssm.model(0)
    ssm.add_model(ModelSpec(ADAPTIVE_MODEL, first.theta, first.bias, "adaptive"))
    return ssm
