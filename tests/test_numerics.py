"""plant_sim numerics: simulate/step (ZOH), steady states, linearization, classification.

References are closed forms (scalar and 2x2 linear ODEs, matrix exponentials,
analytic Jacobians), never the code under test.
"""

import math

import numpy as np
import pytest
from scipy.linalg import expm

from plant_sim.base import PlantInputError, PlantModel, Variable
from plant_sim.integrate import PiecewiseConstant, simulate, step
from plant_sim.linearize import classify_stability, jacobian, linearize
from plant_sim.steady_state import SteadyStateError, find_steady_state

TRAJ_TOL = 1e-7       # integrated vs closed-form trajectory (rtol 1e-9 integrator)
JAC_TOL = 1e-8        # Richardson Jacobian vs analytic derivative (relative)
SS_TOL = 1e-10        # steady state vs closed form


class LinearPlant(PlantModel):
    """dx/dt = A x + B u + E d, y = C x (a test plant with closed-form answers)."""

    name = "linear-test"
    time_unit = "s"

    def __init__(self, A, B, C, E=None):
        self.A, self.B, self.C = (np.asarray(M, float) for M in (A, B, C))
        self.E = np.zeros((self.A.shape[0], 0)) if E is None else np.asarray(E, float)
        self.state_vars = tuple(Variable(f"x{i}") for i in range(self.A.shape[0]))
        self.input_vars = tuple(Variable(f"u{i}") for i in range(self.B.shape[1]))
        self.output_vars = tuple(Variable(f"y{i}") for i in range(self.C.shape[0]))
        self.disturbance_vars = tuple(Variable(f"d{i}") for i in range(self.E.shape[1]))

    def rhs(self, t, x, u, d):
        return self.A @ x + self.B @ u + (self.E @ d if d.size else 0.0)

    def outputs(self, x, u):
        return self.C @ x

    @property
    def operating_points(self):
        return {}


class Curved(PlantModel):
    """A nonlinear plant with a hand-derived Jacobian."""

    name = "curved-test"
    state_vars = (Variable("a"), Variable("b"))
    input_vars = (Variable("u"),)
    output_vars = (Variable("y"),)

    def rhs(self, t, x, u, d):
        return np.array([math.sin(x[0]) * u[0] - x[0], x[0] * x[1] ** 2 + math.exp(u[0]) - 3.0])

    def outputs(self, x, u):
        return np.array([x[0] * x[1] + u[0] ** 2])

    @property
    def operating_points(self):
        return {}


def zoh_reference(A, B, x0, schedule, t):
    """Exact ZOH solution of x' = A x + B u at time t (piecewise matrix exponentials)."""
    x = np.asarray(x0, float)
    times = [s[0] for s in schedule] + [math.inf]
    t_now = schedule[0][0]
    for k, (_ts, u) in enumerate(schedule):
        t_stop = min(times[k + 1], t)
        if t_stop <= t_now:
            continue
        h = t_stop - t_now
        n = A.shape[0]
        M = np.zeros((n + 1, n + 1))
        M[:n, :n] = A
        M[:n, n] = B @ np.asarray(u, float)
        Phi = expm(M * h)
        x = Phi[:n, :n] @ x + Phi[:n, n]
        t_now = t_stop
    return x


def test_simulate_matches_closed_form_with_off_grid_steps():
    A = np.array([[-0.5, 0.2], [0.0, -1.3]])
    B = np.array([[1.0], [0.5]])
    plant = LinearPlant(A, B, np.eye(2))
    sched = [(0.0, [1.0]), (0.37, [-2.0]), (1.91, [0.5])]
    res = simulate(plant, [0.3, -0.1], sched, t_end=4.0, dt=0.25)
    assert res.t[0] == 0.0 and res.t[-1] == pytest.approx(4.0)
    for k in (0, 1, 2, 8, 16):
        ref = zoh_reference(A, B, [0.3, -0.1], sched, res.t[k])
        np.testing.assert_allclose(res.x[k], ref, atol=TRAJ_TOL)
    # held inputs are recorded at each sample
    assert res.u[1, 0] == 1.0 and res.u[2, 0] == -2.0 and res.u[8, 0] == 0.5


def test_simulate_stiff_system_matches_matrix_exponential():
    A = np.array([[-841.0, 50.0], [0.0, -0.8]])
    B = np.array([[0.0], [1.0]])
    plant = LinearPlant(A, B, np.eye(2))
    for method in ("LSODA", "BDF", "Radau"):
        res = simulate(plant, [1.0, 0.0], [2.0], t_end=3.0, dt=0.5, method=method)
        ref = zoh_reference(A, B, [1.0, 0.0], [(0.0, [2.0])], 3.0)
        np.testing.assert_allclose(res.x[-1], ref, rtol=1e-6, atol=TRAJ_TOL)


def test_simulate_adds_final_point_when_dt_does_not_divide():
    plant = LinearPlant([[-1.0]], [[1.0]], [[1.0]])
    res = simulate(plant, [0.0], [1.0], t_end=1.0, dt=0.3)
    np.testing.assert_allclose(res.t, [0.0, 0.3, 0.6, 0.9, 1.0])
    np.testing.assert_allclose(res.x[:, 0], 1.0 - np.exp(-res.t), atol=TRAJ_TOL)


def test_disturbance_schedule_is_held():
    plant = LinearPlant([[-2.0]], [[0.0]], [[1.0]], E=[[1.0]])
    res = simulate(plant, [0.0], [0.0], t_end=2.0, dt=0.5, d=[(0.0, [0.0]), (1.0, [4.0])])
    np.testing.assert_allclose(res.x[2, 0], 0.0, atol=TRAJ_TOL)
    np.testing.assert_allclose(res.x[-1, 0], 2.0 * (1 - math.exp(-2.0)), atol=TRAJ_TOL)
    assert res.d[-1, 0] == 4.0


def test_step_equals_closed_form_and_simulate():
    A = np.array([[-0.5, 1.0], [-1.0, -0.5]])
    B = np.array([[0.0], [1.0]])
    plant = LinearPlant(A, B, np.eye(2))
    x = np.array([1.0, 2.0])
    for _ in range(3):
        x = step(plant, x, [0.7], 0.4)
    ref = zoh_reference(A, B, [1.0, 2.0], [(0.0, [0.7])], 1.2)
    np.testing.assert_allclose(x, ref, atol=TRAJ_TOL)


@pytest.mark.parametrize(
    ("call", "field"),
    [
        (lambda p: simulate(p, [0.0, 0.0], [1.0], 1.0, 0.1), "x0"),
        (lambda p: simulate(p, [0.0], [math.nan], 1.0, 0.1), "inputs"),
        (lambda p: simulate(p, [0.0], [(0.0, [1.0]), (0.5, [math.nan])], 1.0, 0.1), "inputs"),
        (lambda p: simulate(p, [0.0], [1.0], 1.0, 0.0), "dt"),
        (lambda p: simulate(p, [0.0], [1.0], 1.0, -1.0), "dt"),
        (lambda p: simulate(p, [0.0], [1.0], 0.0, 0.1), "t_end"),
        (lambda p: simulate(p, [0.0], [1.0], 1.0, 0.1, method="RK45"), "method"),
        (lambda p: step(p, [math.nan], [1.0], 0.1), "x"),
        (lambda p: step(p, [0.0], [1.0, 2.0], 0.1), "u"),
        (lambda p: step(p, [0.0], [1.0], math.nan), "dt"),
        (lambda p: step(p, [0.0], [1.0], -0.1), "dt"),
    ],
)
def test_bad_simulation_input_names_the_field(call, field):
    plant = LinearPlant([[-1.0]], [[1.0]], [[1.0]])
    with pytest.raises(PlantInputError, match=rf"^{field}"):
        call(plant)


def test_schedule_validation():
    with pytest.raises(PlantInputError, match="increasing"):
        PiecewiseConstant(np.array([0.0, 0.0]), np.array([[1.0], [2.0]]))
    sched = PiecewiseConstant.from_steps([(1.0, [2.0]), (0.0, [1.0])])
    assert sched.at(-1.0)[0] == 1.0 and sched.at(0.99)[0] == 1.0 and sched.at(1.0)[0] == 2.0


def test_jacobian_matches_analytic_derivatives():
    plant = Curved()
    x = np.array([0.7, -1.3])
    u = np.array([0.4])
    lm = linearize(plant, _op(x, u))
    A_ref = np.array([[math.cos(x[0]) * u[0] - 1.0, 0.0], [x[1] ** 2, 2 * x[0] * x[1]]])
    B_ref = np.array([[math.sin(x[0])], [math.exp(u[0])]])
    C_ref = np.array([[x[1], x[0]]])
    D_ref = np.array([[2 * u[0]]])
    for got, ref in ((lm.A, A_ref), (lm.B, B_ref), (lm.C, C_ref), (lm.D, D_ref)):
        np.testing.assert_allclose(got, ref, rtol=JAC_TOL, atol=JAC_TOL)
    assert lm.error < 1e-8


def test_jacobian_of_polynomial_with_tiny_and_zero_entries():
    f = lambda z: np.array([z[0] ** 3, z[0] * z[1], 1e-6 * z[1] ** 2])
    J, err = jacobian(f, np.array([3e-4, 0.0]))
    np.testing.assert_allclose(J, [[3 * 9e-8, 0.0], [0.0, 3e-4], [0.0, 0.0]], atol=1e-14)


def test_transfer_function_of_a_known_second_order_system():
    # G(s) = 3 (s + 2) / (s^2 + 4 s + 5) in controllable canonical form
    plant = LinearPlant([[0.0, 1.0], [-5.0, -4.0]], [[0.0], [1.0]], [[6.0, 3.0]])
    lm = linearize(plant, _op([0.0, 0.0], [0.0]))
    num, den = lm.to_transfer_function()
    np.testing.assert_allclose(num, [3.0, 6.0], atol=1e-9)
    np.testing.assert_allclose(den, [1.0, 4.0, 5.0], atol=1e-9)
    sub = lm.select(outputs=["y0"], inputs=["u0"])
    assert sub.B.shape == (2, 1) and sub.C.shape == (1, 2)
    with pytest.raises(PlantInputError, match="^input"):
        lm.select(inputs=["nope"])


@pytest.mark.parametrize(
    ("eigs", "expected"),
    [
        ([-1.0, -2.0], ("stable", "stable node")),
        ([-1 + 1j, -1 - 1j], ("stable", "stable focus")),
        ([-1.0, 0.2], ("unstable", "saddle")),
        ([0.5, 2.0], ("unstable", "unstable node")),
        ([0.5 + 1j, 0.5 - 1j], ("unstable", "unstable focus")),
        ([0.0, -1.0], ("marginal", "marginal")),
    ],
)
def test_classify_stability(eigs, expected):
    assert classify_stability(eigs) == expected


def test_find_steady_state_closed_form_and_targets():
    # x' = -2 x + u, y = x: steady x = u/2; target y = 3 needs u = 6
    plant = LinearPlant([[-2.0]], [[1.0]], [[1.0]])
    ss = find_steady_state(plant, [1.0], [5.0])
    assert ss.x[0] == pytest.approx(0.5, abs=SS_TOL)
    ss = find_steady_state(plant, [1.0], [0.0], free_inputs=["u0"], targets={"y0": 3.0})
    assert ss.u[0] == pytest.approx(6.0, abs=SS_TOL) and ss.x[0] == pytest.approx(3.0)
    with pytest.raises(PlantInputError, match="^targets"):
        find_steady_state(plant, [1.0], [0.0], free_inputs=["u0"])
    with pytest.raises(PlantInputError, match="^input"):
        find_steady_state(plant, [1.0], [0.0], free_inputs=["v"], targets={"y0": 1.0})


def test_find_steady_state_reports_failure():
    class NoRoot(LinearPlant):
        def rhs(self, t, x, u, d):
            return np.array([x[0] ** 2 + 1.0])

    with pytest.raises(SteadyStateError):
        find_steady_state(NoRoot([[0.0]], [[0.0]], [[1.0]]), [0.0], [0.3])


def test_result_columns_are_unique_and_named():
    plant = LinearPlant([[-1.0]], [[1.0]], [[1.0]])
    res = simulate(plant, [0.0], [1.0], t_end=1.0, dt=0.5)
    names = [c[0] for c in res.columns()]
    assert names == ["t", "x0", "u0", "y0"]
    np.testing.assert_array_equal(res.signal("y0"), res.y[:, 0])


def _op(x, u):
    from plant_sim.base import OperatingPoint

    return OperatingPoint(name="", x=np.asarray(x, float), u=np.asarray(u, float))
