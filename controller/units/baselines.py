"""Baseline controllers any square unit can run: a decoupled PI and "hold".

:class:`PIBaseline` is the honest multivariable baseline (static decoupling with the
plant's steady-state gain, velocity form, no wind-up); :class:`HoldController` holds
the MVs where they are ("advanced control off": for TE the regulatory layer alone
keeps the levels and the reactor temperature).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from controller.interfaces import ControlDecision
from controller.readback import finite_vector
from controller.units.config import UnitConfig, cv_indices, mv_indices

__all__ = ["HoldController", "PIBaseline", "build_pi"]


# -- controller side ----------------------------------------------------------------------
class PIBaseline:
    """Multivariable discrete PI with static decoupling (velocity form).

    Per sample, with ``e = r - y`` (row 0 of the reference)::

        u_k = sat( u_{k-1} + K ( (e_k - e_{k-1}) + Ts / Ti * e_k ) ),   K = g * G0^{-1}

    ``G0`` is the plant's steady-state gain at the initial grade (CV by MV,
    computed from the linearization ``D - C A^{-1} B``) and ``g`` a
    dimensionless gain. The velocity form does not wind up on the limits, and
    its state (``u_{k-1}``, ``e_{k-1}``) is all a restart needs: the first move
    after :meth:`restore` continues from the last one (bumpless).

    An invalid measurement (NaN/inf, wrong length) holds the input and raises an
    alarm (``fallback=True``), as the interface requires.
    """

    def __init__(self, gain_matrix, Ts: float, Ti: float, u0, u_min=None, u_max=None,
                 names: tuple[str, ...] = ("PI",)) -> None:
        self.K = np.atleast_2d(np.asarray(gain_matrix, dtype=float))
        self.nu, self.ny = self.K.shape
        if not np.all(np.isfinite(self.K)):
            raise ValueError("gain_matrix: must be finite (is the steady-state gain singular?)")
        self.ratio = float(Ts) / float(Ti)
        self.u = np.asarray(u0, dtype=float).copy()
        self.u_min = np.full(self.nu, -np.inf) if u_min is None else np.asarray(u_min, float)
        self.u_max = np.full(self.nu, np.inf) if u_max is None else np.asarray(u_max, float)
        self.e_prev: np.ndarray | None = None
        self.names = names

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        t0 = time.perf_counter()
        y = np.asarray(y, dtype=float).reshape(-1)
        r = np.atleast_2d(np.asarray(reference, dtype=float))[0]
        if y.shape != (self.ny,) or not np.all(np.isfinite(y)):
            return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                                   J=np.zeros(1), solve_ms=(time.perf_counter() - t0) * 1e3,
                                   fallback=True, status="invalid_measurement",
                                   alarms=(f"invalid measurement at sample {k}: input held",))
        e = r - y
        if self.e_prev is None:
            self.e_prev = e.copy()
        du = self.K @ ((e - self.e_prev) + self.ratio * e)
        self.u = np.clip(self.u + du, self.u_min, self.u_max)
        self.e_prev = e
        return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                               J=np.array([float(e @ e)]),
                               solve_ms=(time.perf_counter() - t0) * 1e3, status="solved")

    def align(self, u) -> None:
        """Continue from the move the plant holds (a restart); no proportional kick."""
        self.u = np.asarray(u, dtype=float).copy()
        self.e_prev = None

    def applied(self, u) -> None:
        """The plant got ``u`` instead of the last move (a missed deadline, warm mode, an
        MV held by the operator): the velocity form goes on from it, so a release is
        bumpless."""
        u = np.asarray(u, dtype=float).reshape(-1)
        if u.shape == self.u.shape and np.all(np.isfinite(u)):
            self.u = np.minimum(np.maximum(u, self.u_min), self.u_max)

    def checkpoint(self) -> dict[str, Any]:
        return {"u": self.u.tolist(),
                "e_prev": None if self.e_prev is None else self.e_prev.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        """Take the last move and error back; ``ValueError`` when the move is not
        ``nu`` finite numbers or the error (if any) not ``ny`` (the node refuses such a
        checkpoint)."""
        u = finite_vector(state["u"], self.nu, "u")
        e = state.get("e_prev")
        self.e_prev = None if e is None else finite_vector(e, self.ny, "e_prev")
        self.u = u


def build_pi(cfg: UnitConfig, plant, u0, grades) -> PIBaseline:
    from plant_sim.linearize import linearize

    cvi, mvi = cv_indices(cfg, plant), mv_indices(cfg, plant)
    lm = linearize(plant, cfg.initial_grade)
    G = lm.D - lm.C @ np.linalg.solve(lm.A, lm.B)
    G0 = G[np.ix_(cvi, mvi)]
    if G0.shape[0] != G0.shape[1]:
        raise ValueError(f"cvs/mvs: the PI baseline needs as many CVs as MVs, got "
                         f"{G0.shape[0]} and {G0.shape[1]}")
    K = cfg.pi_gain * np.linalg.inv(G0)
    lo = np.array([plant.input_vars[i].lower for i in mvi])
    hi = np.array([plant.input_vars[i].upper for i in mvi])
    return PIBaseline(K, cfg.sample_period_s, cfg.pi_integral_time_s, u0, lo, hi)


class HoldController:
    """Holds the MVs where they are: "MPC off" (for TE: the regulatory layer alone).

    A documented safe mode, not a tracking controller: transitions do not move
    the plant. Invalid measurements raise an alarm; the move is the same anyway.
    """

    def __init__(self, u0, names: tuple[str, ...] = ("hold",)) -> None:
        self.u = np.asarray(u0, dtype=float).copy()
        self.names = names

    def step(self, k: int, t: float, y, reference) -> ControlDecision:
        y = np.asarray(y, dtype=float)
        bad = not np.all(np.isfinite(y))
        return ControlDecision(u=self.u.copy(), active_model=0, model_names=self.names,
                               J=np.zeros(1), solve_ms=0.0, fallback=bad,
                               status="invalid_measurement" if bad else "hold",
                               alarms=(f"invalid measurement at sample {k}",) if bad else ())

    def align(self, u) -> None:
        self.u = np.asarray(u, dtype=float).copy()

    def applied(self, u) -> None:
        """The move in force is ``u`` (a missed deadline, an MV held by the operator):
        hold that one."""
        self.u = np.asarray(u, dtype=float).copy()

    def checkpoint(self) -> dict[str, Any]:
        return {"u": self.u.tolist()}

    def restore(self, state: dict[str, Any]) -> None:
        """Take the held move back; ``ValueError`` when it is not as many finite
        numbers as the move in force."""
        self.u = finite_vector(state["u"], self.u.size, "u")
