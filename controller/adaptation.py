"""Normalized least-squares parameter adaptation (seed eq. 4.1) with covariance bounds.

The seed's law (after Goodwin & Mayne and Ioannou & Sun) is written in continuous
time for a SISO identifier ``y = p' w``:

    e     = y - p' w
    dp/dt = g P w e / (1 + gamma w' P w)
    dP/dt = -g P w w' P / (1 + gamma w' P w)

with the covariance initialized to ``kappa I`` and reset when its smallest
eigenvalue falls to a threshold (seed §5.1.3: kappa = 10, lambda_min(P) > 1).

Here it is used in the discrete-time, multi-output form for ``y = W p`` with a
measurement matrix ``W`` of shape ``(m, N)`` (one row per output), stepped once
per sample with the per-sample gain ``g_d = g * dt``:

    S  = I_m + gamma W P W'                    (m x m normalization)
    K  = P W' S^-1
    p <- p + g_d K e
    P <- P - g_d K W P

For ``g_d = gamma`` this is exactly recursive least squares with the data scaled
by ``sqrt(gamma)``; for ``g_d < gamma`` it is a damped version. ``g_d > gamma``
would make ``P`` indefinite, so it is rejected.

Covariance resetting: a cheap lower bound on ``lambda_min(P)`` is carried from
sample to sample (each update lowers it by at most ``g_d trace(K W P)``); only
when the bound reaches the floor is ``lambda_min(P) > floor`` decided exactly (for
``N`` up to :attr:`NLSSettings.exact_check_max_params`; larger problems reset on
the bound alone). The exact decision is a Cholesky factorization of ``P - floor I``
(:mod:`controller.definiteness`; for the implicit ``c I - V V'`` of the Gram matrix
``V' V``, kept up to date as V grows), which decides as the smallest eigenvalue
would; a passed check leaves the floor itself as the bound. A covariance that is not finite, not
symmetric positive definite, or a singular ``S`` also triggers a reset. Every reset
is counted.

The implicit form keeps V, ``V' V`` and the Cholesky factor of the floor check in
buffers that grow to the largest rank once: the covariance step writes its block of m
columns into V and borders ``V' V`` in one compiled call, as the products ``P W'``
before an update are one (:mod:`controller.lowrank_kernel`), and a check factors only
the rows added since the last one (:func:`controller.definiteness.cholesky_extend`).
When V outgrows ``lowrank_max_rank`` at a sample whose bound has reached the floor and
``N > exact_check_max_params``, the reset on the bound alone follows at once, so P is
not made dense first (the dense P would be discarded by the reset). The compiled
products sum in their own order, so they differ from numpy's in the last bits: the TE
moves stay within 4e-9 of those made with numpy's products (48 h, and the short cases
of ``tests/data/te_moves``; the same as between two numpy builds).

**Measured** (TE ``ssmpc`` closed loop, N = 213, m = 5: a floor check at 4,235 of
4,800 samples in 48 h, 281 resets, all at the rank limit; shared 2-core AMD EPYC at
load 4-7, the code before and after run alternately).

One estimator sample (prepare, update, commit) on TE-size data, best of 5 x 2,000
samples' CPU time, two alternated pairs:

==============  ==========  ==========  ==========  ===========
code            prepare us  update us   commit us   sample (CPU)
==============  ==========  ==========  ==========  ===========
before          124-131     62-65       315-360     354-364 us
after           90-95       43-52       68-72       139-167 us
==============  ==========  ==========  ==========  ===========

Where a 48 h ``ssmpc`` sample goes (inclusive method timers, ms per sample of wall
time, two alternated pairs at load 4.0-5.5; every number is inflated 3-5x against a
quiet machine, and unchanged parts moved by up to 30 % between runs with the load):

======================================  =============  =============
part                                    before         after
======================================  =============  =============
whole sample (plant, controller, loop)  3.63-4.32      4.33-5.49
TE step, of which                       2.11-2.46      2.72-3.42
  core step (MultiModelController)      1.29-1.43      1.53-1.96
    MPC law and QP                      0.53-0.57      0.67-0.90
    first-order-hold errors, advance    0.15-0.18      0.18-0.22
    NLS update (compiled step)          0.13           0.14-0.19
    index, switching, steady scale      0.15-0.16      0.16-0.20
  steady-state targets                  0.52-0.66      0.79-0.95
  plan references (ahead)               0.16           0.23-0.28
core bookkeeping after the move         0.99-1.26      0.88-1.17
  covariance commit (this module)       0.44-0.59      0.23-0.32
  NLS prepare                           0.19-0.24      0.24-0.33
  regressor (with its hold part)        0.13-0.16      0.10-0.13
  shared-state update                   0.07-0.09      0.10-0.13
  MPC law's refresh ahead               0.13-0.14      0.18-0.20
plant and inner loops (compiled)        0.23-0.28      0.32-0.40
======================================  =============  =============

The commit halved in the runs where everything else slowed by a quarter.
``ssmpc bench te-closed-loop --runs 2 --strategies ssmpc``, three alternated pairs
at load 5.0-7.2: 1.55-1.96 process-h/s before (best run 2.02), 2.16-2.71 after (best
2.92). At 40 process-h/s a sample has 0.25 ms; on this machine the core's remaining
per-sample Python (law, targets, index, bookkeeping; about a dozen calls of a few
µs each per part) is far above that, and only compiling the sample as a whole would
reach it.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.definiteness import (
    ABOVE,
    cholesky_extend,
    floor_check,
    lowrank_floor_check,
)
from controller.lowrank_kernel import compile_lowrank, lowrank_append, lowrank_products
from controller.nls_kernel import (
    DEAD_ZONE,
    DIVERGED,
    FROZEN,
    INVALID_DATA,
    NONFINITE,
    SINGULAR,
    compile_nls_step,
    nls_step,
)
from controller.packing import pack_array, unpack_array
from controller.readback import count_below, finite_number

__all__ = ["AdaptiveKind", "NLSSettings", "NLSStep", "NormalizedLeastSquares"]

#: Dense covariance steps between two symmetrizations ``P <- (P + P')/2``, which keep
#: round-off from making P unsymmetric (the count is part of a checkpoint).
SYMMETRIZE_EVERY = 64


class AdaptiveKind(enum.Enum):
    """The three adaptive models of seed §4 (after Narendra & Balakrishnan, ref. [19]).

    ``FIXED`` is a non-adapted model. At a *restart event* (see
    :class:`controller.multimodel.MultiModelController`): a ``CONVENTIONAL``
    model starts again from its initial parameters, a ``FREE_RUNNING`` model
    continues from its current ones, and a ``REINITIALIZED`` model takes the
    parameters of the fixed model with the smallest performance index.
    """

    FIXED = "fixed"
    CONVENTIONAL = "conventional"
    FREE_RUNNING = "free-running"
    REINITIALIZED = "re-initialized"

    @property
    def adaptive(self) -> bool:
        return self is not AdaptiveKind.FIXED

    @classmethod
    def parse(cls, value: AdaptiveKind | str) -> AdaptiveKind:
        """Accept an enum member or its value/name (``"free-running"``, ``"FREE_RUNNING"``)."""
        if isinstance(value, cls):
            return value
        text = str(value).strip()
        for member in cls:
            if text in (member.value, member.name, member.name.lower()):
                return member
        known = ", ".join(m.value for m in cls)
        raise ValueError(f"kind: unknown adaptive kind {value!r}; known: {known}")


@dataclass(frozen=True)
class NLSSettings:
    """Tuning of the normalized least-squares law (eq. 4.1).

    Parameters
    ----------
    kappa : float
        Initial covariance ``P(0) = kappa I`` (seed: 10).
    gain : float
        Adaptive gain ``g`` in 1/(time unit) (seed: ``0 < g < 100``). The
        per-sample gain is ``g * dt`` and must not exceed ``rate``.
    rate : float
        Adaptive rate ``gamma`` of the normalization ``1 + gamma w'Pw`` (seed: 1).
    eig_floor : float
        Reset the covariance when its smallest eigenvalue falls to this value
        (seed: lambda_min(P) > 1).
    reset_value : float or None
        Covariance after a reset, ``reset_value * I``; None means ``kappa``.
        Must exceed ``eig_floor``.
    exact_check_max_params : int
        Largest parameter count for which the exact smallest eigenvalue is
        computed when the cheap bound reaches the floor; above it the bound alone
        triggers the reset (an eigen-decomposition of a 1000 x 1000 matrix would
        cost more than a sample).
    max_abs_param : float
        A parameter larger than this in magnitude is treated as divergence: the
        update is rejected and the covariance reset (counted).
    lowrank_min_params : int
        From this many parameters on, the covariance is kept implicitly as
        ``c I - V V'`` (c the last reset value, V one block of m columns per
        update since) until V has ``lowrank_max_rank`` columns, then densified.
        Exact same algorithm, but a sample costs O(N r m) instead of O(N^2 m)
        while covariance resets keep r small (the seed's kappa = 10 with
        lambda_min(P) > 1 resets every few samples).
    lowrank_max_rank : int
        Columns of V before switching to the dense form.
    dead_zone : float
        No update while every output's prediction error is within this band
        (output units; 0 = always adapt, the seed's law). The classic robust
        modification (Ioannou & Sun §8.5): without excitation at a steady state,
        tiny errors from unmodelled dynamics otherwise let the parameters drift.
    """

    kappa: float = 10.0
    gain: float = 10.0
    rate: float = 1.0
    eig_floor: float = 1.0
    reset_value: float | None = None
    exact_check_max_params: int = 64
    max_abs_param: float = 1e8
    lowrank_min_params: int = 128
    lowrank_max_rank: int = 80
    dead_zone: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.dead_zone, int | float) and math.isfinite(self.dead_zone)
                and self.dead_zone >= 0):
            raise ValueError(f"dead_zone: must be a finite number >= 0, got {self.dead_zone!r}")
        for name in ("kappa", "gain", "rate", "eig_floor", "max_abs_param"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
        if self.reset_value is not None and not (
            math.isfinite(self.reset_value) and self.reset_value > self.eig_floor
        ):
            raise ValueError(
                f"reset_value: must be finite and > eig_floor ({self.eig_floor}), "
                f"got {self.reset_value!r}"
            )
        if self.reset_value is None and self.kappa <= self.eig_floor:
            raise ValueError(
                f"kappa: must exceed eig_floor ({self.eig_floor}) when reset_value is None, "
                f"got {self.kappa}"
            )
        if int(self.exact_check_max_params) < 0:
            raise ValueError("exact_check_max_params: must be >= 0")
        if int(self.lowrank_min_params) < 1 or int(self.lowrank_max_rank) < 1:
            raise ValueError("lowrank_min_params, lowrank_max_rank: must be >= 1")

    @property
    def reset_to(self) -> float:
        """Covariance scale after a reset."""
        return float(self.kappa if self.reset_value is None else self.reset_value)

    def per_sample_gain(self, dt: float) -> float:
        """``g * dt``, checked against ``gamma`` (else P would lose definiteness)."""
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        g_d = self.gain * dt
        if g_d > self.rate * (1.0 + 1e-12):
            raise ValueError(
                f"gain: per-sample gain gain*dt = {g_d:g} exceeds rate = {self.rate:g}; "
                f"the covariance update would lose positive definiteness "
                f"(use gain <= {self.rate / dt:g} at dt = {dt:g})"
            )
        return g_d


@dataclass(frozen=True)
class NLSStep:
    """What one update did.

    Attributes
    ----------
    error : ndarray, shape (m,)
        Prediction error ``y - W p`` before the update.
    updated : bool
        False when the sample was skipped (invalid data or frozen).
    reset : bool
        True when the covariance was reset at this sample.
    reason : str
        ``""``, ``"floor"``, ``"singular"``, ``"nonfinite"``, ``"diverged"``,
        ``"invalid_data"``, ``"frozen"`` or ``"dead_zone"``.
    """

    error: np.ndarray
    updated: bool
    reset: bool = False
    reason: str = ""


class NormalizedLeastSquares:
    """Discrete normalized least squares for ``y = W p`` (eq. 4.1, MIMO form).

    Parameters
    ----------
    settings : NLSSettings
        Tuning.
    p0 : array_like, shape (N,)
        Initial parameter vector.
    dt : float
        Sample time (same time unit as ``settings.gain``).
    lower, upper : array_like, shape (N,), optional
        Box that the parameters are projected onto after each update (a known
        region of the true parameters, e.g. around the fixed models; the
        "projection" modification of Ioannou & Sun §4.11). Counted in
        ``n_projections``.

    Attributes
    ----------
    p : ndarray, shape (N,)
        Current parameters.
    P : ndarray, shape (N, N)
        Current covariance.
    n_updates, n_resets, n_skipped : int
        Counters: updates applied, covariance resets, samples skipped.
    """

    def __init__(self, settings: NLSSettings, p0, dt: float, lower=None, upper=None) -> None:
        self.settings = settings
        p0 = np.asarray(p0, dtype=float).reshape(-1)
        if p0.size == 0 or not np.isfinite(p0).all():
            raise ValueError("p0: must be a non-empty finite vector")
        self.lower = np.full(p0.size, -np.inf) if lower is None else np.array(lower, float)
        self.upper = np.full(p0.size, np.inf) if upper is None else np.array(upper, float)
        if self.lower.shape != p0.shape or self.upper.shape != p0.shape:
            raise ValueError(f"lower, upper: must have length {p0.size}")
        if np.isnan(self.lower).any() or np.isnan(self.upper).any() or np.any(
                self.lower > self.upper):
            raise ValueError("lower, upper: must not be NaN and lower <= upper")
        self.n_projections = 0
        self.dt = float(dt)
        self.g_d = settings.per_sample_gain(self.dt)
        self.p = p0.copy()
        self._lowrank = p0.size >= settings.lowrank_min_params
        self._Pd: np.ndarray | None = None
        self._c = 0.0
        # the implicit form's V (N, r), V' V (r, r) and the Cholesky factor of
        # (c - floor) I - V' V (its first _chol_n rows), in buffers of _cap columns
        self._r = 0
        self._cap = 0
        self._Vbuf = np.zeros((p0.size, 0))
        self._Gbuf = np.zeros((0, 0))
        self._Lbuf = np.zeros((0, 0))
        self._chol_n = 0
        self._T: np.ndarray | None = None  # scratch of the implicit form's kernels
        self._pending: tuple | None = None  # a deferred covariance step (update(defer=True))
        self._prepared: tuple | None = None  # P W' of the next update (prepare())
        # the compiled step's K, P W' and L^-1, written in place each update and read by
        # its covariance step (the pending one, until committed)
        self._out: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        self._check_finite = False
        self._set_identity(float(settings.kappa))
        self._warm_kernels()
        self.n_updates = 0
        self.n_resets = 0
        self.n_skipped = 0
        self.n_dead_zone = 0
        self.reset_reasons: dict[str, int] = {}

    def _warm_kernels(self) -> None:
        """Compile the update's kernels (or load them from numba's on-disk cache) now, not
        at the first sample: :func:`~controller.nls_kernel.nls_step` and, for the
        implicit (low-rank) covariance, the products of :mod:`controller.lowrank_kernel`
        and :func:`~controller.definiteness.cholesky_extend` with the argument types the
        covariance step passes (C-ordered writeable float64 buffers, Python ints and
        floats). Scratch arrays: the estimator is not touched."""
        compile_nls_step()
        if not self._lowrank:
            return
        compile_lowrank(self.p.size, 1)
        G, L = np.zeros((1, 1)), np.zeros((1, 1))
        cholesky_extend(L, G, 0, 1, 1.0)

    # -- covariance representation --------------------------------------------------------
    @property
    def _V(self) -> np.ndarray:
        """The implicit form's V, (N, r) (a view of its buffer)."""
        return self._Vbuf[:, :self._r]

    @property
    def _G(self) -> np.ndarray:
        """``V' V``, (r, r) (a view of its buffer)."""
        return self._Gbuf[:self._r, :self._r]

    def _reserve(self, cols: int) -> None:
        """Room for ``cols`` columns of V in the buffers (kept: they grow, never shrink)."""
        if cols <= self._cap:
            return
        cap = max(cols, int(self.settings.lowrank_max_rank) + 8)
        r = self._r
        V, G, L = np.zeros((self.p.size, cap)), np.zeros((cap, cap)), np.zeros((cap, cap))
        V[:, :r] = self._Vbuf[:, :r]
        G[:r, :r] = self._Gbuf[:r, :r]
        L[:r, :r] = self._Lbuf[:r, :r]
        self._Vbuf, self._Gbuf, self._Lbuf, self._cap = V, G, L, cap

    def _set_lowrank(self, c: float, V: np.ndarray) -> None:
        """The implicit form ``c I - V V'`` (V copied)."""
        self._Pd, self._c, self._r, self._chol_n = None, c, 0, 0
        r = V.shape[1]
        self._reserve(r)
        self._Vbuf[:, :r] = V
        self._Gbuf[:r, :r] = V.T @ V
        self._r = r

    def _set_identity(self, value: float) -> None:
        self._prepared = None
        if self._lowrank:
            self._Pd, self._c, self._r, self._chol_n = None, value, 0, 0
        else:
            self._Pd = value * np.eye(self.p.size)
        self._lower = value  # lower bound on lambda_min(P)
        self._since_sym = 0

    @property
    def P(self) -> np.ndarray:
        """The covariance (N, N); reading it in the implicit form makes it dense."""
        self.commit()
        if self._Pd is None:
            self._Pd = self._c * np.eye(self.p.size) - self._V @ self._V.T
            self._r = self._chol_n = 0
        self._prepared = None
        self._check_finite = True  # the caller may write into it
        return self._Pd

    @P.setter
    def P(self, value) -> None:
        self._pending = None
        self._prepared = None
        self._Pd = np.array(value, dtype=float)
        self._check_finite = True  # checked (and reset if need be) at the next update

    @property
    def n_params(self) -> int:
        return self.p.size

    def reset_covariance(self, reason: str = "requested") -> None:
        """Set ``P = reset_value I`` and count the reset under ``reason``."""
        self.commit()
        self._set_identity(self.settings.reset_to)
        self.n_resets += 1
        self.reset_reasons[reason] = self.reset_reasons.get(reason, 0) + 1

    def set_params(self, p, *, reset_covariance: bool = True) -> None:
        """Replace the parameters (re-initialization); optionally reset ``P`` (not counted)."""
        p = np.asarray(p, dtype=float).reshape(-1)
        if p.shape != self.p.shape or not np.isfinite(p).all():
            raise ValueError(f"p: expected a finite vector of length {self.p.size}")
        self.commit()
        self.p = p.copy()
        if reset_covariance:
            self._set_identity(self.settings.reset_to)

    def error(self, W, y) -> np.ndarray:
        """Prediction error ``y - W p``, shape ``(m,)``."""
        W = np.atleast_2d(np.asarray(W, dtype=float))
        return np.asarray(y, dtype=float).reshape(-1) - W @ self.p

    def update(self, W, y, *, freeze: bool = False, defer: bool = False) -> NLSStep:
        """One adaptation step with measurement matrix ``W`` (m, N) and output ``y`` (m,).

        Invalid data (NaN/inf in ``W`` or ``y``, wrong shapes) skips the step
        (counted) and leaves ``p`` and ``P`` untouched. ``freeze=True`` computes
        the error but does not adapt.

        ``defer=True`` updates ``p`` now and leaves the covariance step (the
        ``P`` decrement and the check of its smallest eigenvalue, the costly part
        at TE size) to :meth:`commit`, which a real-time caller runs after it has
        sent its move; every reader of ``P`` and the next update commit first, so
        the estimates are the same as without deferral. A floor reset found at
        commit is counted then and not reported in the returned step.
        """
        self.commit()
        self._prepared = None
        return self._step(np.atleast_2d(np.asarray(W, dtype=float)), y, freeze, defer)

    def prepare(self, W_base, d=None) -> None:
        """Compute the covariance products of the next update before its ``y`` is known.

        The next update's measurement matrix is ``W = W_base + y d'`` (``d`` None:
        ``W = W_base``), i.e. known now except for a part linear in the coming
        output, as for the shared regressor with the first-order hold
        (:meth:`controller.multimodel.OutputHoldCorrection.regressor_parts`). Then
        ``P W' = P W_base' + (P d) y'``, and :meth:`update_prepared` needs only
        products of size (N, m): the (N, N) covariance is not read between the
        measurement and the move. A pending covariance step is committed first;
        any later change of ``P`` discards the preparation.

        Parameters
        ----------
        W_base : array_like, shape (m, N)
        d : array_like, shape (N,), optional
        """
        self.commit()
        W_base = np.atleast_2d(np.asarray(W_base, dtype=float))
        if self._check_finite:  # a covariance set from outside: check it before using it
            self._check_outside_covariance()
        self._prepared = (W_base, *self._products(W_base, d))

    def _check_outside_covariance(self) -> bool:
        """Check a covariance set from outside (``P`` read or assigned) once: reset it
        when it is not finite. Returns True when it was reset."""
        self._check_finite = False
        if np.isfinite(self._Pd if self._Pd is not None else self._V).all():
            return False
        self.reset_covariance("nonfinite")
        return True

    def _products(self, W_base, d) -> tuple[np.ndarray, np.ndarray]:
        """``(d, [P W_base', P d])``, ``d`` = zeros when None (shapes (N,), (N, m + 1))."""
        d = np.zeros(self.p.size) if d is None else np.asarray(d, dtype=float).reshape(-1)
        m = W_base.shape[0]
        if self._Pd is None:  # the implicit form: one compiled call
            Pc = np.empty((self.p.size, m + 1))
            lowrank_products(self._Vbuf, self._r, float(self._c),
                             np.ascontiguousarray(W_base, dtype=float),
                             np.ascontiguousarray(d), Pc, self._scratch(m))
            return d, Pc
        cols = np.empty((self.p.size, m + 1))  # np.column_stack((W_base.T, d))
        cols[:, :m] = W_base.T
        cols[:, m] = d
        with np.errstate(invalid="ignore", over="ignore"):  # bad data: a skip, no warning
            Pc = self._Pd @ cols
        return d, Pc

    def _scratch(self, m: int) -> np.ndarray:
        """Scratch of the implicit form's kernels, (m + 1, columns of V's buffer)."""
        T = self._T
        if T is None or T.shape[0] < m + 1 or T.shape[1] < self._cap:
            T = self._T = np.zeros((m + 1, max(self._cap, 1)))
        return T

    @property
    def prepared(self) -> bool:
        """True when :meth:`prepare`'s products are current for the next update."""
        return self._prepared is not None

    def update_prepared(self, y, *, freeze: bool = False, defer: bool = False) -> NLSStep:
        """:meth:`update` with the measurement matrix given to :meth:`prepare`.

        The same step as ``update(W_base + y d', y, ...)`` up to round-off (``P W'``
        is summed in another order).

        Raises
        ------
        RuntimeError
            When nothing is prepared (or ``P`` changed since).
        """
        if self._prepared is None:
            raise RuntimeError("update_prepared: call prepare() first (or P changed since)")
        W_base, d, Pc = self._prepared
        self._prepared = None
        return self._step(W_base, y, freeze, defer, d, Pc)

    def _outputs(self, m: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The compiled step's output buffers K, P W' (N, m) and L^-1 (m, m)."""
        out = self._out
        if out is None or out[2].shape[0] != m:
            n = self.p.size
            out = self._out = (np.zeros((n, m)), np.zeros((n, m)), np.zeros((m, m)))
        return out

    def _step(self, W, y, freeze: bool, defer: bool, d=None, Pc=None) -> NLSStep:
        """The step of eq. 4.1 on ``W + y d'``; ``Pc`` = ``[P W_base', P d]`` when
        prepared (else computed here).

        The arithmetic is :func:`controller.nls_kernel.nls_step` (one compiled call);
        the covariance, the counters and the resets stay here.
        """
        y = np.asarray(y, dtype=float).reshape(-1)
        m = y.size
        if W.shape != (m, self.p.size):
            self.n_skipped += 1
            return NLSStep(np.full(m, np.nan), False, reason="invalid_data")
        if self._check_finite:  # a covariance set from outside (the steps check their own)
            with np.errstate(invalid="ignore", over="ignore"):
                Wy = W if d is None else W + np.outer(y, d)  # the kernel's W
                data_ok = bool(np.isfinite(y - Wy @ self.p).all())
            if data_ok and self._check_outside_covariance():  # invalid data skips first
                Pc = None
        if Pc is None:
            d, Pc = self._products(W, d)
        s = self.settings
        # the buffers are free: a pending covariance step was committed before the
        # products (prepare, update)
        K, PWt, L_inv = self._outputs(m)
        code, e, p_new, projected, trace_dP = nls_step(
            W, d, Pc, y, self.p, self.g_d, float(s.rate), self.lower, self.upper,
            float(s.max_abs_param), float(s.dead_zone), bool(freeze), K, PWt, L_inv)
        if code == INVALID_DATA:
            self.n_skipped += 1
            return NLSStep(np.full(m, np.nan), False, reason="invalid_data")
        if code == FROZEN:
            self.n_skipped += 1
            return NLSStep(e, False, reason="frozen")
        if code == DEAD_ZONE:
            self.n_dead_zone += 1
            return NLSStep(e, False, reason="dead_zone")
        if code == SINGULAR:
            self.reset_covariance("singular")
            return NLSStep(e, False, True, "singular")
        if code == DIVERGED:
            self.reset_covariance("diverged")
            return NLSStep(e, False, True, "diverged")
        if projected:
            self.n_projections += 1
        self.p = p_new
        self.n_updates += 1
        if code == NONFINITE:
            self.reset_covariance("nonfinite")
            return NLSStep(e, True, True, "nonfinite")
        if defer:
            self._pending = (K, PWt, L_inv, trace_dP)
            return NLSStep(e, True)
        reason = self._covariance_step(K, PWt, L_inv, trace_dP)
        return NLSStep(e, True, reason is not None, reason or "")

    def commit(self) -> str | None:
        """Apply a deferred covariance step (see :meth:`update`); returns the reason of a
        covariance reset it caused, else None. A no-op when nothing is pending."""
        if self._pending is None:
            return None
        pending, self._pending = self._pending, None
        return self._covariance_step(*pending)

    def _covariance_step(self, K, PWt, L_inv, trace_dP) -> str | None:
        """``P -= g_d K (P W')'`` and the floor check; returns a reset reason or None."""
        self._prepared = None
        if self._Pd is not None:
            dP = self.g_d * (K @ PWt.T)
            if not np.isfinite(dP).all():
                self.reset_covariance("nonfinite")
                return "nonfinite"
            self._Pd -= dP
            self._since_sym += 1
            if self._since_sym >= SYMMETRIZE_EVERY:
                self._Pd += self._Pd.T
                self._Pd *= 0.5
                self._since_sym = 0
        else:
            # g_d S^-1 = G G' with G = sqrt(g_d) L^-T: dP = (PWt G)(PWt G)', one more
            # block of V; the Gram matrix V' V grows by its border
            r, m = self._r, PWt.shape[1]
            self._reserve(r + m)
            if not lowrank_append(self._Vbuf, self._Gbuf, r, PWt, L_inv,
                                  math.sqrt(self.g_d), self._scratch(m)):
                self.reset_covariance("nonfinite")
                return "nonfinite"
            self._r = r + m
        # trace of the PSD decrement bounds its largest eigenvalue
        self._lower -= trace_dP
        below = self._lower <= self.settings.eig_floor
        large = self.p.size > self.settings.exact_check_max_params
        # V grown past its rank: dense from now on, unless the reset on the bound alone
        # (a dense P too large for the exact check) follows at once
        densify = self._Pd is None and self._r > self.settings.lowrank_max_rank
        if densify and not (below and large):
            _ = self.P
            densify = False
        if below:
            exact = (self._Pd is None and not densify) or not large
            if exact:
                outcome, bound = self._floor_check()
                if outcome != ABOVE:
                    self.reset_covariance(outcome)
                    return outcome
                self._lower = bound
            else:
                self.reset_covariance("floor")
                return "floor"
        return None

    def _floor_check(self) -> tuple[str, float]:
        """``lambda_min(P) > eig_floor``? By Cholesky (:mod:`controller.definiteness`):
        ``("above", eig_floor)`` (``eig_floor < lambda_min(P)``, the new lower bound),
        else ``("floor" | "singular", eig_floor)``.

        No tighter bound is formed: with the seed's tuning (kappa = 10, floor 1) the
        bound reaches the floor again at once either way (TE bench, 600 samples: 573
        checks of 650 covariance steps with the bound ``floor + 1/||(P - floor I)^-1||_F``
        and without), and the bound costs twice the factorization."""
        floor = float(self.settings.eig_floor)
        if self._Pd is not None:
            return floor_check(self._Pd, floor)
        r = self._r
        if r > 0:  # the rows of the factor added since the last check
            done = cholesky_extend(self._Lbuf, self._Gbuf, self._chol_n, r,
                                   float(self._c) - floor)
            self._chol_n = done
            if done == r:
                return ABOVE, floor
        # no columns, or a pivot not positive: LAPACK decides, and names the reason
        return lowrank_floor_check(self._c, self._G, floor)

    def smallest_eigenvalue(self) -> float:
        """Exact ``lambda_min(P)`` (for the dense form costly at large N)."""
        self.commit()
        if self._Pd is not None:
            return float(np.linalg.eigvalsh(self._Pd)[0])
        if self._V.shape[1] == 0:
            return float(self._c)
        # nonzero eigenvalues of V V' are those of V' V (r x r)
        return float(self._c - np.linalg.eigvalsh(self._V.T @ self._V)[-1])

    def counters(self) -> dict[str, int]:
        self.commit()
        return {"updates": self.n_updates, "resets": self.n_resets, "skipped": self.n_skipped}

    def checkpoint(self) -> dict[str, Any]:
        """JSON-serialisable state (parameters, covariance, bound, counters).

        A deferred covariance step is committed first. The parameters and the
        covariance (as given, dense ``P`` or the implicit ``c``, ``V``) are packed exactly
        (:func:`controller.packing.pack_array`: a TE-size covariance as decimal
        lists would cost ~6 ms of serialization per snapshot).
        """
        self.commit()
        out = {
            "p": pack_array(self.p),
            "lower": self._lower,
            "n_updates": self.n_updates,
            "n_resets": self.n_resets,
            "n_skipped": self.n_skipped,
            "n_dead_zone": self.n_dead_zone,
            "reset_reasons": dict(self.reset_reasons),
            "since_sym": self._since_sym,
        }
        if self._Pd is not None:
            out["P"] = pack_array(self._Pd)
        else:
            out["c"], out["V"] = self._c, pack_array(np.ascontiguousarray(self._V))
        return out

    def restore(self, state: dict[str, Any]) -> None:
        p = unpack_array(state["p"]).reshape(-1)  # packed, or a list (older checkpoints)
        if p.shape != self.p.shape or not np.isfinite(p).all():
            raise ValueError(f"state: parameters must be {self.p.size} finite values")
        self._pending = None
        self._prepared = None
        if state.get("P") is not None:
            P = unpack_array(state["P"])
            if P.shape != (p.size, p.size) or not np.isfinite(P).all():
                raise ValueError("state.P: wrong shape or non-finite covariance")
            self._Pd = 0.5 * (P + P.T)
        else:
            c = float(state["c"])
            V = unpack_array(state["V"]).reshape(p.size, -1)
            if not (math.isfinite(c) and np.isfinite(V).all()):
                raise ValueError("state.V: non-finite covariance")
            self._set_lowrank(c, V)
        self.p = p.copy()
        since = state.get("since_sym", 0)
        self._since_sym = since if count_below(since, SYMMETRIZE_EVERY) else 0
        stored = float(state["lower"]) if finite_number(state.get("lower")) else None
        if self._Pd is None or p.size <= self.settings.exact_check_max_params:
            # never trust a stored bound when the exact value is cheap, but keep one
            # that is valid (at most the exact value): the floor checks, and the resets
            # they lead to, then fall on the same samples as without the restart
            exact = self.smallest_eigenvalue()
            self._lower = exact if stored is None else min(stored, exact)
        else:
            self._lower = -math.inf if stored is None else stored
        self.n_updates = int(state.get("n_updates", 0))
        self.n_resets = int(state.get("n_resets", 0))
        self.n_skipped = int(state.get("n_skipped", 0))
        self.n_dead_zone = int(state.get("n_dead_zone", 0))
        self.reset_reasons = {str(k): int(v) for k, v in state.get("reset_reasons", {}).items()}
