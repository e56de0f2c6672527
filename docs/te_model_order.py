"""Measure the table "The order" of ``controller.units.te.models``.

For n = 8, 10, 12, 16 and each model grade (modes 0, 2, 3): the reduction's DC error
(the largest entry of the feedthrough ``D`` that the strictly proper state-shared
models drop) and the largest deviation of the reduced ``(A, B, C)``'s step responses
from the full cascade's over 0.05-100 h, in units of the CV scales; then the DC gains
of the state-shared models the MPC runs on (orthonormal basis) against the cascade's:
the largest error of a gain to the reactor pressure, and the condenser's (XMV 11)
gains to the reactor pressure and the separator temperature. First, per grade, the
slowest mode of the cascade and of the MPC's reduced model.

    PYTHONPATH=. python docs/te_model_order.py     # about half a wall minute

The cascade is :func:`controller.units.te.models.closed_loop` with the inner loops of
:data:`controller.units.te.loops.MODEL_LOOPS` as they stand (the loops the core's models
are linearized with).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import expm

from controller.units.te.models import (
    MODEL_GRADES,
    MPC_ORDER,
    closed_loop,
    reduced,
    state_shared_model,
)
from controller.units.te.targets import model_steady_state

#: CV scales: reactor pressure kPa, separator temperature degC, separator and stripper
#: pressure kPa, stripper temperature degC.
SCALES = np.array([20.0, 1.0, 20.0, 20.0, 1.0])
#: Step sizes: XMV 3 %, XMV 4 %, P_r* kPa, T_r* degC, XMV 11 %.
STEPS = np.array([10.0, 10.0, 50.0, 1.0, 10.0])
TIMES_H = np.concatenate([np.linspace(0.05, 1.0, 40), np.linspace(1.0, 100.0, 400)])
ORDERS = (8, 10, 12, 16)
PRESSURE, SEPARATOR_T, CONDENSER = 0, 1, 4


def step_responses(A: np.ndarray, B: np.ndarray, C: np.ndarray) -> np.ndarray:
    """Responses to :data:`STEPS` at :data:`TIMES_H` in CV scales, shape (t, cv, input)."""
    n = A.shape[0]
    x_ss = np.linalg.solve(A, B * STEPS)
    out = np.array([C @ (expm(A * t) - np.eye(n)) @ x_ss for t in TIMES_H])
    return out / SCALES[None, :, None]


def cascade_dc_gain(grade: str) -> np.ndarray:
    sys, _, _ = closed_loop(grade)
    return -sys.C @ np.linalg.solve(sys.A, sys.B)


def main() -> None:
    for g in MODEL_GRADES:
        sys, _, _ = closed_loop(g)
        slowest = reduced(g, MPC_ORDER).reduced.poles().real.max()
        print(f"{g}: largest real part of the cascade's eigenvalues "
              f"{np.linalg.eigvals(sys.A).real.max():+.3f} 1/h, of the order-{MPC_ORDER} "
              f"model's {slowest:+.3f} 1/h")
    fmt = lambda v, spec: " / ".join(format(x, spec) for x in v)  # noqa: E731
    print("n   DC error (max |D|)      step-response error (of the largest response)")
    for n in ORDERS:
        dc, err, big = [], [], []
        for g in MODEL_GRADES:
            sys, _, _ = closed_loop(g)
            r = reduced(g, n).reduced
            dc.append(0.0 if r.D is None else np.abs(r.D).max())
            full, red = step_responses(sys.A, sys.B, sys.C), step_responses(r.A, r.B, r.C)
            err.append(np.abs(full - red).max())
            big.append(np.abs(full).max())
        print(f"{n:<3} {fmt(dc, '.2f'):<23} {fmt(err, '.1f')} (of {fmt(big, '.1f')})")
    print("n   pressure gain error   condenser->pressure   condenser->separator T (plant)")
    for n in ORDERS[:3]:
        ssm = state_shared_model(0.01, adaptive=False, order=n, basis="orthonormal")
        e, cp, cs, ps = [], [], [], []
        for j, g in enumerate(MODEL_GRADES):
            model, plant = model_steady_state(ssm, j)[0], cascade_dc_gain(g)
            e.append(np.abs(model[PRESSURE] - plant[PRESSURE]).max())
            cp.append(model[PRESSURE, CONDENSER])
            cs.append(model[SEPARATOR_T, CONDENSER])
            ps.append(plant[SEPARATOR_T, CONDENSER])
        print(f"{n:<3} {fmt(e, '.2f'):<21} {fmt(cp, '+.2f'):<21} {fmt(cs, '+.2f')} "
              f"({fmt(ps, '+.2f')})")


if __name__ == "__main__":
    main()
