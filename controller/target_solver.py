"""Steady-state targets sample after sample: :func:`controller.targets.solve_targets`
with the structure worked out once.

The same problem and the same algorithm as :mod:`controller.targets` (ranked,
lexicographic relaxation of soft CV limits, one DAQP QP per stage), for a unit that
asks every sample: what does not change between samples is set up once, what does is
written into arrays kept for it.

- **Structure** (sizes, which CV limits and specifications are finite, their ranks):
  the soft-limit rows ``a_i u <= b_i``, their order, the relaxation stages (rows per
  rank, rows held from higher ranks) and every QP's arrays (DAQP's ``bupper``,
  ``blower``, ``sense``; a stage's Hessian, constraint matrix with its slack block)
  are built on the first problem of a structure and kept (a few structures at once:
  an operator's limit switched on and off does not rebuild).
- **Numbers** (gain, operating point, bias, limits, weights): each solve checks them
  (the rules of :class:`~controller.targets.TargetProblem`; a bad one raises its
  ``ValueError`` naming the field) and writes them into the kept arrays, vectorized
  over the rows; one ``daqp.solve`` per QP.

The arithmetic is that of :func:`~controller.targets.solve_targets` operation for
operation, so the targets are the same numbers.

Measured limits (``tests/test_targets_solver.py``; ``ssmpc bench targets``, TE core
size, this 2-core machine at load 2.5-3.2 shared with other work, six runs)::

    quantity                                   measured
    u, y, status, QPs, relaxed limits          bit-identical to solve_targets on 360
    (names, ranks, amounts)                    random problems 1x1 to 7x5 (both
                                               paths met), 40 problems of changing
                                               structure on one solver, and the
                                               two-phase bench's 570 problems
    cost                                       equal (zero terms left out)
    one solve, feasible (1 QP), median         31-58 µs (solve_targets 60-120 µs,
                                               TargetProblem 83-150 µs beside it)
    one solve, relaxed (5 QPs), median         97-208 µs (solve_targets 274-516 µs)
    p99                                        90-190 µs feasible, 240-400 relaxed
    DAQP itself, relaxed case (5 QPs)          25-38 µs
    a new structure's set-up (first problem)   ~0.2 ms, then kept (8 structures)
    two-phase unit (3x3), inside its sample    0.12 ms median (a fifth relax)

What remains is ~40 NumPy calls on 5-vectors of 0.5-1.5 µs each (checks, rows,
Hessian, bounds, cost, report) around 3-8 µs of DAQP per QP.
"""

from __future__ import annotations

import math

import daqp
import numpy as np

from controller.targets import (
    STAGE_REGULARIZATION,
    VIOLATION_TOL,
    RelaxedLimit,
    TargetProblem,
    TargetResult,
    _vec,
)

__all__ = ["TargetSolver"]

_BIG = 1e20
_DAQP_OK = (1, 2)
#: structures kept at once
_MAX_LAYOUTS = 8
_KINDS = ("max", "min", "spec", "spec")
#: the fields of a TargetProblem but the names (what a refusal hands to it)
_FIELDS = ("gain", "u0", "y0", "u_min", "u_max", "q_u", "bias", "y_min", "y_max", "y_rank",
           "y_spec", "spec_rank", "y_scale", "cost_u", "cost_y", "q_y", "u_ref", "y_ref")


class _Stage:
    """One relaxation stage's QP: variables ``[u (nu); s (k)]``, rows ``[held; current]``.

    ``held``: the rows of higher ranks (original order), ``lo:hi``: the current rank's
    rows in the rank-sorted order (the original order within the rank). The arrays
    are views into the layout's buffers, which a solve fills for all stages at once."""

    def __init__(self, nu: int, lo: int, hi: int, cur: np.ndarray, held: np.ndarray,
                 H: np.ndarray, f: np.ndarray, A: np.ndarray, bupper: np.ndarray,
                 blower: np.ndarray) -> None:
        k, mh = cur.size, held.size
        self.lo, self.hi, self.cur, self.held, self.mh, self.n = lo, hi, cur, held, mh, nu + k
        self.H, self.f, self.A, self.bupper, self.blower = H, f, A, bupper, blower
        A[mh:, nu:] = -np.eye(k)
        bupper[nu:nu + k] = _BIG
        blower[nu + k:] = -_BIG
        self.sense = np.zeros(bupper.size, dtype=np.int32)


class _Layout:
    """Rows, metadata and QP arrays of one structure."""

    def __init__(self, ny: int, nu: int, finite: np.ndarray, y_rank: np.ndarray,
                 spec_rank: np.ndarray) -> None:
        lim, cv, sign, rank, kind = [], [], [], [], []
        for i in range(ny):
            for src, s, r, kd in ((i, 1.0, y_rank[i], 0), (ny + i, -1.0, y_rank[i], 1),
                                  (2 * ny + i, 1.0, spec_rank[i], 2),
                                  (2 * ny + i, -1.0, spec_rank[i], 3)):
                if finite[src]:
                    lim.append(src), cv.append(i), sign.append(s), rank.append(int(r))
                    kind.append(kd)
        m = len(lim)
        self.m = m
        self.row_lim = np.array(lim, dtype=np.intp)  # into [y_max; y_min; y_spec]
        self.row_cv = np.array(cv, dtype=np.intp)
        self.row_sign = np.array(sign, dtype=float)[:, None]
        self.row_rank = np.array(rank, dtype=int)
        self.row_kind = tuple(_KINDS[k] for k in kind)
        # the relaxed limits' report order: by rank, rows in order within one
        self.report_order = tuple(np.argsort(self.row_rank, kind="stable").tolist())
        self.A = np.zeros((m, nu))
        self.bupper = np.zeros(nu + m)
        self.blower = np.concatenate([np.zeros(nu), np.full(m, -_BIG)])
        self.sense = np.zeros(nu + m, dtype=np.int32)
        # the relaxation works on the rows sorted by rank: a rank's rows are one slice
        self.by_rank = np.array(self.report_order, dtype=np.intp)
        self.by_rank_cv = self.row_cv[self.by_rank]
        sorted_rank = self.row_rank[self.by_rank]
        ranks = sorted(set(rank))
        spans = [tuple(int(v) for v in np.searchsorted(sorted_rank, [r, r + 1])) for r in ranks]
        helds = [np.flatnonzero(self.row_rank < r) for r in ranks]
        dims = [(nu + hi - lo, h.size + hi - lo) for (lo, hi), h in zip(spans, helds)]
        # every stage's H, f, A, bupper, blower: views into one buffer
        sizes = [n * n + n + n * r + 2 * (n + r) for n, r in dims]
        self.buffer = buf = np.zeros(sum(sizes))
        # flat positions in it of what a solve writes: per stage the u block's diagonal
        # of H, the u part of f and of the bounds (from [δ q_u; f_reg; u_max; u_min]),
        # the slacks' diagonal and the current rows' bounds (from [w; b], rank order)
        # and the constraint rows' u columns (from A)
        tiled_at, tiled_from, wb_at_w, wb_at_b, a_at, a_from = [], [], [], [], [], []
        self.stages = []
        o = 0
        for (lo, hi), held, (n, r) in zip(spans, helds, dims):
            cur = self.by_rank[lo:hi]
            mh, k = held.size, hi - lo
            oh, of, oa = o, o + n * n, o + n * n + n
            ob = oa + n * r
            ol = ob + n + r
            st = _Stage(nu, lo, hi, cur, held, buf[oh:of].reshape(n, n), buf[of:oa],
                        buf[oa:ob].reshape(r, n), buf[ob:ol], buf[ol:ol + n + r])
            self.stages.append(st)
            for part, start in enumerate((oh, of, ob, ol)):
                step = n + 1 if part == 0 else 1
                tiled_at += [start + i * step for i in range(nu)]
                tiled_from += [part * nu + i for i in range(nu)]
            wb_at_w += [oh + (nu + q) * (n + 1) for q in range(k)]
            wb_at_b += [ob + n + mh + q for q in range(k)]
            for t, row in enumerate(np.concatenate([held, cur]).tolist()):
                a_at += [oa + t * n + c for c in range(nu)]
                a_from += [row * nu + c for c in range(nu)]
            o = ol + n + r
        (self.tiled_at, self.tiled_from, self.wb_at, self.a_at, self.a_from) = (
            np.array(v, dtype=np.intp)
            for v in (tiled_at, tiled_from, wb_at_w + wb_at_b, a_at, a_from))


def _qp(H, f, A, bupper, blower, sense):
    """DAQP on ``min ½xᵀHx + fᵀx``, ``blower <= [x; A x] <= bupper``: (x, ok)."""
    x, _, flag, _ = daqp.solve(H, f, A, bupper, blower, sense)
    x = np.asarray(x, dtype=float)
    return x, int(flag) in _DAQP_OK and np.count_nonzero(np.isfinite(x)) == x.size


class TargetSolver:
    """Steady-state targets of problems of one size, one call per sample.

    ``solve(...)`` takes the fields of :class:`~controller.targets.TargetProblem` (the
    same meanings, units and defaults) and returns what
    ``solve_targets(TargetProblem(...))`` returns, without building the problem. The
    arrays it keeps are written by every solve: one solver per caller (thread).

    Parameters
    ----------
    ny, nu : int
        CVs and MVs (>= 1).
    cv_names, mv_names : tuple of str, optional
        Names used in :attr:`TargetResult.relaxed` (default ``cv0``..., ``mv0``...).
    """

    def __init__(self, ny: int, nu: int, cv_names: tuple[str, ...] = (),
                 mv_names: tuple[str, ...] = ()) -> None:
        for name, n in (("ny", ny), ("nu", nu)):
            if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
                raise ValueError(f"{name}: must be an integer >= 1, got {n!r}")
        self.ny, self.nu = int(ny), int(nu)
        self.cv_names = tuple(cv_names) or tuple(f"cv{i}" for i in range(self.ny))
        self.mv_names = tuple(mv_names) or tuple(f"mv{i}" for i in range(self.nu))
        if len(self.cv_names) != self.ny or len(self.mv_names) != self.nu:
            raise ValueError(f"cv_names/mv_names: expected {self.ny} and {self.nu} names")
        self._layouts: dict[bytes, _Layout] = {}
        self._lims = np.empty(3 * self.ny)  # [y_max; y_min; y_spec] of the current solve
        self._inf = np.full(self.ny, math.inf)
        self._ninf = np.full(self.ny, -math.inf)
        self._nan = np.full(self.ny, math.nan)
        self._ones = np.ones(self.ny)
        self._rank1 = np.ones(self.ny)
        self._u_zero = np.zeros(self.nu)
        self._H = np.zeros((self.nu, self.nu))

    # -- inputs --------------------------------------------------------------------------
    def _refuse(self, kw: dict) -> None:
        """Raise the ValueError of :class:`~controller.targets.TargetProblem` on ``kw``."""
        TargetProblem(**kw, cv_names=self.cv_names, mv_names=self.mv_names)
        raise ValueError("target problem: invalid numbers")  # not reached for a bad field

    def _layout(self, key: bytes, finite: np.ndarray, y_rank: np.ndarray,
                spec_rank: np.ndarray) -> _Layout:
        """Set up and keep the layout of a new structure (ranks checked, whole)."""
        if len(self._layouts) >= _MAX_LAYOUTS:
            self._layouts.clear()
        lay = self._layouts[key] = _Layout(self.ny, self.nu, finite, y_rank, spec_rank)
        return lay

    def check(self, **fields) -> None:
        """Check a problem's fields as :meth:`solve` does, without solving.

        Raises
        ------
        ValueError
            As :meth:`solve`.
        """
        self._take(**fields)

    def _take(self, *, gain, u0, y0, u_min, u_max, q_u, bias=None, y_min=None, y_max=None,
              y_rank=None, y_spec=None, spec_rank=None, y_scale=None, cost_u=None,
              cost_y=None, q_y=None, u_ref=None, y_ref=None):
        """The checked fields as arrays (the optional ones None when not given), the
        limits in :attr:`_lims` and the structure's layout."""
        ny, nu = self.ny, self.nu
        G = np.asarray(gain, dtype=float)
        if G.shape != (ny, nu):
            G = np.atleast_2d(G)
            if G.shape != (ny, nu):
                raise ValueError(f"gain: expected shape ({ny}, {nu}), got {G.shape}")

        def vec(name, v, n):
            a = np.asarray(v, dtype=float)
            return a if a.shape == (n,) else _vec(name, v, n)

        u_0, y_0 = vec("u0", u0, nu), vec("y0", y0, ny)
        lo_u, hi_u, qu = vec("u_min", u_min, nu), vec("u_max", u_max, nu), vec("q_u", q_u, nu)
        checked = [G.ravel(), u_0, y_0, lo_u, hi_u, qu]
        opt = {}
        for name, v, n in (("bias", bias, ny), ("y_scale", y_scale, ny),
                           ("cost_u", cost_u, nu), ("cost_y", cost_y, ny), ("q_y", q_y, ny),
                           ("u_ref", u_ref, nu), ("y_ref", y_ref, ny)):
            if v is not None:
                a = np.asarray(v, dtype=float)
                if a.shape != (n,):
                    a = _vec(name, v, n)
                opt[name] = a
                checked.append(a)
        lo = self._ninf if y_min is None else vec("y_min", y_min, ny)
        hi = self._inf if y_max is None else vec("y_max", y_max, ny)
        spec = self._nan if y_spec is None else vec("y_spec", y_spec, ny)
        q_y = opt.get("q_y")
        scale = opt.get("y_scale", self._ones)
        cat = np.concatenate(checked)
        cnt = np.count_nonzero  # faster than ndarray.all on a few values
        # (a NaN limit fails its comparison)
        if (cnt(np.isfinite(cat)) != cat.size or cnt(lo_u <= hi_u) != nu or cnt(qu > 0) != nu
                or ((y_min is not None or y_max is not None) and cnt(lo <= hi) != ny)
                or (q_y is not None and cnt(q_y >= 0) != ny)
                or (y_scale is not None and cnt(scale > 0) != ny)):
            self._refuse({k: v for k, v in locals().items() if k in _FIELDS})
        lims = self._lims
        lims[:ny], lims[ny:2 * ny], lims[2 * ny:] = hi, lo, spec
        rk = self._rank1 if y_rank is None else vec("y_rank", y_rank, ny)
        srk = self._rank1 if spec_rank is None else vec("spec_rank", spec_rank, ny)
        finite = np.isfinite(lims)
        key = finite.tobytes() + rk.tobytes() + srk.tobytes()
        lay = self._layouts.get(key)
        if lay is None:
            for r in (rk, srk):
                if np.any(r < 1) or np.any(r != np.round(r)):
                    self._refuse({k: v for k, v in locals().items() if k in _FIELDS})
            lay = self._layout(key, finite, rk.astype(int), srk.astype(int))
        return (G, u_0, y_0, lo_u, hi_u, qu, opt.get("bias"), scale, opt.get("cost_u"),
                opt.get("cost_y"), q_y, opt.get("u_ref", u_0), opt.get("y_ref", y_0), lay)

    def solve(self, **fields) -> TargetResult:
        """Targets of one problem: the fields of :class:`~controller.targets.TargetProblem`
        but the names (keywords; ``gain`` (ny, nu), the vectors (nu,) or (ny,)).

        Raises
        ------
        ValueError
            A field that :class:`~controller.targets.TargetProblem` refuses, named, or a
            gain of another size than the solver's.
        """
        (G, u0, y0, u_min, u_max, q_u, bias, scale, cost_u, cost_y, q_y, u_ref, y_ref,
         lay) = self._take(**fields)
        nu = self.nu
        lims = self._lims
        # y_b = y0 + d - G u0; the soft rows A u <= b; the economic H, f (controller.targets)
        yb = (y0 + bias if bias is not None else y0) - G @ u0
        m = lay.m
        A = lay.A
        if m:
            np.take(G, lay.row_cv, axis=0, out=A)
            A *= lay.row_sign
            b = (lims.take(lay.row_lim) - yb.take(lay.row_cv)) * lay.row_sign[:, 0]
        else:
            b = np.zeros(0)
        H = self._H  # diag(q_u): DAQP copies it in
        H.reshape(-1)[::nu + 1] = q_u
        if q_y is not None:
            H = H + G.T @ (q_y[:, None] * G)
        f = cost_u if cost_u is not None else self._u_zero
        if cost_y is not None:
            f = f + G.T @ cost_y
        f = f - q_u * u_ref
        if q_y is not None:
            f = f + G.T @ (q_y * (yb - y_ref))

        qps = 1
        bu, bl = lay.bupper, lay.blower
        bu[:nu], bl[:nu] = u_max, u_min
        bu[nu:] = b
        x, ok = _qp(H, f, A, bu, bl, lay.sense)
        widen = None
        if not ok:
            # lexicographic relaxation (controller.targets.solve_targets), rank by rank
            widen = np.zeros(m)
            bw = b.copy()  # b + widen
            order = lay.by_rank
            A_r, b_r = A.take(order, axis=0), b.take(order)
            scale_r = scale.take(lay.by_rank_cv)
            w_r = 2.0 / scale_r ** 2
            tol_r = VIOLATION_TOL * scale_r
            room_r = tol_r * 1e-3  # a hair of room so that the next stage stays feasible
            d = STAGE_REGULARIZATION
            freg = -d * q_u * u_ref
            buf = lay.buffer  # every stage's QP arrays: the numbers of this solve
            buf[lay.tiled_at] = np.concatenate([d * q_u, freg, u_max, u_min]).take(
                lay.tiled_from)
            buf[lay.wb_at] = np.concatenate([w_r, b_r])
            buf[lay.a_at] = A.reshape(-1).take(lay.a_from)
            for st in lay.stages:
                lo, hi, mh, n = st.lo, st.hi, st.mh, st.n
                if mh:  # the rows held at the violations found for them
                    st.bupper[n:n + mh] = bw.take(st.held)
                xs, ok_s = _qp(st.H, st.f, st.A, st.bupper, st.blower, st.sense)
                qps += 1
                if not ok_s:
                    return self._failed(G, yb, u_min, u_max, q_u, u_ref, y_ref, cost_u,
                                        cost_y, q_y, qps)
                # the violation found, s = max(A u - b, 0), counted where above tolerance
                raw = A_r[lo:hi] @ xs[:nu] - b_r[lo:hi]
                widen[st.cur] = np.where(raw > tol_r[lo:hi], raw + room_r[lo:hi], 0.0)
                np.add(b, widen, out=bw)
            bu[nu:] = bw
            x, ok = _qp(H, f, A, bu, bl, lay.sense)
            qps += 1
            if not ok:
                return self._failed(G, yb, u_min, u_max, q_u, u_ref, y_ref, cost_u, cost_y,
                                    q_y, qps)
        u = np.minimum(np.maximum(x[:nu], u_min), u_max)  # np.clip's values, faster
        y = yb + G @ u
        relaxed = []
        if widen is not None and m:
            # a relaxed limit is reported where it was widened and the targets use the room
            # (rows by rank; a CV's limit once)
            order = lay.by_rank
            viol_r = (A @ u - b).take(order)
            hit = np.flatnonzero((widen.take(order) > 0) & (viol_r > tol_r))
            seen = set()
            for q in hit.tolist():
                j = order[q]
                i, kind = int(lay.row_cv[j]), lay.row_kind[j]
                if (i, kind) not in seen:
                    seen.add((i, kind))
                    relaxed.append(RelaxedLimit(self.cv_names[i], kind, int(lay.row_rank[j]),
                                                float(lims[lay.row_lim[j]]), float(viol_r[q])))
        return TargetResult("relaxed" if relaxed else "optimal", u, y, tuple(relaxed),
                            _cost(u, y, q_u, u_ref, y_ref, cost_u, cost_y, q_y), qps)

    def _failed(self, G, yb, u_min, u_max, q_u, u_ref, y_ref, cost_u, cost_y, q_y,
                qps) -> TargetResult:
        u = np.clip(u_ref, u_min, u_max)
        y = yb + G @ u
        return TargetResult("failed", u, y, (),
                            _cost(u, y, q_u, u_ref, y_ref, cost_u, cost_y, q_y), qps)


def _cost(u, y, q_u, u_ref, y_ref, cost_u, cost_y, q_y) -> float:
    """J at (u, y); the terms of zero (default) costs and weights left out."""
    du = u - u_ref
    J = 0.5 * np.add.reduce(q_u * (du * du))  # np.sum's arithmetic
    if cost_u is not None or cost_y is not None:
        lin = (0.0 if cost_u is None else cost_u @ u) + (0.0 if cost_y is None else cost_y @ y)
        J = lin + J
    if q_y is not None:
        dy = y - y_ref
        J = J + 0.5 * np.add.reduce(q_y * (dy * dy))
    return float(J)
