"""Tuning and limits of the Δu model predictive controller (seed §6.1, eq. 6.6–6.10).

:class:`MPCSettings` holds everything a user sets: horizons, weights, limits, the
solver and its budget. It validates itself on construction, so a bad setting is a
:class:`MPCSettingsError` naming the field at configuration time, never a surprise
inside the control loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

__all__ = ["MPCSettings", "MPCSettingsError", "BACKENDS", "OFFLINE_BUDGET_MS"]

#: Names of the QP backends :mod:`controller.mpc.qp` provides.
BACKENDS = ("daqp", "proxsuite")

#: ``budget_ms`` of offline runs in simulated time (studies, campaigns), ms: none in
#: practice, every solved move is kept, so a busy machine slows a run instead of
#: changing its moves.
OFFLINE_BUDGET_MS = 1e9


class MPCSettingsError(ValueError):
    """An MPC setting is malformed; the message names the field."""


def _vector(name: str, value, n: int, *, allow_inf: bool, default: float | None = None):
    if value is None:
        if default is None:
            raise MPCSettingsError(f"{name}: required")
        value = default
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise MPCSettingsError(f"{name}: not a numeric vector ({exc})") from exc
    if arr.size == 1 and n != 1:
        arr = np.full(n, float(arr[0]))
    if arr.size != n:
        raise MPCSettingsError(f"{name}: expected {n} values, got {arr.size}")
    if np.isnan(arr).any():
        raise MPCSettingsError(f"{name}: NaN at index {np.flatnonzero(np.isnan(arr)).tolist()}")
    if not allow_inf and not np.isfinite(arr).all():
        raise MPCSettingsError(f"{name}: must be finite")
    arr = arr.copy()
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class MPCSettings:
    """Settings of the Δu MPC (eq. 6.6–6.10).

    Parameters
    ----------
    nu, ny : int
        Numbers of manipulated and controlled variables.
    P : int
        Prediction horizon in samples (outputs ``y(k+1) … y(k+P)``).
    M : int
        Control horizon in samples, ``1 <= M <= P`` (moves ``Δu(k) … Δu(k+M-1)``;
        later moves are zero).
    Xi : array_like, shape (ny,)
        Output weights Ξ (diagonal), on the squared error in output units.
    Lambda : array_like, shape (nu,)
        Move weights Λ (diagonal), on the squared move in input units. Positive.
    u_min, u_max : array_like, shape (nu,)
        Hard input limits in input units; ``±inf`` where there is none.
    du_max : array_like, shape (nu,)
        Hard rate limit ``|Δu| <= du_max`` per sample; ``inf`` where there is none.
    y_min, y_max : array_like, shape (ny,)
        Soft output limits (output units); ``±inf`` where there is none.
    slack_scale : array_like, shape (ny,)
        How many output units one unit of the (single, shared) slack ε relaxes each
        output limit: row ``y_i <= y_max_i + slack_scale_i ε``. Defaults to 1.
    slack_linear : float
        Linear (exact-penalty) weight ρ on ε ≥ 0. Large enough, the soft limits hold
        exactly whenever they can be met.
    slack_quadratic : float
        Quadratic weight on ε, > 0, keeping the QP strictly convex.
    budget_ms : float
        Wall-time budget of one solve in ms; an overrun applies the fallback move.
    backend : str
        ``"daqp"`` (default, dual active set) or ``"proxsuite"`` (dense proximal).
    max_iter : int
        Iteration limit of every solve.
    warm_start : bool
        Start each solve from the previous one (active set for DAQP). Proxsuite's
        warm start is never used: it misreports feasible problems as infeasible
        (see ``tests/test_mpc_qp.py``).
    filter_alpha : float
        First-order measurement filter ``y_f(k) = α y(k) + (1-α) y_f(k-1)``,
        ``0 < α <= 1`` (§6.1.2 uses 0.2; 1 disables it).
    fallback : str
        What to apply when a solve fails or overruns: ``"shift"`` (the next move of
        the previous optimal plan, holding once the plan is used up) or ``"hold"``.
    u_target : array_like, shape (nu,), optional
        Resting values of the inputs (e.g. a trigger's nominal 0); with
        ``u_target_weight`` > 0 the cost adds ``Σ_j ‖u(k+j) − u_target‖²_W`` over the
        control horizon, so redundant inputs settle at their targets.
    u_target_weight : array_like, shape (nu,)
        Diagonal W, >= 0 (default 0: no input targets).
    output_limit_start : int
        The first predicted sample, 1 ... ``P``, on which the soft output limits act
        (the constraint window of industrial MPC; 1, the default: every prediction,
        eq. 6.9). The first prediction ``y(k+1)`` starts from the measured ``y(k)``:
        a limit on it makes a measurement beyond the limit, noise included, demand
        that one move bring the output back within one sample, and a handle whose
        effect on the output is small in one sample is moved by its whole rate limit.
    """

    nu: int
    ny: int
    P: int
    M: int
    Xi: np.ndarray = None
    Lambda: np.ndarray = None
    u_min: np.ndarray = None
    u_max: np.ndarray = None
    du_max: np.ndarray = None
    y_min: np.ndarray = None
    y_max: np.ndarray = None
    slack_scale: np.ndarray = None
    slack_linear: float = 1.0e4
    slack_quadratic: float = 1.0e2
    budget_ms: float = 5.0
    backend: str = "daqp"
    max_iter: int = 1000
    warm_start: bool = True
    filter_alpha: float = 1.0
    fallback: str = "shift"
    u_target: np.ndarray = None
    u_target_weight: np.ndarray = None
    output_limit_start: int = 1

    def __post_init__(self) -> None:
        for name in ("nu", "ny", "P", "M", "max_iter", "output_limit_start"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | np.integer) or v < 1:
                raise MPCSettingsError(f"{name}: must be a positive integer, got {v!r}")
        if self.M > self.P:
            raise MPCSettingsError(f"M: control horizon {self.M} exceeds prediction horizon "
                                   f"P = {self.P}")
        if self.output_limit_start > self.P:
            raise MPCSettingsError(f"output_limit_start: {self.output_limit_start} is beyond "
                                   f"the prediction horizon P = {self.P}")
        nu, ny = int(self.nu), int(self.ny)
        set_ = lambda k, v: object.__setattr__(self, k, v)
        set_("Xi", _vector("Xi", self.Xi, ny, allow_inf=False, default=1.0))
        set_("Lambda", _vector("Lambda", self.Lambda, nu, allow_inf=False, default=1.0))
        set_("u_min", _vector("u_min", self.u_min, nu, allow_inf=True, default=-math.inf))
        set_("u_max", _vector("u_max", self.u_max, nu, allow_inf=True, default=math.inf))
        set_("du_max", _vector("du_max", self.du_max, nu, allow_inf=True, default=math.inf))
        set_("y_min", _vector("y_min", self.y_min, ny, allow_inf=True, default=-math.inf))
        set_("y_max", _vector("y_max", self.y_max, ny, allow_inf=True, default=math.inf))
        set_("slack_scale", _vector("slack_scale", self.slack_scale, ny, allow_inf=False,
                                    default=1.0))
        set_("u_target", _vector("u_target", self.u_target, nu, allow_inf=False, default=0.0))
        set_("u_target_weight", _vector("u_target_weight", self.u_target_weight, nu,
                                        allow_inf=False, default=0.0))
        if np.any(self.u_target_weight < 0):
            raise MPCSettingsError("u_target_weight: must be >= 0")
        if np.any(self.Xi < 0):
            raise MPCSettingsError("Xi: output weights must be >= 0")
        if np.any(self.Lambda <= 0):
            raise MPCSettingsError("Lambda: move weights must be > 0")
        for lo, hi in (("u_min", "u_max"), ("y_min", "y_max")):
            bad = np.flatnonzero(getattr(self, lo) > getattr(self, hi))
            if bad.size:
                raise MPCSettingsError(f"{lo}/{hi}: lower limit above upper limit at index "
                                       f"{bad.tolist()} (infeasible hard bounds)")
        if np.any(np.isinf(self.u_min) & (self.u_min > 0)) or np.any(
                np.isinf(self.u_max) & (self.u_max < 0)):
            raise MPCSettingsError("u_min/u_max: +inf lower or -inf upper limit")
        if np.any(self.du_max <= 0):
            raise MPCSettingsError("du_max: rate limits must be > 0")
        if np.any(self.slack_scale <= 0):
            raise MPCSettingsError("slack_scale: must be > 0")
        for name in ("slack_linear", "slack_quadratic", "budget_ms", "filter_alpha"):
            v = getattr(self, name)
            if not isinstance(v, int | float | np.floating) or not math.isfinite(v):
                raise MPCSettingsError(f"{name}: must be a finite number, got {v!r}")
        if self.slack_linear < 0:
            raise MPCSettingsError("slack_linear: must be >= 0")
        if self.slack_quadratic <= 0:
            raise MPCSettingsError("slack_quadratic: must be > 0")
        if self.budget_ms <= 0:
            raise MPCSettingsError("budget_ms: must be > 0")
        if not 0 < self.filter_alpha <= 1:
            raise MPCSettingsError(f"filter_alpha: must be in (0, 1], got {self.filter_alpha}")
        if self.backend not in BACKENDS:
            raise MPCSettingsError(f"backend: unknown {self.backend!r}; known: "
                                   f"{', '.join(BACKENDS)}")
        if self.fallback not in ("shift", "hold"):
            raise MPCSettingsError(f"fallback: must be 'shift' or 'hold', got {self.fallback!r}")

    @property
    def has_output_limits(self) -> bool:
        """True when at least one soft output limit is finite."""
        return bool(np.any(np.isfinite(self.y_min)) or np.any(np.isfinite(self.y_max)))

    def as_dict(self) -> dict:
        """JSON-friendly view (infinite limits become None)."""
        out = {}
        for f in fields(self):
            if f.name.startswith("_"):
                continue
            v = getattr(self, f.name)
            if isinstance(v, np.ndarray):
                v = [None if not math.isfinite(x) else float(x) for x in v]
            out[f.name] = v
        return out
