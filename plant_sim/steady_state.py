"""Steady states of a plant: solve ``f(x, u, d) = 0``, optionally with output targets.

:func:`find_steady_state` solves for the states at given inputs. With
``free_inputs`` and matching ``targets`` it also solves for some inputs so that
named outputs (or states) take given values: this is how operating points such as
"P = 2700 kPa, yA3 = 47 %, F4 = 100 kmol/h" are turned into valve positions.

The solver is :func:`scipy.optimize.root` (MINPACK hybrid) followed by Newton
polishing with the central-difference Jacobian, so that the residual reaches
round-off level.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import root

from plant_sim.base import PlantInputError, PlantModel, as_vector

__all__ = ["SteadyState", "SteadyStateError", "find_steady_state", "residual_norm"]


class SteadyStateError(RuntimeError):
    """The solver did not converge to a steady state."""


@dataclass(frozen=True)
class SteadyState:
    """A steady state found by :func:`find_steady_state`.

    Attributes
    ----------
    x, u, d : ndarray, shapes (nx,), (nu,), (nd,)
    y : ndarray, shape (ny,)
        Outputs at the steady state.
    residual : float
        ``max |f_i(x, u, d)| / scale_i`` (relative to the state scale).
    """

    x: np.ndarray
    u: np.ndarray
    d: np.ndarray
    y: np.ndarray
    residual: float


def _state_scale(model: PlantModel, x: np.ndarray) -> np.ndarray:
    base = np.asarray(getattr(model, "state_scale", np.ones(model.nx)), dtype=float)
    return np.maximum(np.abs(x), base)


def residual_norm(model: PlantModel, x, u, d=None) -> float:
    """``max_i |f_i(x, u, d)| / max(|x_i|, state_scale_i)`` in the plant's time unit."""
    xv = as_vector(x, model.nx, "x")
    uv = as_vector(u, model.nu, "u")
    dv = as_vector(model.default_disturbance() if d is None else d, model.nd, "d")
    f = model.rhs(0.0, xv, uv, dv)
    return float(np.max(np.abs(f) / _state_scale(model, xv)))


def find_steady_state(model: PlantModel, u, guess, d=None, *,
                      free_inputs: Sequence[str] = (),
                      targets: Mapping[str, float] | None = None,
                      tol: float = 1e-13, max_newton: int = 20) -> SteadyState:
    """Find ``x`` (and optionally some inputs) with ``f(x, u, d) = 0``.

    Parameters
    ----------
    model : PlantModel
    u : array_like, shape (nu,)
        Inputs; entries named in ``free_inputs`` are initial guesses.
    guess : array_like, shape (nx,)
        Initial guess for the state.
    d : array_like, shape (nd,), optional
        Disturbances; default :meth:`PlantModel.default_disturbance`.
    free_inputs : sequence of str
        Input names to solve for.
    targets : mapping of str to float
        Output or state names and the values they must take; exactly one per free
        input. An output name wins over a state of the same name.
    tol : float
        Required scaled residual.

    Returns
    -------
    SteadyState

    Raises
    ------
    PlantInputError
        Bad vectors, unknown names, or a count mismatch between free inputs and targets.
    SteadyStateError
        No convergence.
    """
    targets = dict(targets or {})
    uv = as_vector(u, model.nu, "u")
    x0 = as_vector(guess, model.nx, "guess")
    dv = as_vector(model.default_disturbance() if d is None else d, model.nd, "d")
    if len(free_inputs) != len(targets):
        raise PlantInputError(
            f"targets: {len(targets)} targets for {len(free_inputs)} free inputs; "
            "give one target per free input")
    free_idx = [model.index("input", n) for n in free_inputs]
    out_names = model.names("output")
    tgt: list[tuple[str, int, float]] = []
    for name, value in targets.items():
        if name in out_names:
            tgt.append(("output", out_names.index(name), float(value)))
        else:
            tgt.append(("state", model.index("state", name), float(value)))

    xscale = _state_scale(model, x0)
    uscale = np.maximum(np.abs(uv[free_idx]), 1.0) if free_idx else np.zeros(0)

    def unpack(z):
        x = z[: model.nx] * xscale
        uu = uv.copy()
        uu[free_idx] = z[model.nx:] * uscale
        return x, uu

    def resid(z):
        x, uu = unpack(z)
        r = list(model.rhs(0.0, x, uu, dv) / xscale)
        if tgt:
            y = model.outputs(x, uu)
            for kind, i, value in tgt:
                v = y[i] if kind == "output" else x[i]
                r.append((v - value) / max(abs(value), 1.0))
        return np.asarray(r)

    z = np.concatenate([x0 / xscale, uv[free_idx] / uscale]) if free_idx else x0 / xscale
    sol = root(resid, z, method="hybr", options={"xtol": 1e-14})
    z = sol.x
    # Newton polish with a central-difference Jacobian.
    for _ in range(max_newton):
        r = resid(z)
        if np.max(np.abs(r)) <= tol:
            break
        J = _jac(resid, z)
        try:
            dz = np.linalg.solve(J, -r)
        except np.linalg.LinAlgError:
            dz = np.linalg.lstsq(J, -r, rcond=None)[0]
        z = z + dz
    r = resid(z)
    if not np.all(np.isfinite(r)) or np.max(np.abs(r)) > max(tol, 1e-10):
        raise SteadyStateError(
            f"find_steady_state: no convergence for plant {model.name!r} "
            f"(scaled residual {np.max(np.abs(r)):.3g})")
    x, uu = unpack(z)
    return SteadyState(x=x, u=uu, d=dv, y=model.outputs(x, uu),
                       residual=residual_norm(model, x, uu, dv))


def _jac(fun, z: np.ndarray) -> np.ndarray:
    f0 = fun(z)
    J = np.empty((f0.size, z.size))
    for j in range(z.size):
        h = 1e-6 * max(abs(z[j]), 1.0)
        zp = z.copy()
        zm = z.copy()
        zp[j] += h
        zm[j] -= h
        J[:, j] = (fun(zp) - fun(zm)) / (2 * h)
    return J
