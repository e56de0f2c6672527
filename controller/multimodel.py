"""Multiple-model controller on the state-shared model (seed chapters 3-5).

:class:`MultiModelController` implements :class:`controller.interfaces.SampleController`.
Per sample (y_k measured, absolute units):

1. validate y_k; an invalid measurement (wrong length, NaN/inf) skips the
   sample: u is held, adaptation and the index are frozen, an alarm is counted
   and the shared state is advanced with the active model's estimate instead of
   y_k, so no NaN enters any state;
2. a-priori model errors ``e_j = y_k - y_j`` (the models' estimates of y_k from
   data up to the previous sample, eq. 3.10; by default with y taken linear
   between samples, see :class:`OutputHoldCorrection` and ``y_hold``);
3. adapt every adaptive model by normalized least squares (eq. 4.1) on the
   shared regressor ``W`` (``y_j = W p_j``);
4. update the performance index (eq. 4.6) and switch (smallest J, dwell time);
5. restart events of the adaptive kinds (seed §4, ref. [19]): a *re-initialized*
   model "assumes the parameter values of the fixed model that gives the smallest
   estimation error" when that fixed model is strictly better than it: with
   ``b = argmin_{fixed} J``, it takes model b's parameters (and its index
   history) when ``J_b < (1 - hysteresis) J_j - J_TOL`` (the switcher's
   hysteresis and round-off tolerance, :class:`controller.switching.ModelSwitcher`).
   A tie (e.g. right after a re-initialization, when both J are the same) keeps
   the adaptive model adapting, whatever the order of the models. When the active
   model changes, each *conventional* model restarts from its initial parameters;
   *free-running* models just continue;
6. the control law computes u_k for the active model; its soft-constraint slack
   and status (when it reports them) go into ``decision.extra``
   (``"constraint_slack"``, ``"law_status"``);
7. the shared state advances with (u_k, y_k).

Switching is bumpless with respect to the model output because every model
reads the same shared state: the new model's estimate at the switching instant
is computed from the very state the old model used.

The control law is any object with the :class:`ControlLaw` methods
(:class:`controller.hinf.HInfLaw`, :class:`controller.mrac.MRACLaw`, or an MPC
adapter written elsewhere).
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.linalg

from controller.adaptation import AdaptiveKind, NLSSettings, NormalizedLeastSquares
from controller.finite_kernel import all_finite
from controller.hold_kernel import (
    hold_advance,
    hold_errors,
    hold_estimates,
    hold_forward,
    hold_regressor_parts,
)
from controller.interfaces import QP_WORK_KEYS, ControlDecision
from controller.state_shared import StateSharedModel
from controller.switching import IndexSettings, ModelSwitcher, PerformanceIndex
from controller.switching_kernel import steady_output_errors

__all__ = ["ControlLaw", "HoldLaw", "MultiModelSettings", "MultiModelController",
           "OutputHoldCorrection"]


class ControlLaw(Protocol):
    """A per-model control law driven by :class:`MultiModelController`.

    ``compute`` returns ``(u, info)``: the move (absolute units, shape (nu,))
    and a dict with at least ``"status"`` and optionally ``"alarms"`` (list of
    str), ``"fallback"`` (bool) and ``"slack"`` (float, the exact-penalty slack of
    a soft output constraint; reported as ``decision.extra["constraint_slack"]``).
    It may raise; the controller then holds u.
    """

    def reset(self, u: np.ndarray, y: np.ndarray) -> None: ...

    # optional: ``align(u, y)``, a re-initialization at a move held from outside (see
    # MultiModelController.align); a law without it is reset instead

    def compute(self, k: int, model: int, ssm: StateSharedModel, y: np.ndarray,
                reference: np.ndarray, u_last: np.ndarray) -> tuple[np.ndarray, dict]: ...

    def checkpoint(self) -> dict[str, Any]: ...

    def restore(self, state: dict[str, Any]) -> None: ...


class HoldLaw:
    """A :class:`ControlLaw` that keeps the last move ("controller off").

    The models still adapt and the index still switches, so a loop can track
    the plant with its outputs frozen (commissioning, benchmarks of the model
    side alone).
    """

    def reset(self, u, y) -> None:
        pass

    def compute(self, k, model, ssm, y, reference, u_last):
        return u_last, {"status": "solved"}

    def checkpoint(self) -> dict[str, Any]:
        return {}

    def restore(self, state: dict[str, Any]) -> None:
        pass


def _bounds(value, m: int, field: str, default: float) -> np.ndarray:
    if value is None:
        return np.full(m, default)
    arr = np.broadcast_to(np.asarray(value, dtype=float), (m,)).copy()
    if np.isnan(arr).any():
        raise ValueError(f"{field}: must not be NaN")
    return arr


@dataclass(frozen=True)
class MultiModelSettings:
    """Tuning of adaptation, switching and the input limits.

    Parameters
    ----------
    nls : NLSSettings
        Normalized least squares (eq. 4.1).
    index : IndexSettings
        Performance index weights and dwell time (eq. 4.6).
    u_min, u_max : float or sequence of float or None
        Input limits applied to every move (None = unbounded).
    param_margin : float or None
        When set, adaptive parameters are projected onto the box spanned by the
        fixed models' parameters widened by ``param_margin`` times its width
        (per parameter; at least ``param_margin`` times the parameter's size).
        None = no projection.
    y_hold : {"foh", "zoh"}
        How the measured outputs are taken to vary between samples when the
        models are *compared and identified*. ``"foh"`` (default): linear between
        samples (see :class:`OutputHoldCorrection`); a-priori errors and the
        regressor then hold to O(dt^2) for the continuous models, so fixed and
        adaptive models live in the same (continuous) class of eq. 3.16.
        ``"zoh"``: held, as :meth:`StateSharedModel.update` does (the behaviour
        before this option); an identified Theta is then the sampled-equivalent
        model, O(dt) away from the continuous Theta that the fixed models carry
        (14.7 % in one parameter for the CSTR at dt = 0.05). The shared state
        itself and everything the control law reads are unchanged.
    index_errors : {"equation", "steady_output"}
        What the index (eq. 4.6) is fed. ``"equation"`` (default, the seed's): the
        models' errors ``y - y_j`` as they are. These are equation errors,
        ``(d_j/omega) (y - H_j u)`` up to transients, so at low frequency each
        model's output error is weighted by ``d_j(0)/omega(0)`` = prod of its
        poles over omega's: models whose poles are faster count more (on TE
        mode 2's error counts 121 times mode 0's, whatever omega).
        ``"steady_output"``: each model's errors divided by its own
        ``d_j(0)/omega(0)``, read from Theta (``1 - theta2_j' n_ss``), so the index
        compares the models' output errors at low frequency on one scale.
    """

    nls: NLSSettings = NLSSettings()
    index: IndexSettings = IndexSettings()
    u_min: float | tuple[float, ...] | None = None
    u_max: float | tuple[float, ...] | None = None
    param_margin: float | None = None
    y_hold: str = "foh"
    index_errors: str = "equation"

    def __post_init__(self) -> None:
        if self.index_errors not in ("equation", "steady_output"):
            raise ValueError(f"index_errors: must be 'equation' or 'steady_output', got "
                             f"{self.index_errors!r}")
        if self.y_hold not in ("zoh", "foh"):
            raise ValueError(f"y_hold: must be 'zoh' or 'foh', got {self.y_hold!r}")
        if self.param_margin is not None and not (
                math.isfinite(self.param_margin) and self.param_margin >= 0):
            raise ValueError(f"param_margin: must be >= 0 or None, got {self.param_margin!r}")
        if not isinstance(self.nls, NLSSettings):
            raise ValueError("nls: must be an NLSSettings")
        if not isinstance(self.index, IndexSettings):
            raise ValueError("index: must be an IndexSettings")
        lo = np.atleast_1d(np.asarray(-math.inf if self.u_min is None else self.u_min, float))
        hi = np.atleast_1d(np.asarray(math.inf if self.u_max is None else self.u_max, float))
        if np.isnan(lo).any() or np.isnan(hi).any():
            raise ValueError("u_min, u_max: must not be NaN")
        if lo.shape == hi.shape and np.any(lo > hi):
            raise ValueError("u_min: must not exceed u_max")


def _theta2_scratch(ssm: StateSharedModel) -> np.ndarray:
    """Zeros laid out as :meth:`StateSharedModel.theta2_all` is for two models, shape
    (2, n): a read-only view of every p-th row of a (2p, order) stack, not C-ordered.
    The compiled kernels that read theta2 are warmed with it (numba specializes on the
    layout and the writeability); they run only with more than one model."""
    nm = ssm.n_deg * ssm.m
    view = np.zeros((2 * ssm.p, ssm.order))[:: ssm.p, nm : nm + ssm.n_deg]
    view.flags.writeable = False
    return view


class OutputHoldCorrection:
    """First-order hold of the measured outputs for comparing and identifying models.

    :meth:`StateSharedModel.update` holds y over a sample (zero-order hold), which
    is exact for the piecewise-constant input u but lags a continuous y by about
    half a sample. With y taken linear between samples (first-order hold) the
    output part of the shared state is, per output block (eq. 3.10 sampled)::

        n2(t_k) = Fd n2(t_(k-1)) + Gd y_(k-1) + H (y_k - y_(k-1)),
        H = (1/dt) int_0^dt exp(F (dt - s)) g s ds,

    i.e. the held state z_k plus a correction ``c_k = Fd c_(k-1) + H (y_k - y_(k-1))``
    (c = 0 in a steady state, so biases and steady states are unchanged). This
    object carries ``c`` beside the shared state without changing it.

    A model's a-priori estimate must not use y_k, yet n2(t_k) depends on it; it is
    the solution of ``yhat = Theta1' n1 + theta2' (z_k + Fd c_(k-1) + H (yhat - y_(k-1))) + b``,
    explicit because theta2' H is a scalar per output (O(dt)).

    Parameters
    ----------
    ssm : StateSharedModel
        The shared state (read only).
    """

    def __init__(self, ssm: StateSharedModel) -> None:
        n = ssm.n_deg
        self.ssm = ssm
        self.n = n
        # Van Loan: exp([[F, g, 0], [0, 0, 1], [0, 0, 0]] dt) holds Gd and H
        M = np.zeros((n + 2, n + 2))
        M[:n, :n] = ssm.Fb * ssm.dt
        M[:n, n] = ssm.gb * ssm.dt
        M[n, n + 1] = 1.0
        E = scipy.linalg.expm(M)
        self.Fbd_T = np.ascontiguousarray(E[:n, :n].T)
        self.h = E[:n, n + 1].copy()
        self.c = np.zeros((ssm.p, n))
        self.y_prev = np.zeros(ssm.p)
        # (c Fd', c Fd' - y_prev h') of the current c and y_prev, or None: the sample
        # reads them three times (regressor_parts, estimates, advance)
        self._cf: tuple[np.ndarray, np.ndarray] | None = None
        # the compiled arithmetic (controller.hold_kernel) where numpy's products are
        # the BLAS dgemm/dgemv that numba's are (no dimension of 1: numpy takes
        # other calls for a vector), so the numbers are the same to the last bit
        self._compiled = ssm.p > 1 and n > 1
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """Call the sample's compiled kernels (:mod:`controller.hold_kernel`) once with
        the argument types a sample passes (C-ordered writeable float64 arrays, theta2 as
        :meth:`StateSharedModel.theta2_all` gives it for several models), so that their
        compilation or their load from numba's cache happens when the controller is
        built, never in a sample. :func:`hold_advance` runs at every sample, the others
        only where :attr:`_compiled`. Scratch arrays: the correction is not touched."""
        ssm, n, h = self.ssm, self.n, self.h
        c, y = np.zeros_like(self.c), np.zeros_like(self.y_prev)  # (p, n), (p,)
        hold_advance(c, y, y, h)
        if not self._compiled:
            return
        cF, free = hold_forward(c, self.Fbd_T, y, h)
        t2 = _theta2_scratch(ssm)
        est = np.zeros((t2.shape[0], ssm.p))
        hold_estimates(est, t2, cF, free, h)
        hold_errors(y, est, t2, cF, free, h)
        hold_regressor_parts(np.zeros((ssm.p, n + 1)), free, h, 0)

    def _c_forward(self) -> tuple[np.ndarray, np.ndarray]:
        """``(c Fd', c Fd' - y_prev h')``, computed once per (c, y_prev)."""
        if self._cf is None:
            if self._compiled:  # one call (controller.hold_kernel)
                self._cf = hold_forward(self.c, self.Fbd_T, self.y_prev, self.h)
            else:
                cF = self.c @ self.Fbd_T
                self._cf = (cF, cF - self.y_prev[:, None] * self.h[None, :])
        return self._cf

    def reset(self, y) -> None:
        """Steady start (matches :meth:`StateSharedModel.initialize`): c = 0."""
        self.c[:] = 0.0
        self.y_prev = np.asarray(y, dtype=float).reshape(-1).copy()
        self._cf = None

    def _theta2(self) -> np.ndarray:
        """theta2 of every model, shape (k, n) (the same vector in every output block)."""
        return self.ssm.theta2_all()

    def estimates(self) -> np.ndarray:
        """A-priori estimates of all models with the first-order hold, shape (k, p)."""
        est = self.ssm.estimates()
        t2 = self._theta2()
        cF, free = self._c_forward()  # free: (p, n)
        if self._compiled and t2.shape[0] > 1:
            # (est + theta2 free') / (1 - theta2 h), or est + theta2 cF' where that is ~0
            # (no slope over the sample): one compiled call (controller.hold_kernel)
            return hold_estimates(est, t2, cF, free, self.h)
        num = est + t2 @ free.T  # (k, p)
        den = 1.0 - t2 @ self.h  # (k,)
        safe = np.abs(den) > 1e-6
        if safe.all():
            return num / den[:, None]
        out = est + t2 @ cF.T  # fallback: no slope over the sample
        out[safe] = num[safe] / den[safe, None]
        return out

    def errors(self, y) -> np.ndarray:
        """``y - yhat_j`` for every model, shape (k, p)."""
        y = np.asarray(y, dtype=float).reshape(-1)
        if self._compiled and self.ssm.k > 1 and y.shape == (self.ssm.p,):
            if not y.flags.carray:  # the kernel's own type (no compilation in a sample)
                y = np.array(y)
            cF, free = self._c_forward()
            return hold_errors(y, self.ssm.estimates(), self._theta2(), cF, free, self.h)
        return y.reshape(1, -1) - self.estimates()

    def advance(self, y) -> None:
        """Take in y_k: ``c_k = Fd c_(k-1) + H (y_k - y_(k-1))`` (call after :meth:`errors`)."""
        y = np.array(y, dtype=float).reshape(-1)  # a copy: y_prev
        if y.shape != self.y_prev.shape:
            raise ValueError(f"y: expected {self.y_prev.size} outputs, got {y.size}")
        self.c = hold_advance(self._c_forward()[0], y, self.y_prev, self.h)
        self.y_prev = y
        self._cf = None

    def regressor(self) -> np.ndarray:
        """The shared regressor W with n2(t_k) = z_k + c_k (call after :meth:`advance`)."""
        ssm = self.ssm
        W = ssm.regressor()
        start = self.n * ssm.m * ssm.p
        W[:, start : start + self.n] += self.c
        return W

    def regressor_parts(self) -> tuple[np.ndarray, np.ndarray]:
        """The next sample's regressor before its output is known: ``(W_base, d)``.

        After the shared state's advance with the last sample, the regressor that
        :meth:`regressor` will give once ``y_k`` has come in (and :meth:`advance` has
        run) is ``W_base + y_k d'``: c_k = c_(k-1) Fd' + (y_k - y_(k-1)) h is affine in
        y_k, and ``d`` is h in the n2 columns (the same in every output row).

        Returns
        -------
        W_base : ndarray, shape (p, N)
        d : ndarray, shape (N,)
        """
        ssm = self.ssm
        W = ssm.regressor()
        start = self.n * ssm.m * ssm.p
        if self._compiled:  # the n2 columns and d in one call (controller.hold_kernel)
            return W, hold_regressor_parts(W, self._c_forward()[1], self.h, start)
        cols = slice(start, start + self.n)
        W[:, cols] += self._c_forward()[1]
        d = np.zeros(W.shape[1])
        d[cols] = self.h
        return W, d

    def checkpoint(self) -> dict[str, Any]:
        return {"c": self.c.tolist(), "y_prev": self.y_prev.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        c = np.asarray(state["c"], dtype=float).reshape(self.c.shape)
        y = np.asarray(state["y_prev"], dtype=float).reshape(self.y_prev.shape)
        if not (np.isfinite(c).all() and np.isfinite(y).all()):
            raise ValueError("state.hold: non-finite first-order-hold correction")
        self.c, self.y_prev = c, y
        self._cf = None


class MultiModelController:
    """State-shared multiple-model controller (fixed + adaptive models, switching, a law).

    Parameters
    ----------
    ssm : StateSharedModel
        The shared state and the models; adaptive models are changed in place.
    law : ControlLaw
        The per-model control law.
    u0 : array_like, shape (m,)
        Input in force before the first sample (absolute units).
    settings : MultiModelSettings
    kinds : sequence of AdaptiveKind or str, optional
        Kind of each model; default from ``ssm.kinds`` ("adaptive" ->
        free-running).
    initial_model : int
        Model active at the start.
    record_params : bool
        Put the adaptive models' parameter vectors into ``decision.extra["params"]``
        (for parameter-trajectory figures).
    """

    def __init__(self, ssm: StateSharedModel, law: ControlLaw, u0,
                 settings: MultiModelSettings | None = None,
                 kinds: Sequence[AdaptiveKind | str] | None = None,
                 initial_model: int = 0, record_params: bool = False) -> None:
        self.record_params = bool(record_params)
        self.ssm = ssm
        self.law = law
        self.settings = settings or MultiModelSettings()
        m = ssm.m
        self.u_last = _bounds(u0, m, "u0", 0.0)
        if not np.isfinite(self.u_last).all():
            raise ValueError("u0: must be finite")
        self.u_min = _bounds(self.settings.u_min, m, "u_min", -math.inf)
        self.u_max = _bounds(self.settings.u_max, m, "u_max", math.inf)
        if kinds is None:
            kinds = [AdaptiveKind.FIXED if k == "fixed" else AdaptiveKind.FREE_RUNNING
                     for k in ssm.kinds]
        self.kinds = [AdaptiveKind.parse(k) for k in kinds]
        if len(self.kinds) != ssm.k:
            raise ValueError(f"kinds: expected {ssm.k} entries, got {len(self.kinds)}")
        dt = ssm.dt
        self.adaptive = [j for j, k in enumerate(self.kinds) if k.adaptive]
        self.fixed = [j for j, k in enumerate(self.kinds) if not k.adaptive]
        self.p_initial = {j: ssm.params_from_theta(ssm.theta(j), ssm.bias(j))
                          for j in self.adaptive}
        lower = upper = None
        if self.settings.param_margin is not None and self.fixed:
            P = np.vstack([self.params(j) for j in self.fixed])
            lo, hi = P.min(axis=0), P.max(axis=0)
            width = np.maximum(hi - lo, np.abs(P).max(axis=0))
            lower = lo - self.settings.param_margin * width
            upper = hi + self.settings.param_margin * width
        self.param_lower, self.param_upper = lower, upper
        self.estimators = {j: NormalizedLeastSquares(self.settings.nls, self.p_initial[j], dt,
                                                     lower, upper)
                           for j in self.adaptive}
        self.index = PerformanceIndex(self.settings.index, ssm.k, dt)
        self.switcher = ModelSwitcher(ssm.k, self.settings.index.min_dwell, dt, initial_model,
                                      self.settings.index.hysteresis)
        self.hold = OutputHoldCorrection(ssm) if self.settings.y_hold == "foh" else None
        self.initialized = False
        self._aligned = False  # the next (re-)initialization takes over a held move
        self.n_invalid = 0
        self.n_law_failures = 0
        self.n_reinit = 0
        self.n_restarts = 0
        self.n_samples = 0
        # per re-initialized model: (the fixed model it took its parameters from, sample)
        self.reinit_from: dict[int, tuple[int, int]] = {}
        self._detail: tuple | None = None  # (key, text) of _active_detail
        self._names_of: tuple | None = None  # (ssm, its k, its names as a tuple)
        self._deferred: tuple[np.ndarray, np.ndarray, int] | None = None
        self._prepared = False  # the estimators hold products for the current shared state
        if self.settings.index_errors == "steady_output":
            # compile or load the errors' scaling now, not in a sample (it runs with more
            # than one model)
            t2 = _theta2_scratch(ssm)
            steady_output_errors(np.zeros((t2.shape[0], ssm.p)), t2, ssm.basis.steady)

    # -- helpers -------------------------------------------------------------------------
    @property
    def names(self) -> tuple[str, ...]:
        ssm, cached = self.ssm, self._names_of  # names change only when a model is added
        if cached is None or cached[0] is not ssm or cached[1] != ssm.k:
            cached = self._names_of = (ssm, ssm.k, tuple(ssm.names))
        return cached[2]

    @property
    def active(self) -> int:
        return self.switcher.active

    def params(self, j: int) -> np.ndarray:
        """Structured parameter vector of model j (see StateSharedModel.params_from_theta)."""
        return self.ssm.params_from_theta(self.ssm.theta(j), self.ssm.bias(j))

    def counters(self) -> dict[str, int]:
        self.finish_sample()
        out = {
            "samples": self.n_samples,
            "invalid_measurements": self.n_invalid,
            "law_failures": self.n_law_failures,
            "switches": self.switcher.n_switches,
            "reinitializations": self.n_reinit,
            "restarts": self.n_restarts,
            "covariance_resets": sum(e.n_resets for e in self.estimators.values()),
            "projections": sum(e.n_projections for e in self.estimators.values()),
        }
        law_counters = getattr(self.law, "counters", None)
        if callable(law_counters):
            out.update(law_counters())
        return out

    def _decision(self, u, status: str, fallback: bool, alarms: list[str], t0: float,
                  extra: dict | None = None) -> ControlDecision:
        return ControlDecision(
            u=np.asarray(u, dtype=float).copy(), active_model=self.switcher.active,
            model_names=self.names, J=self.index.J.copy(),
            solve_ms=(time.perf_counter() - t0) * 1e3, fallback=fallback, status=status,
            alarms=tuple(alarms), extra=extra or {})

    # -- the sample ------------------------------------------------------------------------
    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        """One sample: adapt, switch, compute the move (see the class notes).

        The bookkeeping that the move does not need (the shared state's advance with
        this sample's ``(u, y)``, the estimators' covariance steps, the law's
        preparation of the next sample) is left to :meth:`finish_sample`, which a
        real-time caller runs after it has sent the move; the next ``step`` (and
        every checkpoint) runs it first if the caller did not, so the moves are the
        same either way.
        """
        t0 = time.perf_counter()
        self.n_samples += 1
        try:
            self.finish_sample()
        except Exception as exc:  # never raise out of step: hold the input
            self.n_law_failures += 1
            return self._decision(self.u_last, "error", True,
                                  [f"controller error, input held: {exc}"], t0)
        try:
            return self._step(k, t, y, reference, t0)
        except Exception as exc:  # never raise out of step: hold the input
            self.n_law_failures += 1
            return self._decision(self.u_last, "error", True,
                                  [f"controller error, input held: {exc}"], t0)

    def _step(self, k, t, y, reference, t0) -> ControlDecision:
        m = self.ssm.m
        ny = getattr(self.ssm, "p", m)  # outputs (= inputs for the seed's square models)
        y = np.asarray(y, dtype=float).reshape(-1)
        valid = y.shape == (ny,) and all_finite(y)
        if not valid:
            self.n_invalid += 1
            alarm = (f"invalid measurement at sample {k}: sample skipped, input held, "
                     f"adaptation frozen ({self.n_invalid} so far)")
            if self.initialized:
                y_sub = self.ssm.estimates()[self.switcher.active]
                if np.isfinite(y_sub).all():
                    if self.hold is not None:
                        self.hold.advance(y_sub)
                    self.ssm.update(self.u_last, y_sub)
                    self._prepared = False
            return self._decision(self.u_last, "invalid_measurement", True, [alarm], t0)
        ref = np.atleast_2d(np.asarray(reference, dtype=float))
        if ref.shape[1] != ny or not all_finite(ref):
            return self._decision(self.u_last, "invalid_reference", True,
                                  [f"invalid reference at sample {k}: input held"], t0)
        if not self.initialized:
            self.ssm.initialize(self.u_last, y)
            if self.hold is not None:
                self.hold.reset(y)
            align = getattr(self.law, "align", None) if self._aligned else None
            if callable(align):
                align(self.u_last, y)
            else:
                self.law.reset(self.u_last, y)
            self.initialized = True
            self._aligned = False
            self._prepared = False
        alarms: list[str] = []
        if self.adaptive:
            self._prepare_adaptation()  # a no-op when finish_sample did it
        if self.hold is None:
            errors = self.ssm.errors(y)
        else:
            errors = self.hold.errors(y)
            self.hold.advance(y)
        # adaptation (eq. 4.1) on the shared regressor, prepared before y came in
        if self.adaptive:
            self._prepared = False
            for j in self.adaptive:
                est = self.estimators[j]
                res = est.update_prepared(y, defer=True)
                if res.updated or res.reset:
                    self.ssm.set_params(j, est.p)
        # index (eq. 4.6) and switching
        if self.settings.index_errors == "steady_output":
            errors = self._steady_output_errors(errors)
        J = self.index.update(errors)
        dec = self.switcher.step(J)
        # restart events of the adaptive kinds
        if self.adaptive:
            best_fixed = self._best_fixed(J)
            for j in self.adaptive:
                kind = self.kinds[j]
                if kind is AdaptiveKind.REINITIALIZED and self._fixed_beats(best_fixed, j, J):
                    self._reinitialize(j, best_fixed)
                elif kind is AdaptiveKind.CONVENTIONAL and dec.switched:
                    self.estimators[j].set_params(self.p_initial[j])
                    self.ssm.set_params(j, self.p_initial[j])
                    self.n_restarts += 1
        # control
        status, fallback = "solved", False
        info: dict = {}
        try:
            u, info = self.law.compute(k, self.switcher.active, self.ssm, y, ref, self.u_last)
            u = np.asarray(u, dtype=float).reshape(-1)
            status = str(info.get("status", "solved"))
            fallback = bool(info.get("fallback", False))
            alarms.extend(info.get("alarms", ()))
            if u.shape != (m,) or not all_finite(u):
                raise ValueError(f"control law returned an invalid move {u!r}")
        except Exception as exc:
            self.n_law_failures += 1
            u, status, fallback = self.u_last.copy(), "law_failed", True
            alarms.append(f"control law failed, input held: {exc}")
        u = np.minimum(np.maximum(u, self.u_min), self.u_max)  # np.clip, without its overhead
        self._deferred = (u, y, self.switcher.active)
        self.u_last = u
        extra: dict[str, Any] = {"switched": dec.switched, "best": dec.best,
                                 "law_status": status,
                                 "prediction_rms": self.index.rms_error(),
                                 "active_model_detail": self._active_detail()}
        # the soft output constraint's exact-penalty slack (not the timing slack);
        # None when the law has no soft constraint or did not solve this sample
        reported = info if isinstance(info, dict) and status != "law_failed" else {}
        slack = reported.get("slack")
        extra["constraint_slack"] = None if slack is None else float(slack)
        # the QP's own work, when the law reports it
        extra.update((key, reported[key]) for key in QP_WORK_KEYS if key in reported)
        if self.record_params:
            extra["params"] = {j: self.estimators[j].p.copy() for j in self.adaptive}
        return self._decision(u, status, fallback, alarms, t0, extra)

    def finish_sample(self) -> None:
        """The sample's bookkeeping after its move (idempotent): advance the shared state
        with ``(u, y)``, commit the estimators' covariance steps, let the law prepare the
        next sample (``law.finish_sample(ssm, active)`` if it has one)."""
        if self._deferred is None:
            return
        u, y, active = self._deferred
        self._deferred = None
        self.ssm.update(u, y)
        for est in self.estimators.values():
            est.commit()
        self._prepared = False
        self._prepare_adaptation()
        finish = getattr(self.law, "finish_sample", None)
        if callable(finish):
            finish(self.ssm, active)

    def _prepare_adaptation(self) -> None:
        """The estimators' covariance products for the next sample's regressor
        (:meth:`NormalizedLeastSquares.prepare`), so that the adaptation between the
        measurement and the move reads no (N, N) covariance. The same arithmetic
        whether it runs in :meth:`finish_sample` or at the start of the step."""
        if not self.adaptive or not self.initialized:
            return
        if self._prepared and all(self.estimators[j].prepared for j in self.adaptive):
            return
        if self.hold is None:
            W_base, d = self.ssm.regressor(), None
        else:
            W_base, d = self.hold.regressor_parts()
        for j in self.adaptive:
            self.estimators[j].prepare(W_base, d)
        self._prepared = True

    def _best_fixed(self, J: np.ndarray) -> int | None:
        """Fixed model with the smallest finite J (None if there is none)."""
        best, best_J = None, math.inf  # the first of equal ones, as np.argmin
        for j in self.fixed:
            v = float(J[j])
            if math.isfinite(v) and v < best_J:
                best, best_J = j, v
        return best

    def _fixed_beats(self, b: int | None, j: int, J: np.ndarray) -> bool:
        """True when fixed model b is strictly better than adaptive model j (step 5)."""
        if b is None:
            return False
        Jj = float(J[j])
        if not math.isfinite(Jj):  # a diverged adaptive index: take the fixed model
            return True
        margin = (1.0 - self.switcher.hysteresis) * Jj - self.switcher.J_TOL
        return float(J[b]) < margin

    def describe(self, j: int) -> str:
        """What model ``j`` is, in words: ``"fixed model mode2"``, ``"adaptive
        (re-initialized), from mode0 at sample 812"``."""
        kind, name = self.kinds[j], self.names[j]
        if kind is AdaptiveKind.FIXED:
            return f"fixed model {name}"
        text = f"adaptive ({kind.value}) model {name}"
        if j in self.reinit_from:
            source, k = self.reinit_from[j]
            text += f", re-initialized from {self.names[source]} at sample {k}"
        return text

    def _active_detail(self) -> str:
        """:meth:`describe` of the active model, formatted again only when the active
        model or its re-initialization changed (the text goes out with every sample)."""
        j = self.switcher.active
        key = (j, self.reinit_from.get(j))
        if self._detail is None or self._detail[0] != key:
            self._detail = (key, self.describe(j))
        return self._detail[1]

    def _reinitialize(self, j: int, source: int) -> None:
        p = self.params(source)
        est = self.estimators[j]
        if np.array_equal(est.p, p):
            return
        self.reinit_from[j] = (source, self.n_samples)
        est.set_params(p)
        self.ssm.set_params(j, p)
        self.index.copy_model(source, j)
        self.n_reinit += 1

    def align(self, u) -> None:
        """Take over a move held from outside (restart from an old checkpoint, manual to
        automatic): bumpless transfer.

        ``u`` becomes the last move, and at the next valid sample the dynamic states are
        re-initialized from ``(u, y_k)`` as at a first sample: the shared state and the
        first-order-hold correction at a steady state, and the control law through its
        ``align(u, y)`` (which sets its internal states so that its first move is ``u``
        given the current error) or, if it has none, its ``reset(u, y)``. The models'
        parameters, covariances, J values and the active model are kept.

        Parameters
        ----------
        u : array_like, shape (m,)
            The move in force (absolute units); clipped to the input limits.

        Raises
        ------
        ValueError
            When ``u`` has the wrong length or is not finite.
        """
        u = self._move_in_force(u)
        self.finish_sample()
        self.u_last = u
        self.initialized = False
        self._aligned = True

    def _move_in_force(self, u) -> np.ndarray:
        """``u`` checked (length, finite: else ValueError) and clipped to the input limits."""
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape != self.u_last.shape or not all_finite(u):
            raise ValueError(f"u: expected {self.u_last.size} finite values, got {u!r}")
        return np.minimum(np.maximum(u, self.u_min), self.u_max)  # np.clip, without its overhead

    def applied(self, u) -> None:
        """The plant got ``u`` instead of the last step's move (a missed deadline: the
        move held; a controller in warm mode; an MV the operator holds): go on from ``u``.

        Called before :meth:`finish_sample`: the shared state is advanced with the
        applied ``u`` (the measured input, eq. 3.10) and ``u`` becomes the last move,
        so the next move is computed from what the plant has. A law with
        ``applied(u, computed)`` corrects its own states too (an output offset, an
        input filter). Models, J values and the active model are kept.

        Parameters
        ----------
        u : array_like, shape (m,)
            The move in force (absolute units); clipped to the input limits.

        Raises
        ------
        ValueError
            When ``u`` has the wrong length or is not finite.
        """
        u = self._move_in_force(u)
        computed = self.u_last.copy()
        if self._deferred is not None:
            _, y, active = self._deferred
            self._deferred = (u.copy(), y, active)
        law_applied = getattr(self.law, "applied", None)
        if callable(law_applied):
            law_applied(u, computed)
        self.u_last = u.copy()

    # -- persistence ---------------------------------------------------------------------
    def _steady_output_errors(self, errors: np.ndarray) -> np.ndarray:
        """``errors * _steady_output_scale()[:, None]``; one compiled call
        (:func:`controller.switching_kernel.steady_output_errors`) where numpy's product
        is the BLAS dgemv numba's is (more than one model)."""
        if (self.ssm.k > 1 and isinstance(errors, np.ndarray) and errors.dtype == np.float64
                and errors.shape == (self.ssm.k, self.ssm.p)):
            return steady_output_errors(errors, self.ssm.theta2_all(), self.ssm.basis.steady)
        return errors * self._steady_output_scale()[:, None]

    def _steady_output_scale(self) -> np.ndarray:
        """omega(0)/d_j(0) per model (k,): 1 / |1 - theta2_j' n_ss|, n_ss the block's
        steady state for a unit input; 1 where d_j(0) is (numerically) zero."""
        ratio = (1.0 - self.ssm.theta2_all() @ self.ssm.basis.steady).tolist()
        return np.array([1.0 / abs(r) if math.isfinite(r) and abs(r) > 1e-12 else 1.0
                         for r in ratio])

    def checkpoint(self) -> dict[str, Any]:
        """Everything for a bumpless restart, as plain JSON data (the last sample's
        bookkeeping is finished first)."""
        self.finish_sample()
        return {
            "ssm": self.ssm.checkpoint(),
            "estimators": {str(j): e.checkpoint() for j, e in self.estimators.items()},
            "index": self.index.checkpoint(),
            "switcher": self.switcher.checkpoint(),
            "law": self.law.checkpoint(),
            "u_last": self.u_last.tolist(),
            "initialized": self.initialized,
            "aligned": self._aligned,
            **({"hold": self.hold.checkpoint()} if self.hold is not None else {}),
            "reinit_from": {str(j): list(v) for j, v in self.reinit_from.items()},
            "counters": {"n_invalid": self.n_invalid, "n_law_failures": self.n_law_failures,
                         "n_reinit": self.n_reinit, "n_restarts": self.n_restarts,
                         "n_samples": self.n_samples},
        }

    def restore(self, state: dict[str, Any]) -> None:
        self._deferred = None
        self._prepared = False
        self.ssm.restore(state["ssm"])
        for j, e in self.estimators.items():
            e.restore(state["estimators"][str(j)])
        self.index.restore(state["index"])
        self.switcher.restore(state["switcher"])
        self.law.restore(state["law"])
        u = np.asarray(state["u_last"], dtype=float).reshape(-1)
        if u.shape != self.u_last.shape or not np.isfinite(u).all():
            raise ValueError("state.u_last: wrong length or non-finite")
        self.u_last = u
        self.initialized = bool(state["initialized"])
        self._aligned = bool(state.get("aligned", False))
        if self.hold is not None:
            if "hold" in state:
                self.hold.restore(state["hold"])
            else:  # a checkpoint from a zero-order-hold controller: start the slope afresh
                self.hold.reset(self.ssm.estimates()[self.switcher.active])
        for key, value in state.get("counters", {}).items():
            setattr(self, key, int(value))
        self.reinit_from = {int(j): (int(v[0]), int(v[1]))
                            for j, v in state.get("reinit_from", {}).items()
                            if 0 <= int(v[0]) < self.ssm.k}
