"""Exact zero-order-hold discretization."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from controller.linear.realization import as_realization

__all__ = ["DiscreteRealization", "zoh", "zoh_matrices"]


@dataclass(frozen=True)
class DiscreteRealization:
    """``x(k+1) = Phi x(k) + Gamma u(k)``, ``y(k) = C x(k) + D u(k)``, sample time dt."""

    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    D: np.ndarray
    dt: float


def zoh_matrices(A: np.ndarray, B: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """``Phi = e^(A dt)``, ``Gamma = int_0^dt e^(A t) dt B`` via one expm of [[A, B], [0, 0]] dt.

    Exact for inputs held constant over each sample.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if not (math.isfinite(dt) and dt > 0):
        raise ValueError(f"dt: must be finite and > 0, got {dt}")
    nx, nu = B.shape
    M = np.zeros((nx + nu, nx + nu))
    M[:nx, :nx] = A * dt
    M[:nx, nx:] = B * dt
    E = scipy.linalg.expm(M)
    return E[:nx, :nx].copy(), E[:nx, nx:].copy()


def zoh(A, B=None, C=None, D=None, *, dt: float) -> DiscreteRealization:
    """ZOH discretization of a continuous model with sample time ``dt`` (> 0)."""
    sys = as_realization(A, B, C, D)
    Phi, Gamma = zoh_matrices(sys.A, sys.B, float(dt))
    return DiscreteRealization(Phi, Gamma, sys.C.copy(), sys.D.copy(), float(dt))
