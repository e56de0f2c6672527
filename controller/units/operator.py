"""A unit's controller under operator control: controller mode OFF/WARM/ON and per-variable
modes and limits (:mod:`controller.operator_modes`), the same code offline and in the
service node.

:class:`OperatedController` wraps a unit's :class:`~controller.interfaces.SampleController`
and is stepped with the plant's applied move besides the measurement:

``off``
    nothing is computed and nothing written (``step`` returns None): the plant keeps
    its regulatory layer and the last values. Leaving ``off`` takes over the plant's
    move as a restart does (``align(u)`` or
    :func:`~controller.units.takeover.align_multimodel`): the first move then starts
    from the values the plant holds.
``warm``
    the controller computes (the decision is reported) and nothing is written; after
    the step it is told the move actually in force (``applied(u)``), so its
    shared state, models and last move follow the plant's measured inputs and outputs,
    and the first move after ``on`` starts from the plant's applied values.
``on``
    the move is written.

Per variable, the operator's settings at the sample's time go to the controller
before its step (``set_operator(view)``, :class:`OperatorView`), where it offers
it (the TE controller plans around a held MV and drops a CV off, see
:mod:`controller.units.te.operator`); then, whatever the controller did, every MV in
``manual`` or ``off`` is written exactly at its held value and every MV in ``auto``
inside its operator limits, and a move so changed is handed back to the controller
(``applied``) as the one in force. What a controller offers per variable comes
from its ``operator_capabilities(cv_names, mv_names)`` (name -> ``{"modes", "limits",
"note"}``); without it: MVs ``auto``/``manual``/``off`` with limits (enforced on the
move), and for a state-shared MPC on exactly the unit's CVs and MVs (the two-phase
reactor) CVs ``auto``/``off`` with limits too, through
:class:`~controller.units.mpc_operator.MPCOperatorLayer`; other controllers' CVs
none.

Cost per TE sample (``ssmpc bench operator-step``, the cases taking turns, 299 samples
each, this 2-core machine at load 6.8 shared with other work; medians):

==========================================  ==========
the TE controller alone                     0.52 ms
operated, default settings                  0.535 ms
operated, XMV 11 in manual and XMEAS 18 off 0.65 ms
==========================================  ==========

The default path returns the controller's own decision (no copies); the view of the
settings is rebuilt only when they change or a limit is on its way.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from controller.operator_modes import CV_MODES, MV_MODES, OperatorState, VariableSpec
from controller.units.mpc_operator import MPCOperatorLayer
from controller.units.takeover import align_multimodel, continue_from_applied

__all__ = ["OperatorView", "OperatedController", "operate", "operator_specs"]


@dataclass(frozen=True)
class OperatorView:
    """The operator's settings at one sample, as vectors in the unit's CV and MV order.

    Attributes
    ----------
    mode : str
        Controller mode.
    mv_mode : tuple of str, (nu,)
        ``auto``, ``manual`` or ``off``.
    mv_value : ndarray (nu,)
        Held value of an MV in manual or off (engineering units), NaN in auto.
    mv_lo, mv_hi : ndarray (nu,)
        Operator limits in force (±inf: none).
    cv_on : ndarray of bool (ny,)
        False for a CV the operator switched off.
    cv_lo, cv_hi : ndarray (ny,)
        Operator limits in force (±inf: none).
    """

    mode: str
    mv_mode: tuple[str, ...]
    mv_value: np.ndarray
    mv_lo: np.ndarray
    mv_hi: np.ndarray
    cv_on: np.ndarray
    cv_lo: np.ndarray
    cv_hi: np.ndarray

    @property
    def plain(self) -> bool:
        """Every MV in auto without operator limits: the move is the controller's."""
        return all(m == "auto" for m in self.mv_mode) and not (
            np.isfinite(self.mv_lo).any() or np.isfinite(self.mv_hi).any())

    @property
    def mv_held(self) -> np.ndarray:
        """True for an MV in manual or off (written at ``mv_value``)."""
        return np.array([m != "auto" for m in self.mv_mode], dtype=bool)

    @classmethod
    def of(cls, state: OperatorState, t_h: float, cv_names, mv_names) -> OperatorView:
        def limits(names):
            lo = np.full(len(names), -math.inf)
            hi = np.full(len(names), math.inf)
            for i, n in enumerate(names):
                c = state.controls.get(n)
                if c is not None:
                    lo[i], hi[i] = c.limits_at(t_h)
            return lo, hi

        mv_mode, mv_value = [], np.full(len(mv_names), math.nan)
        for i, n in enumerate(mv_names):
            c = state.controls.get(n)
            mv_mode.append("auto" if c is None else c.mode)
            if c is not None and c.mode != "auto" and c.value is not None:
                mv_value[i] = c.value
        cv_on = np.array([getattr(state.controls.get(n), "mode", "auto") != "off"
                          for n in cv_names], dtype=bool)
        mv_lo, mv_hi = limits(mv_names)
        cv_lo, cv_hi = limits(cv_names)
        return cls(state.mode, tuple(mv_mode), mv_value, mv_lo, mv_hi, cv_on, cv_lo, cv_hi)


def operator_specs(variables, cv_range: dict[str, tuple[float, float]],
                   controller) -> tuple[VariableSpec, ...]:
    """The unit's :class:`~controller.operator_modes.VariableSpec` s.

    Parameters
    ----------
    variables : sequence of controller.units.variables.VariableInfo
    cv_range : dict name -> (lo, hi)
        Instrument range of each CV; a CV's operator limits must lie inside it and
        inside the controller's own limits (they can tighten, never widen, an alarm
        limit). An MV's engineering range is its controller range (``VariableInfo``).
    controller : object
        The unit's controller (``operator_capabilities`` if it offers it).
    """
    cv_names = [v.name for v in variables if v.kind == "cv"]
    mv_names = [v.name for v in variables if v.kind == "mv"]
    caps_fn = getattr(controller, "operator_capabilities", None)
    caps = caps_fn(tuple(cv_names), tuple(mv_names)) if callable(caps_fn) else None
    mpc = _square_mpc(controller, len(cv_names), len(mv_names))
    out = []
    for v in variables:
        if caps is not None:
            cap = caps.get(v.name, {})
        elif v.kind == "cv" and mpc:
            cap = {"modes": CV_MODES, "limits": True, "controlled": True}
        elif v.kind == "mv":
            cap = {"modes": MV_MODES, "limits": True, "controlled": True}
        elif v.kind == "cv":
            cap = {"controlled": True, "note": "this unit's controller offers no CV modes "
                                               "or limits"}
        else:
            cap = {"note": "a measured disturbance"}
        if v.kind == "cv":
            r_lo, r_hi = cv_range.get(v.name, (-math.inf, math.inf))
            eng = (max(v.lo, r_lo), min(v.hi, r_hi))
        else:
            eng = (v.lo, v.hi)
        out.append(VariableSpec(v.name, v.kind, v.lo, v.hi, eng[0], eng[1],
                                tuple(cap.get("modes", ())), bool(cap.get("limits", False)),
                                bool(cap.get("controlled", bool(cap.get("modes")))),
                                str(cap.get("note", ""))))
    return tuple(out)


def _square_mpc(controller, ny: int, nu: int) -> bool:
    """A state-shared MPC on exactly the unit's CVs and MVs without hooks of its own:
    :class:`~controller.units.mpc_operator.MPCOperatorLayer` applies the settings."""
    if callable(getattr(controller, "set_operator", None)) or not MPCOperatorLayer.fits(
            controller):
        return False
    s = controller.law.settings
    return (s.ny, s.nu) == (ny, nu)


class OperatedController:
    """A unit's controller under the operator's mode and settings (module docstring).

    Parameters
    ----------
    inner : SampleController
    specs : tuple of VariableSpec
        From :func:`operator_specs`.
    cv_names, mv_names : sequence of str
        The unit's vectors' order.
    time_unit_s : float
        Seconds per unit of the ``t`` passed to :meth:`step` (1: seconds, as on the
        wire); ramps run in process hours.

    Attributes
    ----------
    state : OperatorState
        Replaced as a whole by a command (:meth:`set_state`), read once per sample.
    """

    def __init__(self, inner, specs, cv_names, mv_names, time_unit_s: float = 1.0) -> None:
        self.inner = inner
        self.cv_names, self.mv_names = tuple(cv_names), tuple(mv_names)
        self.state = OperatorState(tuple(specs))
        self.time_unit_s = float(time_unit_s)
        #: the generic MPC layer (a state-shared MPC on the unit's vectors), else None
        self.mpc_layer = (MPCOperatorLayer(inner, range(len(self.mv_names)),
                                           range(len(self.cv_names)))
                          if _square_mpc(inner, len(self.cv_names), len(self.mv_names))
                          else None)
        self._resume = False  # the next sample that computes takes over the plant's move
        self._cached: tuple | None = None  # (state, ramping, view) of the last sample
        self._plain = True  # that view's MVs all auto without limits

    def __getattr__(self, name: str) -> Any:
        # the inner controller's optional hooks (on_transition, check_grade, horizon, ...)
        if name == "inner":
            raise AttributeError(name)
        return getattr(self.inner, name)

    @property
    def mode(self) -> str:
        return self.state.mode

    @property
    def writes(self) -> bool:
        """True when moves are written (mode ``on``)."""
        return self.state.mode == "on"

    def set_state(self, state: OperatorState) -> None:
        """Take ``state`` from the next sample on; leaving ``off`` re-aligns then."""
        if state.mode == "off":
            self._resume = True
        self.state = state

    def view(self, t: float) -> OperatorView:
        return OperatorView.of(self.state, t * self.time_unit_s / 3600.0, self.cv_names,
                               self.mv_names)

    def _view_at(self, state: OperatorState, t: float) -> OperatorView:
        """The view at ``t``; the previous one (the same object) while the state is the
        same and no limit is on its way, so that a controller can tell nothing changed."""
        cached = self._cached
        if cached is not None and cached[0] is state and not cached[1]:
            return cached[2]
        t_h = t * self.time_unit_s / 3600.0
        view = OperatorView.of(state, t_h, self.cv_names, self.mv_names)
        ramping = any(c.limits_at(t_h) != (c.lo.end, c.hi.end)
                      for c in state.controls.values())
        self._cached = (state, ramping, view)
        self._plain = view.plain
        return view

    # -- the sample -------------------------------------------------------------------
    def step(self, k: int, t: float, y, reference, u_applied):
        """One sample; None in ``off``, else the decision (written only in ``on``).

        Parameters
        ----------
        u_applied : array_like (nu,)
            The move the plant holds now (what stays in force unless one is written).
        """
        state = self.state
        if state.mode == "off":
            self._resume = True
            return None
        u_applied = np.asarray(u_applied, dtype=float)
        if self._resume:
            self._resume = False
            self.align(u_applied)
        view = self._view_at(state, t)
        hook = getattr(self.inner, "set_operator", None)
        if callable(hook):
            hook(view)
        elif self.mpc_layer is not None:
            self.mpc_layer.apply(view)
        dec = self.inner.step(k, t, y, reference)
        if state.mode == "on" and self._plain:
            return dec  # nothing to enforce (the usual sample: no copies)
        u = self.enforce(np.asarray(dec.u, dtype=float), view)
        extra = dict(dec.extra)
        if state.mode == "warm":
            continue_from_applied(self.inner, u_applied)
            extra["computed_u"] = u
            return replace(dec, u=u_applied.copy(), extra=extra)
        if not np.array_equal(u, np.asarray(dec.u, dtype=float), equal_nan=True):
            continue_from_applied(self.inner, u)
        return replace(dec, u=u, extra=extra)

    @staticmethod
    def enforce(u: np.ndarray, view: OperatorView) -> np.ndarray:
        """``u`` with every held MV at its value and every other inside its operator
        limits (a NaN, an undefined move, is left for the caller to refuse)."""
        u = u.copy()
        held = view.mv_held & np.isfinite(view.mv_value)
        u[held] = view.mv_value[held]
        free = ~held & np.isfinite(u)
        u[free] = np.minimum(np.maximum(u[free], view.mv_lo[free]), view.mv_hi[free])
        return u

    def align(self, u) -> None:
        """Take over the plant's move (a restart, or leaving ``off``)."""
        align = getattr(self.inner, "align", None)
        if callable(align):
            align(np.asarray(u, dtype=float))
        else:
            align_multimodel(self.inner, np.asarray(u, dtype=float))

    # -- persistence ------------------------------------------------------------------
    def checkpoint(self) -> dict:
        return self.inner.checkpoint()

    def restore(self, state: dict) -> None:
        self.inner.restore(state)

    def operator_checkpoint(self) -> dict:
        return self.state.checkpoint()

    def operator_restore(self, state: dict) -> None:
        """Resume the operator's settings (ValueError when they do not fit the unit)."""
        self.set_state(self.state.restore(state))


def operate(cfg, plant, controller, grades) -> OperatedController:
    """The unit's controller under operator control, with its variables' specs.

    Parameters
    ----------
    cfg : controller.units.config.UnitConfig
    plant : plant_sim.base.Plant
    controller : SampleController
        The unit's controller (:func:`services.registry.build_controller`).
    grades : dict
        The unit's grades (the CVs' instrument ranges follow from them,
        :func:`controller.units.config.plausible_ranges`).
    """
    from controller.units.config import plausible_ranges, unit_info
    from controller.units.variables import unit_variables

    info = unit_info(cfg, plant)
    lo, hi = plausible_ranges(cfg, plant, grades)
    cv_range = {n: (float(a), float(b)) for n, a, b in zip(info.cv_names, lo, hi)}
    specs = operator_specs(unit_variables(cfg, plant), cv_range, controller)
    return OperatedController(controller, specs, info.cv_names, info.mv_names)
