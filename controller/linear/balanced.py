"""Balanced truncation (sec. 3.5) with the relative error Re of eq. 3.22.

Square-root method: with Cholesky-like factors ``Wc = Lc Lc^T`` and
``Wo = Lo Lo^T`` of the controllability and observability gramians
(Definition 3.5.1), ``Lo^T Lc = U Sigma V^T`` gives the Hankel singular values
``sigma_i`` and the balancing projections ``T = Lc V Sigma^-1/2``,
``T^-1 = Sigma^-1/2 U^T Lo^T``. Keeping the first k columns/rows truncates the
balanced realization (eq. 3.19). The reduced model of a stable minimal model is
stable and ``||G - G_k||_inf <= 2 sum_(i>k) sigma_i`` (the bound of eq. 3.20).

``Re(k) = sqrt(sum_(i>k) sigma_i^2) / sqrt(sum_i sigma_i^2)`` (eq. 3.22,
reconstructed: Frobenius norms of the discarded and full Sigma). The seed
accepts order k when ``Re(k) < epsilon``; the order-k model "captures
(1 - Re) 100 %" of the full one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from controller.linear.realization import Realization, as_realization

__all__ = [
    "stable_unstable_split",
    "BalancedTruncation",
    "balanced_truncation",
    "hankel_singular_values",
    "relative_error",
    "select_order",
    "gramians",
]

METHODS = ("truncate", "matchdc")


def gramians(sys: Realization) -> tuple[np.ndarray, np.ndarray]:
    """Controllability and observability gramians (Wc, Wo), each (nx, nx).

    Raises ValueError if A is not asymptotically stable.
    """
    if not sys.is_stable():
        raise ValueError("A: balanced truncation needs an asymptotically stable model")
    Wc = scipy.linalg.solve_continuous_lyapunov(sys.A, -sys.B @ sys.B.T)
    Wo = scipy.linalg.solve_continuous_lyapunov(sys.A.T, -sys.C.T @ sys.C)
    return (Wc + Wc.T) / 2, (Wo + Wo.T) / 2


def _psd_factor(W: np.ndarray) -> np.ndarray:
    """L with L L^T = W for a symmetric positive semidefinite W (eigenvalues clipped at 0)."""
    lam, V = np.linalg.eigh(W)
    return V * np.sqrt(np.clip(lam, 0.0, None))


def _balancing(sys: Realization):
    Wc, Wo = gramians(sys)
    Lc, Lo = _psd_factor(Wc), _psd_factor(Wo)
    U, s, Vt = np.linalg.svd(Lo.T @ Lc)
    return s, U, Vt.T, Lc, Lo


def hankel_singular_values(A, B=None, C=None, D=None) -> np.ndarray:
    """Hankel singular values sigma_1 >= ... >= sigma_nx >= 0 (eq. 3.18), shape (nx,)."""
    sys = as_realization(A, B, C, D)
    return _balancing(sys)[0]


def relative_error(hsv: ArrayLike, k: int) -> float:
    """Re(k) of eq. 3.22 (a fraction; multiply by 100 for %), for 0 <= k <= len(hsv)."""
    s = np.asarray(hsv, dtype=float).reshape(-1)
    if not 0 <= k <= s.size:
        raise ValueError(f"k: order must be in 0..{s.size}, got {k}")
    total = math.sqrt(float(np.sum(s**2)))
    if total == 0.0:
        return 0.0
    return math.sqrt(float(np.sum(s[k:] ** 2))) / total


def select_order(hsv: ArrayLike, re_threshold: float) -> int:
    """Smallest order k >= 1 with Re(k) < re_threshold (a fraction, e.g. 0.01 for 1 %)."""
    if not (math.isfinite(re_threshold) and 0 < re_threshold <= 1):
        raise ValueError(f"re_threshold: must be in (0, 1], got {re_threshold}")
    s = np.asarray(hsv, dtype=float).reshape(-1)
    for k in range(1, s.size + 1):
        if relative_error(s, k) < re_threshold:
            return k
    return s.size


@dataclass(frozen=True)
class BalancedTruncation:
    """Result of :func:`balanced_truncation`.

    Attributes
    ----------
    reduced : Realization
        The order-k model (balanced coordinates).
    hsv : ndarray, shape (nx,)
        Hankel singular values of the full model, descending.
    order : int
        k.
    Re : float
        Relative error of eq. 3.22 for order k (fraction).
    error_bound : float
        ``2 sum_(i>k) sigma_i``, the H-infinity bound on ``G - G_k``.
    method : str
        ``"truncate"`` (plain truncation, eq. 3.19) or ``"matchdc"``
        (singular perturbation: same DC gain as the full model).
    """

    reduced: Realization
    hsv: np.ndarray
    order: int
    Re: float
    error_bound: float
    method: str

    @property
    def Re_percent(self) -> float:
        return 100.0 * self.Re


def stable_unstable_split(sys: Realization) -> tuple[Realization, Realization]:
    """Additive split ``G = G_s + G_u`` (real Schur form, then a Sylvester equation).

    Returns (stable part with the feedthrough, unstable part with D = 0); the
    unstable part holds every eigenvalue with real part >= 0.
    """
    T, Z, n_s = scipy.linalg.schur(sys.A, output="real", sort="lhp")
    A11, A12, A22 = T[:n_s, :n_s], T[:n_s, n_s:], T[n_s:, n_s:]
    # [I X; 0 I] decouples the blocks when A11 X - X A22 + A12 = 0
    X = scipy.linalg.solve_sylvester(A11, -A22, -A12)
    Bz, Cz = Z.T @ sys.B, sys.C @ Z
    Bs = Bz[:n_s] - X @ Bz[n_s:]
    Cu = Cz[:, n_s:] + Cz[:, :n_s] @ X
    stable = Realization(A11, Bs, Cz[:, :n_s], sys.D)
    unstable = Realization(A22, Bz[n_s:], Cu, np.zeros_like(sys.D))
    return stable, unstable


def balanced_truncation(A, B=None, C=None, D=None, *, order: int | None = None,
                        re_threshold: float | None = None,
                        method: str = "truncate",
                        unstable: str = "error") -> BalancedTruncation:
    """Reduce a stable model by balanced truncation.

    Parameters
    ----------
    A, B, C, D : array_like or Realization-like
    order : int, optional
        Reduced order k (1 <= k <= nx).
    re_threshold : float, optional
        Instead of ``order``: the smallest k with Re(k) < re_threshold (fraction).
    method : {"truncate", "matchdc"}
    unstable : {"error", "keep"}
        With "keep", a model with eigenvalues in the closed right half plane is
        split additively into stable and unstable parts; the stable part is
        reduced and the unstable part kept whole (as SLICOT AB09MD does). Then
        ``order`` counts both parts and hsv/Re refer to the stable part.

    Raises
    ------
    ValueError
        Unstable model (unless ``unstable="keep"``), neither or both of
        order/re_threshold, k out of range, or k above the number of nonzero
        Hankel singular values.
    """
    sys = as_realization(A, B, C, D)
    if method not in METHODS:
        raise ValueError(f"method: must be one of {METHODS}, got {method!r}")
    if unstable not in ("error", "keep"):
        raise ValueError(f"unstable: must be 'error' or 'keep', got {unstable!r}")
    if unstable == "keep" and not sys.is_stable():
        stab, unst = stable_unstable_split(sys)
        nu = unst.order
        if order is not None and (isinstance(order, bool) or not isinstance(order, int | np.integer)
                                  or order <= nu):
            raise ValueError(f"order: must exceed the {nu} unstable modes, got {order!r}")
        part = balanced_truncation(stab, order=None if order is None else int(order) - nu,
                                   re_threshold=re_threshold, method=method)
        r = part.reduced
        k = r.order
        A_ = np.zeros((k + nu, k + nu))
        A_[:k, :k], A_[k:, k:] = r.A, unst.A
        return BalancedTruncation(
            reduced=Realization(A_, np.vstack((r.B, unst.B)), np.hstack((r.C, unst.C)), r.D),
            hsv=part.hsv, order=k + nu, Re=part.Re, error_bound=part.error_bound,
            method=method)
    if (order is None) == (re_threshold is None):
        raise ValueError("order, re_threshold: give exactly one of them")
    s, U, V, Lc, Lo = _balancing(sys)
    nx = sys.order
    k = select_order(s, re_threshold) if order is None else order
    if isinstance(k, bool) or not isinstance(k, int | np.integer) or not 1 <= k <= nx:
        raise ValueError(f"order: must be an integer in 1..{nx}, got {k!r}")
    k = int(k)
    tiny = s[0] * nx * np.finfo(float).eps if s.size else 0.0
    # Project onto the nonzero Hankel singular values (the minimal part), then truncate.
    r = int(np.sum(s > tiny))
    if k > r:
        raise ValueError(f"order: {k} exceeds the number of nonzero Hankel singular "
                         f"values ({r}; the McMillan degree)")
    kk = r if method == "matchdc" else k
    sr = s[:kk] ** -0.5
    T = Lc @ V[:, :kk] * sr
    Ti = (sr[:, None] * U[:, :kk].T) @ Lo.T
    Ab, Bb, Cb = Ti @ sys.A @ T, Ti @ sys.B, sys.C @ T
    Db = sys.D.copy()
    if method == "matchdc" and k < kk:
        A11, A12, A21, A22 = Ab[:k, :k], Ab[:k, k:], Ab[k:, :k], Ab[k:, k:]
        B1, B2, C1, C2 = Bb[:k], Bb[k:], Cb[:, :k], Cb[:, k:]
        X = np.linalg.solve(A22, np.hstack((A21, B2)))
        Ab = A11 - A12 @ X[:, :k]
        Bb = B1 - A12 @ X[:, k:]
        Cb = C1 - C2 @ X[:, :k]
        Db = Db - C2 @ X[:, k:]
    else:
        Ab, Bb, Cb = Ab[:k, :k], Bb[:k], Cb[:, :k]
    return BalancedTruncation(
        reduced=Realization(Ab, Bb, Cb, Db),
        hsv=s,
        order=k,
        Re=relative_error(s, k),
        error_bound=2.0 * float(np.sum(s[k:])),
        method=method,
    )
