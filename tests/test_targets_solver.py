"""The per-sample target solver against the one-shot reference, solve_targets: the same
numbers on random feasible and infeasible problems (ranks, specifications, limits on
either side), one solver across changing structures, and the same refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest

from controller.target_solver import TargetSolver
from controller.targets import TargetProblem, solve_targets


def _random_fields(rng, ny, nu):
    """A random problem's fields: about half of them infeasible (limits and
    specifications the MV box cannot meet), every optional field given or left out."""
    G = rng.normal(size=(ny, nu)) * 10 ** rng.uniform(-1, 1)
    u0 = rng.uniform(20, 80, nu)
    y0 = rng.normal(size=ny) * 5
    center = y0 + rng.normal(size=ny) * (2 if rng.random() < 0.5 else 40)
    half = rng.uniform(0.5, 20, ny)
    y_min = np.where(rng.random(ny) < 0.6, center - half, -np.inf)
    y_max = np.where(rng.random(ny) < 0.6, center + half, np.inf)
    y_spec = np.where(rng.random(ny) < 0.4, center + rng.normal(size=ny), np.nan)
    f = dict(gain=G, u0=u0, y0=y0, u_min=np.zeros(nu), u_max=np.full(nu, 100.0),
             q_u=rng.uniform(0.1, 3.0, nu), y_min=y_min, y_max=y_max, y_spec=y_spec)
    optional = dict(
        bias=lambda: rng.normal(size=ny),
        y_rank=lambda: rng.integers(1, 4, ny),
        spec_rank=lambda: rng.integers(1, 4, ny),
        y_scale=lambda: rng.uniform(0.2, 5.0, ny),
        cost_u=lambda: rng.normal(size=nu),
        cost_y=lambda: rng.normal(size=ny),
        q_y=lambda: rng.uniform(0, 0.5, ny) * (rng.random(ny) < 0.7),
        u_ref=lambda: rng.uniform(0, 100, nu),
        y_ref=lambda: rng.normal(size=ny) * 5,
    )
    for name, draw in optional.items():
        if rng.random() < 0.6:
            f[name] = draw()
    return f


def _assert_same(fast, ref):
    assert fast.status == ref.status
    assert fast.qps == ref.qps
    np.testing.assert_array_equal(fast.u, ref.u)
    np.testing.assert_array_equal(fast.y, ref.y)
    assert fast.relaxed == ref.relaxed  # names, kinds, ranks, limits and amounts
    assert fast.cost == ref.cost or math.isclose(fast.cost, ref.cost, rel_tol=1e-9)


@pytest.mark.parametrize("ny, nu", [(1, 1), (3, 3), (5, 5), (4, 2), (2, 4), (7, 5)])
def test_the_solver_gives_the_reference_targets_bit_for_bit(ny, nu):
    rng = np.random.default_rng(1000 * ny + nu)
    solver = TargetSolver(ny, nu)
    statuses = []
    for _ in range(60):
        fields = _random_fields(rng, ny, nu)
        ref = solve_targets(TargetProblem(**fields))
        _assert_same(solver.solve(**fields), ref)
        statuses.append(ref.status)
    # both kinds of problem were met, so both paths were compared
    assert statuses.count("optimal") >= 5 and statuses.count("relaxed") >= 5, statuses


def test_one_solver_across_structures_as_operator_limits_come_and_go():
    rng = np.random.default_rng(7)
    solver = TargetSolver(5, 5)
    base = _random_fields(rng, 5, 5)
    for k in range(40):  # more structures than the solver keeps at once
        f = dict(base, bias=rng.normal(size=5) * 5, u0=rng.uniform(20, 80, 5))
        f["y_max"] = np.where(rng.random(5) < 0.5, np.maximum(base["y_min"], 0) + (10 * k) % 7,
                              np.inf)
        f["y_rank"] = rng.integers(1, 3 + k % 3, 5)
        _assert_same(solver.solve(**f), solve_targets(TargetProblem(**f)))


def test_the_bench_problems_and_scalar_fields_give_the_reference_targets():
    from services.bench.targets import _problem

    rng = np.random.default_rng(0)
    for relaxed in (False, True):
        p = _problem(rng, relaxed)
        f = dict(gain=p.gain, u0=p.u0, y0=p.y0, u_min=0.0, u_max=100.0, q_u=1.0,
                 y_min=p.y_min, y_max=p.y_max, y_rank=p.y_rank, cost_u=p.cost_u)
        _assert_same(TargetSolver(5, 5).solve(**f), solve_targets(p))


@pytest.mark.parametrize("bad, match", [
    (dict(u_min=[5.0], u_max=[1.0]), "u_min"),
    (dict(q_u=[0.0]), "q_u"),
    (dict(gain=[[np.nan]]), "gain"),
    (dict(y_min=[2.0], y_max=[1.0]), "y_min"),
    (dict(y_max=[np.nan]), "y_min/y_max"),
    (dict(y_rank=[0]), "y_rank"),
    (dict(spec_rank=[1.5], y_spec=[0.5]), "spec_rank"),
    (dict(u0=[1.0, 2.0]), "u0"),
    (dict(bias=[np.inf]), "bias"),
    (dict(y_scale=[0.0]), "y_scale"),
    (dict(q_y=[-1.0]), "q_y"),
    (dict(gain=[[1.0, 2.0]]), "gain"),
])
def test_bad_fields_are_refused_as_the_problem_refuses_them(bad, match):
    base = dict(gain=[[1.0]], u0=[0.0], y0=[0.0], u_min=[0.0], u_max=[1.0], q_u=[1.0])
    base.update(bad)
    with pytest.raises(ValueError, match=match):
        TargetSolver(1, 1).solve(**base)


def test_a_solver_of_no_size_is_refused():
    with pytest.raises(ValueError, match="ny"):
        TargetSolver(0, 2)
    with pytest.raises(ValueError, match="cv_names"):
        TargetSolver(2, 2, cv_names=("a",))


def test_check_refuses_what_solve_refuses_and_leaves_good_fields_alone():
    good = dict(gain=[[1.0]], u0=[0.0], y0=[0.0], u_min=[0.0], u_max=[1.0], q_u=[1.0])
    solver = TargetSolver(1, 1)
    solver.check(**good)
    with pytest.raises(ValueError, match="q_u"):
        solver.check(**dict(good, q_u=[-1.0]))


def test_the_callers_arrays_are_not_written_and_results_are_their_own():
    rng = np.random.default_rng(3)
    solver = TargetSolver(4, 3)
    for _ in range(20):
        fields = _random_fields(rng, 4, 3)
        before = {k: np.array(v, copy=True) for k, v in fields.items()}
        first = solver.solve(**fields)
        u, y = first.u.copy(), first.y.copy()
        solver.solve(**_random_fields(rng, 4, 3))  # the next sample reuses the kept arrays
        for k, v in fields.items():
            np.testing.assert_array_equal(v, before[k], err_msg=k)
        np.testing.assert_array_equal(first.u, u)
        np.testing.assert_array_equal(first.y, y)
