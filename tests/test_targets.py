"""Steady-state target optimizer against independent solves (SciPy HiGHS LP, SLSQP)
and hand-worked relaxation orders."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog, minimize

from controller.targets import TargetProblem, solve_targets

#: agreement with the independent solves, relative to the MV range
RTOL_QP = 1e-6
#: LP-like problems: the optimizer carries a 1e-9 quadratic term the LP does not
RTOL_LP = 1e-5


def _random_problem(rng, ny=5, nu=5, **kw):
    G = rng.normal(size=(ny, nu))
    u0 = rng.uniform(30, 70, nu)
    y0 = rng.normal(size=ny) * 10
    base = dict(gain=G, u0=u0, y0=y0, u_min=np.zeros(nu), u_max=np.full(nu, 100.0),
                q_u=rng.uniform(0.5, 2.0, nu), cost_u=rng.normal(size=nu),
                cost_y=rng.normal(size=ny), bias=rng.normal(size=ny))
    base.update(kw)
    return TargetProblem(**base)


def _constraints(p):
    """Soft limits as ``A u <= b`` (rows as the module defines them), built here anew."""
    G, yb = p.gain, p.y0 + p.bias - p.gain @ p.u0
    rows, rhs = [], []
    for i in range(p.ny):
        if np.isfinite(p.y_max[i]):
            rows.append(G[i]), rhs.append(p.y_max[i] - yb[i])
        if np.isfinite(p.y_min[i]):
            rows.append(-G[i]), rhs.append(yb[i] - p.y_min[i])
    return np.array(rows), np.array(rhs), yb


def _objective(p, yb):
    def J(u):
        y = yb + p.gain @ u
        return (p.cost_u @ u + p.cost_y @ y + 0.5 * np.sum(p.q_u * (u - p.u_ref) ** 2)
                + 0.5 * np.sum(p.q_y * (y - p.y_ref) ** 2))
    return J


@pytest.mark.parametrize("seed", range(5))
def test_feasible_targets_equal_an_slsqp_solve(seed):
    rng = np.random.default_rng(seed)
    p = _random_problem(rng, y_min=np.full(5, -15.0), y_max=np.full(5, 15.0),
                        q_y=rng.uniform(0, 0.1, 5))
    res = solve_targets(p)
    A, b, yb = _constraints(p)
    def grad(u):
        y = yb + p.gain @ u
        return (p.cost_u + p.gain.T @ p.cost_y + p.q_u * (u - p.u_ref)
                + p.gain.T @ (p.q_y * (y - p.y_ref)))

    ref = minimize(_objective(p, yb), p.u0, jac=grad, method="SLSQP",
                   bounds=list(zip(p.u_min, p.u_max)),
                   constraints=[{"type": "ineq", "fun": lambda u: b - A @ u,
                                 "jac": lambda u: -A}],
                   options={"ftol": 1e-13, "maxiter": 500})
    assert ref.success, ref.message
    if res.status == "optimal":
        np.testing.assert_allclose(res.u, ref.x, atol=RTOL_QP * 100.0)
        np.testing.assert_allclose(res.y, yb + p.gain @ ref.x, atol=RTOL_QP * 100.0 * 10)
    else:  # the limits do not all hold: SLSQP must not have found them feasible either
        assert np.max(A @ ref.x - b) > 1e-6


@pytest.mark.parametrize("seed", range(5))
def test_lp_like_targets_equal_a_highs_linprog_solve(seed):
    rng = np.random.default_rng(100 + seed)
    p = _random_problem(rng, q_u=np.full(5, 1e-9), y_min=np.full(5, -20.0),
                        y_max=np.full(5, 20.0))
    A, b, yb = _constraints(p)
    c = p.cost_u + p.gain.T @ p.cost_y
    lp = linprog(c, A_ub=A, b_ub=b, bounds=list(zip(p.u_min, p.u_max)), method="highs")
    assert lp.status == 0
    res = solve_targets(p)
    assert res.status == "optimal"
    np.testing.assert_allclose(res.u, lp.x, atol=RTOL_LP * 100.0)


def test_relaxation_order_one_mv_one_cv_by_hand():
    # y = u on 0..100; the limit y <= 10 and the specification y = 12 cannot both hold
    common = dict(gain=[[1.0]], u0=[0.0], y0=[0.0], u_min=[0.0], u_max=[100.0], q_u=[1e-3],
                  y_max=[10.0], y_spec=[12.0], cv_names=("y",))
    limit_first = solve_targets(TargetProblem(**common, y_rank=[1], spec_rank=[2]))
    assert limit_first.status == "relaxed"
    assert limit_first.u[0] == pytest.approx(10.0, abs=1e-6)
    (r,) = limit_first.relaxed
    assert (r.cv, r.kind, r.rank) == ("y", "spec", 2) and r.amount == pytest.approx(2.0, abs=1e-6)
    spec_first = solve_targets(TargetProblem(**common, y_rank=[2], spec_rank=[1]))
    assert spec_first.u[0] == pytest.approx(12.0, abs=1e-6)
    (r,) = spec_first.relaxed
    assert (r.kind, r.rank) == ("max", 2) and r.amount == pytest.approx(2.0, abs=1e-6)


def test_hard_mv_limits_are_never_relaxed():
    # y = 2 u with u <= 4: the rank-1 spec y = 10 is out of reach; it is relaxed, u is not
    p = TargetProblem(gain=[[2.0]], u0=[0.0], y0=[0.0], u_min=[0.0], u_max=[4.0], q_u=[1.0],
                      y_spec=[10.0])
    res = solve_targets(p)
    assert res.u[0] == pytest.approx(4.0, abs=1e-9)
    assert res.relaxed[0].amount == pytest.approx(2.0, abs=1e-6)


def _lexicographic_reference(p, ranks_rows, A, b, scale):
    """Relax rank by rank with SLSQP (no regularization), then the economic QP."""
    J = _objective(p, p.y0 + p.bias - p.gain @ p.u0)
    bounds = list(zip(p.u_min, p.u_max))
    widen = np.zeros(b.size)
    for r in sorted(set(ranks_rows)):
        cur = np.flatnonzero(ranks_rows == r)
        fix = np.flatnonzero(ranks_rows < r)

        def viol(u, cur=cur):
            return float(np.sum((np.maximum(A[cur] @ u - b[cur], 0.0) / scale[cur]) ** 2))

        cons = [] if fix.size == 0 else [
            {"type": "ineq", "fun": lambda u, fix=fix: b[fix] + widen[fix] + 1e-9 - A[fix] @ u}]
        best = min((minimize(viol, x0, method="SLSQP", bounds=bounds, constraints=cons,
                             options={"ftol": 1e-16, "maxiter": 1000})
                    for x0 in (p.u0, p.u_min, p.u_max, (p.u_min + p.u_max) / 2)),
                   key=lambda r: r.fun)
        widen[cur] = np.maximum(A[cur] @ best.x - b[cur], 0.0)
    final = minimize(J, p.u0, method="SLSQP", bounds=bounds,
                     constraints=[{"type": "ineq", "fun": lambda u: b + widen + 1e-9 - A @ u}],
                     options={"ftol": 1e-15, "maxiter": 1000})
    return final.x, widen


@pytest.mark.parametrize("seed", range(4))
def test_infeasible_ranked_limits_equal_a_lexicographic_scipy_solve(seed):
    rng = np.random.default_rng(200 + seed)
    ny, nu = 4, 2  # more CV limits than MVs can meet: some must give
    G = rng.normal(size=(ny, nu))
    ranks = np.array([1, 2, 2, 3])
    lo = rng.uniform(1.0, 3.0, ny)  # y >= lo with y near 0 at u0: not all reachable
    p = TargetProblem(gain=G, u0=np.zeros(nu), y0=np.zeros(ny), u_min=np.full(nu, -1.0),
                      u_max=np.full(nu, 1.0), q_u=np.ones(nu), y_min=lo, y_rank=ranks,
                      y_scale=rng.uniform(0.5, 2.0, ny), cost_u=rng.normal(size=nu))
    A, b, _ = _constraints(p)
    ref_u, ref_widen = _lexicographic_reference(p, ranks, A, b, p.y_scale)
    res = solve_targets(p)
    assert res.status == "relaxed"
    got = {(r.cv, r.kind): r.amount for r in res.relaxed}
    for i in range(ny):
        amount = got.get((p.cv_names[i], "min"), 0.0)
        assert amount == pytest.approx(ref_widen[i], abs=1e-5), (i, got, ref_widen)
    np.testing.assert_allclose(res.u, ref_u, atol=1e-5)
    # the highest rank keeps the smallest violation it can: never worse than the reference
    assert got.get((p.cv_names[0], "min"), 0.0) <= ref_widen[0] + 1e-6


@pytest.mark.parametrize("bad, match", [
    (dict(u_min=[5.0], u_max=[1.0]), "u_min"),
    (dict(q_u=[0.0]), "q_u"),
    (dict(gain=[[np.nan]]), "gain"),
    (dict(y_min=[2.0], y_max=[1.0]), "y_min"),
    (dict(y_rank=[0]), "y_rank"),
    (dict(u0=[1.0, 2.0]), "u0"),
])
def test_bad_problems_are_refused_naming_the_field(bad, match):
    base = dict(gain=[[1.0]], u0=[0.0], y0=[0.0], u_min=[0.0], u_max=[1.0], q_u=[1.0])
    base.update(bad)
    with pytest.raises(ValueError, match=match):
        TargetProblem(**base)


def test_bench_targets_reports_both_cases():
    import json
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-m", "services.cli", "bench", "targets", "--n", "20",
                          "--json"], capture_output=True, text=True, timeout=120, check=True)
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    cases = {c["case"]: c for c in doc["cases"]}
    assert set(cases) == {"feasible", "relaxed"} and doc["machine"]
    assert cases["feasible"]["status"] == "optimal" and cases["relaxed"]["status"] == "relaxed"
    assert all(c["n"] == 20 and c["median"] > 0 for c in cases.values())
