"""Left matrix fraction description with a scalar denominator, eq. 2.9.

``H(s) = D(s)^-1 N(s)`` with ``D(s) = d(s) I``: ``d`` is the characteristic
polynomial of a minimal realization (a common denominator of every entry of H,
of degree the McMillan degree) and ``N(s) = d(s) (H(s) - D0)`` is a polynomial
matrix of degree below that of d. This is the form Theta of eq. 3.16 is read
from.

Coefficient order (everywhere in this package): **lowest power first**, as in
the seed's ``d(s) = s^n + sum_i d_i s^(i-1)``. So ``d[i]`` multiplies ``s^i``
and ``d[-1] == 1``; ``N[:, :, i]`` multiplies ``s^i``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from controller.linear.realization import as_realization, minimal_realization

__all__ = ["LeftMFD", "left_mfd"]


@dataclass(frozen=True)
class LeftMFD:
    """``H(s) = d(s)^-1 N(s) + D0`` (eq. 2.9 with D(s) = d(s) I).

    Attributes
    ----------
    d : ndarray, shape (n+1,)
        Monic denominator, lowest power first (``d[n] == 1``).
    N : ndarray, shape (p, m, n)
        Numerator coefficients of the strictly proper part, lowest power first:
        ``N_ij(s) = sum_k N[i, j, k] s^k``.
    D0 : ndarray, shape (p, m)
        Feedthrough ``H(inf)``; the state-shared form needs it zero.
    """

    d: np.ndarray
    N: np.ndarray
    D0: np.ndarray

    def __post_init__(self) -> None:
        d = np.array(self.d, dtype=float).reshape(-1)
        N = np.array(self.N, dtype=float)
        D0 = np.array(self.D0, dtype=float)
        if d.size < 1 or not np.isfinite(d).all():
            raise ValueError("d: must be a non-empty finite coefficient vector")
        if d[-1] != 1.0:
            raise ValueError(f"d: must be monic (d[-1] == 1, lowest power first), got {d[-1]}")
        n = d.size - 1
        if N.ndim != 3 or N.shape[2] != n:
            raise ValueError(f"N: expected shape (p, m, {n}), got {N.shape}")
        if D0.shape != N.shape[:2]:
            raise ValueError(f"D0: expected shape {N.shape[:2]}, got {D0.shape}")
        if not (np.isfinite(N).all() and np.isfinite(D0).all()):
            raise ValueError("N, D0: non-finite entries")
        for name, arr in (("d", d), ("N", N), ("D0", D0)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def degree(self) -> int:
        """Degree n of d(s)."""
        return self.d.size - 1

    @property
    def shape(self) -> tuple[int, int]:
        """(p, m): outputs by inputs."""
        return self.N.shape[0], self.N.shape[1]

    def evaluate(self, s: ArrayLike) -> np.ndarray:
        """H(s) at complex points s, shape (len(s), p, m)."""
        s = np.atleast_1d(np.asarray(s, dtype=complex))
        powers = s[:, None] ** np.arange(self.degree + 1)[None, :]
        den = powers @ self.d
        num = np.einsum("ijk,sk->sij", self.N, powers[:, : self.degree])
        return num / den[:, None, None] + self.D0[None]


def left_mfd(A, B=None, C=None, D=None, *, minimal: bool = True) -> LeftMFD:
    """Left MFD ``H(s) = d(s)^-1 N(s) + D0`` of a state-space model (eq. 2.9).

    Parameters
    ----------
    A, B, C, D : array_like or Realization-like
        Continuous-time model, shapes (nx,nx), (nx,m), (p,nx), (p,m).
    minimal : bool
        Reduce to a minimal realization first (default), so that the degree of
        d is the McMillan degree. With False, d is the characteristic
        polynomial of A as given.

    Returns
    -------
    LeftMFD
        With ``d = det(sI - A_min)`` and ``N(s) = C adj(sI - A_min) B``.

    Notes
    -----
    The adjugate is expanded as ``adj(sI - A) = sum_k R_k s^k`` with
    ``R_(n-1) = I`` and ``R_(k-1) = A R_k + d_k I`` (Faddeev recursion), applied
    to B so only (n, m) products are formed. Like any coefficient
    representation it loses accuracy for high degree (tested to n ~ 15 on
    well-scaled models); reduce first (balanced truncation) rather than
    building MFDs of large models.
    """
    sys = as_realization(A, B, C, D)
    if minimal:
        sys = minimal_realization(sys)
    n = sys.order
    p, m = sys.n_outputs, sys.n_inputs
    if n == 0:
        return LeftMFD(np.ones(1), np.zeros((p, m, 0)), sys.D.copy())
    # np.poly returns highest power first; flip to lowest first.
    d = np.real_if_close(np.poly(np.linalg.eigvals(sys.A)))[::-1].real.copy()
    d[-1] = 1.0
    N = np.zeros((p, m, n))
    RB = sys.B.copy()
    N[:, :, n - 1] = sys.C @ RB
    for k in range(n - 1, 0, -1):
        RB = sys.A @ RB + d[k] * sys.B
        N[:, :, k - 1] = sys.C @ RB
    return LeftMFD(d, N, sys.D.copy())
