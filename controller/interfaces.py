"""The per-sample contract between a controller and whatever runs it.

The offline closed-loop runner and the controller service node drive a
controller through exactly this interface, so the same controller code runs in
both. A controller never raises out of :meth:`SampleController.step`: a failure
becomes a safe :class:`ControlDecision` with ``fallback=True`` and alarms.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

__all__ = ["ControlDecision", "SampleController", "QP_WORK_KEYS"]

#: Keys of ``ControlDecision.extra`` with the QP's own work at a sample, where a
#: controller solves one: ``iterations`` (int) and ``qp_solve_ms`` (float). Layers
#: that wrap a QP controller pass them on.
QP_WORK_KEYS = ("iterations", "qp_solve_ms")


@dataclass(frozen=True)
class ControlDecision:
    """What a controller decided at one sample.

    Attributes
    ----------
    u : ndarray, shape (nu,)
        Manipulated variables to apply until the next sample (absolute, engineering units).
    active_model : int
        Index of the model in use (state-shared model slot), -1 if not applicable.
    model_names : tuple of str
        Names of all models, index-aligned with ``J``.
    J : ndarray, shape (n_models,)
        Performance-index values (eq. 4.6) after this sample.
    solve_ms : float
        Wall time of the optimisation/controller computation in ms.
    fallback : bool
        True when the move is not a fresh optimal solution (deadline miss, solver
        failure, invalid measurement): the next move of the previous plan or a hold.
    status : str
        Solver or controller status (``"solved"``, ``"max_iter"``, ``"infeasible"``,
        ``"deadline"``, ``"invalid_measurement"``, ...).
    alarms : tuple of str
        Human-readable alarms raised at this sample.
    extra : dict
        Anything else worth logging (slack values, references over the horizon, ...).
    """

    u: np.ndarray
    active_model: int = -1
    model_names: tuple[str, ...] = ()
    J: np.ndarray = field(default_factory=lambda: np.zeros(0))
    solve_ms: float = 0.0
    fallback: bool = False
    status: str = "solved"
    alarms: tuple[str, ...] = ()
    extra: dict[str, Any] = field(default_factory=dict)


@runtime_checkable
class SampleController(Protocol):
    """A discrete-time controller stepped once per sample.

    ``y`` are the measured controlled variables (absolute units), ``reference``
    the set-point trajectory over the prediction horizon, shape ``(P, ny)`` (a
    controller without a horizon uses row 0).

    A controller may also offer ``finish_sample()``: bookkeeping of the last sample
    that its move does not need (state advance, covariance steps, preparing the
    next sample's QP). A real-time caller runs it after sending the move; the
    controller runs it itself at the next ``step`` or ``checkpoint`` if nobody did,
    so the moves do not depend on whether or when it is called.
    """

    def step(self, k: int, t: float, y: np.ndarray, reference: np.ndarray) -> ControlDecision:
        ...

    def checkpoint(self) -> dict[str, Any]:
        """JSON-serialisable state sufficient to resume bumplessly after a restart."""
        ...

    def restore(self, state: dict[str, Any]) -> None:
        """Resume from :meth:`checkpoint` output."""
        ...
