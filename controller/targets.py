"""Steady-state target optimizer: economic CV and MV targets with ranked, relaxable limits.

The layer commercial APC runs above the dynamic controller (DMC3's and Profit
Controller's steady-state LP/QP): from the active model's steady-state gain it finds
where the plant should settle, and the MPC then steers there.

Model (one steady state of the active model, deviation form)::

    y = y_b + G u,        y_b = y0 + d - G u0

with ``G`` (ny, nu) the model's steady-state gain at the operating point
``(u0, y0)`` and ``d`` (ny,) the current output bias (measured minus predicted, the
"disturbance" the MPC also corrects for).

Economic objective (linear and quadratic terms; for TE the Downs & Vogel operating
cost linearized at the point)::

    J(u) = c_uᵀ u + c_yᵀ y + ½ Σ q_u,i (u_i - u_ref,i)² + ½ Σ q_y,i (y_i - y_ref,i)²

with every ``q_u,i > 0`` so the targets are unique.

Limits:

- MV limits ``u_min <= u <= u_max`` are hard (valve ranges);
- CV limits ``y_min <= y <= y_max`` and grade specifications ``y = y_spec`` are soft,
  each with a rank (1 = most important). When they cannot all hold, the lowest-ranked
  ones are relaxed first and minimally: ranks are taken in order; at rank r the
  optimizer minimizes the scaled squared violation ``Σ (s_i / y_scale,i)²`` of the
  rank-r limits while every higher-ranked limit keeps the violation found for it
  (lexicographic relaxation; ranks below r are ignored at that stage). The economic
  objective then chooses among the points that meet every limit so relaxed.
  :attr:`TargetResult.relaxed` reports each relaxed limit, its rank and by how much.

Each stage is a small dense QP solved by DAQP (Arnström, Bemporad & Axehill 2022);
a feasible problem (the usual case) is one QP. A stage's QP carries a tiny
``δ ½ Σ q_u,i (u_i - u_ref,i)²`` (δ = :data:`STAGE_REGULARIZATION`) so that its
Hessian is positive definite; the violations it finds are those of the pure
problem up to a relative ~δ.

Sample after sample (a unit's controller), :class:`controller.target_solver.TargetSolver`
gives the same numbers without a :class:`TargetProblem` per sample: the structure's
rows, stages and QP arrays are set up once, the numbers written into them.

Measured limits (tests/test_targets.py against SciPy's HiGHS LP and SLSQP on the
same problem): targets agree to 1e-6 relative on feasible LP-like and QP problems
and on the relaxed violations of infeasible ones. Time (``ssmpc bench targets``, TE
core size, 5 MVs and 5 CVs; this 2-core machine at load 2.5-3.2, shared with other
work; six runs, the range of their medians and of their p99s, µs)::

    case       TargetProblem(...)       solve_targets(p)          TargetSolver.solve
               median     p99           median     p99            median     p99
    feasible   83-150     190-480       60-120     180-280        31-58      90-190
    relaxed    83-158     180-280       274-516    520-1160       97-208     240-400

(relaxed: 5 QPs). Where the one-shot path's time goes (each part timed alone, 5x5, load
2-4): building the problem is 17 field conversions and ~25 whole-array checks; in
:func:`solve_targets` the soft rows' loop took 12-19 µs, the Hessian and gradient 9-14,
one QP call 8-14 of which DAQP itself 3.3 (the rest concatenating its bounds), then
the cost and the report; a relaxation stage builds its QP with
``hstack``/``vstack``/``eye``/``diag`` each time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["STAGE_REGULARIZATION", "RelaxedLimit", "TargetProblem", "TargetResult",
           "solve_targets"]

#: Weight of the MV-reference term in a relaxation stage, relative to the economic one.
STAGE_REGULARIZATION = 1e-7
#: A violation below this (in units of y_scale) counts as met.
VIOLATION_TOL = 1e-7
_DAQP_OK = (1, 2)


def _vec(name: str, v, n: int, default: float | None = None) -> np.ndarray:
    if v is None:
        if default is None:
            raise ValueError(f"{name}: required")
        return np.full(n, float(default))
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.size == 1 and n != 1:
        a = np.full(n, float(a[0]))
    if a.shape != (n,):
        raise ValueError(f"{name}: expected {n} values, got {a.size}")
    return a


@dataclass(frozen=True)
class TargetProblem:
    """One steady-state target problem (see the module docstring for the math).

    Parameters
    ----------
    gain : array_like (ny, nu)
        Steady-state gain of the active model, CV units per MV unit.
    u0 : array_like (nu,)
        MVs of the operating point the gain is taken at.
    y0 : array_like (ny,)
        CVs there.
    bias : array_like (ny,), optional
        Output bias d (measured minus predicted), default 0.
    u_min, u_max : array_like (nu,)
        Hard MV limits (finite).
    y_min, y_max : array_like (ny,), optional
        Soft CV limits; ±inf = none.
    y_rank : array_like of int (ny,), optional
        Rank of each CV's limits, 1 = most important (default 1).
    y_spec : array_like (ny,), optional
        Grade specifications; NaN = none.
    spec_rank : array_like of int (ny,), optional
        Rank of each specification (default 1).
    y_scale : array_like (ny,), optional
        Engineering scale of each CV for comparing violations (default 1).
    cost_u, cost_y : array_like, optional
        Linear economic cost per unit of MV and CV (default 0).
    q_u : array_like (nu,)
        Quadratic weight toward ``u_ref`` (> 0), per MV unit².
    q_y : array_like (ny,), optional
        Quadratic weight toward ``y_ref`` (>= 0, default 0).
    u_ref, y_ref : array_like, optional
        References of the quadratic terms (default u0, y0).
    cv_names, mv_names : tuple of str, optional
        Names used in :attr:`TargetResult.relaxed`.
    """

    gain: np.ndarray
    u0: np.ndarray
    y0: np.ndarray
    u_min: np.ndarray
    u_max: np.ndarray
    q_u: np.ndarray
    bias: np.ndarray | None = None
    y_min: np.ndarray | None = None
    y_max: np.ndarray | None = None
    y_rank: np.ndarray | None = None
    y_spec: np.ndarray | None = None
    spec_rank: np.ndarray | None = None
    y_scale: np.ndarray | None = None
    cost_u: np.ndarray | None = None
    cost_y: np.ndarray | None = None
    q_y: np.ndarray | None = None
    u_ref: np.ndarray | None = None
    y_ref: np.ndarray | None = None
    cv_names: tuple[str, ...] = ()
    mv_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        G = np.atleast_2d(np.asarray(self.gain, dtype=float))
        if not np.all(np.isfinite(G)):
            raise ValueError("gain: must be finite")
        ny, nu = G.shape
        s = object.__setattr__
        s(self, "gain", G)
        s(self, "u0", _vec("u0", self.u0, nu))
        s(self, "y0", _vec("y0", self.y0, ny))
        s(self, "bias", _vec("bias", self.bias, ny, 0.0))
        s(self, "u_min", _vec("u_min", self.u_min, nu))
        s(self, "u_max", _vec("u_max", self.u_max, nu))
        s(self, "y_min", _vec("y_min", self.y_min, ny, -math.inf))
        s(self, "y_max", _vec("y_max", self.y_max, ny, math.inf))
        s(self, "y_spec", _vec("y_spec", self.y_spec, ny, math.nan))
        s(self, "y_scale", _vec("y_scale", self.y_scale, ny, 1.0))
        s(self, "cost_u", _vec("cost_u", self.cost_u, nu, 0.0))
        s(self, "cost_y", _vec("cost_y", self.cost_y, ny, 0.0))
        s(self, "q_u", _vec("q_u", self.q_u, nu))
        s(self, "q_y", _vec("q_y", self.q_y, ny, 0.0))
        s(self, "u_ref", self.u0.copy() if self.u_ref is None else _vec("u_ref", self.u_ref, nu))
        s(self, "y_ref", self.y0.copy() if self.y_ref is None else _vec("y_ref", self.y_ref, ny))
        for name in ("y_rank", "spec_rank"):
            r = _vec(name, getattr(self, name), ny, 1.0)
            if np.any(r < 1) or np.any(r != np.round(r)):
                raise ValueError(f"{name}: ranks are whole numbers >= 1")
            s(self, name, r.astype(int))
        finite = ("u0", "y0", "bias", "u_min", "u_max", "y_scale", "cost_u", "cost_y", "q_u",
                  "q_y", "u_ref", "y_ref")
        for name in finite:
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"{name}: must be finite")
        if np.any(self.u_min > self.u_max):
            raise ValueError("u_min/u_max: need u_min <= u_max for every MV")
        if np.any(np.isnan(self.y_min)) or np.any(np.isnan(self.y_max)):
            raise ValueError("y_min/y_max: NaN is not a limit (use ±inf for none)")
        if np.any(self.y_min > self.y_max):
            raise ValueError("y_min/y_max: need y_min <= y_max for every CV")
        if np.any(self.q_u <= 0):
            raise ValueError("q_u: every MV needs a positive quadratic weight (unique targets)")
        if np.any(self.q_y < 0) or np.any(self.y_scale <= 0):
            raise ValueError("q_y >= 0 and y_scale > 0 required")
        for name, n in (("cv_names", ny), ("mv_names", nu)):
            names = tuple(getattr(self, name))
            s(self, name, names or tuple(f"{name[:2]}{i}" for i in range(n)))
            if len(getattr(self, name)) != n:
                raise ValueError(f"{name}: expected {n} names")

    @property
    def nu(self) -> int:
        return self.gain.shape[1]

    @property
    def ny(self) -> int:
        return self.gain.shape[0]

    @property
    def y_base(self) -> np.ndarray:
        """``y_b = y0 + d - G u0`` (ny,): the CVs at u = 0 of the linear model."""
        return self.y0 + self.bias - self.gain @ self.u0


@dataclass(frozen=True)
class RelaxedLimit:
    """A soft limit the targets do not meet: ``amount`` (CV units, > 0) beyond it."""

    cv: str
    kind: str  # "min", "max" or "spec"
    rank: int
    limit: float
    amount: float


@dataclass(frozen=True)
class TargetResult:
    """Targets of one solve.

    Attributes
    ----------
    status : str
        ``"optimal"`` (every soft limit met), ``"relaxed"`` (some relaxed, listed in
        :attr:`relaxed`) or ``"failed"`` (the solver did not finish: ``u``, ``y`` are
        then the reference point clipped to the MV limits).
    u : ndarray (nu,)
        MV targets.
    y : ndarray (ny,)
        CV targets (the model's steady state at ``u``).
    relaxed : tuple of RelaxedLimit
        Limits relaxed, highest rank first.
    cost : float
        Economic objective J at the targets.
    qps : int
        QPs solved.
    """

    status: str
    u: np.ndarray
    y: np.ndarray
    relaxed: tuple[RelaxedLimit, ...] = field(default_factory=tuple)
    cost: float = math.nan
    qps: int = 0


def _soft_rows(p: TargetProblem):
    """Soft limits as rows ``a_i u <= b_i`` (a violation s_i >= 0 widens b_i)."""
    yb, G = p.y_base, p.gain
    rows, rhs, meta = [], [], []
    for i in range(p.ny):
        if math.isfinite(p.y_max[i]):
            rows.append(G[i]), rhs.append(p.y_max[i] - yb[i])
            meta.append((i, "max", int(p.y_rank[i]), p.y_max[i]))
        if math.isfinite(p.y_min[i]):
            rows.append(-G[i]), rhs.append(yb[i] - p.y_min[i])
            meta.append((i, "min", int(p.y_rank[i]), p.y_min[i]))
        if math.isfinite(p.y_spec[i]):
            rows.append(G[i]), rhs.append(p.y_spec[i] - yb[i])
            meta.append((i, "spec", int(p.spec_rank[i]), p.y_spec[i]))
            rows.append(-G[i]), rhs.append(yb[i] - p.y_spec[i])
            meta.append((i, "spec", int(p.spec_rank[i]), p.y_spec[i]))
    A = np.array(rows, dtype=float).reshape(len(rows), p.nu)
    return A, np.array(rhs, dtype=float), meta


def _economic(p: TargetProblem) -> tuple[np.ndarray, np.ndarray]:
    """H (nu, nu) and f (nu,) of J(u) up to a constant."""
    G, yb = p.gain, p.y_base
    H = np.diag(p.q_u) + G.T @ (p.q_y[:, None] * G)
    f = p.cost_u + G.T @ p.cost_y - p.q_u * p.u_ref + G.T @ (p.q_y * (yb - p.y_ref))
    return H, f


def _qp(H, f, A, bu, bl, lb, ub):
    """DAQP on ``min ½xᵀHx + fᵀx``, ``lb <= x <= ub``, ``bl <= A x <= bu``; (x, ok)."""
    import daqp

    n = H.shape[0]
    bupper = np.concatenate([ub, bu])
    blower = np.concatenate([lb, bl])
    Afull = A if A.size else np.zeros((0, n))
    sense = np.zeros(bupper.size, dtype=np.int32)
    x, _, flag, _ = daqp.solve(np.ascontiguousarray(H), np.ascontiguousarray(f),
                               np.ascontiguousarray(Afull), np.ascontiguousarray(bupper),
                               np.ascontiguousarray(blower), sense)
    x = np.asarray(x, dtype=float)
    return x, int(flag) in _DAQP_OK and bool(np.all(np.isfinite(x)))


def solve_targets(p: TargetProblem) -> TargetResult:
    """Steady-state targets of ``p`` (see the module docstring).

    Never raises for a valid problem: a solver failure gives ``status="failed"`` and
    the MV reference clipped to its limits.
    """
    nu = p.nu
    A, b, meta = _soft_rows(p)
    m = A.shape[0]
    H, f = _economic(p)
    big = 1e20
    qps = 1
    # the usual case: every soft limit holds (one QP)
    x, ok = _qp(H, f, A, b, np.full(m, -big), p.u_min, p.u_max)
    widen = np.zeros(m)
    if not ok:
        scale = np.array([p.y_scale[i] for i, *_ in meta]) if m else np.zeros(0)
        ranks = np.array([r for _, _, r, _ in meta], dtype=int)
        Hreg = STAGE_REGULARIZATION * np.diag(p.q_u)
        freg = -STAGE_REGULARIZATION * p.q_u * p.u_ref
        for r in sorted(set(ranks.tolist())):
            cur = np.flatnonzero(ranks == r)
            fixed = np.flatnonzero(ranks < r)
            k = cur.size
            # variables [u (nu); s (k)]: min Σ (s/scale)² + δ ½ q_u (u - u_ref)²
            Hs = np.zeros((nu + k, nu + k))
            Hs[:nu, :nu] = Hreg
            Hs[nu:, nu:] = np.diag(2.0 / scale[cur] ** 2)
            fs = np.concatenate([freg, np.zeros(k)])
            rows_cur = np.hstack([A[cur], -np.eye(k)])
            rows_fix = np.hstack([A[fixed], np.zeros((fixed.size, k))])
            As = np.vstack([rows_fix, rows_cur])
            bus = np.concatenate([b[fixed] + widen[fixed], b[cur]])
            lbs = np.concatenate([p.u_min, np.zeros(k)])
            ubs = np.concatenate([p.u_max, np.full(k, big)])
            xs, ok_s = _qp(Hs, fs, As, bus, np.full(bus.size, -big), lbs, ubs)
            qps += 1
            if not ok_s:
                return _failed(p, qps)
            s = np.maximum(A[cur] @ xs[:nu] - b[cur], 0.0)
            s[s <= VIOLATION_TOL * scale[cur]] = 0.0
            # a hair of room so that the next stage's QP stays feasible in floating point
            widen[cur] = np.where(s > 0, s + VIOLATION_TOL * scale[cur] * 1e-3, 0.0)
        x, ok = _qp(H, f, A, b + widen, np.full(m, -big), p.u_min, p.u_max)
        qps += 1
        if not ok:
            return _failed(p, qps)
    u = np.clip(x[:nu], p.u_min, p.u_max)
    y = p.y_base + p.gain @ u
    relaxed = []
    viol = A @ u - b if m else np.zeros(0)
    seen = set()
    for j in np.argsort([meta[j][2] for j in range(m)], kind="stable"):
        i, kind, rank, lim = meta[j]
        amt = float(viol[j])
        if widen[j] > 0 and amt > VIOLATION_TOL * p.y_scale[i] and (i, kind) not in seen:
            seen.add((i, kind))
            relaxed.append(RelaxedLimit(p.cv_names[i], kind, rank, float(lim), amt))
    return TargetResult("relaxed" if relaxed else "optimal", u, y, tuple(relaxed),
                        _cost(p, u, y), qps)


def _cost(p: TargetProblem, u, y) -> float:
    return float(p.cost_u @ u + p.cost_y @ y + 0.5 * np.sum(p.q_u * (u - p.u_ref) ** 2)
                 + 0.5 * np.sum(p.q_y * (y - p.y_ref) ** 2))


def _failed(p: TargetProblem, qps: int) -> TargetResult:
    u = np.clip(p.u_ref, p.u_min, p.u_max)
    y = p.y_base + p.gain @ u
    return TargetResult("failed", u, y, (), _cost(p, u, y), qps)
