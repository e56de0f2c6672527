"""One unit's KPIs per sample: its CVs and MVs at their limits in force, its operating
cost, its models' prediction errors, into a :class:`controller.kpis.KPIAccumulator`.

What the controller node feeds after each sample's move is out (and what
``ssmpc bench kpis`` times): the values of the unit's CVs (measured) and MVs (the move
in force), the limits in force as the status' ``variables`` shows them (the
operator's inside the controller's own, ramped:
:meth:`controller.operator_modes.OperatorState.effective_limits`), the at-limit rule
of the status (:func:`controller.units.variables.limit_thresholds`), and the cost of
:func:`controller.units.economics.operating_cost` against the unit's base case.

The thresholds are worked out again only when the operator's settings change (a new
:class:`~controller.operator_modes.OperatorState`) or while one of its limits ramps.
"""

from __future__ import annotations

import numpy as np

from controller.kpis import KPIAccumulator, KPISettings
from controller.units.economics import operating_cost
from controller.units.variables import flags_at, limit_thresholds

__all__ = ["UnitKPIs"]


class UnitKPIs:
    """The KPIs of one unit's controller.

    Parameters
    ----------
    cfg : controller.units.config.UnitConfig
    cv_names, mv_names : sequence of str
        The unit's CV and MV vectors' names (:class:`~controller.units.config.UnitInfo`).
    variables : sequence of controller.units.variables.VariableInfo
        The unit's variables; its CVs and MVs among ``cv_names``/``mv_names`` are counted.
    """

    def __init__(self, cfg, cv_names, mv_names, variables) -> None:
        self.cost = operating_cost(cfg)
        cost = self.cost
        settings = KPISettings(cfg.sample_period_s,
                               base_cost_usd_h=None if cost is None else cost.base_usd_h,
                               base_cost_origin="" if cost is None else cost.base_origin)
        ny = len(cv_names)
        where = {"cv": {n: i for i, n in enumerate(cv_names)},
                 "mv": {n: ny + i for i, n in enumerate(mv_names)}}
        kept = [v for v in variables if v.name in where.get(v.kind, {})]
        #: where each counted variable's value is in the vector [y, u]
        self._src = np.array([where[v.kind][v.name] for v in kept], dtype=int)
        self.names = tuple(v.name for v in kept)
        self.descriptions = {v.name: v.description for v in kept}
        self._thresholds: tuple | None = None  # (operator state, ramping, (lo_at, hi_at))
        self.acc = KPIAccumulator(settings, [(v.name, v.kind) for v in kept])

    def _limits_at(self, state, t_h: float) -> tuple[np.ndarray, np.ndarray]:
        cached = self._thresholds
        if cached is not None and cached[0] is state and not cached[1]:
            return cached[2]
        lims = np.array([state.effective_limits(n, t_h) for n in self.names],
                        dtype=float).reshape(-1, 2)
        ramping = any(c.limits_at(t_h) != (c.lo.end, c.hi.end)
                      for c in state.controls.values())
        self._thresholds = (state, ramping, limit_thresholds(lims[:, 0], lims[:, 1]))
        return self._thresholds[2]

    def count(self, t_s: float, mode: str, fallback: bool, y, u, state,
              prediction_rms=None, models=None) -> None:
        """One sample.

        Parameters
        ----------
        t_s : float
            Process time, s.
        mode : str
            Controller mode of the sample.
        fallback : bool
            The move written was not the controller's own.
        y, u : array_like, shapes (ny,), (nu,)
            The measured CVs and the move in force, engineering units.
        state : controller.operator_modes.OperatorState
            The operator's settings (the limits in force).
        prediction_rms : array_like, optional
            Each model's RMS prediction error (``ControlDecision.extra``).
        models : sequence of str, optional
            Their names (``ControlDecision.model_names``).
        """
        y = np.asarray(y, dtype=float)
        values = np.concatenate((y, np.asarray(u, dtype=float)))[self._src]
        at_lo, at_hi = flags_at(values, *self._limits_at(state, t_s / 3600.0))
        cost = None if self.cost is None else self.cost.usd_per_h(y)
        self.acc.update(t_s, mode, fallback, at_lo, at_hi, cost, prediction_rms, models)

    def count_held(self, t_s: float, mode: str) -> None:
        """A sample whose measurement was not acted on (the move held): time in
        fallback (ON), nothing else counted."""
        self.acc.update(t_s, mode, True)

    def report(self) -> dict:
        """:meth:`KPIAccumulator.report` with each variable's description."""
        rep = self.acc.report()
        for w in rep["windows"]:
            for a in w["constraint_activity"]:
                a["description"] = self.descriptions.get(a["name"], "")
        return rep

    def checkpoint(self) -> dict:
        return self.acc.checkpoint()

    def restore(self, state: dict) -> None:
        self.acc.restore(state)
