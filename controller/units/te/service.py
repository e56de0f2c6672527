"""The TE supervisory controller behind a unit's MV vector (what the service runs).

``y`` is the 41 XMEAS; the move is the unit's MVs
(:func:`controller.units.te.structure.te_mv_names`): the valves the controller writes
and the inner loops' set points. Time on the wire is in process seconds, the TE
controller's in hours. Transitions arrive through
:meth:`TEServiceController.on_transition` and become a
:class:`~controller.units.te.grades.TransitionPlan` (first-order references between
grades). An abort (or a failed transition) holds the references where they are
(:class:`HeldPlan`): every strategy then keeps controlling toward the held set points.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from controller.interfaces import ControlDecision
from controller.units.takeover import align_multimodel
from controller.units.te.control import CORE_NAMES, make_te_controller
from controller.units.te.grades import Leg, TransitionPlan, check_reachable
from controller.units.te.operator import TEOperatorLayer
from controller.units.te.structure import te_mv_names, te_setpoint_name

__all__ = ["HeldPlan", "TEServiceController", "build"]

#: The TE unit's CVs (:data:`controller.units.te.structure.TE_XMEAS`).
_TE_XMEAS = tuple(f"XMEAS{i}" for i in range(1, 42))


class HeldPlan:
    """A TE transition plan held at one time ``t_h``: every reference stays where the
    plan had it then (an aborted transition).

    It answers the plan's queries with the same shapes as
    :class:`~controller.units.te.grades.TransitionPlan`: a scalar time gives one row,
    an array of K times gives K identical rows.
    """

    def __init__(self, plan: TransitionPlan, t_h: float) -> None:
        self.plan, self.t_h = plan, float(t_h)

    def _held(self, fn, t):
        row = fn(self.t_h)
        tt = np.asarray(t, dtype=float)
        if tt.ndim == 0:
            return row
        return np.broadcast_to(row, (tt.size, row.size)).copy()

    def with_leg_references(self, settings) -> HeldPlan:
        """Held where the plan with the controller's own leg references was (see
        :meth:`TransitionPlan.with_leg_references
        <controller.units.te.grades.TransitionPlan.with_leg_references>`)."""
        return HeldPlan(self.plan.with_leg_references(settings), self.t_h)

    def xmeas_ref(self, t) -> np.ndarray:
        return self._held(self.plan.xmeas_ref, t)

    def xmv_ref(self, t) -> np.ndarray:
        return self._held(self.plan.xmv_ref, t)

    def d_fraction_ref(self, t) -> float:
        return self.plan.d_fraction_ref(self.t_h)

    def grade_at(self, t):
        return self.plan.grade_at(self.t_h)

    def change_at(self, t):
        """No leg under way: the grade held, before and after."""
        g = self.plan.grade_at(self.t_h)
        return g, g

    @property
    def legs(self) -> tuple:
        """None under way: the held references do not move."""
        return ()

    def hours_since_change(self, t) -> float:
        """As the plan had it at the hold (the references stop there, so does the
        settling the economics wait for)."""
        return self.plan.hours_since_change(self.t_h)


class TEServiceController:
    """The TE supervisory controller behind the service's MV vector (module docstring).

    Parameters
    ----------
    strategy : {"ssmpc", "fixed", "pi"}
    start_grade : str
        Grade the plant starts at (``modeN``).
    mvs : tuple of str
        The unit's MV names, in the order of the move.
    sample_h : float
        Supervisory sample, h.
    u0 : array_like (len(mvs),)
        The move in force at the start.
    """

    def __init__(self, strategy: str, start_grade: str, mvs: tuple[str, ...],
                 sample_h: float, u0) -> None:
        self.strategy = strategy
        self.sample_h = sample_h
        self.plan_def = {"start": start_grade, "legs": [], "freeze_h": None, "tau_h": None}
        self.ctl, self.spec = make_te_controller(strategy, TransitionPlan(start_grade),
                                                 sample_h=sample_h)
        self.mvs = tuple(mvs)
        self.u = np.asarray(u0, dtype=float).copy()
        sp_names = [te_setpoint_name(lp) for lp in self.spec.loops]
        self._map = []
        for name in self.mvs:
            if name in sp_names:
                self._map.append(("sp", sp_names.index(name)))
            elif name.startswith("XMV"):
                self._map.append(("xmv", int(name[3:]) - 1))
            else:
                raise ValueError(f"mvs: {name!r} is neither an XMV nor a set point of the "
                                 f"TE controller's loops ({', '.join(sp_names)})")
        alias = {"Tr_sp": "reactor_temperature_sp", "Pr_sp": "reactor_pressure_sp"}
        self._core_idx = [self.mvs.index(alias.get(n, n)) if alias.get(n, n) in self.mvs
                          else None for n in CORE_NAMES]
        self.operator = TEOperatorLayer(self.ctl, self.mvs, self._core_idx)
        self._xmv2 = self.mvs.index("XMV2") if "XMV2" in self.mvs else None
        self._d_meas = math.nan  # the latest XMEAS 2 (D feed), kg/h
        self._track_ratio_u: float | None = None  # XMV 2 to track at the next step

    def _apply_plan(self) -> None:
        d = self.plan_def
        extra = {} if d.get("tau_h") is None else {"tau_xmeas_h": d["tau_h"]}
        plan = TransitionPlan(d["start"], tuple(Leg(t, g) for t, g in d["legs"]), **extra)
        self.ctl.retarget(plan if d["freeze_h"] is None else HeldPlan(plan, d["freeze_h"]))

    def check_grade(self, grade: str) -> None:
        """Refuse a grade this control structure cannot hold from the current one.

        Raises
        ------
        controller.units.te.grades.GradeError
            (a ``ValueError``) naming the grade and the valve without margin.
        """
        legs = self.plan_def["legs"]
        check_reachable(legs[-1][1] if legs else self.plan_def["start"], grade)

    def on_transition(self, event: str, grade: str, t_s: float,
                      duration_s: float | None = None) -> None:
        """``running``: head for ``grade`` from ``t_s``; ``aborted``/``failed``: hold.

        The references' time constant is a quarter of the transition's duration (98 %
        of the move after it), as for the other units.
        """
        d = self.plan_def
        if event == "running":
            if duration_s is not None:
                d["tau_h"] = duration_s / 4.0 / 3600.0
            # After an abort the references jump from the held values to the plan's
            # path; the new leg then moves them on with first-order dynamics.
            d["freeze_h"] = None
            d["legs"] = [*d["legs"], [t_s / 3600.0, grade]]
        elif event in ("aborted", "failed"):
            # held where the references are: on the plan's clock, which the plan hold
            # (TransitionGuards) may have put behind real time
            d["freeze_h"] = t_s / 3600.0 - getattr(self.ctl, "plan_lag_h", 0.0)
        self._apply_plan()

    # -- operator control (controller.units.operator) -----------------------------------
    def operator_capabilities(self, cv_names, mv_names) -> dict[str, dict]:
        """What an operator may set per variable (:class:`TEOperatorLayer`)."""
        return self.operator.capabilities(cv_names, mv_names)

    def set_operator(self, view) -> None:
        """The operator's settings for the coming step (held handles, limits, CVs off)."""
        self.operator.apply(view, _TE_XMEAS)

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        y = np.asarray(y, dtype=float)
        if y.shape == (41,):
            self._d_meas = float(y[1])
            if self._track_ratio_u is not None:  # a take-over: start from the valve
                track = getattr(self.ctl, "track_ratio", None)
                if callable(track):
                    track(self._track_ratio_u, self._d_meas)
                self._track_ratio_u = None
        dec = self.ctl.step(k, t / 3600.0, y, None)
        u_full = np.asarray(dec.u, dtype=float)
        sp = np.asarray(dec.extra.get("setpoints", np.full(len(self.spec.loops), np.nan)),
                        dtype=float)
        u = np.array([sp[j] if kind == "sp" else u_full[j] for kind, j in self._map])
        fallback, alarms = dec.fallback, list(dec.alarms)
        if not np.all(np.isfinite(u)):
            u = np.where(np.isfinite(u), u, self.u)
            fallback = True
            alarms.append(f"TE controller left MVs undefined at sample {k}; held")
        self.u = u
        return ControlDecision(u=u, active_model=dec.active_model, model_names=dec.model_names,
                               J=np.asarray(dec.J), solve_ms=dec.solve_ms, fallback=fallback,
                               status=dec.status, alarms=tuple(alarms), extra=dec.extra)

    def finish_sample(self) -> None:
        """The TE controller's bookkeeping after the move (see
        :meth:`controller.units.te.control.TEController.finish_sample`)."""
        self.ctl.finish_sample()

    def applied(self, u) -> None:
        """The move in force over the coming sample is ``u``, not the last decision (a
        missed deadline, warm mode, an MV the operator holds): the core goes on from its
        handles (:meth:`TEController.applied`) and the E/D ratio from the applied XMV 2."""
        self.u = np.asarray(u, dtype=float).copy()
        idx = self._core_idx
        applied = getattr(self.ctl, "applied", None)
        if None not in idx and callable(applied):
            applied(self.u[idx])
        track = getattr(self.ctl, "track_ratio", None)
        if self._xmv2 is not None and callable(track):
            track(float(self.u[self._xmv2]), self._d_meas)

    def align(self, u) -> None:
        """Take over the plant's move: the core (five handles,
        :data:`~controller.units.te.control.CORE_NAMES`) restarts from the matching
        valves and set points (re-initialized dynamics), the outer loops without their
        previous errors and the E/D ratio from the applied XMV 2 at the next sample."""
        self.u = np.asarray(u, dtype=float).copy()
        take_over = getattr(self.ctl, "take_over", None)
        idx = self._core_idx
        core_u = None if None in idx else self.u[idx]
        if callable(take_over):
            # the core's own handles under the plant's (the pressure lead taken off)
            own = take_over(core_u)
            if own is not None:
                core_u = own
        if core_u is not None:
            align_multimodel(getattr(self.ctl, "core", None), core_u)
        # the E/D ratio takes over from the plant too (a stale D share would kick the
        # first moves of XMV 2)
        if self._xmv2 is not None:
            self._track_ratio_u = float(self.u[self._xmv2])

    def checkpoint(self) -> dict[str, Any]:
        return {"ctl": self.ctl.checkpoint(), "plan": self.plan_def, "u": self.u.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        self.plan_def = state["plan"]
        self._apply_plan()
        self.ctl.restore(state["ctl"])
        self.u = np.asarray(state["u"], dtype=float)


def build(cfg, plant, u0, grades) -> TEServiceController:
    """The TE controller of ``cfg.strategy`` behind :class:`TEServiceController`."""
    return TEServiceController(cfg.strategy, cfg.initial_grade, te_mv_names(cfg),
                               cfg.sample_period_s / 3600.0, u0)
