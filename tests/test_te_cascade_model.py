"""The TE MPC's linear cascade is the plant with its inner loops closed
(controller.units.te.models.closed_loop): checked against the same plant, loops and
pressure filter interconnected by python-control (``control.interconnect``, signals
joined by name), for the loops the core's models close
(controller.units.te.loops.MODEL_LOOPS) and for the plant side's, whose reactor
temperature is a cascade (controller.units.te.loops.INNER_LOOPS)."""

from __future__ import annotations

import warnings

import control as ct
import numpy as np
import pytest

from controller.units.te.grades import grade as get_grade
from controller.units.te.loops import INNER_LOOPS, MODEL_LOOPS
from controller.units.te.models import MODEL_GRADES, PRESSURE_FILTER_H, closed_loop
from plant_sim import get_plant
from plant_sim.linearize import linearize

#: Largest difference of the two frequency responses, relative to the largest response
#: (measured 5e-14 to 1.6e-13).
FREQUENCY_RESPONSE_RTOL = 1e-10
W_RAD_H = np.logspace(-2, 3, 30)


def _pi(gain: float, ti_h: float, error: str, output: str, name: str):
    # u = Kc e + Kc / Ti * integral of e
    return ct.ss([[0.0]], [[1.0]], [[gain / ti_h]], [[gain]], inputs=[error],
                 outputs=[output], name=name)


def _interconnected(grade: str, loops: tuple):
    g = get_grade(grade)
    plant = get_plant("te")
    lm = linearize(plant, plant.operating_point(g.name))
    A = lm.A.copy()
    A[:, 38] += lm.B[:, 1] * g.xmv[1] / g.xmv[0]  # the E/D ratio on the D valve's state
    ny = lm.C.shape[0]
    parts = [ct.ss(A, lm.B, lm.C, np.zeros((ny, 12)), name="plant",
                   inputs=[f"xmv{i + 1}" for i in range(12)],
                   outputs=[f"y{i + 1}" for i in range(ny)])]
    for k, lp in enumerate(loops):
        parts.append(ct.summing_junction(inputs=[f"r{k}", f"-y{lp.cv}"], output=f"e{k}",
                                         name=f"error{k}"))
        if lp.secondary is None:
            parts.append(_pi(lp.gain, lp.ti_h, f"e{k}", f"xmv{lp.mv}", f"loop{k}"))
            continue
        s = lp.secondary
        parts += [_pi(lp.gain, lp.ti_h, f"e{k}", f"rs{k}", f"loop{k}"),
                  ct.summing_junction(inputs=[f"rs{k}", f"-y{s.cv}"], output=f"es{k}",
                                      name=f"secondary_error{k}"),
                  _pi(s.gain, s.ti_h, f"es{k}", f"xmv{lp.mv}", f"secondary{k}")]
    parts.append(ct.ss([[-1.0 / PRESSURE_FILTER_H]], [[1.0 / PRESSURE_FILTER_H]], [[1.0]],
                       [[0.0]], inputs=["y7"], outputs=["pressure_filtered"], name="filter"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the level loops' set points stay unconnected (0)
        return ct.interconnect(parts, inplist=["xmv3", "xmv4", "r4", "r0", "xmv11"],
                               outlist=["pressure_filtered", "y11", "y13", "y16", "y18"],
                               check_unused=False)


def _frequency_response(A, B, C, D, w) -> np.ndarray:
    n = A.shape[0]
    return np.array([C @ np.linalg.solve(1j * x * np.eye(n) - A, B) + D for x in w])


@pytest.mark.parametrize("cascaded", [False, True], ids=["model loops", "plant loops"])
@pytest.mark.parametrize("grade", MODEL_GRADES)
def test_closed_loop_is_the_interconnected_cascade(grade, cascaded):
    loops = INNER_LOOPS if cascaded else MODEL_LOOPS
    ref = _interconnected(grade, loops)
    ours, _, _ = closed_loop(grade, loops)
    assert ours.A.shape == ref.A.shape
    h_ref = _frequency_response(ref.A, ref.B, ref.C, ref.D, W_RAD_H)
    h_ours = _frequency_response(ours.A, ours.B, ours.C, 0.0, W_RAD_H)
    assert np.abs(h_ours - h_ref).max() <= FREQUENCY_RESPONSE_RTOL * np.abs(h_ref).max()
