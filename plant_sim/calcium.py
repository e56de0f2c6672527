"""Cardiac calcium-induced calcium release (Tang-Othmer CICR): seed eq. 3.27-3.29.

**Reconstructed model.** The structure is the seed's; the flux parameters of Tang &
Othmer (Biophys. J. 67, 1994) are not available and were fitted to the numbers the
seed prints (docs/calcium_reconstruction.md, reproducible with docs/calcium_fit.py).

Ryanodine-receptor (RyR) kinetics with independent activating (+) and inactivating (-)
Ca binding sites; x1 = [R], x2 = [RC+] (open), x3 = [RC+C-], x4 = [RC-] =
1 - x1 - x2 - x3 (fractions of [R]T); x5 cytosolic Ca, x6 SR Ca (uM):

    dx1/dt = k-1 x2 + k-2 x4 - (k1 + k2) x1 x5                      (3.27)
    dx2/dt = -k-1 x2 + k-2 x3 + (k1 x1 - k2 x2) x5
    dx3/dt = -(k-1 + k-2) x3 + (k2 x2 + k1 x4) x5
    dx5/dt = vr J_lSR + J_lm + vr J_ch - J_pm - vr J_pSR + J         (3.28)
    dx6/dt = J_pSR - J_lSR - J_ch

    J_pSR = p1 x5^2 / (x5^2 + p2^2)      SR pump (cytosol -> SR)
    J_pm  = q1 x5^2 / (x5^2 + q2^2)      plasma-membrane pump (cytosol -> outside)
    J_ch  = gamma1 x2 (x6 - x5)          RyR channel release
    J_lSR = gamma0 (x6 - x5)             SR leak
    J_lm  = constant membrane leak into the cytosol
    J     = trigger influx (input, J >= 0, nominally 0)

Inputs (J, q1) as chapter 6 (both enter dx5/dt only, so the input matrix has rank
1). Outputs: chapter 3's (x2, x5, x6) by default; ``outputs=("x5", "x6")`` gives
chapter 6's measurement (eq. 6.11). Time unit: s.

Reconstruction, in short (numbers in the doc):

- OPI is the x5 = 0.1370 uM point and OPII the 0.1670 uM point: Fig. 6.4 is
  "OPII -> OPI" and its caption goes 0.1670 -> 0.1370; the -10.605 pole/zero pair
  equals -(k-1 + k-2 + (k1 + k2) x5) at 0.1370; the chapter-3 plot range of x2
  (0.165-0.195) contains x2 = 0.188 at 0.137, not 0.214 at 0.167. (The facts file
  assigns them the other way round.)
- The printed chapter-6 B matrices order their columns (q1, J): with that order the
  J coefficient is exactly 1 and both points give q2 = 0.0600 uM.
- The total-Ca identity G5 (s + J_pm') + vr s G6 = 1 applied to the printed OPI
  model gives vr = 0.18-0.19 (the fit lands on 0.187; Othmer-Tang use 0.185).
- vr, gamma0, gamma1, p1, p2 and J_lm are a least-squares fit to the printed fast and
  slow eigenvalues (ch. 3), the poles and Hankel singular values of the printed
  order-3 models (ch. 6), the printed OPI DC gains and the printed SR Ca levels.
  Documented residuals: ch. 6 order-3 poles within 1 %, Hankel singular values
  within 1.1 %, OPI DC gains within 1.6 %, fast eigenvalues within 4.3 %, slow
  eigenvalues within 1.1 %, SR Ca within 0.7 %. The chapter-3 complex pairs are NOT
  matched (real parts 18 % / 52 % off): they disagree with the chapter-6 reduced
  models, which this model follows.
- The operating points are exact steady states of this model at x5 = 0.137 / 0.167
  uM and J = 0, so x6 = 38.356 / 39.518 uM instead of the printed 38.6162 / 39.262.
- The RyR rate constants (15, 7.6, 0.8, 0.84) are the facts file's (their -10.6046
  check matches the printed -10.605).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from plant_sim.base import OperatingPoint, PlantInputError, PlantModel, Variable

__all__ = ["Calcium", "PARAMETERS", "OP_CYTOSOL_CA", "ryr_steady_state"]

#: Model parameters. RyR constants from the facts file; fluxes reconstructed (see module doc).
PARAMETERS: dict[str, float] = {
    "k1": 15.0,     # 1/(uM s)
    "km1": 7.6,     # 1/s
    "k2": 0.8,      # 1/(uM s)
    "km2": 0.84,    # 1/s
    "vr": 0.1866636808902557,     # SR/cytosol volume ratio, -
    "gamma0": 0.6194384360440574,  # 1/s
    "gamma1": 91.35090856676938,   # 1/s
    "p1": 1200.1402826045073,      # uM/s
    "p2": 0.11961357368680499,     # uM
    "q2": 0.05999511307151453,     # uM
    "J_lm": 16.08007545599009,     # uM/s
}

#: Cytosolic Ca (uM) that defines each operating point.
OP_CYTOSOL_CA = {"OPI": 0.1370, "OPII": 0.1670}

_STATE_NAMES = ("x1", "x2", "x3", "x5", "x6")


def ryr_steady_state(x5: float, p: Mapping[str, float] = PARAMETERS) -> tuple[float, float, float]:
    """Steady RyR fractions (x1, x2, x3) at cytosolic Ca ``x5`` (uM), independent sites."""
    a = p["k1"] * x5 / p["km1"]
    b = p["k2"] * x5 / p["km2"]
    z = (1.0 + a) * (1.0 + b)
    return 1.0 / z, a / z, a * b / z


class Calcium(PlantModel):
    """Tang-Othmer CICR model of a cardiac myocyte, 5 states (reconstructed parameters).

    Parameters
    ----------
    outputs : sequence of str
        State names to measure, default ``("x2", "x5", "x6")`` (chapter 3); chapter 6
        uses ``("x5", "x6")``.
    params : mapping, optional
        Overrides of :data:`PARAMETERS` (for sensitivity studies and the fit).
    """

    name = "calcium"
    title = "Cardiac CICR, Tang-Othmer (seed eq. 3.27-3.29; reconstructed fluxes)"
    time_unit = "s"
    reconstructed = True
    state_vars = (
        Variable("x1", "-", "fraction of RyR in state R", 0.0, 1.0),
        Variable("x2", "-", "fraction of RyR in state RC+ (open)", 0.0, 1.0),
        Variable("x3", "-", "fraction of RyR in state RC+C- (closed)", 0.0, 1.0),
        Variable("x5", "uM", "cytosolic Ca", 0.0, math.inf),
        Variable("x6", "uM", "SR Ca", 0.0, math.inf),
    )
    input_vars = (
        Variable("J", "uM/s", "Ca trigger influx", 0.0, math.inf),
        Variable("q1", "uM/s", "maximal rate of the plasma-membrane pump", 0.0, math.inf),
    )
    disturbance_vars = ()
    state_scale = np.array([1.0, 1.0, 1.0, 0.1, 10.0])
    input_scale = np.array([1.0, 10.0])

    def __init__(self, *, outputs: Sequence[str] = ("x2", "x5", "x6"),
                 params: Mapping[str, float] | None = None) -> None:
        if isinstance(outputs, str):
            outputs = tuple(s.strip() for s in outputs.split(",") if s.strip())
        outputs = tuple(outputs)
        if not outputs:
            raise PlantInputError("outputs: at least one output is needed")
        for o in outputs:
            if o not in _STATE_NAMES:
                raise PlantInputError(f"outputs: unknown state {o!r}; known: "
                                      f"{', '.join(_STATE_NAMES)}")
        if len(set(outputs)) != len(outputs):
            raise PlantInputError(f"outputs: repeated name in {outputs}")
        p = dict(PARAMETERS)
        for key, value in (params or {}).items():
            if key not in PARAMETERS:
                raise PlantInputError(f"params: unknown parameter {key!r}")
            v = float(value)
            if not math.isfinite(v) or v < 0:
                raise PlantInputError(f"params: {key} must be finite and >= 0, got {value!r}")
            p[key] = v
        self.p = p
        self._out_idx = [_STATE_NAMES.index(o) for o in outputs]
        by_name = {v.name: v for v in self.state_vars}
        self.output_vars = tuple(by_name[o] for o in outputs)
        self._nominal = not params
        self._ops = {name: self._op(name, x5) for name, x5 in OP_CYTOSOL_CA.items()}

    # -- fluxes ----------------------------------------------------------------------
    def fluxes(self, x, u) -> dict[str, float]:
        """The Ca fluxes of eq. 3.28 at state ``x`` and input ``u`` (uM/s)."""
        p = self.p
        x2, x5, x6 = x[1], x[3], x[4]
        x5sq = x5 * x5
        return {
            "J_pSR": p["p1"] * x5sq / (x5sq + p["p2"] ** 2),
            "J_pm": u[1] * x5sq / (x5sq + p["q2"] ** 2),
            "J_ch": p["gamma1"] * x2 * (x6 - x5),
            "J_lSR": p["gamma0"] * (x6 - x5),
            "J_lm": p["J_lm"],
            "J": u[0],
        }

    def rhs(self, t, x, u, d):
        p = self.p
        x1, x2, x3, x5, x6 = x[0], x[1], x[2], x[3], x[4]
        x4 = 1.0 - x1 - x2 - x3
        x5sq = x5 * x5
        jpsr = p["p1"] * x5sq / (x5sq + p["p2"] ** 2)
        jpm = u[1] * x5sq / (x5sq + p["q2"] ** 2)
        release = (p["gamma0"] + p["gamma1"] * x2) * (x6 - x5)  # J_lSR + J_ch
        k1, km1, k2, km2 = p["k1"], p["km1"], p["k2"], p["km2"]
        return np.array([
            km1 * x2 + km2 * x4 - (k1 + k2) * x1 * x5,
            -km1 * x2 + km2 * x3 + (k1 * x1 - k2 * x2) * x5,
            -(km1 + km2) * x3 + (k2 * x2 + k1 * x4) * x5,
            p["vr"] * (release - jpsr) + p["J_lm"] - jpm + u[0],
            jpsr - release,
        ])

    def outputs(self, x, u):
        return np.asarray(x, dtype=float)[self._out_idx]

    # -- operating points ----------------------------------------------------------------
    def steady_state_at(self, x5: float, J: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Exact steady state with cytosolic Ca ``x5`` (uM) and trigger ``J``.

        Returns ``(x, u)``: RyR fractions in closed form, x6 from the SR balance
        ``J_pSR = (gamma0 + gamma1 x2)(x6 - x5)``, and q1 from the total-Ca balance
        ``J_pm = J_lm + J``.
        """
        p = self.p
        if not (math.isfinite(x5) and x5 > 0):
            raise PlantInputError(f"x5: must be positive and finite, got {x5!r}")
        x1, x2, x3 = ryr_steady_state(x5, p)
        x5sq = x5 * x5
        jpsr = p["p1"] * x5sq / (x5sq + p["p2"] ** 2)
        x6 = x5 + jpsr / (p["gamma0"] + p["gamma1"] * x2)
        q1 = (p["J_lm"] + J) * (x5sq + p["q2"] ** 2) / x5sq
        return np.array([x1, x2, x3, x5, x6]), np.array([J, q1])

    def _op(self, name: str, x5: float) -> OperatingPoint:
        x, u = self.steady_state_at(x5)
        printed = {"OPI": "38.6162", "OPII": "39.262"}[name]
        stab, detail = "stable", "stable focus"   # seed: both linearizations stable
        if not self._nominal:
            from plant_sim.linearize import classify_point

            stab, detail = classify_point(self, x, u, np.zeros(0))
        return OperatingPoint(
            name=name, x=x, u=u, d=np.zeros(0),
            description=(f"x5 = {x5} uM (seed, Figs. 6.4-6.5), J = 0; x6 = {x[4]:.4f} uM is "
                         f"this model's steady state (seed prints {printed}); q1 from the "
                         "total-Ca balance. RECONSTRUCTED flux parameters"),
            stability=stab, stability_detail=detail, confidence="reconstructed")

    @property
    def operating_points(self) -> dict[str, OperatingPoint]:
        return dict(self._ops)
