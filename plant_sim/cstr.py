"""Exothermic CSTR (A -> B) in dimensionless form: seed eq. 5.8.

The Uppal-Ray-Poore reactor with a cooling jacket, in the concentration form

    dx1/dt = x1f - x1 - Da x1 K(x2)
    dx2/dt = -x2 + B Da x1 K(x2) - beta (x2 - u)
    y      = x2,          K(x2) = exp(x2 / (1 + x2/gamma))

x1 is the dimensionless concentration of A (1 - conversion), x2 the dimensionless
reactor temperature, u the dimensionless jacket temperature and x1f the
dimensionless feed concentration (a disturbance, nominally 1, so the +10 % feed
step of Fig. 5.15a is ``d = [1.1]``). Time is dimensionless (``time_unit = "-"``).

Parameters Da = 0.072, gamma = 20, B = 8, beta = 0.3 reproduce all twelve
coefficients of Table 5.3 (facts: cstr_bioreactor.md §1, §3). ``gamma=math.inf``
gives the model-error variant K = exp(x2) of Fig. 5.15b; ``B=7.2`` the
heat-of-reaction error of Fig. 5.15c.

Operating points are defined by their output (y = 1.3, 5.0, 2.0 as in Table 5.3)
and computed in closed form from the steady-state map, so every option set gets
exact steady states: x1 = x1f / (1 + Da K(y)), u = y + (y - B Da x1 K(y)) / beta.
Input bounds are lost in the seed's OCR; none are imposed.
"""

from __future__ import annotations

import math

import numpy as np

from plant_sim.base import OperatingPoint, PlantInputError, PlantModel, Variable

__all__ = ["CSTR", "OP_OUTPUTS"]

#: Output (dimensionless temperature) at each operating point of Table 5.3.
OP_OUTPUTS = {"OPI": 1.3, "OPII": 5.0, "OPIII": 2.0}

_SEED_TYPES = {  # as the seed classifies them (Table 5.3 text, Fig. 5.2)
    "OPI": ("stable", "stable node"),
    "OPII": ("stable", "stable focus"),
    "OPIII": ("unstable", "saddle"),
}


def _positive(name: str, value: float, allow_inf: bool = False) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as exc:
        raise PlantInputError(f"{name}: not a number ({value!r})") from exc
    if math.isnan(v) or v <= 0 or (math.isinf(v) and not allow_inf):
        raise PlantInputError(f"{name}: must be positive{'' if allow_inf else ' and finite'}, "
                              f"got {value!r}")
    return v


class CSTR(PlantModel):
    """Exothermic CSTR of seed eq. 5.8 (dimensionless, concentration form).

    Parameters
    ----------
    Da : float
        Damkohler number (default 0.072).
    gamma : float
        Dimensionless activation energy (default 20; ``math.inf`` for K = exp(x2)).
    B : float
        Dimensionless heat of reaction (default 8).
    beta : float
        Dimensionless heat-transfer coefficient (default 0.3).
    x1f : float
        Nominal dimensionless feed concentration (default 1), the disturbance's
        nominal value.
    """

    name = "cstr"
    title = "Exothermic CSTR (Uppal-Ray-Poore, seed eq. 5.8)"
    time_unit = "-"
    state_vars = (
        Variable("x1", "-", "dimensionless concentration of A", 0.0, math.inf),
        Variable("x2", "-", "dimensionless reactor temperature"),
    )
    input_vars = (Variable("u", "-", "dimensionless jacket temperature"),)
    output_vars = (Variable("y", "-", "dimensionless reactor temperature x2"),)
    disturbance_vars = (Variable("x1f", "-", "dimensionless feed concentration", 0.0),)
    state_scale = np.array([1.0, 1.0])
    input_scale = np.array([1.0])

    def __init__(self, *, Da: float = 0.072, gamma: float = 20.0, B: float = 8.0,
                 beta: float = 0.3, x1f: float = 1.0) -> None:
        self.Da = _positive("Da", Da)
        self.gamma = _positive("gamma", gamma, allow_inf=True)
        self.B = _positive("B", B)
        self.beta = _positive("beta", beta)
        self.x1f = _positive("x1f", x1f)
        self._ops = {name: self._op_at(name, y) for name, y in OP_OUTPUTS.items()}

    def K(self, x2):
        """Arrhenius factor exp(x2 / (1 + x2/gamma))."""
        if math.isinf(self.gamma):
            return np.exp(x2)
        return np.exp(x2 / (1.0 + x2 / self.gamma))

    def rhs(self, t, x, u, d):
        x1, x2 = x[0], x[1]
        r = self.Da * x1 * self.K(x2)
        return np.array([d[0] - x1 - r, -x2 + self.B * r - self.beta * (x2 - u[0])])

    def outputs(self, x, u):
        return np.array([x[1]])

    def default_disturbance(self) -> np.ndarray:
        return np.array([self.x1f])

    def steady_input(self, y: float) -> tuple[float, float]:
        """Closed-form steady state with output ``y``: returns ``(x1, u)``."""
        k = float(self.K(y))
        x1 = self.x1f / (1.0 + self.Da * k)
        u = y + (y - self.B * self.Da * x1 * k) / self.beta
        return x1, u

    def _op_at(self, name: str, y: float) -> OperatingPoint:
        x1, u = self.steady_input(y)
        x = np.array([x1, y])
        d = np.array([self.x1f])
        desc = f"y = x2 = {y} (Table 5.3); x1 and u from the closed-form steady-state map"
        if self.is_nominal:
            stab, detail = _SEED_TYPES[name]
            confidence = "verified"
        else:  # a variant (Fig. 5.15): classify from its own Jacobian
            from plant_sim.linearize import classify_point

            stab, detail = classify_point(self, x, [u], d)
            desc += f"; variant Da={self.Da}, gamma={self.gamma}, B={self.B}, " \
                    f"beta={self.beta}, x1f={self.x1f}"
            confidence = "derived"
        return OperatingPoint(name=name, x=x, u=np.array([u]), d=d, description=desc,
                              stability=stab, stability_detail=detail, confidence=confidence)

    @property
    def is_nominal(self) -> bool:
        """True for the seed's parameter set (Da 0.072, gamma 20, B 8, beta 0.3, x1f 1)."""
        return (self.Da, self.gamma, self.B, self.beta, self.x1f) == (0.072, 20.0, 8.0, 0.3,
                                                                         1.0)

    @property
    def operating_points(self) -> dict[str, OperatingPoint]:
        return dict(self._ops)
