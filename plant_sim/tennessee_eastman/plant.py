"""The Tennessee Eastman plant as a :class:`~plant_sim.base.PlantModel` (registry name ``te``).

``rhs`` and ``outputs`` are pure: each call evaluates the model once from a fresh
model memory (temperature-solver start 0.0, random processes at their centre
values, valve commands equal to the XMVs), at t = 0 and without noise. The
model is time-invariant, so ``t`` does not enter. The disturbance vector holds
the 20 IDV flags (> 0 is on): the step disturbances IDV 1-7 act; the random ones
act only through their random processes, which sit at their centres here, and
the sticking valves never stick at t = 0. For runs with noise, random
disturbances, analyzers and interlock records use :class:`TESimulator`.
"""

from __future__ import annotations

import numpy as np

from plant_sim.base import OperatingPoint, PlantModel, Variable, as_vector
from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman import model as M
from plant_sim.tennessee_eastman.modes import MODES, grade_name, start_state
from plant_sim.tennessee_eastman.random import ORIGINAL_SEED

__all__ = ["TennesseeEastman", "STATE_VARS", "INPUT_VARS", "OUTPUT_VARS", "DISTURBANCE_VARS"]

_COMP = "ABCDEFGH"
_state_desc = (
    [f"reactor vapour holdup of {c}" for c in "ABC"]
    + [f"reactor liquid holdup of {c}" for c in "DEFGH"]
    + ["reactor energy holdup"]
    + [f"separator vapour holdup of {c}" for c in "ABC"]
    + [f"separator liquid holdup of {c}" for c in "DEFGH"]
    + ["separator energy holdup"]
    + [f"stripper liquid holdup of {c}" for c in _COMP]
    + ["stripper energy holdup"]
    + [f"vapour-header holdup of {c}" for c in _COMP]
    + ["vapour-header energy holdup",
       "reactor cooling-water outlet temperature",
       "condenser cooling-water outlet temperature"]
    + [f"valve position of XMV {i}" for i in range(1, 13)]
)
_state_unit = (["lb-mol"] * 8 + ["energy"] + ["lb-mol"] * 8 + ["energy"] + ["lb-mol"] * 8
               + ["energy"] + ["lb-mol"] * 8 + ["energy", "degC", "degC"] + ["%"] * 12)
STATE_VARS = tuple(Variable(f"X{i + 1}", u, d) for i, (u, d) in
                   enumerate(zip(_state_unit, _state_desc, strict=True)))

_xmv_desc = ("D feed flow (stream 2)", "E feed flow (stream 3)", "A feed flow (stream 1)",
             "A and C feed flow (stream 4)", "compressor recycle valve", "purge valve (stream 9)",
             "separator pot liquid flow (stream 10)", "stripper liquid product flow (stream 11)",
             "stripper steam valve", "reactor cooling-water flow",
             "condenser cooling-water flow", "agitator speed")
INPUT_VARS = tuple(Variable(f"XMV{i + 1}", "%", d, 0.0, 100.0) for i, d in enumerate(_xmv_desc))

_xmeas = (
    ("kscmh", "A feed (stream 1)"), ("kg/h", "D feed (stream 2)"),
    ("kg/h", "E feed (stream 3)"), ("kscmh", "A and C feed (stream 4)"),
    ("kscmh", "recycle flow (stream 8)"), ("kscmh", "reactor feed rate (stream 6)"),
    ("kPa gauge", "reactor pressure"), ("%", "reactor level"), ("degC", "reactor temperature"),
    ("kscmh", "purge rate (stream 9)"), ("degC", "product separator temperature"),
    ("%", "product separator level"), ("kPa gauge", "product separator pressure"),
    ("m3/h", "separator underflow (stream 10)"), ("%", "stripper level"),
    ("kPa gauge", "stripper pressure"), ("m3/h", "stripper underflow (stream 11)"),
    ("degC", "stripper temperature"), ("kg/h", "stripper steam flow"),
    ("kW", "compressor work"), ("degC", "reactor cooling-water outlet temperature"),
    ("degC", "separator cooling-water outlet temperature"),
) + tuple(("mol%", f"reactor feed (stream 6) {c}") for c in "ABCDEF") \
  + tuple(("mol%", f"purge gas (stream 9) {c}") for c in _COMP) \
  + tuple(("mol%", f"product (stream 11) {c}") for c in "DEFGH")
OUTPUT_VARS = tuple(Variable(f"XMEAS{i + 1}", u, d) for i, (u, d) in enumerate(_xmeas))

_idv_desc = ("A/C feed ratio, B composition constant (stream 4), step",
             "B composition, A/C ratio constant (stream 4), step", "D feed temperature, step",
             "reactor cooling-water inlet temperature, step",
             "condenser cooling-water inlet temperature, step", "A feed loss (stream 1), step",
             "C header pressure loss (stream 4), step",
             "A, B, C feed composition (stream 4), random",
             "D feed temperature, random", "C feed temperature (stream 4), random",
             "reactor cooling-water inlet temperature, random",
             "condenser cooling-water inlet temperature, random",
             "reaction kinetics, slow drift", "reactor cooling-water valve, sticking",
             "condenser cooling-water valve, sticking", "stripper heat transfer (unknown)",
             "reactor heat transfer spikes (unknown)", "condenser heat transfer spikes (unknown)",
             "valves of XMV 5, 7, 8, 9 sticking (unknown)",
             "reactor effluent flow coefficient spikes (unknown)")
DISTURBANCE_VARS = tuple(Variable(f"IDV{i + 1}", "-", d, 0.0, 1.0)
                         for i, d in enumerate(_idv_desc))


class TennesseeEastman(PlantModel):
    """Tennessee Eastman challenge process (Downs & Vogel 1993), time in hours.

    Parameters
    ----------
    literals : {"single", "double"}
        Published build (default) or all-double literals.
    """

    name = "te"
    title = "Tennessee Eastman challenge process (Downs & Vogel 1993)"
    time_unit = "h"
    state_vars = STATE_VARS
    input_vars = INPUT_VARS
    output_vars = OUTPUT_VARS
    disturbance_vars = DISTURBANCE_VARS

    def __init__(self, literals: str = "single") -> None:
        self.literals = literals
        self._K = C.materialize(literals)
        self._ops: dict[str, OperatingPoint] | None = None

    def _evaluate(self, x, u, d) -> tuple[np.ndarray, np.ndarray]:
        x = as_vector(x, 50, "x")
        u = as_vector(u, 12, "u")
        d = as_vector(d, 20, "d")
        idv = (d > 0).astype(np.int64)
        mem = M.new_memory(self._K, ORIGINAL_SEED)
        xmeas = np.zeros(41)
        yp = np.zeros(50)
        M.tefunc(self._K, False, 0.0, x.copy(), u, idv, mem, M.new_work(), xmeas, yp)
        return yp, xmeas

    def rhs(self, t, x, u, d=None) -> np.ndarray:
        """Noise-free derivative (50,) in state units per hour; zero if an interlock trips."""
        return self._evaluate(x, u, np.zeros(20) if d is None else d)[0]

    def outputs(self, x, u) -> np.ndarray:
        """Noise-free XMEAS (41,), analyzers equal to the current compositions."""
        return self._evaluate(x, u, np.zeros(20))[1]

    @property
    def operating_points(self) -> dict[str, OperatingPoint]:
        if self._ops is None:
            ops = {}
            for mode in MODES:
                x = start_state(mode, self.literals)
                name = grade_name(mode)
                if mode == "base":
                    desc = "Downs & Vogel base case (published initial state of teprob.f)"
                    conf = "verified"
                else:
                    desc = (f"Ricker (1995) optimal steady state of mode {mode}, "
                            "states to about 7 digits")
                    conf = "text"
                ops[name] = OperatingPoint(name=name, x=x, u=x[38:50].copy(), d=np.zeros(20),
                                           description=desc, stability="unstable",
                                           stability_detail="open loop: levels and reactor "
                                           "temperature unstable (seed ch. 7.3)",
                                           confidence=conf)
            self._ops = ops
        return self._ops
