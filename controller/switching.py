"""Performance index (seed eq. 4.6) and model switching with a minimum dwell time.

The seed's index for model j is

    J_j(t) = mu e_j(t)^2 + nu * integral_0^t exp(-lambda (t - tau)) e_j(tau)^2 dtau

with ``e_j`` the output error of model j. Sampled every ``dt`` with the
integral by the rectangle rule it becomes the recursion

    I_j(k) = exp(-lambda dt) I_j(k-1) + dt |e_j(k)|^2
    J_j(k) = mu |e_j(k)|^2 + nu I_j(k)

where ``|e|^2`` is the (optionally weighted) squared norm for several outputs.
The model with the smallest J wins, but a new model is taken only after the
current one has been active for at least ``min_dwell`` time units (the seed:
"a nonzero lower bound ... but too small a value will result in chattering").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.switching_kernel import index_step, smallest_index

__all__ = ["IndexSettings", "PerformanceIndex", "ModelSwitcher", "SwitchDecision"]


@dataclass(frozen=True)
class IndexSettings:
    """Weights of the performance index (eq. 4.6) and the dwell time.

    Parameters
    ----------
    mu : float
        Weight of the instantaneous squared error (seed: 1), >= 0.
    nu : float
        Weight of the discounted integral of the squared error (seed: 0.1), >= 0.
    forgetting : float
        Exponential forgetting rate lambda in 1/(time unit), >= 0 (lost in the
        seed's OCR; 0.5 here, so errors older than a few time units fade).
    min_dwell : float
        Minimum time a model stays active after a switch, > 0, in time units.
    output_weights : tuple of float or None
        Weights of each output's squared error (MIMO); None means all 1.
    hysteresis : float
        Relative margin in [0, 1): a model replaces the active one only if its J
        is below ``(1 - hysteresis)`` times the active model's J (0 = the seed's
        plain smallest-J rule). Stops chattering between near-equal models.
    """

    mu: float = 1.0
    nu: float = 0.1
    forgetting: float = 0.5
    min_dwell: float = 0.5
    output_weights: tuple[float, ...] | None = None
    hysteresis: float = 0.0

    def __post_init__(self) -> None:
        if not (isinstance(self.hysteresis, int | float) and 0 <= self.hysteresis < 1):
            raise ValueError(f"hysteresis: must be in [0, 1), got {self.hysteresis!r}")
        for name in ("mu", "nu", "forgetting"):
            v = getattr(self, name)
            if not (isinstance(v, int | float) and math.isfinite(v) and v >= 0):
                raise ValueError(f"{name}: must be a finite number >= 0, got {v!r}")
        if self.mu == 0 and self.nu == 0:
            raise ValueError("mu, nu: at least one must be > 0")
        if not (isinstance(self.min_dwell, int | float) and math.isfinite(self.min_dwell)
                and self.min_dwell > 0):
            raise ValueError(f"min_dwell: must be a finite number > 0, got {self.min_dwell!r}")
        if self.output_weights is not None:
            w = np.asarray(self.output_weights, dtype=float)
            if w.ndim != 1 or w.size == 0 or not np.isfinite(w).all() or np.any(w < 0):
                raise ValueError("output_weights: must be a non-empty vector of finite values >= 0")


class PerformanceIndex:
    """Discrete eq. 4.6 for ``n_models`` models.

    Parameters
    ----------
    settings : IndexSettings
    n_models : int
    dt : float
        Sample time.

    Attributes
    ----------
    J : ndarray, shape (n_models,)
        Index after the last update.
    integral : ndarray, shape (n_models,)
        Discounted integral of the squared errors.
    """

    def __init__(self, settings: IndexSettings, n_models: int, dt: float) -> None:
        if n_models < 1:
            raise ValueError(f"n_models: must be >= 1, got {n_models}")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.settings = settings
        self.dt = float(dt)
        self.decay = math.exp(-settings.forgetting * self.dt)
        self.J = np.zeros(n_models)
        self.integral = np.zeros(n_models)
        self._w = (None if settings.output_weights is None
                   else np.asarray(settings.output_weights, dtype=float))
        if self._w is not None:  # compile or load the kernel now, not in a sample
            index_step(np.zeros((n_models, self._w.size)), self._w, np.zeros(n_models),
                       self.decay, self.dt, 1.0, 1.0)

    @property
    def n_models(self) -> int:
        return self.J.size

    def squared_errors(self, errors) -> np.ndarray:
        """``|e_j|^2`` per model from errors of shape ``(n_models,)`` or ``(n_models, m)``."""
        e = np.asarray(errors, dtype=float)
        if e.ndim == 1:
            e = e[:, None]
        if e.shape[0] != self.n_models:
            raise ValueError(f"errors: expected {self.n_models} rows, got {e.shape[0]}")
        if self._w is None:
            return np.einsum("ij,ij->i", e, e)
        if self._w.size != e.shape[1]:
            raise ValueError(f"errors: {e.shape[1]} outputs but {self._w.size} output_weights")
        return (e * e) @ self._w

    def update(self, errors) -> np.ndarray:
        """Advance one sample with the model errors; returns ``J`` (n_models,).

        Non-finite errors are not allowed here (the caller skips such samples).
        """
        e = errors
        if (self._w is not None and isinstance(e, np.ndarray) and e.dtype == np.float64
                and e.ndim == 2 and e.shape == (self.n_models, self._w.size)
                and e.flags.c_contiguous):  # the sample's case: one compiled call
            J, integral, finite = index_step(e, self._w, self.integral, self.decay,
                                             self.dt, float(self.settings.mu),
                                             float(self.settings.nu))
            if not finite:
                raise ValueError("errors: non-finite model error (skip the sample instead)")
            self.integral, self.J = integral, J
            return self.J
        e2 = self.squared_errors(errors)
        if not np.isfinite(e2).all():
            raise ValueError("errors: non-finite model error (skip the sample instead)")
        self.integral = self.decay * self.integral + self.dt * e2
        self.J = self.settings.mu * e2 + self.settings.nu * self.integral
        return self.J

    @property
    def steady_gain(self) -> float:
        """J over ``|e|^2`` for an error held constant long enough:
        ``mu + nu dt / (1 - exp(-lambda dt))`` (``mu + nu t`` without forgetting, never
        reached; then the sample count so far is not known here, and ``mu + nu dt``
        is used)."""
        s = self.settings
        if self.decay < 1.0:
            return s.mu + s.nu * self.dt / (1.0 - self.decay)
        return s.mu + s.nu * self.dt

    def rms_error(self) -> np.ndarray:
        """Each model's J on a readable scale: the constant weighted error
        ``|e|_W`` (output weights applied, so in the units of the outputs'
        scales) that gives the same J, ``sqrt(J / steady_gain)``, shape (n_models,).

        With the TE tuning (weights 1/scale^2; 20 kPa for pressures, 1 degC for
        temperatures) 1.0 means the model misses the outputs by about one scale.
        """
        return np.sqrt(np.maximum(self.J, 0.0) / self.steady_gain)

    def copy_model(self, source: int, target: int) -> None:
        """Give model ``target`` the index history of ``source`` (re-initialization)."""
        self.integral[target] = self.integral[source]
        self.J[target] = self.J[source]

    def checkpoint(self) -> dict[str, Any]:
        return {"J": self.J.tolist(), "integral": self.integral.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        J = np.asarray(state["J"], dtype=float)
        integral = np.asarray(state["integral"], dtype=float)
        if J.shape != self.J.shape or integral.shape != self.J.shape:
            raise ValueError(f"state: expected {self.n_models} models")
        self.J, self.integral = J.copy(), integral.copy()


@dataclass(frozen=True)
class SwitchDecision:
    """Result of one switching step.

    Attributes
    ----------
    active : int
        Model in use after this sample.
    best : int
        Model with the smallest J at this sample (may differ from ``active``
        while the dwell time holds the current one).
    switched : bool
        True when ``active`` changed at this sample.
    held : bool
        True when a better model was waiting for the dwell time.
    """

    active: int
    best: int
    switched: bool
    held: bool


class ModelSwitcher:
    """Smallest-J switching with a minimum dwell time.

    Parameters
    ----------
    n_models : int
    min_dwell : float
        Minimum active time after a switch (time units), > 0.
    dt : float
        Sample time.
    initial : int
        Model active at the start.
    hysteresis : float
        Relative margin in [0, 1) (see :class:`IndexSettings`).
    """

    #: J differences below this are treated as ties (round-off of exact models).
    J_TOL = 1e-12

    def __init__(self, n_models: int, min_dwell: float, dt: float, initial: int = 0,
                 hysteresis: float = 0.0) -> None:
        if not 0 <= hysteresis < 1:
            raise ValueError(f"hysteresis: must be in [0, 1), got {hysteresis!r}")
        self.hysteresis = float(hysteresis)
        if not 0 <= initial < n_models:
            raise ValueError(f"initial: must be in [0, {n_models}), got {initial}")
        if not (math.isfinite(min_dwell) and min_dwell > 0):
            raise ValueError(f"min_dwell: must be a finite number > 0, got {min_dwell!r}")
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be a finite number > 0, got {dt!r}")
        self.n_models = int(n_models)
        # at least one sample, rounding the dwell time up to whole samples
        self.dwell_samples = max(1, math.ceil(min_dwell / dt - 1e-9))
        self.active = int(initial)
        self.since_switch = self.dwell_samples  # free to switch at the first sample
        self.n_switches = 0
        self.n_held = 0
        smallest_index(np.zeros(self.n_models), 0, self.hysteresis, self.J_TOL)  # compile now

    def step(self, J, allowed=None) -> SwitchDecision:
        """Choose the model for this sample from the index values ``J`` (n_models,).

        ``allowed`` (n_models,) of bool excludes models (e.g. one without a controller).
        """
        J = np.asarray(J, dtype=float).reshape(-1)
        if J.size != self.n_models:
            raise ValueError(f"J: expected {self.n_models} values, got {J.size}")
        if allowed is not None:
            J = np.where(np.asarray(allowed, dtype=bool), J, np.inf)
        self.since_switch += 1
        # smallest finite J; J differences at round-off level (all models exact at a
        # steady state) never switch
        best, any_finite, beats = smallest_index(np.ascontiguousarray(J), self.active,
                                                 self.hysteresis, self.J_TOL)
        if not any_finite:
            return SwitchDecision(self.active, self.active, False, False)
        best = int(best)
        if not beats:
            return SwitchDecision(self.active, best, False, False)
        if self.since_switch < self.dwell_samples:
            self.n_held += 1
            return SwitchDecision(self.active, best, False, True)
        self.active = best
        self.since_switch = 0
        self.n_switches += 1
        return SwitchDecision(self.active, best, True, False)

    def force(self, model: int) -> None:
        """Make ``model`` active now (operator command); restarts the dwell timer."""
        if not 0 <= model < self.n_models:
            raise ValueError(f"model: must be in [0, {self.n_models}), got {model}")
        if model != self.active:
            self.active = int(model)
            self.since_switch = 0
            self.n_switches += 1

    def checkpoint(self) -> dict[str, Any]:
        return {"active": self.active, "since_switch": self.since_switch,
                "n_switches": self.n_switches, "n_held": self.n_held}

    def restore(self, state: dict[str, Any]) -> None:
        active = int(state["active"])
        if not 0 <= active < self.n_models:
            raise ValueError(f"state: active model {active} out of range")
        self.active = active
        self.since_switch = int(state["since_switch"])
        self.n_switches = int(state.get("n_switches", 0))
        self.n_held = int(state.get("n_held", 0))
