"""Deadline-safe Δu MPC stepped once per sample (seed §6.1, eq. 6.3–6.10).

:class:`MPCController` follows :class:`controller.interfaces.SampleController`. Each
:meth:`MPCController.step`:

1. validates the measurement and the reference (a NaN is a safe action, not an error);
2. filters the measurement (§6.1.2 first-order filter);
3. asks its :class:`StateSource` for the model state and the active model's discrete
   prediction form (Φ, Γ, C) — a state-shared model, or :class:`LinearModelState`;
4. takes the cached condensed QP of that model (built once per model), forms the
   vectors from ``x_a = [x(k) − x(k−1); y_f(k)]`` and solves it with an iteration limit;
5. applies ``u(k) = u(k−1) + Δu(k)`` when the solve is optimal and inside the budget;
   otherwise the next move of the previous optimal plan (or a hold), flagged and
   counted. Nothing raises out of :meth:`step`. A fallback input is always clipped
   into ``[u_min, u_max]``: an input found outside its hard range (e.g. after a
   manual override, which makes the QP infeasible under the rate limit) is brought
   back in one sample, the hard range taking precedence over the rate limit.

Because the Δu model starts from measured outputs and state increments, a model
switch needs no state reset (bumpless).
"""

from __future__ import annotations

import time
from collections.abc import Hashable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, Protocol, runtime_checkable

import numpy as np

from controller.finite_kernel import all_finite
from controller.interfaces import ControlDecision
from controller.mpc.filters import FirstOrderFilter
from controller.mpc.formulation import DeltaUFormulation, FormulationCache
from controller.mpc.qp import QPResult, QPSolver, make_solver
from controller.mpc.settings import MPCSettings
from controller.mpc.vector_kernel import clip_move

__all__ = ["ModelView", "StateSource", "LinearModelState", "MPCController"]


@dataclass(frozen=True)
class ModelView:
    """What the MPC needs from the model at one sample.

    Attributes
    ----------
    key : hashable
        Identity of the active model (its formulation is cached under this key).
    x, x_prev : ndarray, shape (n,)
        Model state now and one sample ago (their difference is Δx of eq. 6.3).
    Phi, Gamma, C : ndarray
        Discrete prediction form of the active model, shapes (n, n), (n, nu), (ny, n).
    index : int
        Active model index for reporting (-1 if none).
    J : ndarray
        Performance-index values of all models (eq. 4.6), for reporting.
    names : tuple of str
        Model names aligned with ``J``.
    Gamma_d : ndarray, shape (n, nd), optional
        Measured-disturbance input of the model (feedforward of Δd).
    """

    key: Hashable
    x: np.ndarray
    x_prev: np.ndarray
    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    index: int = -1
    J: np.ndarray = field(default_factory=lambda: np.zeros(0))
    names: tuple[str, ...] = ()
    Gamma_d: np.ndarray | None = None


@runtime_checkable
class StateSource(Protocol):
    """Supplies the model state and the active model to :class:`MPCController`."""

    def observe(self, u_prev: np.ndarray, y: np.ndarray) -> ModelView:
        """Advance with the inputs applied over the last sample and the new
        (filtered) measurement, and return the view at this sample."""
        ...


class LinearModelState:
    """Model states of fixed discrete models, each run open loop on the applied inputs.

    ``x_j(k) = Φ_j x_j(k−1) + Γ_j u(k−1)`` for every model j, so each model has its own
    Δx and switching between them (:meth:`select`) is bumpless. The Δu formulation
    corrects the open-loop prediction with the measured output, so no observer is needed
    for stable models.

    Parameters
    ----------
    models : mapping key -> (Phi, Gamma, C[, Gamma_d]) or sequence of such tuples
        Deviation models around an operating point; the model input is ``u − u_ref``;
        ``Gamma_d`` (n, nd) is the input of a measured disturbance (see
        :meth:`MPCController.set_measured_disturbance`).
    u_ref : array_like, shape (nu,), optional
        Input about which the models are linear (default zero). A constant offset
        cancels in Δx.
    active : key, optional
        Initially active model (default: the first).
    """

    def __init__(self, models, u_ref=None, active=None) -> None:
        if isinstance(models, Mapping):
            items = list(models.items())
        else:
            items = list(enumerate(models))
        if not items:
            raise ValueError("models: at least one model is required")
        self.models = {k: tuple(np.asarray(m, dtype=float) for m in v[:3]) for k, v in items}
        self.Gamma_d = {k: (np.asarray(v[3], dtype=float) if len(v) > 3 and v[3] is not None
                            else None) for k, v in items}
        self.d = None  # measured disturbance in force over the last sample
        self._d_next = None
        self.keys = [k for k, _ in items]
        nu = self.models[self.keys[0]][1].shape[1]
        self.u_ref = np.zeros(nu) if u_ref is None else np.asarray(u_ref, dtype=float)
        self.x = {k: np.zeros(m[0].shape[0]) for k, m in self.models.items()}
        self.x_prev = {k: v.copy() for k, v in self.x.items()}
        self.active = self.keys[0] if active is None else active
        if self.active not in self.models:
            raise ValueError(f"active: unknown model {active!r}")
        self._started = False

    def select(self, key) -> None:
        """Make ``key`` the active model (no state reset)."""
        if key not in self.models:
            raise ValueError(f"key: unknown model {key!r}")
        self.active = key

    def observe(self, u_prev, y) -> ModelView:
        du = np.asarray(u_prev, dtype=float) - self.u_ref
        for k, (Phi, Gamma, _C) in self.models.items():
            self.x_prev[k] = self.x[k]
            if self._started:
                self.x[k] = Phi @ self.x[k] + Gamma @ du
                if self.Gamma_d[k] is not None and self.d is not None:
                    self.x[k] = self.x[k] + self.Gamma_d[k] @ self.d
        if self._d_next is not None:
            self.d = self._d_next
        self._started = True
        Phi, Gamma, C = self.models[self.active]
        return ModelView(self.active, self.x[self.active], self.x_prev[self.active], Phi, Gamma,
                         C, index=self.keys.index(self.active),
                         names=tuple(str(k) for k in self.keys),
                         Gamma_d=self.Gamma_d[self.active])

    def set_measured_disturbance(self, d) -> None:
        """Disturbance measured now, in force over the coming sample (deviation units)."""
        self._d_next = np.asarray(d, dtype=float).copy()

    def checkpoint(self) -> dict[str, Any]:
        return {"x": {str(k): v.tolist() for k, v in self.x.items()},
                "active": self.keys.index(self.active), "started": self._started}

    def restore(self, state: dict[str, Any]) -> None:
        for k in self.keys:
            self.x[k] = np.asarray(state["x"][str(k)], dtype=float)
            self.x_prev[k] = self.x[k].copy()
        self.active = self.keys[int(state["active"])]
        self._started = bool(state["started"])


class MPCController:
    """Δu MPC on the active model of a :class:`StateSource`, deadline-safe.

    Parameters
    ----------
    settings : MPCSettings
    source : StateSource
        Model state and active prediction form per sample.
    u0 : array_like, shape (nu,)
        Inputs applied before the first sample.
    terminal_weight : ndarray, optional
        Terminal weight on the augmented state (see
        :func:`controller.mpc.formulation.build_formulation`).
    clock : callable, optional
        Time source in seconds (default ``time.perf_counter``); tests may inject one.

    Attributes
    ----------
    counters : dict
        ``steps``, ``solved``, ``fallback``, ``deadline``, ``solver_failure``,
        ``invalid_measurement``, ``invalid_reference``, ``error``, ``rebuilds``.
    """

    def __init__(self, settings: MPCSettings, source: StateSource, u0, *,
                 terminal_weight=None, clock=time.perf_counter) -> None:
        self.settings = settings
        self.source = source
        u0 = np.asarray(u0, dtype=float).reshape(-1)
        if u0.size != settings.nu or not np.isfinite(u0).all():
            raise ValueError(f"u0: expected {settings.nu} finite values, got {u0.tolist()}")
        self.u = u0.copy()
        self.filter = FirstOrderFilter(settings.filter_alpha)
        self.cache = FormulationCache(settings, terminal_weight)
        self._solvers: dict[Hashable, tuple[DeltaUFormulation, QPSolver]] = {}
        self.plan: np.ndarray | None = None  # (M, nu) moves of the last optimal solve
        self.plan_index = 0
        self.clock = clock
        self.counters = {k: 0 for k in ("steps", "solved", "fallback", "deadline",
                                        "solver_failure", "invalid_measurement",
                                        "invalid_reference", "error", "rebuilds")}
        self.last_result: QPResult | None = None
        self.d: np.ndarray | None = None
        self.d_prev: np.ndarray | None = None
        self.u_target = settings.u_target.copy()
        self.op_limits: tuple | None = None  # (u_min, u_max, y_min, y_max), see below
        self.op_fixed: np.ndarray | None = None
        self._plan_basis: tuple | None = None  # (formulation, x_a, Δd) of self.plan

    def predicted(self) -> np.ndarray | None:
        """Predicted outputs ``y(k+1) … y(k+P)`` of the last optimal plan, shape
        (P, ny), in output units; None before the first optimal solve.

        Made from the formulation, augmented state and plan of that solve when asked
        (:meth:`controller.mpc.formulation.DeltaUFormulation.predict`), not in the
        sample: the prediction costs 3-7 µs at TE size that no move needs.
        """
        if self._plan_basis is None or self.plan is None:
            return None
        form, x_a, dd = self._plan_basis
        return form.predict(x_a, self.plan.reshape(-1), dd)

    def set_input_target(self, u_target) -> None:
        """Input targets (resting values) from this sample on, shape (nu,), input units.

        Replaces ``settings.u_target`` in the input-target cost term
        ``Σ_j ‖u(k+j) − u_target‖²_W`` (W = ``settings.u_target_weight``; with W = 0
        the target has no effect). Call before :meth:`step`, e.g. every sample from a
        grade plan or an optimizer.

        Raises
        ------
        ValueError
            ``u_target`` is not ``nu`` finite numbers (the target is then unchanged).
        """
        try:
            arr = np.asarray(u_target, dtype=float).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"u_target: not a numeric vector ({exc})") from exc
        if arr.size != self.settings.nu or not all_finite(arr):
            raise ValueError(f"u_target: expected {self.settings.nu} finite values, got "
                             f"{arr.tolist()}")
        self.u_target = arr.copy()

    def set_operator_limits(self, fixed=None, u_min=None, u_max=None, y_min=None,
                            y_max=None) -> None:
        """An operator's settings from this sample on (None everywhere: none).

        Parameters
        ----------
        fixed : array_like of bool, shape (nu,), optional
            Inputs held where they are (``u(k-1)``, which the caller sets to the held
            value): all their moves are zero, the others are planned around them.
        u_min, u_max : array_like, shape (nu,), optional
            Hard input limits in place of the settings'.
        y_min, y_max : array_like, shape (ny,), optional
            Soft output limits in place of the settings', on the rows the settings
            have (a new finite limit needs :meth:`retune`).
        """
        lim = tuple(None if v is None else np.asarray(v, dtype=float).reshape(-1)
                    for v in (u_min, u_max, y_min, y_max))
        self.op_limits = None if all(v is None for v in lim) else lim
        mask = None if fixed is None else np.asarray(fixed, dtype=bool).reshape(-1)
        self.op_fixed = mask if mask is not None and mask.any() else None

    def retune(self, settings: MPCSettings) -> None:
        """New weights or limits (same nu, ny, P, M) from the next solve on: every
        model's formulation is rebuilt when next used (or by ``prepare``)."""
        s = self.settings
        if (settings.nu, settings.ny, settings.P, settings.M) != (s.nu, s.ny, s.P, s.M):
            raise ValueError("settings: retune keeps nu, ny, P and M")
        self.settings = settings
        self.cache = FormulationCache(settings, self.cache.terminal_weight)
        self._solvers = {}
        self._plan_basis = None

    def _u_limits(self) -> tuple[np.ndarray, np.ndarray]:
        s, lim = self.settings, self.op_limits
        if lim is None:
            return s.u_min, s.u_max
        return (s.u_min if lim[0] is None else lim[0], s.u_max if lim[1] is None else lim[1])

    def set_measured_disturbance(self, d) -> None:
        """Measured disturbance at this sample, before :meth:`step` (feedforward).

        ``Δd = d(k) − d(k−1)`` enters the prediction through the model's ``Gamma_d``;
        future changes are taken as zero. A non-finite value is ignored (no feedforward
        this sample). Forwarded to the state source when it accepts it.
        """
        d = np.asarray(d, dtype=float).reshape(-1)
        if not np.isfinite(d).all():
            return
        self.d_prev = d.copy() if self.d is None else self.d
        self.d = d.copy()
        fwd = getattr(self.source, "set_measured_disturbance", None)
        if callable(fwd):
            fwd(d)

    # -- preparation ---------------------------------------------------------------
    def prepare(self, key: Hashable, Phi, Gamma, C, Gamma_d=None, *,
                setup_solver: bool = False) -> DeltaUFormulation:
        """Build (or fetch) the formulation and solver of one model ahead of use.

        With ``setup_solver`` a new solver also sets its workspace up now
        (:meth:`controller.mpc.qp.QPSolver.setup_ahead`: its first solve then starts
        cold, equal to one set up in the solve within
        :data:`controller.mpc.qp.SETUP_AHEAD_ATOL`), so that no sample pays for it.
        """
        form, built = self.cache.get(key, Phi, Gamma, C, Gamma_d)
        entry = self._solvers.get(key)
        if built or entry is None or entry[0] is not form:
            s = self.settings
            solver = make_solver(s.backend, form.H, form.A, s.max_iter, s.warm_start)
            if setup_solver:
                solver.setup_ahead()
            self._solvers[key] = (form, solver)
            if built:
                self.counters["rebuilds"] += 1
        return form

    # -- helpers -------------------------------------------------------------------
    def _reference(self, reference) -> np.ndarray | None:
        s = self.settings
        R = np.asarray(reference, dtype=float)
        if R.ndim == 1:
            if R.size != s.ny:
                return None
            R = np.broadcast_to(R, (s.P, s.ny))
        if R.ndim != 2 or R.shape[1] != s.ny or R.shape[0] == 0:
            return None
        if R.shape[0] < s.P:
            R = np.vstack([R, np.repeat(R[-1:], s.P - R.shape[0], axis=0)])
        R = R[:s.P]
        if not all_finite(R):
            return None
        return R

    def _fallback_move(self) -> tuple[np.ndarray, str]:
        """Next move of the previous optimal plan (or zero), kept inside the hard limits."""
        s = self.settings
        du = np.zeros(s.nu)
        how = "hold"
        if s.fallback == "shift" and self.plan is not None and self.plan_index + 1 < s.M:
            self.plan_index += 1
            du = self.plan[self.plan_index].copy()
            how = "shift"
        elif self.plan is not None:
            self.plan_index = s.M  # plan used up: hold from now on
        du = np.minimum(np.maximum(du, -s.du_max), s.du_max)  # np.clip, without its overhead
        if self.op_fixed is not None:
            du[self.op_fixed] = 0.0
        u_min, u_max = self._u_limits()
        u = np.minimum(np.maximum(self.u + du, u_min), u_max)
        return u, how

    def _decision(self, u, view, *, fallback, status, solve_ms, alarms=(), extra=None):
        self.u = u
        self.counters["steps"] += 1
        if fallback:
            self.counters["fallback"] += 1
        return ControlDecision(
            u=u.copy(),
            active_model=int(view.index) if view is not None else -1,
            model_names=tuple(view.names) if view is not None else (),
            J=np.asarray(view.J) if view is not None else np.zeros(0),
            solve_ms=float(solve_ms), fallback=fallback, status=status,
            alarms=tuple(alarms), extra=extra or {},
        )

    # -- the step ------------------------------------------------------------------
    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        """One sample: see the module docstring. Never raises."""
        t0 = self.clock()
        view = None
        try:
            s = self.settings
            y = np.asarray(y, dtype=float).reshape(-1)
            if y.size != s.ny or not all_finite(y):
                self.counters["invalid_measurement"] += 1
                if self.filter.state is not None:
                    # Keep the model state in step with time, on the last good value.
                    view = self.source.observe(self.u, self.filter.state.copy())
                u, how = self._fallback_move()
                return self._decision(u, view, fallback=True, status="invalid_measurement",
                                      solve_ms=0.0, alarms=(
                                          f"sample {k}: invalid measurement {y.tolist()}; "
                                          f"{how}",),
                                      extra={"fallback_move": how})
            R = self._reference(reference)
            y_f = self.filter.update(y)
            view = self.source.observe(self.u, y_f)
            t_pre = self.clock()
            if R is None:
                self.counters["invalid_reference"] += 1
                u, how = self._fallback_move()
                return self._decision(u, view, fallback=True, status="invalid_reference",
                                      solve_ms=0.0, alarms=(
                                          f"sample {k}: invalid reference; {how}",),
                                      extra={"fallback_move": how, "y_filtered": y_f})
            form = self.prepare(view.key, view.Phi, view.Gamma, view.C, view.Gamma_d)
            solver = self._solvers[view.key][1]
            t_build = self.clock()
            dd = None
            if view.Gamma_d is not None and self.d is not None:
                dd = self.d - self.d_prev
            self.d_prev = self.d
            if (dd is None or form.S_d is None) and self.op_limits is None:
                x_a, vec = form.sample_vectors(view.x, view.x_prev, y_f, self.u, R,
                                               self.u_target)
            else:
                x_a = np.concatenate([np.asarray(view.x) - np.asarray(view.x_prev), y_f])
                vec = form.qp_vectors(x_a, self.u, R, dd, self.u_target, self.op_limits)
            if self.op_fixed is not None:  # held inputs: no move over the horizon
                held = np.concatenate([np.tile(self.op_fixed, s.M),
                                       np.zeros(form.nz - form.n_moves, dtype=bool)])
                vec = replace(vec, lb=np.where(held, 0.0, vec.lb),
                              ub=np.where(held, 0.0, vec.ub))
            res = solver.solve(vec)
            self.last_result = res
            # The budget covers the sample's work except a one-off (re)build of a
            # model's matrices, which prepare() can do ahead of time.
            elapsed_ms = (self.clock() - t_build + t_pre - t0) * 1e3
            extra = {"iterations": res.iterations, "qp_solve_ms": res.solve_ms,
                     "y_filtered": y_f, "elapsed_ms": elapsed_ms, "backend": res.backend}
            if res.ok and elapsed_ms <= s.budget_ms:
                z = res.x
                plan = z[:form.n_moves].reshape(s.M, s.nu)
                self.plan, self.plan_index = plan.copy(), 0
                if self.op_fixed is None and self.op_limits is None:  # one compiled call
                    du, u = clip_move(plan[0], s.du_max, self.u, s.u_min, s.u_max)
                else:  # an operator's held inputs and limits
                    du = np.minimum(np.maximum(plan[0], -s.du_max), s.du_max)  # as np.clip
                    if self.op_fixed is not None:
                        du[self.op_fixed] = 0.0
                    u_min, u_max = self._u_limits()
                    u = np.minimum(np.maximum(self.u + du, u_min), u_max)
                if form.has_slack:
                    extra["slack"] = float(z[-1])
                # the plan's predicted outputs are made on request (predicted()), after
                # the move is out: nothing on the sample's path reads them
                self._plan_basis = (form, x_a, dd)
                self.counters["solved"] += 1
                return self._decision(u, view, fallback=False, status="solved",
                                      solve_ms=res.solve_ms, extra=extra)
            # Failure or overrun: the previous plan, and a cold start next time.
            solver.reset()
            if res.ok:
                status = "deadline"
                self.counters["deadline"] += 1
                alarm = (f"sample {k}: MPC step took {elapsed_ms:.3f} ms > budget "
                         f"{s.budget_ms} ms")
            else:
                status = res.status
                self.counters["solver_failure"] += 1
                alarm = f"sample {k}: QP {res.status} ({res.backend} {res.raw_status})"
            u, how = self._fallback_move()
            extra["fallback_move"] = how
            return self._decision(u, view, fallback=True, status=status,
                                  solve_ms=res.solve_ms, alarms=(f"{alarm}; {how}",),
                                  extra=extra)
        except Exception as exc:  # never out of the control step
            self.counters["error"] += 1
            try:
                u, how = self._fallback_move()
            except Exception:
                u, how = self.u.copy(), "hold"
            return self._decision(u, view, fallback=True, status="error",
                                  solve_ms=(self.clock() - t0) * 1e3,
                                  alarms=(f"sample {k}: controller error "
                                          f"{type(exc).__name__}: {exc}; {how}",),
                                  extra={"fallback_move": how})

    # -- restart -------------------------------------------------------------------
    def checkpoint(self) -> dict[str, Any]:
        """JSON-serialisable state: applied inputs, filter, plan, counters, source."""
        src = getattr(self.source, "checkpoint", None)
        return {
            "u": self.u.tolist(),
            "filter": None if self.filter.state is None else self.filter.state.tolist(),
            "plan": None if self.plan is None else self.plan.tolist(),
            "plan_index": self.plan_index,
            "counters": dict(self.counters),
            "source": src() if callable(src) else None,
            "d": None if self.d is None else self.d.tolist(),
            "d_prev": None if self.d_prev is None else self.d_prev.tolist(),
            "u_target": self.u_target.tolist(),
        }

    def restore(self, state: dict[str, Any]) -> None:
        self.u = np.asarray(state["u"], dtype=float)
        self.filter.reset(state["filter"])
        self.plan = None if state["plan"] is None else np.asarray(state["plan"], dtype=float)
        self._plan_basis = None  # the restored plan's formulation is not known here
        self.plan_index = int(state["plan_index"])
        self.counters.update(state.get("counters", {}))
        for name in ("d", "d_prev"):
            v = state.get(name)
            setattr(self, name, None if v is None else np.asarray(v, dtype=float))
        if state.get("u_target") is not None:
            self.set_input_target(state["u_target"])
        src = getattr(self.source, "restore", None)
        if callable(src) and state.get("source") is not None:
            src(state["source"])
        for _, solver in self._solvers.values():
            solver.reset()
