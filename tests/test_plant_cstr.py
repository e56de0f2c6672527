"""CSTR (seed eq. 5.8): steady states, Table 5.3, stability types, Fig. 5.15 variants.

Expected numbers are the seed's printed Table 5.3 and the independently computed
values of facts/cstr_bioreactor.md §1.3 and §3.
"""

import math

import numpy as np
import pytest

from plant_sim import get_plant
from plant_sim.base import PlantInputError
from plant_sim.cstr import CSTR
from plant_sim.integrate import simulate
from plant_sim.linearize import linearize
from plant_sim.steady_state import find_steady_state

STEADY_TOL = 1e-9           # ||f||_inf relative to the state scale
# Table 5.3 prints 4 decimals; the seed's own numerical linearization differs from the
# exact Jacobian by up to 1.3e-4 (facts §3), i.e. one unit in the last digit.
TABLE_TOL = 1.5e-4
FACTS_TOL = 1e-5            # facts' 5-6 digit recomputations
EXACT_TOL = 1e-8            # numerical vs analytic Jacobian

TABLE_5_3 = {  # k1, k2, k3, k4 of k1 (s + k2) / (s^2 + k3 s + k4)
    "OPI": (0.3000, 1.2440, 1.1605, 0.2337),
    "OPII": (0.3000, 4.9310, 2.1493, 2.3286),
    "OPIII": (0.3000, 1.4437, 0.7121, -0.1548),
}
SEED_TYPES = {"OPI": "stable", "OPII": "stable", "OPIII": "unstable"}


def k_coeffs(lm):
    num, den = lm.to_transfer_function()
    assert len(num) == 2 and len(den) == 3
    return num[0], num[1] / num[0], den[1], den[2]


def analytic_A(m, x1, x2):
    """Hand-derived Jacobian of eq. 5.8 (concentration form)."""
    g = m.gamma
    K = math.exp(x2 / (1 + x2 / g))
    dK = K / (1 + x2 / g) ** 2
    return np.array([[-1 - m.Da * K, -m.Da * x1 * dK],
                     [m.B * m.Da * K, -1 + m.B * m.Da * x1 * dK - m.beta]])


def test_registry_builds_cstr():
    assert isinstance(get_plant("cstr"), CSTR)


@pytest.mark.parametrize("op", ["OPI", "OPII", "OPIII"])
def test_operating_points_are_steady(op):
    m = CSTR()
    p = m.operating_point(op)
    f = m.rhs(0.0, p.x, p.u, p.d)
    assert np.max(np.abs(f) / np.maximum(np.abs(p.x), 1.0)) <= STEADY_TOL


def test_operating_points_match_facts():
    m = CSTR()
    expected = {"OPI": (0.80383, 1.3, 0.40224), "OPII": (0.20280, 5.0, 0.40789),
                "OPIII": (0.69273, 2.0, 0.47277)}
    for op, (x1, x2, u) in expected.items():
        p = m.operating_point(op)
        np.testing.assert_allclose([p.x[0], p.x[1], p.u[0]], [x1, x2, u], atol=FACTS_TOL)


@pytest.mark.parametrize("op", ["OPI", "OPII", "OPIII"])
def test_table_5_3_transfer_functions(op):
    lm = linearize(CSTR(), op)
    np.testing.assert_allclose(k_coeffs(lm), TABLE_5_3[op], atol=TABLE_TOL)


@pytest.mark.parametrize("op", ["OPI", "OPII", "OPIII"])
def test_linearization_matches_analytic_jacobian(op):
    m = CSTR()
    p = m.operating_point(op)
    lm = linearize(m, p)
    np.testing.assert_allclose(lm.A, analytic_A(m, *p.x), rtol=EXACT_TOL, atol=EXACT_TOL)
    np.testing.assert_allclose(lm.B, [[0.0], [m.beta]], atol=EXACT_TOL)
    np.testing.assert_allclose(lm.C, [[0.0, 1.0]], atol=EXACT_TOL)
    np.testing.assert_allclose(lm.E, [[1.0], [0.0]], atol=EXACT_TOL)


@pytest.mark.parametrize("op", ["OPI", "OPII", "OPIII"])
def test_stability_types_match_seed(op):
    m = CSTR()
    stab, detail = linearize(m, op).stability()
    assert stab == SEED_TYPES[op]
    assert m.operating_point(op).stability == SEED_TYPES[op]
    if op == "OPIII":
        assert detail == "saddle"


def test_three_steady_states_at_opi_input():
    # facts §1.3: at u = 0.40224 the steady states are y = 1.300, 2.161, 4.996
    m = CSTR()
    ys = []
    for guess in ([0.8, 1.2], [0.6, 2.2], [0.2, 5.0]):
        ys.append(find_steady_state(m, [0.40224], guess).x[1])
    np.testing.assert_allclose(ys, [1.300, 2.161, 4.996], atol=1e-3)


@pytest.mark.parametrize(
    ("options", "u_ss"),
    [({"gamma": math.inf}, (0.061, -2.718)), ({"B": 7.2}, (0.925, 2.534)),
     ({"x1f": 1.1}, (-0.121, -1.718))],
)
def test_fig_5_15_variants(options, u_ss):
    m = CSTR(**options)
    got = (m.operating_point("OPI").u[0], m.operating_point("OPII").u[0])
    np.testing.assert_allclose(got, u_ss, atol=1e-3)


def test_gamma_inf_linear_models_and_types():
    m = CSTR(gamma=math.inf)
    np.testing.assert_allclose(k_coeffs(linearize(m, "OPI")), (0.3, 1.2642, 0.8924, -0.0284),
                               atol=1e-4)
    np.testing.assert_allclose(k_coeffs(linearize(m, "OPII")), (0.3, 11.686, 5.670, 7.876),
                               atol=1e-3)
    assert m.operating_point("OPI").stability_detail == "saddle"


def test_feed_disturbance_moves_the_steady_state():
    m = CSTR()
    p = m.operating_point("OPI")
    res = simulate(m, p.x, p.u, t_end=40.0, dt=1.0, d=[(0.0, [1.0]), (5.0, [1.1])])
    assert abs(res.y[5, 0] - 1.3) < 1e-8
    assert res.y[-1, 0] > 1.3 + 0.05


@pytest.mark.parametrize("field", ["Da", "gamma", "B", "beta", "x1f"])
def test_bad_parameters_name_the_field(field):
    with pytest.raises(PlantInputError, match=f"^{field}"):
        CSTR(**{field: -1.0})
    with pytest.raises(PlantInputError, match=f"^{field}"):
        CSTR(**{field: math.nan})


def test_unknown_operating_point():
    with pytest.raises(PlantInputError, match="^op: unknown operating point 'OPIV'"):
        CSTR().operating_point("OPIV")
