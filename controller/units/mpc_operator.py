"""The operator's per-variable settings on a state-shared multiple-model MPC
(:class:`controller.multimodel.MultiModelController` with a
:class:`controller.mpc.law.MPCLaw`, seed §6.1 Δu formulation), applied before a step.

- an MV held (``manual``/``off``): its last move is the held value and all its moves
  over the control horizon are fixed at zero in the QP, so the other MVs are planned
  around it;
- an MV's operator limits: the QP's hard input limits of the sample (inside the
  tuned ones);
- a CV ``off``: its weight Ξ is 0 and it has no soft limit;
- a CV's operator limits: soft output limits of the sample (inside the tuned ones).

A change of which CVs are off or have a finite limit rebuilds every model's QP
(:meth:`~controller.mpc.law.MPCLaw.retune`; TE, four models: ~3 ms on this 2-core
machine); the limit values themselves, ramping, change per sample without a rebuild.
Back at the tuned shape the tuned settings themselves are put back.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

__all__ = ["MPCOperatorLayer"]


class MPCOperatorLayer:
    """Applies an :class:`~controller.units.operator.OperatorView` to one MPC core.

    Parameters
    ----------
    core : controller.multimodel.MultiModelController
        With an MPC law (:meth:`fits`).
    mv_idx : sequence of int
        For each core input its index in the unit's MV vector.
    cv_idx : sequence of int
        For each core output its index in the unit's CV vector.
    """

    def __init__(self, core, mv_idx, cv_idx) -> None:
        if not self.fits(core):
            raise ValueError("core: needs a multiple-model controller with an MPC law")
        self.core = core
        self.law = core.law
        self.base = self.law.settings
        self.mv_idx = np.asarray(list(mv_idx), dtype=int)
        self.cv_idx = np.asarray(list(cv_idx), dtype=int)
        if self.mv_idx.size != self.base.nu or self.cv_idx.size != self.base.ny:
            raise ValueError("mv_idx/cv_idx: one index per MPC input and output")
        self._shape: tuple | None = None  # (CVs on, finite soft-limit rows) in force
        self._last_view = None
        self._fixed: np.ndarray | None = None  # held inputs of that view and their values
        self._fixed_values: np.ndarray | None = None
        self.retunes = 0

    @staticmethod
    def fits(core) -> bool:
        law = getattr(core, "law", None)
        return (callable(getattr(law, "set_operator_limits", None))
                and callable(getattr(law, "retune", None))
                and isinstance(getattr(core, "u_last", None), np.ndarray))

    def _hold(self) -> None:
        u_last = self.core.u_last.copy()
        u_last[self._fixed] = self._fixed_values
        self.core.u_last = u_last

    def apply(self, view) -> None:
        """Before the step (the same view object as last time: only the held inputs'
        last moves are set again)."""
        if view is self._last_view:
            if self._fixed is not None:
                self._hold()
            return
        self._last_view = view
        self._fixed = None
        mi, ci = self.mv_idx, self.cv_idx
        fixed = view.mv_held[mi] & np.isfinite(view.mv_value[mi])
        if fixed.any():
            self._fixed, self._fixed_values = fixed, view.mv_value[mi][fixed]
            self._hold()
        b = self.base
        u_min = np.maximum(b.u_min, view.mv_lo[mi])
        u_max = np.minimum(b.u_max, view.mv_hi[mi])
        on = view.cv_on[ci]
        y_min = np.where(on, np.maximum(b.y_min, view.cv_lo[ci]), -math.inf)
        y_max = np.where(on, np.minimum(b.y_max, view.cv_hi[ci]), math.inf)
        shape = (tuple(on), tuple(np.isfinite(y_min)), tuple(np.isfinite(y_max)))
        if shape != self._shape:
            tuned = (tuple([True] * on.size), tuple(np.isfinite(b.y_min)),
                     tuple(np.isfinite(b.y_max)))
            settings = b if shape == tuned else replace(
                b, Xi=np.where(on, b.Xi, 0.0), y_min=y_min, y_max=y_max)
            if self._shape is not None or settings is not b:
                self.law.retune(settings, self.core.ssm)
                self.retunes += 1
            self._shape = shape
        plain = (not fixed.any() and np.array_equal(u_min, b.u_min)
                 and np.array_equal(u_max, b.u_max) and np.array_equal(y_min, b.y_min)
                 and np.array_equal(y_max, b.y_max))
        if plain:
            self.law.set_operator_limits()  # the tuned problem exactly
        else:
            self.law.set_operator_limits(fixed=fixed, u_min=u_min, u_max=u_max,
                                         y_min=y_min, y_max=y_max)
