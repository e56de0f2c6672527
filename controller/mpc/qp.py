"""One QP interface, two dense backends: DAQP (dual active set) and proxsuite (proximal).

Both solve ``min ½ zᵀHz + fᵀz`` s.t. ``lb <= z <= ub``, ``bl <= A z <= bu`` with a
fixed (H, A) given once, and the vectors given per solve. Every solve has an
iteration limit and returns a :class:`QPResult` whose :attr:`QPResult.ok` is True
only for a finished, optimal, finite solution; callers must check it before using
``x``. A backend never raises from :meth:`QPSolver.solve`: solver exceptions become a
result with status ``"error"``.

Warm start: DAQP keeps the working set of the previous solve (proven to give the
cold-solve answer in ``tests/test_mpc_qp.py``).

Set-up ahead (:meth:`QPSolver.setup_ahead`): DAQP's workspace (the factorisation of
``H`` and the constraints' normalisation) can be made when the QP is built, between
samples, instead of inside the first solve. That solve then goes through DAQP's update
path with a cold working set, which rounds differently from its set-up path: measured
on 200 random QPs of the two-phase size, max |Δx| 1.1e-16 with the set-up ahead against
in the solve (:data:`SETUP_AHEAD_ATOL` bounds it in the tests). The workspace's set-up
alone: two-phase QP (P = 40, M = 4) ~0.05 ms, TE (21 variables) ~0.02 ms. Proxsuite's
``WARM_START_WITH_PREVIOUS_RESULT`` misreports feasible problems as primal
infeasible (shown in the same tests), so :class:`ProxsuiteBackend` always solves cold.
"""

from __future__ import annotations

import time
from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from controller.finite_kernel import all_finite
from controller.mpc.formulation import QPVectors
from controller.mpc.vector_kernel import stacked_bounds

__all__ = ["QPResult", "QPSolver", "DAQPBackend", "ProxsuiteBackend", "make_solver",
           "SETUP_AHEAD_ATOL"]

#: Largest difference in a QP's solution between DAQP's workspace set up ahead
#: (:meth:`QPSolver.setup_ahead`) and set up in the solve: round-off of its update path.
SETUP_AHEAD_ATOL = 1e-12

# Finite stand-in for "no limit" where a backend wants finite numbers.
_BIG = 1.0e20


@dataclass(frozen=True)
class QPResult:
    """Outcome of one QP solve.

    Attributes
    ----------
    status : str
        ``"solved"``, ``"max_iter"``, ``"infeasible"``, ``"unbounded"``, ``"nan"``
        (solver returned non-finite numbers) or ``"error"``.
    x : ndarray, shape (nz,) or None
        Solution; only meaningful when :attr:`ok`.
    iterations : int
    solve_ms : float
        Wall time of the solver call (``time.perf_counter``), ms.
    objective : float
        ``½ xᵀHx + fᵀx`` as reported (NaN when unknown).
    backend : str
    raw_status : str
        The backend's own exit code/status.
    """

    status: str
    x: np.ndarray | None
    iterations: int
    solve_ms: float
    objective: float
    backend: str
    raw_status: str

    @property
    def ok(self) -> bool:
        return self.status == "solved" and self.x is not None


class QPSolver(ABC):
    """A dense QP with fixed ``H`` (nz × nz) and ``A`` (m × nz).

    Parameters
    ----------
    H : ndarray, shape (nz, nz)
        Symmetric positive definite.
    A : ndarray, shape (m, nz)
    max_iter : int
        Iteration limit applied to every solve.
    warm_start : bool
        Start from the previous solve where the backend supports it safely.
    """

    name = ""

    def __init__(self, H, A, max_iter: int = 1000, warm_start: bool = True) -> None:
        # Own writable copies: DAQP's bindings reject read-only buffers.
        self.H = np.array(H, dtype=float, order="C", copy=True)
        self.A = np.array(A, dtype=float, order="C", copy=True).reshape(-1, self.H.shape[0])
        if isinstance(max_iter, bool) or int(max_iter) < 1:
            raise ValueError(f"max_iter: must be a positive integer, got {max_iter!r}")
        self.max_iter = int(max_iter)
        self.warm_start = bool(warm_start)
        self._stacked: tuple[np.ndarray, np.ndarray] | None = None  # see _bounds

    @property
    def nz(self) -> int:
        return self.H.shape[0]

    @property
    def m(self) -> int:
        return self.A.shape[0]

    def solve(self, v: QPVectors, *, warm: bool | None = None) -> QPResult:
        """Solve with the vectors ``v``; ``warm`` overrides :attr:`warm_start` once."""
        warm = self.warm_start if warm is None else warm
        t0 = time.perf_counter()
        asc = np.ascontiguousarray  # no copy of the kernels' own vectors
        lb, bl = asc(v.lb, dtype=float), asc(v.bl, dtype=float)
        upper, lower = self._bounds(lb.size + bl.size)
        clean = stacked_bounds(  # the check and [ub; bu], [lb; bl] in one call
            asc(v.f, dtype=float), lb, asc(v.ub, dtype=float), bl, asc(v.bu, dtype=float),
            upper, lower)
        if not clean:
            return QPResult("nan", None, 0, (time.perf_counter() - t0) * 1e3, float("nan"),
                            self.name, "non-finite QP data")
        try:
            status, x, it, obj, raw = self._solve(v, warm, upper, lower)
        except Exception as exc:  # a solver failure is a status, never an exception
            return QPResult("error", None, 0, (time.perf_counter() - t0) * 1e3, float("nan"),
                            self.name, f"{type(exc).__name__}: {exc}")
        ms = (time.perf_counter() - t0) * 1e3
        if x is not None and not all_finite(x):
            status, x = "nan", None
        if status != "solved":
            x = None if status == "nan" else x
        return QPResult(status, x, int(it), ms, float(obj), self.name, str(raw))

    def _bounds(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The stacked bounds' buffers ``[ub; bu]``, ``[lb; bl]`` of ``n`` entries, kept
        from solve to solve (each solve writes them before the backend reads them)."""
        buf = self._stacked
        if buf is None or buf[0].size != n:
            buf = self._stacked = (np.empty(n), np.empty(n))
        return buf

    def setup_ahead(self) -> None:
        """Make the solver's workspace now (between samples) rather than in the next
        solve, which then starts cold; nothing for a backend without one."""
        return None

    @abstractmethod
    def reset(self) -> None:
        """Forget any warm-start information (the next solve is cold)."""

    @abstractmethod
    def _solve(self, v: QPVectors, warm: bool, upper: np.ndarray, lower: np.ndarray):
        """Return ``(status, x, iterations, objective, raw_status)``; ``upper``, ``lower``
        are ``[ub; bu]`` and ``[lb; bl]``."""


class DAQPBackend(QPSolver):
    """DAQP (Arnström, Bemporad, Axehill), a dual active-set solver for small dense QPs.

    The workspace (factorisation of H) is set up once, by the first solve or ahead of
    it (:meth:`setup_ahead`); each solve updates only the vectors. Warm start keeps the
    previous working set; a cold solve clears it.
    """

    name = "daqp"
    # DAQP exit flags (https://darnstrom.github.io/daqp/parameters).
    _FLAGS = {1: "solved", 2: "solved", -1: "infeasible", -2: "error", -3: "unbounded",
              -4: "max_iter", -5: "error", -6: "error"}

    def __init__(self, H, A, max_iter: int = 1000, warm_start: bool = True,
                 primal_tol: float = 1e-9) -> None:
        super().__init__(H, A, max_iter, warm_start)
        import daqp

        self.primal_tol = float(primal_tol)
        self._daqp = daqp
        self._model = None
        self._sense_cold = None
        self._cold_next = False  # a workspace set up ahead: its first solve starts cold

    def reset(self) -> None:
        self._model = None

    def setup_ahead(self) -> None:
        """Set DAQP's workspace up now with placeholder vectors (zero cost vector, unit
        bounds: the set-up factors ``H`` and normalises ``A``, it reads no vector). A
        set-up that fails is left to the first solve, which reports it."""
        if self._model is not None:
            return
        model = self._daqp.Model()
        model.settings = {"iter_limit": self.max_iter, "primal_tol": self.primal_tol}
        n_bounds = self.nz + self.m
        flag = model.setup(self.H, np.zeros(self.nz), self.A, np.ones(n_bounds),
                           -np.ones(n_bounds))
        flag = flag[0] if isinstance(flag, tuple) else flag
        if flag < 0:
            return
        self._model = model
        self._sense_cold = np.zeros(n_bounds, dtype=np.int32)
        self._cold_next = True

    def _solve(self, v: QPVectors, warm: bool, upper: np.ndarray, lower: np.ndarray):
        bu, bl = upper, lower
        f = np.array(v.f, dtype=float)
        if self._model is None:
            model = self._daqp.Model()
            model.settings = {"iter_limit": self.max_iter, "primal_tol": self.primal_tol}
            flag = model.setup(self.H, f, self.A, bu, bl)
            flag = flag[0] if isinstance(flag, tuple) else flag
            if flag < 0:
                return "error", None, 0, float("nan"), f"setup {flag}"
            self._model = model
            self._sense_cold = np.zeros(bu.size, dtype=np.int32)
        elif warm and not self._cold_next:
            self._model.update(f=f, bupper=bu, blower=bl)
        else:
            self._model.update(f=f, bupper=bu, blower=bl, sense=self._sense_cold)
            self._cold_next = False
        x, fval, flag, info = self._model.solve()
        status = self._FLAGS.get(int(flag), "error")
        return status, np.array(x, dtype=float), info.get("iterations", 0), fval, flag


class ProxsuiteBackend(QPSolver):
    """proxsuite's dense ProxQP (Bambade et al.), box constraints on the variables.

    Always solves cold (``NO_INITIAL_GUESS``): its warm start from the previous result
    misreports feasible problems as infeasible.
    """

    name = "proxsuite"

    def __init__(self, H, A, max_iter: int = 1000, warm_start: bool = False,
                 eps_abs: float = 1e-8, unsafe_warm_start: bool = False) -> None:
        super().__init__(H, A, max_iter, warm_start)
        from proxsuite import proxqp

        self._proxqp = proxqp
        self.eps_abs = float(eps_abs)
        self._qp = None
        # Only the tests that demonstrate the defect turn this on.
        self._warm_ok = bool(unsafe_warm_start)

    def reset(self) -> None:
        self._qp = None

    def _new(self, v: QPVectors, warm: bool):
        pq = self._proxqp
        qp = pq.dense.QP(self.nz, 0, self.m, True)
        qp.settings.max_iter = self.max_iter
        qp.settings.max_iter_in = self.max_iter
        qp.settings.eps_abs = self.eps_abs
        qp.settings.eps_rel = 0.0
        qp.settings.verbose = False
        qp.settings.initial_guess = (pq.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT if warm
                                     else pq.InitialGuess.NO_INITIAL_GUESS)
        C = self.A if self.m else None
        qp.init(self.H, v.f, None, None, C, _clip(v.bl) if self.m else None,
                _clip(v.bu) if self.m else None, _clip(v.lb), _clip(v.ub))
        return qp

    def _solve(self, v: QPVectors, warm: bool, upper: np.ndarray, lower: np.ndarray):
        pq = self._proxqp
        warm = warm and self._warm_ok
        if self._qp is None:
            self._qp = self._new(v, warm)
        else:
            self._qp.settings.initial_guess = (
                pq.InitialGuess.WARM_START_WITH_PREVIOUS_RESULT if warm
                else pq.InitialGuess.NO_INITIAL_GUESS)
            self._qp.update(g=v.f, l=_clip(v.bl) if self.m else None,
                            u=_clip(v.bu) if self.m else None,
                            l_box=_clip(v.lb), u_box=_clip(v.ub), update_preconditioner=False)
        self._qp.solve()
        info = self._qp.results.info
        st = info.status
        if st == pq.PROXQP_SOLVED:
            status = "solved"
        elif st == pq.PROXQP_MAX_ITER_REACHED:
            status = "max_iter"
        elif st in (pq.PROXQP_PRIMAL_INFEASIBLE, pq.PROXQP_SOLVED_CLOSEST_PRIMAL_FEASIBLE):
            status = "infeasible"
        elif st == pq.PROXQP_DUAL_INFEASIBLE:
            status = "unbounded"
        else:
            status = "error"
        return (status, np.array(self._qp.results.x, dtype=float), info.iter, info.objValue,
                str(st).rsplit(".", 1)[-1])


def _clip(b: np.ndarray) -> np.ndarray:
    return np.clip(np.asarray(b, dtype=float), -_BIG, _BIG)


def make_solver(backend: str, H, A, max_iter: int = 1000, warm_start: bool = True) -> QPSolver:
    """Backend by name (``"daqp"`` or ``"proxsuite"``)."""
    if backend == "daqp":
        return DAQPBackend(H, A, max_iter, warm_start)
    if backend == "proxsuite":
        return ProxsuiteBackend(H, A, max_iter, warm_start)
    raise ValueError(f"backend: unknown {backend!r}; known: daqp, proxsuite")
