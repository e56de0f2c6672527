"""QP backends on a recorded TE-size closed-loop sequence (29 variables): same answers,
warm start = cold solve for DAQP, proxsuite's warm-start defect, status always checked."""

from __future__ import annotations

import numpy as np
import pytest

from controller.mpc import DAQPBackend, ProxsuiteBackend, QPVectors
from services.bench.qp import record_te_sequence, solve_sequence

WARM_COLD_ATOL = 1e-9     # DAQP warm vs cold: same active set, same factorisation
BACKEND_ATOL = 1e-5       # DAQP vs proxsuite (eps_abs 1e-8) on a Hessian of condition ~3e5
FEASIBILITY_ATOL = 1e-7   # constraint residual accepted as "satisfied"

N_SAMPLES = 200


@pytest.fixture(scope="module")
def sequence():
    return record_te_sequence(seed=0, n_samples=N_SAMPLES)


@pytest.fixture(scope="module")
def daqp_cold(sequence):
    return solve_sequence(sequence, "daqp", warm=False)


def max_violation(seq, v: QPVectors, z) -> float:
    Az = seq.A @ z
    return float(max(np.max(Az - v.bu), np.max(v.bl - Az), np.max(z - v.ub), np.max(v.lb - z),
                     0.0))


def test_sequence_is_te_size_and_exercises_constraints(sequence, daqp_cold):
    assert sequence.nz == 29  # 7 MVs x M = 4 moves + 1 slack
    assert all(r.ok for r in daqp_cold)
    active = 0
    for v, r in zip(sequence.vectors, daqp_cold):
        # Independent feasibility evidence: the returned point satisfies every row.
        assert max_violation(sequence, v, r.x) <= FEASIBILITY_ATOL
        Az = sequence.A @ r.x
        active += bool(np.any(np.isclose(Az, v.bu, atol=1e-7) | np.isclose(Az, v.bl, atol=1e-7))
                       or np.any(np.isclose(r.x, v.ub, atol=1e-7)
                                 | np.isclose(r.x, v.lb, atol=1e-7)))
    assert active > N_SAMPLES // 4  # constraints are active in a good share of the QPs


def test_daqp_warm_start_equals_cold(sequence, daqp_cold):
    warm = solve_sequence(sequence, "daqp", warm=True)
    for r, r0 in zip(warm, daqp_cold):
        assert r.ok
        np.testing.assert_allclose(r.x, r0.x, atol=WARM_COLD_ATOL)


def test_backends_give_the_same_solutions(sequence, daqp_cold):
    prox = solve_sequence(sequence, "proxsuite", warm=False)
    solved = [(r, r0) for r, r0 in zip(prox, daqp_cold) if r.ok]
    assert len(solved) >= int(0.98 * N_SAMPLES)
    for r, r0 in solved:
        np.testing.assert_allclose(r.x, r0.x, atol=BACKEND_ATOL)


def test_proxsuite_warm_start_misreports_feasible_qps_as_infeasible(sequence, daqp_cold):
    """The defect behind 'never warm start proxsuite': every QP here is feasible (DAQP's
    point satisfies all rows), yet warm-started proxsuite calls some primal infeasible."""
    warm = solve_sequence(sequence, "proxsuite", warm=True, unsafe_warm_start=True)
    false_infeasible = [i for i, (r, r0) in enumerate(zip(warm, daqp_cold))
                        if r.status == "infeasible" and r0.ok]
    assert len(false_infeasible) > 0
    # The production backend ignores a warm-start request.
    safe = ProxsuiteBackend(sequence.H, sequence.A, warm_start=True)
    assert not safe._warm_ok


def test_iteration_limit_is_reported_not_used(sequence, daqp_cold):
    busy = [i for i, r in enumerate(daqp_cold) if r.iterations > 3]
    assert busy
    v = sequence.vectors[busy[0]]
    for solver in (DAQPBackend(sequence.H, sequence.A, max_iter=1, warm_start=False),
                   ProxsuiteBackend(sequence.H, sequence.A, max_iter=1)):
        r = solver.solve(v)
        assert r.status == "max_iter"
        assert not r.ok


def test_nan_data_gives_a_status_not_an_exception(sequence):
    v = sequence.vectors[0]
    bad = QPVectors(f=np.full_like(v.f, np.nan), lb=v.lb, ub=v.ub, bl=v.bl, bu=v.bu)
    for solver in (DAQPBackend(sequence.H, sequence.A), ProxsuiteBackend(sequence.H, sequence.A)):
        r = solver.solve(bad)
        assert not r.ok


def test_infeasible_hard_rows_are_reported():
    H = np.eye(2)
    A = np.array([[1.0, 1.0]])
    v = QPVectors(f=np.zeros(2), lb=np.array([1.0, 1.0]), ub=np.array([2.0, 2.0]),
                  bl=np.array([-np.inf]), bu=np.array([0.0]))
    r = DAQPBackend(H, A).solve(v)
    assert r.status == "infeasible" and not r.ok
    # proxsuite may run into its iteration limit instead of proving infeasibility.
    r = ProxsuiteBackend(H, A).solve(v)
    assert r.status in ("infeasible", "max_iter") and not r.ok


def test_daqp_set_up_ahead_solves_as_set_up_in_the_solve(sequence, daqp_cold):
    """A workspace set up before the solve (placeholder vectors) gives the solve's answer
    within SETUP_AHEAD_ATOL: the first solve starts cold, whatever warm_start says."""
    from controller.mpc.qp import SETUP_AHEAD_ATOL

    for v, r0 in zip(sequence.vectors, daqp_cold):
        solver = DAQPBackend(sequence.H, sequence.A, warm_start=True)
        solver.setup_ahead()
        assert solver._model is not None  # set up before any solve
        r = solver.solve(v)
        assert r.ok
        np.testing.assert_allclose(r.x, r0.x, rtol=0, atol=SETUP_AHEAD_ATOL)
    # and warm from there on: the working set carries over as without the set-up ahead
    solver = DAQPBackend(sequence.H, sequence.A, warm_start=True)
    solver.setup_ahead()
    for v, r0 in zip(sequence.vectors, daqp_cold):
        r = solver.solve(v)
        assert r.ok
        np.testing.assert_allclose(r.x, r0.x, atol=WARM_COLD_ATOL)
