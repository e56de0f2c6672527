"""Is a covariance above its floor? A Cholesky test in place of an eigendecomposition.

The covariance reset of seed §5.1.3 (kappa = 10, reset when lambda_min(P) falls to 1)
needs one decision per check: is ``lambda_min(P) > floor``? That holds exactly when
``P - floor I`` is positive definite, i.e. when its Cholesky factor exists (LAPACK
``dpotrf`` through :func:`scipy.linalg.lapack.dpotrf`, info = 0; Golub & Van Loan
§4.2). A failed factorization separates a covariance that is still positive definite
(reason ``"floor"``) from one that is not (``"singular"``) with a second factorization
of ``P`` itself, only on the (rare) reset.

The caller also carries a lower bound on ``lambda_min(P)`` from check to check (each
update lowers it by at most the trace of its decrement), so it needs a bound after a
passed check, not only the yes/no. With ``A = P - floor I = L L'``,
``lambda_min(A) = 1 / ||A^-1||_2 >= 1 / ||A^-1||_F = 1 / ||L^-T L^-1||_F``, so
``lambda_min(P) >= floor + 1 / ||A^-1||_F`` (:func:`floor_check` with
``want_bound=True``; ``dtrtri`` and one product, about twice the factorization). The
bound is at most ``sqrt(N)`` times too low; a lower bound only makes the next check
come earlier, never changes what a check decides.

For the implicit covariance ``P = c I - V V'`` (V: N x r, r < N) the nonzero
eigenvalues of ``V V'`` are those of the Gram matrix ``V' V`` (r x r), so
``P - floor I`` is positive definite exactly when ``(c - floor) I_r - V' V`` is
(:func:`lowrank_floor_check`; the eigenvalues of ``P`` off the range of V are
``c``). The caller keeps ``V' V`` up to date as V grows (O(N r m) per update instead
of O(N r^2) per check).

Round-off: a matrix whose ``lambda_min(P) - floor`` is within a few ``eps ||P||`` of 0
may be decided either way by either test, eigenvalues or Cholesky.

**Measured cost** (one check, ``OPENBLAS_NUM_THREADS=1``, shared 2-core AMD EPYC,
median of 300, µs)::

    N      eigvalsh   dpotrf   dpotrf + dtrtri (bound)
    16       11.5       2.4        7.2
    40       50.8       4.9       14.5
    64      108.3      10.4       33.5
    80      169.5      16.1       53.9
    213    1453.3     184.9     1018.3

**Incremental** (:func:`cholesky_extend`): the implicit form's V only grows by
blocks between resets, so ``V' V`` is bordered
(:func:`controller.lowrank_kernel.lowrank_append`) and the leading rows of
the Cholesky factor of ``(c - floor) I_r - V' V`` stand from check to check; each check
factors only the rows added since (a compiled row-oriented Cholesky, O(m r^2) per block
of m columns instead of LAPACK's O(r^3) and its argument copies). Its pivots differ
from ``dpotrf``'s in round-off only, so the two decide alike outside the round-off
band above; a failed pivot is decided again by :func:`lowrank_floor_check` (the
reason, floor or singular, is LAPACK's). Measured on the TE bench run (N = 213,
blocks of 5, r = 5..85; 4,235 checks in 48 h; shared 2-core AMD EPYC at load 4-7):
the covariance commit with its check 0.44-0.59 -> 0.23-0.32 ms per sample, see
:mod:`controller.adaptation`.

**Decisions against** ``numpy.linalg.eigvalsh`` (``tests/test_definiteness.py``):
the same on random SPD, near-singular (``lambda_min`` at 1e-12 of the scale),
indefinite and implicit ``c I - V V'`` matrices of N = 2 to 120, away from the
round-off band above; the bound never exceeds ``lambda_min``.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.linalg import lapack

__all__ = ["ABOVE", "FLOOR", "SINGULAR", "cholesky_extend", "floor_check",
           "lowrank_floor_check"]

#: Outcomes of a check: ``lambda_min > floor``; ``0 < lambda_min <= floor``;
#: ``lambda_min <= 0`` or non-finite entries.
ABOVE, FLOOR, SINGULAR = "above", "floor", "singular"


def _positive_definite(A: np.ndarray) -> tuple[bool, np.ndarray]:
    """``(True, L)`` when the symmetric ``A`` has a Cholesky factor ``L`` (lower)."""
    L, info = lapack.dpotrf(A, lower=1, clean=1, overwrite_a=0)
    return info == 0, L


def _bound_from_factor(L: np.ndarray) -> float:
    """``1 / ||A^-1||_F <= lambda_min(A)`` for ``A = L L'``; 0 when it cannot be formed."""
    Li, info = lapack.dtrtri(L, lower=1)
    if info != 0:
        return 0.0
    inv_fro = float(np.linalg.norm(Li.T @ Li))  # ||A^-1||_F
    return 1.0 / inv_fro if math.isfinite(inv_fro) and inv_fro > 0 else 0.0


def floor_check(P: np.ndarray, floor: float, *, want_bound: bool = False
                ) -> tuple[str, float]:
    """Decide ``lambda_min(P) > floor`` for a symmetric ``P`` by Cholesky.

    Parameters
    ----------
    P : ndarray, shape (N, N)
        Symmetric covariance (only its lower triangle is read).
    floor : float
        The reset floor (the seed: 1).
    want_bound : bool
        Also return a guaranteed lower bound on ``lambda_min(P)`` when it is above.

    Returns
    -------
    outcome : {"above", "floor", "singular"}
        ``"above"``: ``lambda_min(P) > floor``; ``"floor"``: ``P`` positive definite
        with ``lambda_min(P) <= floor``; ``"singular"``: not positive definite or
        non-finite.
    bound : float
        With ``want_bound`` and ``"above"``: ``floor < bound <= lambda_min(P)`` (or
        ``floor`` itself when the inverse is not representable); else ``floor``.
    """
    P = np.asarray(P, dtype=float)
    if not np.isfinite(P).all():
        return SINGULAR, floor
    ok, L = _positive_definite(P - floor * np.eye(P.shape[0]))
    if ok:
        return ABOVE, floor + _bound_from_factor(L) if want_bound else floor
    return (FLOOR if _positive_definite(P)[0] else SINGULAR), floor


def lowrank_floor_check(c: float, gram: np.ndarray, floor: float, *,
                        want_bound: bool = False) -> tuple[str, float]:
    """:func:`floor_check` for ``P = c I_N - V V'`` given the Gram matrix ``V' V``.

    Parameters
    ----------
    c : float
        Scale of the identity part (the last reset value).
    gram : ndarray, shape (r, r)
        ``V' V`` (r >= 0 columns, r < N).
    floor : float
    want_bound : bool

    Returns
    -------
    outcome, bound
        As :func:`floor_check`, for ``P``.
    """
    if not math.isfinite(c) or not np.isfinite(gram).all():
        return SINGULAR, floor
    r = gram.shape[0]
    if r == 0:
        if c > floor:
            return ABOVE, c
        return (FLOOR if c > 0 else SINGULAR), floor
    ok, L = _positive_definite((c - floor) * np.eye(r) - gram)
    if ok:
        bound = floor
        if want_bound:  # off the range of V the eigenvalues of P are c
            bound = min(c, floor + _bound_from_factor(L))
        return ABOVE, bound
    return (FLOOR if _positive_definite(c * np.eye(r) - gram)[0] and c > 0 else SINGULAR), floor


@njit(cache=True)
def cholesky_extend(L, G, start, stop, shift):  # pragma: no cover - compiled
    """Rows ``start .. stop-1`` of the lower Cholesky factor of ``shift I - G``.

    Rows before ``start`` are those of an earlier call on the same leading block (``G``
    only bordered since). Returns ``stop`` when every pivot is positive, else the row of
    the first pivot that is not (also NaN); rows from there on are not valid.

    Parameters
    ----------
    L : ndarray, shape (R, R)
        Factor buffer (lower triangle used).
    G : ndarray, shape (R, R)
        Symmetric; its lower triangle is read.
    start, stop : int
    shift : float
    """
    for i in range(start, stop):
        for j in range(i):
            s = -G[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
        pivot = shift - G[i, i]
        for k in range(i):
            pivot -= L[i, k] * L[i, k]
        if not pivot > 0.0:
            return i
        L[i, i] = math.sqrt(pivot)
    return stop
