"""State-space records and minimal realization.

A :class:`Realization` is the continuous-time model ``x' = A x + B u``,
``y = C x + D u`` with shapes ``A (nx, nx)``, ``B (nx, nu)``, ``C (ny, nx)``,
``D (ny, nu)``, in the time unit of whatever it came from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["Realization", "as_realization", "minimal_realization"]


def _matrix(value: ArrayLike, field: str) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{field}: not a numeric matrix ({exc})") from exc
    if arr.ndim == 1:
        arr = arr.reshape(1, -1) if field in ("C",) else arr.reshape(-1, 1)
    if arr.ndim != 2:
        raise ValueError(f"{field}: expected a 2-D matrix, got {arr.ndim} dimensions")
    if not np.isfinite(arr).all():
        raise ValueError(f"{field}: non-finite entries")
    return arr


@dataclass(frozen=True)
class Realization:
    """A continuous-time state-space model (A, B, C, D).

    Parameters
    ----------
    A : ndarray, shape (nx, nx)
    B : ndarray, shape (nx, nu)
    C : ndarray, shape (ny, nx)
    D : ndarray, shape (ny, nu)
        Zero when not given.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray

    def __post_init__(self) -> None:
        A = _matrix(self.A, "A")
        B = _matrix(self.B, "B")
        C = _matrix(self.C, "C")
        if A.shape[0] != A.shape[1]:
            raise ValueError(f"A: must be square, got shape {A.shape}")
        nx = A.shape[0]
        if B.shape[0] != nx:
            raise ValueError(f"B: expected {nx} rows (order of A), got shape {B.shape}")
        if C.shape[1] != nx:
            raise ValueError(f"C: expected {nx} columns (order of A), got shape {C.shape}")
        if self.D is None:
            D = np.zeros((C.shape[0], B.shape[1]))
        else:
            D = np.array(self.D, dtype=float)
            if D.ndim == 0:
                D = D.reshape(1, 1)
            D = _matrix(D, "D")
        if D.shape != (C.shape[0], B.shape[1]):
            raise ValueError(f"D: expected shape {(C.shape[0], B.shape[1])}, got {D.shape}")
        for name, arr in (("A", A), ("B", B), ("C", C), ("D", D)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def order(self) -> int:
        """Number of states nx."""
        return self.A.shape[0]

    @property
    def n_inputs(self) -> int:
        return self.B.shape[1]

    @property
    def n_outputs(self) -> int:
        return self.C.shape[0]

    def poles(self) -> np.ndarray:
        """Eigenvalues of A, shape (nx,)."""
        return np.linalg.eigvals(self.A)

    def is_stable(self) -> bool:
        """True when every eigenvalue of A has a negative real part."""
        return bool(self.order == 0 or np.max(self.poles().real) < 0)

    def frequency_response(self, omega: ArrayLike) -> np.ndarray:
        """H(j omega) = C (j omega I - A)^-1 B + D, shape (len(omega), ny, nu)."""
        w = np.atleast_1d(np.asarray(omega, dtype=float))
        eye = np.eye(self.order)
        out = np.empty((w.size, self.n_outputs, self.n_inputs), dtype=complex)
        for i, wi in enumerate(w):
            out[i] = self.C @ np.linalg.solve(1j * wi * eye - self.A, self.B) + self.D
        return out

    def dc_gain(self) -> np.ndarray:
        """H(0) = D - C A^-1 B, shape (ny, nu); A must be nonsingular."""
        return self.D - self.C @ np.linalg.solve(self.A, self.B)

    def to_control(self):
        """The same model as a :class:`control.StateSpace`."""
        import control

        return control.ss(self.A, self.B, self.C, self.D)


def as_realization(A, B=None, C=None, D=None) -> Realization:
    """Accept a :class:`Realization`, an object with A, B, C, D attributes
    (e.g. ``control.StateSpace`` or a linearization record), or four matrices."""
    if B is None and C is None:
        if isinstance(A, Realization):
            return A
        if all(hasattr(A, k) for k in ("A", "B", "C")):
            return Realization(A.A, A.B, A.C, getattr(A, "D", None))
        raise ValueError("A: expected a Realization-like object or the matrices A, B, C")
    if B is None or C is None:
        raise ValueError("B, C: both are needed together with A")
    return Realization(A, B, C, D)


def minimal_realization(A, B=None, C=None, D=None, tol: float | None = None) -> Realization:
    """Remove uncontrollable and unobservable modes (SLICOT TB01PD through slycot).

    The call ``control.minreal`` makes, without importing python-control (which pulls in
    scipy.signal and matplotlib: seconds at a node's start-up).

    Parameters
    ----------
    A, B, C, D : array_like or Realization
        See :func:`as_realization`.
    tol : float, optional
        Rank tolerance of TB01PD (passed as ``control.minreal`` passes it).

    Returns
    -------
    Realization
        A minimal (controllable and observable) realization of the same transfer
        matrix; its order is the McMillan degree.
    """
    from slycot import tb01pd

    sys = as_realization(A, B, C, D)
    if sys.order == 0:
        return sys
    n, m, p = sys.order, sys.n_inputs, sys.n_outputs
    # TB01PD works on B and C padded to max(m, p) columns / rows
    b = np.empty((n, max(m, p)))
    b[:, :m] = sys.B
    c = np.empty((max(p, m), n))
    c[:p, :] = sys.C
    a, b, c, nr = tb01pd(n, m, p, np.array(sys.A, dtype=float), b, c, tol=tol)
    return Realization(np.array(a[:nr, :nr]), np.array(b[:nr, :m]), np.array(c[:p, :nr]),
                       np.array(sys.D, dtype=float))
