"""Downs & Vogel operating cost from what a controller measures (XMEAS 1-41 only).

The simulator's own cost (:meth:`TESimulator.cost`,
:func:`~plant_sim.tennessee_eastman.simulator.cost_from_measurements`, te.md §9)
needs the stripper product's molar flow, an internal of the model (``FTM(13)``,
lb-mol/h). A controller sees only its volumetric flow, XMEAS 17 (m³/h), which the
model computes as ``FTM(13) / ρ / 35.3145`` with ρ the stripper liquid's molar
density (the model's ``TESUB4``: ``1/ρ = Σ x_i MW_i / (AD_i + (BD_i + CD_i T) T)``; T the
stripper temperature XMEAS 18). :func:`product_flow_from_measurements` inverts that
with the product analyzer's composition (XMEAS 37-41, D-H mol %, scaled to the heavy
share) and the light components A, B, C the analyzer does not measure taken at their
base-case mole fractions (1.5 mol % together; being light, they weigh in the molar
volume).

:data:`BASE_CASE_COST_USD_H`: 170.6 $/h, Downs & Vogel's base case (mode 0;
``docs/facts/te.md`` §9, "Base case ≈ 170.6 $/h").

Measured limits against the simulator's cost (open loop from each mode's start
state, 1.8 s Euler step, 3 process hours sampled every 36 s; error =
``measured_operating_cost`` minus ``TESimulator.cost()``; the cost is the simulator's
at the end):

========  =====  ============  ==============  ==================  =========  ========
mode      noise  product flow  per sample max  hourly mean max     3 h mean   cost
========  =====  ============  ==============  ==================  =========  ========
0 (base)  off    5e-5          0.00 $/h        0.000 $/h           +0.000     171 $/h
0 (base)  on     1.5 %         0.45 $/h        0.029 $/h           +0.019     173 $/h
1         off    0.16 %        0.04 $/h        0.040 $/h           -0.040     114 $/h
1         on     1.4 %         0.37 $/h        0.031 $/h           -0.024     116 $/h
2         off    0.38 %        0.13 $/h        0.069 $/h           -0.042     186 $/h
2         on     1.6 %         0.58 $/h        0.026 $/h           -0.019     185 $/h
3         off    0.19 %        0.01 $/h        0.014 $/h           -0.014      44 $/h
3         on     1.8 %         0.14 $/h        0.013 $/h           -0.009      44 $/h
========  =====  ============  ==============  ==================  =========  ========

Two readings measured worse and were dropped: A, B and C as 100 % minus the analyzer's
sum (exact without noise, but the analyzer's noise on G and H, held 15 minutes between
its samples, moved hourly means by up to 2.1 $/h), and the base case's 211.3 kmol/h
scaled by XMEAS 17 (what several implementations do: 2.8 $/h off on the mean at
mode 2).
"""

from __future__ import annotations

import numpy as np

from plant_sim.tennessee_eastman import constants as C
from plant_sim.tennessee_eastman.simulator import cost_from_measurements

__all__ = ["BASE_CASE_COST_USD_H", "BASE_CASE_COST_ORIGIN", "product_flow_from_measurements",
           "measured_operating_cost"]

#: Downs & Vogel's base-case operating cost (mode 0), $/h.
BASE_CASE_COST_USD_H = 170.6
BASE_CASE_COST_ORIGIN = ("Downs & Vogel (1993) base case, mode 0 (docs/facts/te.md, "
                         "section 9)")

#: A, B, C mole fractions of the stripper liquid at the base case (the published
#: initial state, noise-free): how the part the product analyzer does not see is split.
_LIGHT_BASE = np.array([4.79187250e-03, 8.89213429e-05, 1.00777520e-02])
_HEAVY_SHARE = 1.0 - float(_LIGHT_BASE.sum())


def _molar_volume_terms():
    mw, ad, bd, cd = (tuple(float(v) for v in C.get(n)) for n in ("XMW", "AD", "BD", "CD"))
    return mw, ad, bd, cd, float(C.get("FT3_PER_M3")[0])


_MW, _AD, _BD, _CD, _FT3_PER_M3 = _molar_volume_terms()
_LIGHT = tuple(float(v) for v in _LIGHT_BASE)


def product_flow_from_measurements(xmeas) -> float:
    """Stripper product molar flow (stream 11), lb-mol/h, from XMEAS 17, 18 and 37-41.

    Parameters
    ----------
    xmeas : array_like, shape (41,)
        XMEAS 1-41 in Downs & Vogel's units.

    Returns
    -------
    float
        NaN when the analyzer's D-H do not add up to more than 0.

    Notes
    -----
    Plain floats, not numpy: 8 terms (about 3 against 17 us a sample in numpy).
    """
    heavy = [float(v) for v in xmeas[36:41]]
    total = sum(heavy)
    if not total > 0.0:  # no analyzer reading: no flow known
        return float("nan")
    scale = _HEAVY_SHARE / total
    comp = (*_LIGHT, *(h * scale for h in heavy))
    t = float(xmeas[17])
    molar_volume = 0.0  # ft³/lb-mol
    for i in range(8):
        molar_volume += comp[i] * _MW[i] / (_AD[i] + (_BD[i] + _CD[i] * t) * t)
    return float(xmeas[16]) * _FT3_PER_M3 / molar_volume


def measured_operating_cost(xmeas) -> float:
    """Downs & Vogel operating cost, $/h, from XMEAS 1-41 alone (module notes).

    Parameters
    ----------
    xmeas : array_like, shape (41,)
    """
    return cost_from_measurements(xmeas, product_flow_from_measurements(xmeas))
