"""Steady-state targets above a state-shared Δu MPC law, recomputed every sample.

The layer commercial APC runs between the set points and the dynamic controller
(:mod:`controller.targets`: ranked, relaxable CV limits and specifications, DAQP),
fed here from the **active** model of the state-shared model (seed eq. 3.10–3.16) and
handing its results to the MPC of seed eq. 6.3–6.10 (:class:`~controller.mpc.law.MPCLaw`).

Steady state of the active model. Its discrete form (Φ, Γ, C, f, b) as the MPC
predicts with it (:class:`~controller.mpc.law.SharedStateSource`: the exact ZOH form of
a fixed model, the sampled recursion of an adaptive one, taken again at most every
``min_refresh_samples`` samples, the spacing of the MPC's own rebuilds) settles, for
inputs held at u, at ``y_m(u) = G u + K f + b`` with ``K = C (I − Φ)⁻¹`` and the DC gain ``G = K Γ``
(that of the continuous model: the ZOH form keeps it). The target problem takes it at
the input in force, ``u0 = u(k−1)``, ``y0 = y_m(u0)``, with the output bias
``d = y_f(k) − y0``: the measurement (after the MPC's own filter) minus the model's
steady-state prediction at the current input, the static bias of DMC. So the targets'
model passes through the measured point, ``y(u) = y_f + G (u − u(k−1))``, as the Δu
MPC anchors its prediction at the measurement; at any steady state of the plant it is
exact, and where the plant is still moving the targets move with it.

Two other biases were measured on the two-phase reactor and left (its slow inert mode,
Φ's eigenvalue 0.993 at 0.1 h, a 14 h time constant):

==========================================  =============================================
the Δu prediction's own steady state        K Φ Δx amplifies the last state step ~140x on
(``y_f + K Φ Δx + G (u − u(k−1))``)         the slow mode; a 150 kmol/h request went
                                            unstable (P 3577 kPa, F4 to 0)
an independent model (``y − C x_ol − b``)   smooth, but its own 14 h mode: 20 h after the
                                            transition its prediction at the valves in
                                            force is 6.4 kPa, 1.0 mol % off the plant and
                                            the MV targets 0.9 % (one case 7.7 %) off the
                                            valves the plant settles at
the static bias (used)                      MV targets within 0.2 % of the settled valves,
                                            the prediction at the valves in force exact
==========================================  =============================================

The problem (:class:`controller.targets.TargetProblem`):

- specifications ``y = r(k+P)`` (rank ``TargetSettings.spec_rank``): the reference at
  the end of the prediction horizon, the grade's set point as the MPC sees it; a CV
  with no output weight (Ξ = 0, an operator's CV ``off``) has none;
- CV limits: the MPC's soft output limits in force (tuned or the operator's), less
  ``TargetSettings.limit_backoff``, rank ``TargetSettings.limit_rank``;
- MV limits: the MPC's hard input limits in force (an MV the operator holds: its held
  value);
- violations compared on the scale ``1/sqrt(Ξ_i)``: a compromise among specifications
  of one rank weighs them as the MPC's own output weights do;
- a quadratic term ``½ q_u ‖u − u_target(k−1)‖²`` (``TargetSettings.mv_weight``)
  toward the input targets in force, which makes the targets unique and keeps them
  still where the specifications leave freedom; no linear economic term (the unit says
  why).

What the MPC gets: the MV targets as its input targets
(:meth:`~controller.mpc.law.MPCLaw.set_input_target`, weight
``MPCSettings.u_target_weight``), and, for a relaxed specification, its CV target as the
reference: the reference rows of that CV are cut at the target (never beyond it in the
direction of the set point). Where every specification holds the reference is the set
point's and the targets only add the input-target term.

A solve that fails, an active model without a steady state (an eigenvalue of Φ at or
outside the unit circle) or a non-finite measurement: the documented safe action is the
MPC on its own set points with the last good input targets (the current input if there
were none), and an alarm; nothing raises out of the targets' part of
:meth:`TargetingLaw.compute` (the MPC's step then runs as without them).

Measured limits (tests/test_two_phase_targets.py, the two-phase reactor's service
controller on its nonlinear plant): the targets agree with an independent SciPy
(SLSQP) solve of the same problem to 1e-6 in the CVs and 1e-3 % in the valves; the
gain is the plant's own DC gain at the active model's point to 1e-6; a pressure set
point 50 kPa above the limit settles at the targets within 0.5 kPa and 0.1 mol %,
kmol/h, the pressure at most 5 kPa over its (soft) limit. Cost per sample
(``ssmpc bench mpc-step``, three calls on this 2-core machine at load 3.4-4.0 shared
with other work, each beside a call with the problem built as a
:class:`~controller.targets.TargetProblem` and solved by
:func:`~controller.targets.solve_targets`; docs/two_phase_targets.md)::

    case                 step median     step p99       targets median  targets p99
    two-phase            0.33-0.49 ms    1.4-1.8 ms     -               -
    two-phase targets    0.54-0.77 ms    1.9-2.2 ms     0.15-0.19 ms    0.6-0.8 ms
    (problem + solve)    0.95-1.06 ms    2.6-2.8 ms     0.41-0.44 ms    1.1-1.2 ms

The sample's problem goes to a :class:`~controller.target_solver.TargetSolver` as its
fields (no :class:`~controller.targets.TargetProblem` per sample; ``last_problem``
builds one when asked): of the targets' time about 0.12 ms is the solve (a fifth of
the samples relax: four QPs) and 0.05 ms this layer's problem fields.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from controller.target_solver import TargetSolver
from controller.targets import TargetProblem, TargetResult

__all__ = ["TargetSettings", "TargetingLaw", "steady_state_map"]


@dataclass(frozen=True)
class TargetSettings:
    """How the steady-state targets feed the MPC (one unit setting).

    Parameters
    ----------
    enabled : bool
        Compute targets and feed them to the MPC; False: the MPC alone on its set
        points (the seed's path).
    spec_rank : tuple of int (ny,)
        Rank of each CV's set point as a specification (1 = most important).
    limit_rank : int
        Rank of the CV limits (the MPC's soft output limits), usually 1.
    input_weight : float
        The MPC's input-target weight W (``MPCSettings.u_target_weight``), per MV
        unit², >= 0.
    mv_weight : float
        The target problem's quadratic MV weight q_u toward the input targets in force,
        per MV unit², > 0.
    report_fraction : float
        A relaxation is reported (alarm) when it exceeds this fraction of the CV's
        scale ``1/sqrt(Ξ)``, > 0.
    limit_backoff : tuple of float (ny,), optional
        How far inside each CV limit the targets stay (CV units, >= 0; empty: 0): the
        steady-state limit is the MPC's soft limit less this, room for the overshoot of
        the dynamic response on a plant the linear model does not match.
    """

    enabled: bool = True
    spec_rank: tuple[int, ...] = (2, 2, 2)
    limit_rank: int = 1
    input_weight: float = 1e-4
    mv_weight: float = 1.0
    report_fraction: float = 0.01
    limit_backoff: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        back = tuple(self.limit_backoff)
        if any(isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v)
               or v < 0 for v in back):
            raise ValueError(f"limit_backoff: must be finite numbers >= 0, got "
                             f"{self.limit_backoff!r}")
        object.__setattr__(self, "limit_backoff", tuple(float(v) for v in back))
        if not isinstance(self.enabled, bool):
            raise ValueError(f"enabled: must be true or false, got {self.enabled!r}")
        ranks = tuple(self.spec_rank)
        if not ranks or any(isinstance(r, bool) or not isinstance(r, int | np.integer)
                            or r < 1 for r in (*ranks, self.limit_rank)):
            raise ValueError(f"spec_rank/limit_rank: ranks are whole numbers >= 1, got "
                             f"{self.spec_rank!r}, {self.limit_rank!r}")
        object.__setattr__(self, "spec_rank", tuple(int(r) for r in ranks))
        for name, lo_ok in (("input_weight", 0.0), ("mv_weight", None),
                            ("report_fraction", None)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise ValueError(f"{name}: must be a finite number, got {v!r}")
            if (v < 0) if lo_ok is not None else (v <= 0):
                raise ValueError(f"{name}: must be {'>= 0' if lo_ok is not None else '> 0'}, "
                                 f"got {v!r}")


def steady_state_map(Phi, Gamma, C) -> tuple[np.ndarray, np.ndarray] | None:
    """``K = C (I − Φ)⁻¹`` (ny, n) and the DC gain ``G = K Γ`` (ny, nu) of a discrete
    model; None when it has no steady state (an eigenvalue of Φ at or outside the unit
    circle, or a singular ``I − Φ``)."""
    Phi = np.asarray(Phi, dtype=float)
    n = Phi.shape[0]
    if not np.all(np.isfinite(Phi)) or np.max(np.abs(np.linalg.eigvals(Phi))) >= 1.0 - 1e-9:
        return None
    try:
        K = np.linalg.solve((np.eye(n) - Phi).T, np.asarray(C, dtype=float).T).T
    except np.linalg.LinAlgError:
        return None
    G = K @ np.asarray(Gamma, dtype=float)
    if not (np.all(np.isfinite(K)) and np.all(np.isfinite(G))):
        return None
    return K, G


class TargetingLaw:
    """An :class:`~controller.mpc.law.MPCLaw` with steady-state targets (module notes).

    A drop-in control law of :class:`controller.multimodel.MultiModelController`:
    everything but :meth:`compute` goes to the MPC law; the operator's limits
    (:meth:`set_operator_limits`) and a retune (:meth:`retune`) are also read by the
    targets.

    Parameters
    ----------
    inner : MPCLaw
        Its settings carry the input-target weight (``u_target_weight``).
    settings : TargetSettings
    cv_names, mv_names : tuple of str
        Names in the report and the alarms.
    cv_units : tuple of str, optional
        Engineering units of the CVs (alarm text).

    Attributes
    ----------
    report : dict or None
        The last sample's targets (:meth:`compute` puts it into ``info["targets"]``).
    last_problem : TargetProblem or None
        The last sample's target problem (built when asked; :meth:`compute` solves its
        fields with a :class:`~controller.target_solver.TargetSolver`, the numbers of
        ``solve_targets(last_problem)``).
    """

    def __init__(self, inner, settings: TargetSettings, cv_names, mv_names,
                 cv_units=()) -> None:
        self.inner = inner
        self.targets = settings
        self.cv_names, self.mv_names = tuple(cv_names), tuple(mv_names)
        self.cv_units = tuple(cv_units) or ("",) * len(self.cv_names)
        s = inner.settings
        if (len(self.cv_names), len(self.mv_names)) != (s.ny, s.nu):
            raise ValueError("cv_names/mv_names: one name per MPC output and input")
        if len(settings.spec_rank) != s.ny:
            raise ValueError(f"spec_rank: expected {s.ny} ranks, got {len(settings.spec_rank)}")
        if len(settings.limit_backoff) not in (0, s.ny):
            raise ValueError(f"limit_backoff: expected {s.ny} values, got "
                             f"{len(settings.limit_backoff)}")
        self._backoff = (np.asarray(settings.limit_backoff) if settings.limit_backoff
                         else np.zeros(s.ny))
        self._maps: dict[int, tuple] = {}  # model j -> (form, (K, G), sample made)
        self._n = 0  # samples computed
        self._u_ref: np.ndarray | None = None  # input targets in force (last good)
        self._op: dict[str, Any] = {}
        self.report: dict | None = None
        self.last: TargetResult | None = None
        self._last_fields: dict | None = None
        self._last_problem: TargetProblem | None = None
        self._solver = TargetSolver(s.ny, s.nu, self.cv_names, self.mv_names)
        self._q_u = np.full(s.nu, settings.mv_weight)
        self._y_rank = np.full(s.ny, settings.limit_rank)
        self._spec_rank = np.asarray(settings.spec_rank)
        self.solves = 0
        self.failures = 0

    @property
    def last_problem(self) -> TargetProblem | None:
        """The last sample's target problem (None: there was none)."""
        if self._last_problem is None and self._last_fields is not None:
            self._last_problem = TargetProblem(**self._last_fields, cv_names=self.cv_names,
                                               mv_names=self.mv_names)
        return self._last_problem

    # -- the MPC law's protocol (delegated) --------------------------------------------
    @property
    def settings(self):
        return self.inner.settings

    @property
    def mpc(self):
        return self.inner.mpc

    @property
    def source(self):
        return self.inner.source

    @property
    def input_target(self) -> np.ndarray:
        return self.inner.input_target

    def prepare(self, ssm) -> None:
        self.inner.prepare(ssm)

    def set_input_target(self, u_target) -> None:
        self.inner.set_input_target(u_target)

    def set_operator_limits(self, **limits) -> None:
        self._op = dict(limits)
        self.inner.set_operator_limits(**limits)

    def retune(self, settings, ssm) -> None:
        self.inner.retune(settings, ssm)

    def reset(self, u, y) -> None:
        self.inner.reset(u, y)

    def finish_sample(self, ssm, model: int) -> None:
        self.inner.finish_sample(ssm, model)

    def counters(self) -> dict[str, int]:
        out = self.inner.counters()
        out.update(targets_solved=self.solves, targets_failed=self.failures)
        return out

    def checkpoint(self) -> dict[str, Any]:
        """The MPC law's checkpoint with the input targets in force under ``"targets"``
        (the reference of the next target problem's MV term)."""
        out = dict(self.inner.checkpoint())
        out["targets"] = {"u_ref": None if self._u_ref is None else self._u_ref.tolist()}
        return out

    def restore(self, state: dict[str, Any]) -> None:
        """Resume from :meth:`checkpoint` (one without ``"targets"`` starts the MV term
        from the input in force)."""
        state = dict(state)
        own = state.pop("targets", None) or {}
        u_ref = own.get("u_ref")
        u_ref = None if u_ref is None else np.asarray(u_ref, dtype=float).reshape(-1)
        if u_ref is not None and (u_ref.shape != (self.inner.settings.nu,)
                                  or not np.all(np.isfinite(u_ref))):
            raise ValueError("state.targets.u_ref: expected one finite value per MV")
        self.inner.restore(state)
        self._u_ref = u_ref

    # -- targets ----------------------------------------------------------------------
    def _form(self, ssm, j: int):
        """Model j's discrete form and its steady-state map, ``(form, (K, G) or None)``:
        a fixed model's exact ZOH form (cached while its Θ is the same); an adaptive
        one's sampled recursion, taken again every ``min_refresh_samples`` samples, the
        spacing of the MPC law's rebuilds (:class:`~controller.mpc.law.SharedStateSource`)."""
        hit = self._maps.get(j)
        if ssm.kinds[j] == "adaptive":
            every = getattr(self.inner.source, "min_refresh_samples", 1)
            if hit is None or self._n - hit[2] >= every:
                pf = ssm.sampled_form(j)
                hit = (pf, steady_state_map(pf.Phi, pf.Gamma, pf.C), self._n)
                self._maps[j] = hit
            return hit[0], hit[1]
        pf = ssm.prediction_form(j)
        if hit is None or hit[0] is not pf:
            hit = (pf, steady_state_map(pf.Phi, pf.Gamma, pf.C), self._n)
            self._maps[j] = hit
        return hit[0], hit[1]

    def problem(self, model: int, ssm, y, reference, u_last) -> TargetProblem | None:
        """The target problem of this sample (module notes); None without a steady
        state of the active model or with a non-finite input."""
        fields = self._fields(model, ssm, y, reference, u_last)
        if fields is None:
            return None
        return TargetProblem(**fields, cv_names=self.cv_names, mv_names=self.mv_names)

    def _fields(self, model: int, ssm, y, reference, u_last) -> dict | None:
        """The fields of :meth:`problem` (those of :class:`TargetProblem` but the
        names), or None."""
        s = self.inner.settings
        y = np.asarray(y, dtype=float).reshape(-1)
        u_last = np.asarray(u_last, dtype=float).reshape(-1)
        R = np.atleast_2d(np.asarray(reference, dtype=float))
        if not (np.all(np.isfinite(y)) and np.all(np.isfinite(u_last))
                and np.all(np.isfinite(R))):
            return None
        pf, kg = self._form(ssm, model)
        if kg is None:
            return None
        K, G = kg
        state = self.inner.mpc.filter.state
        a = s.filter_alpha
        y_f = y if state is None or a == 1.0 else a * y + (1.0 - a) * state
        y0 = G @ u_last + K @ pf.f + pf.b  # the model's steady output at u(k-1)
        op = self._op
        u_min = s.u_min if op.get("u_min") is None else np.asarray(op["u_min"], float)
        u_max = s.u_max if op.get("u_max") is None else np.asarray(op["u_max"], float)
        fixed = op.get("fixed")
        if fixed is not None:
            fixed = np.asarray(fixed, dtype=bool)
            u_min = np.where(fixed, u_last, u_min)
            u_max = np.where(fixed, u_last, u_max)
        u_min = np.minimum(u_min, u_max)
        y_min = s.y_min if op.get("y_min") is None else np.asarray(op["y_min"], float)
        y_max = s.y_max if op.get("y_max") is None else np.asarray(op["y_max"], float)
        if self._backoff.any():
            lo, hi = y_min + self._backoff, y_max - self._backoff
            tight = lo > hi  # a band narrower than twice its back-off: its middle
            with np.errstate(invalid="ignore"):  # -inf + inf where there is no band
                y_min = np.where(tight, 0.5 * (y_min + y_max), lo)
            y_max = np.where(tight, y_min, hi)
        on = s.Xi > 0
        spec = np.where(on, R[-1], np.nan)
        scale = np.where(on, 1.0 / np.sqrt(np.where(on, s.Xi, 1.0)), 1.0)
        u_ref = u_last if self._u_ref is None else self._u_ref
        return dict(
            gain=G, u0=u_last, y0=y0, bias=y_f - y0, u_min=u_min, u_max=u_max,
            q_u=self._q_u, u_ref=np.clip(u_ref, u_min, u_max), y_min=y_min, y_max=y_max,
            y_rank=self._y_rank, y_spec=spec, spec_rank=self._spec_rank, y_scale=scale)

    def _shaped(self, R: np.ndarray, p: dict, res: TargetResult) -> np.ndarray:
        """The reference with each relaxed specification's rows cut at its CV target."""
        relaxed = {r.cv for r in res.relaxed if r.kind == "spec"}
        if not relaxed:
            return R
        R = np.array(R, dtype=float, copy=True)
        for i, name in enumerate(self.cv_names):
            if name in relaxed:
                if p["y_spec"][i] > res.y[i]:
                    R[:, i] = np.minimum(R[:, i], res.y[i])
                else:
                    R[:, i] = np.maximum(R[:, i], res.y[i])
        return R

    def _alarms(self, p: dict, res: TargetResult) -> list[str]:
        out = []
        frac = self.targets.report_fraction
        for r in res.relaxed:
            i = self.cv_names.index(r.cv)
            if r.amount <= frac * p["y_scale"][i]:
                continue
            unit = self.cv_units[i]
            what = {"spec": "set point", "max": "high limit", "min": "low limit"}[r.kind]
            out.append(f"targets: {r.cv} {what} {r.limit:.4g} {unit} cannot hold within the "
                       f"MV ranges and the higher-ranked limits; relaxed (rank {r.rank}) to a "
                       f"target of {res.y[i]:.4g} {unit}")
        return out

    def _report(self, p, res, ms) -> dict:
        """``extra["targets"]``: ``status`` is ``"relaxed"`` when a relaxation beyond the
        reporting threshold is listed in ``relaxed``, else ``"optimal"``."""
        frac = self.targets.report_fraction
        relaxed = [{"cv": r.cv, "kind": r.kind, "rank": r.rank, "limit": r.limit,
                    "amount": r.amount} for r in res.relaxed
                   if r.amount > frac * p["y_scale"][self.cv_names.index(r.cv)]]
        return {
            "status": "relaxed" if relaxed else "optimal",
            "mv": dict(zip(self.mv_names, map(float, res.u))),
            "cv": dict(zip(self.cv_names, map(float, res.y))),
            "bias": dict(zip(self.cv_names, map(float, p["bias"]))),
            "relaxed": relaxed, "qps": res.qps, "solve_ms": ms,
        }

    def compute(self, k: int, model: int, ssm, y, reference, u_last):
        """The MPC's move with this sample's targets (see the module notes)."""
        if not self.targets.enabled:
            return self.inner.compute(k, model, ssm, y, reference, u_last)
        t0 = time.perf_counter()
        self._n += 1
        alarms: list[str] = []
        R = reference
        try:
            p = self._fields(model, ssm, y, reference, u_last)
            res = None if p is None else self._solver.solve(**p)
        except Exception as exc:  # never out of the targets: the safe action below
            p, res = None, None
            alarms.append(f"targets: not computed ({exc}); the MPC runs on its set points")
        ms = (time.perf_counter() - t0) * 1e3
        self._last_fields, self._last_problem = p, None
        if res is not None and res.status != "failed":
            self.solves += 1
            self.last = res
            self._u_ref = res.u.copy()
            self.inner.set_input_target(res.u)
            R = self._shaped(np.atleast_2d(np.asarray(reference, dtype=float)), p, res)
            alarms += self._alarms(p, res)
            self.report = self._report(p, res, ms)
        else:
            self.failures += 1
            held = np.asarray(u_last, dtype=float) if self._u_ref is None else self._u_ref
            if np.all(np.isfinite(held)):
                self.inner.set_input_target(held)
            if not alarms:
                why = ("the target solve failed" if res is not None else
                       "the active model has no steady state or the measurement is invalid")
                alarms.append(f"targets: not computed ({why}); the MPC runs on its set "
                              f"points with the last input targets")
            self.report = {"status": "failed" if res is not None else "unavailable",
                           "solve_ms": ms}
        u, info = self.inner.compute(k, model, ssm, y, R, u_last)
        if alarms:
            info["alarms"] = list(info.get("alarms", ())) + alarms
        info["targets"] = self.report
        return u, info
