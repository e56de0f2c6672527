"""Continuous bioreactor with substrate inhibition: seed eq. 5.21.

    dx1/dt = mu(x2) x1 - D x1
    dx2/dt = D (x2f - x2) - sigma(x2) x1
    y      = x2

x1 is the cell density (g/L), x2 the substrate (g/L, measured), D the dilution
rate (1/h, input) and x2f the feed substrate (g/L, disturbance, nominally 1.8).
Time unit: h.

The kinetics of the seed (Table 5.9) are lost in its OCR. This module uses the
**reconstruction** of facts/cstr_bioreactor.md §2.2, which reproduces the
denominators of Table 5.10 at both valid operating points:

    mu(x2)    = mu_m x2 / (Km + x2 + K1 x2^2)                        (Haldane)
    sigma(x2) = x2 (a + b x2) / (Ks + x2 + K2 x2^2)

``sigma="ref94"`` replaces sigma by the model-error approximation the seed quotes
from its ref. [94] (Fig. 5.20):

    sigma94(x2) = x2 (1.32 + 3.86 x2) / (0.000849 + x2 + 0.406 x2^2)

Operating points (D = 0.4 1/h) solve mu(x2) = D in closed form; x1 = D (x2f - x2) /
sigma(x2). OPI's substrate is about 0.00358 g/L, **not the 0.0003 printed** in
Table 5.10: the printed OPI numerator (about 1.796 s + 0.719, = (x2f - x2)(s + D))
needs x2 between 0.003 and 0.004, and no Haldane law fits 0.0003 (facts §2.3).
OPIII is the washout state (x1 = 0, x2 = x2f), stable but physically useless.
"""

from __future__ import annotations

import math

import numpy as np

from plant_sim.base import OperatingPoint, PlantInputError, PlantModel, Variable

__all__ = ["Bioreactor", "KINETICS", "SIGMA_REF94"]

#: Reconstructed kinetic constants (facts/cstr_bioreactor.md §2.2).
KINETICS = {
    "mu_m": 0.51601,     # 1/h
    "Km": 0.0010288,     # g/L
    "K1": 0.73878,       # L/g (= 1/Ki, Ki = 1.3536 g/L)
    "a": 1.35066,        # 1/h
    "b": 4.01475,        # L/(g h)
    "Ks": 0.0010297,     # g/L
    "K2": 0.61941,       # L/g
}
#: Ref. [94] approximation of sigma: x2 (a + b x2) / (Ks + x2 + K2 x2^2).
SIGMA_REF94 = {"a": 1.32, "b": 3.86, "Ks": 0.000849, "K2": 0.406}

SIGMA_CHOICES = ("reconstructed", "ref94")
NOMINAL_D = 0.4    # 1/h, all tabulated points
NOMINAL_X2F = 1.8  # g/L


class Bioreactor(PlantModel):
    """Substrate-inhibited continuous bioreactor of seed eq. 5.21 (reconstructed kinetics).

    Parameters
    ----------
    sigma : {"reconstructed", "ref94"}
        Substrate-consumption law: the reconstruction that reproduces Table 5.10,
        or the ref. [94] approximation (the seed's model-error case, Fig. 5.20).
    D : float
        Dilution rate at the operating points, 1/h (default 0.4).
    x2f : float
        Nominal feed substrate, g/L (default 1.8).
    """

    name = "bioreactor"
    title = "Continuous bioreactor, substrate inhibition (seed eq. 5.21)"
    time_unit = "h"
    state_vars = (
        Variable("x1", "g/L", "cell density", 0.0, math.inf),
        Variable("x2", "g/L", "substrate concentration", 0.0, math.inf),
    )
    input_vars = (Variable("D", "1/h", "dilution rate", 0.0, math.inf),)
    output_vars = (Variable("y", "g/L", "substrate concentration x2", 0.0, math.inf),)
    disturbance_vars = (Variable("x2f", "g/L", "feed substrate concentration", 0.0),)
    state_scale = np.array([0.1, 0.001])
    input_scale = np.array([0.1])

    def __init__(self, *, sigma: str = "reconstructed", D: float = NOMINAL_D,
                 x2f: float = NOMINAL_X2F) -> None:
        if sigma not in SIGMA_CHOICES:
            raise PlantInputError(f"sigma: must be one of {SIGMA_CHOICES}, got {sigma!r}")
        for fname, v in (("D", D), ("x2f", x2f)):
            if not (isinstance(v, int | float) and math.isfinite(v) and v > 0):
                raise PlantInputError(f"{fname}: must be a positive finite number, got {v!r}")
        self.sigma_law = sigma
        self.D_nominal = float(D)
        self.x2f = float(x2f)
        k = KINETICS
        self._mu = (k["mu_m"], k["Km"], k["K1"])
        s = SIGMA_REF94 if sigma == "ref94" else k
        self._sigma = (s["a"], s["b"], s["Ks"], s["K2"])
        if sigma == "ref94":
            self.title = self.title + ", sigma of ref. [94]"
        self._ops = self._build_ops()

    def mu(self, x2):
        """Specific growth rate, 1/h (Haldane)."""
        mu_m, Km, K1 = self._mu
        return mu_m * x2 / (Km + x2 + K1 * x2 * x2)

    def sigma(self, x2):
        """Specific substrate consumption rate, g substrate/(g cells h)."""
        a, b, Ks, K2 = self._sigma
        return x2 * (a + b * x2) / (Ks + x2 + K2 * x2 * x2)

    def rhs(self, t, x, u, d):
        x1, x2 = x[0], x[1]
        D = u[0]
        return np.array([(self.mu(x2) - D) * x1, D * (d[0] - x2) - self.sigma(x2) * x1])

    def outputs(self, x, u):
        return np.array([x[1]])

    def default_disturbance(self) -> np.ndarray:
        return np.array([self.x2f])

    def substrate_levels(self, D: float) -> tuple[float, float]:
        """The two roots x2 of mu(x2) = D (low, high), g/L; ValueError if none."""
        mu_m, Km, K1 = self._mu
        # D K1 x^2 + (D - mu_m) x + D Km = 0
        disc = (D - mu_m) ** 2 - 4.0 * D * K1 * D * Km
        if disc < 0 or D >= mu_m:
            raise PlantInputError(f"D: {D} 1/h exceeds the largest growth rate; only washout")
        r = math.sqrt(disc)
        lo = (mu_m - D - r) / (2 * D * K1)
        hi = (mu_m - D + r) / (2 * D * K1)
        return lo, hi

    def _build_ops(self) -> dict[str, OperatingPoint]:
        D, x2f = self.D_nominal, self.x2f
        lo, hi = self.substrate_levels(D)
        src = ("reconstructed kinetics" if self.sigma_law == "reconstructed"
               else "reconstructed mu, sigma of ref. [94]")
        ops = {}
        for name, x2, stab, detail, text in (
            ("OPI", lo, "stable", "stable node",
             "low-substrate point; Table 5.10 prints x1 0.6790, x2 0.0003 (sic: about 0.0036)"),
            ("OPII", hi, "unstable", "saddle",
             "high-substrate point; Table 5.10 prints x1 0.2410, x2 0.3890"),
        ):
            x1 = D * (x2f - x2) / float(self.sigma(x2))
            if (D, x2f) != (NOMINAL_D, NOMINAL_X2F):  # not the seed's point: classify
                from plant_sim.linearize import classify_point

                stab, detail = classify_point(self, [x1, x2], [D], [x2f])
            ops[name] = OperatingPoint(
                name=name, x=np.array([x1, x2]), u=np.array([D]), d=np.array([x2f]),
                description=f"{text}; mu(x2) = D solved in closed form ({src})",
                stability=stab, stability_detail=detail, confidence="reconstructed")
        ops["OPIII"] = OperatingPoint(
            name="OPIII", x=np.array([0.0, x2f]), u=np.array([D]), d=np.array([x2f]),
            description="washout (x1 = 0, x2 = x2f): stable but not a valid operating point",
            stability="stable", stability_detail="stable node", valid=False,
            confidence="verified")
        return ops

    @property
    def operating_points(self) -> dict[str, OperatingPoint]:
        return dict(self._ops)
