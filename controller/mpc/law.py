"""The Δu MPC as a control law of the state-shared multiple-model controller.

:class:`MPCLaw` implements :class:`controller.multimodel.ControlLaw`: at each sample
the multiple-model controller has adapted and switched; the law reads the shared
state ``n(k)`` and the active model's prediction form ``(Φ_j, Γ_j, C_j)``
(:meth:`controller.state_shared.StateSharedModel.prediction_form`) and runs one
deadline-safe :class:`~controller.mpc.controller.MPCController` step on it. Because
the formulation uses ``Δn = n(k) − n(k−1)`` and the measured output, a switch needs no
state reset; each model's condensed QP is cached under its index and rebuilt only
when its Θ changes (adaptive models).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from controller.mpc.controller import ModelView, MPCController
from controller.mpc.settings import MPCSettings

__all__ = ["MPCLaw", "SharedStateSource"]


class SharedStateSource:
    """:class:`~controller.mpc.controller.StateSource` reading a ``StateSharedModel``.

    The multiple-model controller advances the shared state itself; this source only
    remembers the previous state for Δn and reports the model the caller selected.
    """

    def __init__(self) -> None:
        self.ssm = None
        self.model = 0
        self.n_prev: np.ndarray | None = None

    def observe(self, u_prev, y) -> ModelView:
        n = self.ssm.n
        n_prev = n if self.n_prev is None else self.n_prev
        self.n_prev = n
        pf = self.ssm.prediction_form(self.model)
        return ModelView(self.model, n, n_prev, pf[0], pf[1], pf[2], index=self.model,
                         names=tuple(self.ssm.names))

    def checkpoint(self) -> dict[str, Any]:
        return {"n_prev": None if self.n_prev is None else self.n_prev.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        n = state.get("n_prev")
        self.n_prev = None if n is None else np.asarray(n, dtype=float)


class MPCLaw:
    """Δu MPC control law for :class:`controller.multimodel.MultiModelController`.

    Parameters
    ----------
    settings : MPCSettings
        ``nu = ny = m`` of the state-shared model.
    """

    def __init__(self, settings: MPCSettings) -> None:
        self.settings = settings
        self.source = SharedStateSource()
        self.mpc = MPCController(settings, self.source, u0=np.zeros(settings.nu))

    def prepare(self, ssm) -> None:
        """Build every model's QP ahead of time (a switch then costs no build)."""
        for j in range(ssm.k):
            pf = ssm.prediction_form(j)
            self.mpc.prepare(j, pf[0], pf[1], pf[2])

    def reset(self, u, y) -> None:
        self.mpc.u = np.asarray(u, dtype=float).copy()
        self.mpc.filter.reset()
        self.mpc.plan = None
        self.source.n_prev = None

    def compute(self, k: int, model: int, ssm, y, reference, u_last):
        self.source.ssm = ssm
        self.source.model = int(model)
        self.mpc.u = np.asarray(u_last, dtype=float).copy()
        dec = self.mpc.step(k, 0.0, y, reference)
        info = {"status": dec.status, "fallback": dec.fallback, "alarms": list(dec.alarms),
                "solve_ms": dec.solve_ms}
        if "slack" in dec.extra:
            info["slack"] = dec.extra["slack"]
        return dec.u, info

    def counters(self) -> dict[str, int]:
        return {f"mpc_{k}": v for k, v in self.mpc.counters.items()}

    def checkpoint(self) -> dict[str, Any]:
        return self.mpc.checkpoint()

    def restore(self, state: dict[str, Any]) -> None:
        self.mpc.restore(state)
