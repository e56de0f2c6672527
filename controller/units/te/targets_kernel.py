"""Compiled per-sample arithmetic of the TE core's steady-state targets.

:class:`controller.units.te.targets.CoreTargets` keeps the targets' state, the
steady-state cache, the economics' ramp and the QP; this module does the sample's
small dense arithmetic on the five handles and the five CVs in one compiled call
each, in the order and with the IEEE operations of the numpy expressions they
replace (no fast-math: no fused multiply-add; the gain's matrix-vector products are
the BLAS ``dgemv`` numpy calls, through numba's ``@``), so every number is the
numpy path's to the last bit (``tests/test_te_targets_kernel.py``):

- :func:`offset_step`: the slow offset ``d`` of the plant from the active model's
  steady state about the plan (:meth:`CoreTargets.observe
  <controller.units.te.targets.CoreTargets.observe>`)::

      du_lag <- du_lag + lag (u - u_plan - du_lag)
      d      <- d + alpha ((y - y_plan - G du_lag) - d)

- :func:`target_fields`: the target problem's moving fields (the plan's handles in
  their ranges, the box ``u_ref -+ band`` with P_r*'s economic lift) and the two
  answers without a QP of :meth:`CoreTargets.solve
  <controller.units.te.targets.CoreTargets.solve>`: the plan's point as it stands
  (no priced handle can move and ``y_plan + d`` meets the CV limits), or every
  handle at the bound its own minimizer ``u_ref - c_u / q_u`` lies on or beyond,
  with the CV limits held there by more than the tolerance
  (``y = y_plan + d - G u_ref + G u``).

Shapes: G (5, 5) CV units per handle unit; handles (5,) in % / kPa / degC; CVs (5,)
in kPa / degC; ``lag``, ``alpha`` dimensionless; costs in $/h per handle unit.

**Measured** (ssmpc, the 0 -> 2 -> 3 plan over 24 h, noise off; per-call median of a
timer around each method over the run's 2,400 samples, the code before and after in
two processes back to back, two pairs; AMD EPYC 2 vCPU shared with a 2-process
campaign, load 4-5)::

    piece                               numpy path     kernels
    CoreTargets.observe                 14.9-15.8 us   6.2-6.6 us
    CoreTargets.solve                   40.1-41.5 us   16.8 us
    TEController._steady_targets        64.6-67.8 us   33.5 us
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["PLAN", "AT_BOUNDS", "QP", "NO_TARGETS", "compile_targets_kernels", "offset_step",
           "target_fields"]

#: Outcomes of :func:`target_fields`: the plan's point stands, the box's bounds are the
#: answer, the QP decides, no targets (the plan's handles or CVs not finite).
PLAN, AT_BOUNDS, QP, NO_TARGETS = range(4)


@njit(cache=True)
def _np_max(a, b):  # numpy.maximum of two floats (a NaN wins)
    if math.isnan(a) or a > b:
        return a
    return b


@njit(cache=True)
def _np_min(a, b):  # numpy.minimum of two floats (a NaN wins)
    if math.isnan(a) or a < b:
        return a
    return b


@njit(cache=True)
def offset_step(G, y, u, y_plan, u_plan, du_lagged, offset, lag, alpha):
    """One sample of the targets' offset filter, in place.

    Parameters
    ----------
    G : ndarray, shape (p, m)
        Steady-state gain of the active model.
    y, u : ndarray, shapes (p,), (m,)
        Measured CVs and the handles applied.
    y_plan, u_plan : ndarray, shapes (p,), (m,)
        The plan's CVs and handles at the same time.
    du_lagged : ndarray, shape (m,)
        In/out: the handles' departure from the plan through the response lag.
    offset : ndarray, shape (p,)
        In/out: the slow offset ``d``.
    lag, alpha : float
        ``1 - exp(-dt / tau)`` of the response lag and of the offset filter.

    Returns
    -------
    bool
        False (nothing changed) when an input is not finite.
    """
    p, m = y.size, u.size
    for i in range(p):
        if not (math.isfinite(y[i]) and math.isfinite(y_plan[i])):
            return False
    for i in range(m):
        if not (math.isfinite(u[i]) and math.isfinite(u_plan[i])):
            return False
    for i in range(m):
        du = u[i] - u_plan[i]
        du_lagged[i] += lag * (du - du_lagged[i])
    g = G @ du_lagged
    for i in range(p):
        e = y[i] - y_plan[i] - g[i]
        offset[i] += alpha * (e - offset[i])
    return True


@njit(cache=True)
def target_fields(G, u_plan, y_plan, bias, u_min, u_max, band, priced, cost_u, lift,
                  i_lift, q_u, y_min, y_max, tol):
    """The sample's moving fields and the answer when no QP is needed.

    Parameters
    ----------
    G : ndarray, shape (p, m)
    u_plan, y_plan : ndarray, shapes (m,), (p,)
        The plan's handles and CVs at the horizon's end.
    bias : ndarray, shape (p,)
        The offset ``d``.
    u_min, u_max, band : ndarray, shape (m,)
        Handle ranges and how far each target may leave the plan.
    priced : bool
        Whether the economics price the handles (``cost_u`` used).
    cost_u : ndarray, shape (m,)
        The priced cost's gradient times the economic weight.
    lift : float
        How far above the plan the economics may take handle ``i_lift``.
    i_lift : int
        The handle the lift applies to (P_r*).
    q_u : ndarray, shape (m,)
        The handles' weights toward the plan.
    y_min, y_max : ndarray, shape (p,)
        CV limits.
    tol : ndarray, shape (p,)
        The solver's violation tolerance in CV units (priced answers only).

    Returns
    -------
    outcome : int
        :data:`PLAN`, :data:`AT_BOUNDS`, :data:`QP` or :data:`NO_TARGETS` (the other
        answers then undefined).
    cheaper : bool
        A priced handle can move from the plan to a cheaper value within its box (the
        answer at the bounds was tried).
    checked : bool
        The moving fields (G, u_ref, y_plan, d, the box) are finite and the box is
        not empty (what the solver checks of them every sample).
    u_ref, u_lo, u_hi : ndarray, shape (m,)
        The plan's handles in their ranges and the box.
    u, y : ndarray, shapes (m,), (p,)
        The answer (PLAN: ``u_ref`` and ``y_plan + d``; AT_BOUNDS: the bounds and
        the model's CVs there; QP: undefined).
    """
    p, m = y_plan.size, u_plan.size
    u = np.empty(m)
    y = np.empty(p)
    u_ref = np.empty(m)
    u_lo = np.empty(m)
    u_hi = np.empty(m)
    for i in range(m):
        if not math.isfinite(u_plan[i]):
            return NO_TARGETS, False, False, u_ref, u, u, u, y
    for i in range(p):
        if not math.isfinite(y_plan[i]):
            return NO_TARGETS, False, False, u_ref, u, u, u, y
    for i in range(m):
        r = _np_min(_np_max(u_plan[i], u_min[i]), u_max[i])
        u_ref[i] = r
        u_lo[i] = _np_max(u_min[i], r - band[i])
        u_hi[i] = _np_min(u_max[i], r + band[i])
    if priced:
        cap = u_ref[i_lift] + lift
        if cap < u_hi[i_lift]:  # Python's min(u_hi, cap)
            u_hi[i_lift] = cap
    checked = True
    for i in range(p):
        for j in range(m):
            if not math.isfinite(G[i, j]):
                checked = False
        if not (math.isfinite(y_plan[i]) and math.isfinite(bias[i])):
            checked = False
    for i in range(m):
        if not (math.isfinite(u_ref[i]) and math.isfinite(u_lo[i])
                and math.isfinite(u_hi[i]) and u_lo[i] <= u_hi[i]):
            checked = False
    cheaper = False
    if priced:
        for i in range(m):
            c = cost_u[i]
            if (c < 0.0 and u_ref[i] < u_hi[i]) or (c > 0.0 and u_ref[i] > u_lo[i]):
                cheaper = True
    if not cheaper:
        for i in range(p):
            y[i] = y_plan[i] + bias[i]
            if not (y[i] >= y_min[i] and y[i] <= y_max[i]):
                return QP, cheaper, checked, u_ref, u_lo, u_hi, u, y
        for i in range(m):
            u[i] = u_ref[i]
        return PLAN, cheaper, checked, u_ref, u_lo, u_hi, u, y
    for i in range(m):
        q = q_u[i]
        x = -(cost_u[i] - q * u_ref[i]) / q
        if x >= u_hi[i]:
            u[i] = u_hi[i]
        elif x <= u_lo[i]:
            u[i] = u_lo[i]
        else:
            return QP, cheaper, checked, u_ref, u_lo, u_hi, u, y
    g0 = G @ u_ref
    g1 = G @ u
    for i in range(p):
        y[i] = ((y_plan[i] + bias[i]) - g0[i]) + g1[i]
        if not (y[i] <= y_max[i] - tol[i] and y[i] >= y_min[i] + tol[i]):
            return QP, cheaper, checked, u_ref, u_lo, u_hi, u, y
    return AT_BOUNDS, cheaper, checked, u_ref, u_lo, u_hi, u, y


def compile_targets_kernels() -> None:
    """Compile both kernels (or load them from numba's on-disk cache) now, for the
    argument types :class:`~controller.units.te.targets.CoreTargets` passes, so that no
    sample pays for it. Cheap after the first call in a process."""
    if offset_step.signatures and target_fields.signatures:
        return
    G, v = np.eye(2), np.zeros(2)
    offset_step(G, v, v, v, v, np.zeros(2), np.zeros(2), 0.5, 0.5)
    target_fields(G, v, v, v, v, np.ones(2), v, True, v, 0.0, 0, np.ones(2), v - 1.0,
                  v + 1.0, v)
