"""Coordinates of the shared state: the designer pair (F_i, g_i) of one block.

The state-shared structure of seed eq. 3.10 does not depend on the coordinates
of the designer pair: for any invertible T, ``(T F_i T^-1, T g_i)`` keeps one
shared state driven by u and y, and every model stays a linear read-out
``Theta_j`` of it (``Theta -> (I (x) T^-T) Theta``; the block structure of
Theta2, D(s) = d(s) I, is kept). Two coordinates are offered:

``"companion"``
    The seed's block-companion pair (eq. 3.12-3.13), built from omega's
    coefficients: the state holds ``s^k / omega(s)`` and Theta the polynomial
    coefficients of the left MFD (eq. 3.14-3.16). Ill conditioned beyond
    n ~ 10 (see the limits table in :mod:`controller.state_shared`).
``"orthonormal"``
    Generalized orthonormal basis functions (Takenaka-Malmquist / Kautz;
    Ninness & Gustafsson 1997, Heuberger, Van den Hof & Wahlberg 2005) built
    from omega's *roots*: a cascade of first-order all-pass sections (real
    roots) and second-order ones (complex pairs), whose state-space pair is in
    input-normal form, ``F + F^T + g g^T = 0``, i.e. controllability Gramian
    = I. The n basis functions ``(sI - F)^-1 g`` are orthonormal in H2 and
    span exactly the same space as ``s^k / omega(s)``, so the same models are
    represented; with white input their covariance is the identity, which is
    what normalized least squares wants. Scaling time by c scales every Theta
    by sqrt(c): the conditioning does not depend on the time unit.

Theta in the orthonormal basis is solved for from the model itself
(:func:`orthonormal_theta`), never through monomial coefficients: with d the
model's common denominator (characteristic polynomial of its realization,
padded to degree n), ``1 - theta2' phi(s) = d(s)/omega(s)`` and
``Theta1_ij' phi(s) = d(s)/omega(s) H_ij(s)``. Both right-hand sides are
evaluated pointwise on the imaginary axis as products of ratios
``(s - lambda_i)/(s - mu_i)`` (no polynomial is ever formed) and both lie
exactly in the span of phi, so a weighted linear least-squares solve on a
logarithmic frequency grid (log-trapezoid weights, so the sampled Gram
matrix approximates the identity; its condition number is 1.01-1.05 for
n = 10-40 and root spreads 10-1000, measured) recovers Theta to rounding
level.

**Numerical limits (measured, double precision, m = 5, random stable models with
roots spread geometrically over R = |fastest| / |slowest|, omega's roots 1.1 x
the model's).** Relative error of the state-shared frequency response against
the model's own over 2 decades beyond the poles on each side (order 2nm)::

    basis        R     n = 10    n = 20    n = 30    n = 40 (order 400)
    orthonormal  10    1e-14     5e-14     2e-13     5e-13
    orthonormal  100   2e-14     1e-13     3e-13     5e-13
    orthonormal  1000  2e-14     1e-13     3e-13     6e-13
    companion    10    1e-11     2e-5      6e1       3e7
    companion    100   3e-8      2e3       1e13      4e24

**Adaptation.** Normalized least squares (eq. 4.1) on the same data converges at least
as fast in the orthonormal basis (in-class identification of the CSTR and the two-phase
reactor from the other grade's model, ``tests/test_shared_basis_adaptation.py``: e.g. the
reactor's frequency-response error 2.0e-7 vs 4.1e-7 after 4000 samples, the CSTR's
3.3e-2 vs 1.0e-1 after 250) as long as the covariance is not reset. The reset rule
(``lambda_min(P) < eig_floor``) compares with an absolute number, and the orthonormal
regressors are larger (|n| ~ sqrt(sum 2/|mu_k|) against 1/a1 for the companion's first
entry): with kappa = 1000, floor 1e-3 the reactor's covariance was reset 1878 times
instead of 1096 in 4000 samples and its error stayed at 2.4e-2 instead of 9.4e-4. Scale
``eig_floor`` with the regressor when changing the basis.

(the orthonormal rows are reproduced by ``tests/test_shared_basis.py``, the
companion rows by the stored table in ``tests/test_state_shared_limits.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["BASES", "SharedBasis", "companion_block", "finite_vector", "hurwitz_coefficients",
           "orthonormal_block", "orthonormal_theta", "band_roots",
           "roots_from_poles"]

BASES = ("companion", "orthonormal")

#: frequency grid of the Theta solve: decades beyond omega's slowest/fastest root,
#: points per decade
_GRID_MARGIN_DECADES = 2.0
_GRID_PER_DECADE = 20
#: a Theta solve whose relative residual exceeds this is refused (the target is
#: outside the basis' span: the model's degree exceeds n, or it was not strictly proper)
_FIT_RESIDUAL_MAX = 1e-8



def finite_vector(value: ArrayLike, n: int | None, field: str) -> np.ndarray:
    """``value`` as a finite float vector (of length ``n`` if given); ValueError naming
    ``field`` otherwise."""
    try:
        arr = np.array(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{field}: not a numeric vector ({exc})") from exc
    if n is not None and arr.size != n:
        raise ValueError(f"{field}: expected length {n}, got {arr.size}")
    if not np.isfinite(arr).all():
        bad = [int(i) for i in np.flatnonzero(~np.isfinite(arr))]
        raise ValueError(f"{field}: non-finite value at index {bad}")
    return arr


def hurwitz_coefficients(a: ArrayLike, field: str = "a") -> np.ndarray:
    """Validate omega's coefficients (a1..an, lowest power first); return them."""
    a = finite_vector(a, None, field)
    if a.size == 0:
        raise ValueError(f"{field}: the designer polynomial needs degree >= 1 (empty)")
    roots = np.roots(np.concatenate(([1.0], a[::-1])))
    if not np.all(roots.real < 0):
        worst = roots[np.argmax(roots.real)]
        raise ValueError(
            f"{field}: omega(s) = s^{a.size} + ... is not Hurwitz (root {worst:.6g} "
            "not in the open left half plane); F must be asymptotically stable"
        )
    return a


def companion_block(a: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """One companion block (F_i, g_i) of eq. 3.12-3.13, shapes (n, n) and (n,).

    ``F_i`` has ones on the superdiagonal and last row ``-(a1, ..., an)``;
    ``g_i = e_n``. Then ``(sI - F_i)^-1 g_i = [1, s, ..., s^(n-1)]^T / omega(s)``.
    """
    a = hurwitz_coefficients(a)
    n = a.size
    Fb = np.zeros((n, n))
    Fb[np.arange(n - 1), np.arange(1, n)] = 1.0
    Fb[-1, :] = -a
    gb = np.zeros(n)
    gb[-1] = 1.0
    return Fb, gb

def _roots(value: ArrayLike, field: str = "roots") -> np.ndarray:
    try:
        r = np.atleast_1d(np.asarray(value, dtype=complex)).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{field}: not a numeric vector ({exc})") from exc
    if r.size == 0:
        raise ValueError(f"{field}: the designer polynomial needs degree >= 1 (empty)")
    if not np.isfinite(r).all():
        raise ValueError(f"{field}: non-finite root")
    if not np.all(r.real < 0):
        worst = r[np.argmax(r.real)]
        raise ValueError(f"{field}: root {worst:.6g} not in the open left half plane; "
                         "F must be asymptotically stable")
    return r


def _pair_roots(r: np.ndarray, field: str = "roots") -> list[complex]:
    """Real roots and the upper member of each conjugate pair, in the given order."""
    out, used = [], np.zeros(r.size, bool)
    for i, x in enumerate(r):
        if used[i]:
            continue
        used[i] = True
        if abs(x.imag) <= 1e-12 * abs(x):
            out.append(complex(x.real, 0.0))
            continue
        mates = [k for k in range(r.size)
                 if not used[k] and abs(r[k] - np.conj(x)) <= 1e-9 * abs(x)]
        if not mates:
            raise ValueError(f"{field}: complex roots must come in conjugate pairs "
                             f"({x:.6g} has no mate)")
        used[mates[0]] = True
        out.append(complex(x.real, abs(x.imag)))
    return out


def orthonormal_block(roots: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Input-normal pair (F_i, g_i) of the all-pass cascade with poles ``roots``.

    Section k (real root -l: ``A_k = -l``, ``b_k = sqrt(2 l)``; complex pair
    a +- jw: ``A_k = [[2a, |r|], [-|r|, 0]]``, ``b_k = (2 sqrt(-a), 0)``) is fed
    by the all-pass output of the sections before it, ``w_k = w_(k-1) - b_k' x_k``,
    ``w_0 = u``. Then ``F[k, k] = A_k``, ``F[k, j] = -b_k b_j'`` (j < k),
    ``g = [b_1; ...]`` and ``F + F' + g g' = 0`` exactly.

    Parameters
    ----------
    roots : array_like, shape (n,)
        Roots of omega, open left half plane; complex ones in conjugate pairs.

    Returns
    -------
    F : ndarray, shape (n, n)
    g : ndarray, shape (n,)
    """
    sections = []
    for r in _pair_roots(_roots(roots)):
        if r.imag == 0.0:
            lam = -r.real
            sections.append((np.array([[-lam]]), np.array([math.sqrt(2.0 * lam)])))
        else:
            a, w = r.real, abs(r)
            sections.append((np.array([[2.0 * a, w], [-w, 0.0]]),
                             np.array([2.0 * math.sqrt(-a), 0.0])))
    n = sum(s[0].shape[0] for s in sections)
    F, g = np.zeros((n, n)), np.zeros(n)
    rows, o = [], 0
    for A, b in sections:
        k = A.shape[0]
        F[o:o + k, o:o + k] = A
        g[o:o + k] = b
        rows.append(slice(o, o + k))
        o += k
    for k in range(len(sections)):
        for j in range(k):
            F[rows[k], rows[j]] = -np.outer(sections[k][1], sections[j][1])
    return F, g


def roots_from_poles(poles: ArrayLike) -> np.ndarray:
    """omega's roots from a model's poles: the poles, unstable ones reflected into the
    left half plane (``-|Re| + j Im``), poles on the imaginary axis moved to
    ``Re = -1e-6 |p|``.

    The choice that keeps Theta small: ``||theta2||_H2 = ||d/omega - 1||_H2``, which is
    zero for the model whose poles omega holds, and stays O(1) for models whose poles
    moved moderately (the Tennessee Eastman grades: |Theta| 6..2e5 at n = 40). A
    geometric spread over the band (:func:`band_roots`) is a poor choice for models whose
    poles cluster: d/omega = prod (s - lambda_i)/(s - mu_i) then reaches 1e11 on
    the TE models at n = 40 and the representation is lost.
    """
    lam = np.asarray(poles, dtype=complex).reshape(-1)
    if lam.size == 0 or not np.isfinite(lam).all():
        raise ValueError("poles: need a non-empty finite vector")
    re = -np.maximum(np.abs(lam.real), 1e-6 * np.abs(lam))
    if np.any(np.abs(lam) == 0):
        raise ValueError("poles: a pole at s = 0 has no stable image; give omega's roots")
    out = re + 1j * lam.imag
    out[np.abs(lam.imag) <= 1e-12 * np.abs(lam)] = re[np.abs(lam.imag) <= 1e-12 * np.abs(lam)]
    return out


def band_roots(poles: ArrayLike, n: int, *, lo: float | None = None,
               hi: float | None = None) -> np.ndarray:
    """n real roots spread geometrically over the band of ``poles`` (their magnitudes).

    ``lo``/``hi`` (> 0) override the band's ends. Returns negative reals, slowest first.
    """
    mag = np.abs(np.asarray(poles, dtype=complex).reshape(-1))
    mag = mag[np.isfinite(mag) & (mag > 0)]
    if mag.size == 0 and (lo is None or hi is None):
        raise ValueError("poles: need at least one finite nonzero pole (or lo and hi)")
    lo = float(mag.min()) if lo is None else float(lo)
    hi = float(mag.max()) if hi is None else float(hi)
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise ValueError(f"lo, hi: need 0 < lo <= hi, got {lo}, {hi}")
    if isinstance(n, bool) or not isinstance(n, int | np.integer) or n < 1:
        raise ValueError(f"n: must be a positive integer, got {n!r}")
    return -np.geomspace(lo, hi, int(n)) if n > 1 else np.array([-math.sqrt(lo * hi)])


@dataclass(frozen=True, eq=False)
class SharedBasis:
    """The designer pair of one block and the coordinates it is written in.

    Build with :meth:`companion` (omega's coefficients, the seed's form) or
    :meth:`orthonormal` (omega's roots).

    Attributes
    ----------
    kind : {"companion", "orthonormal"}
    a : ndarray, shape (n,)
        omega's coefficients, lowest power first (for ``"orthonormal"`` computed
        from the roots, for information only: nothing is computed from them).
    roots : ndarray of complex, shape (n,) or None
        omega's roots (``"orthonormal"``).
    Fb, gb : ndarray, shapes (n, n), (n,)
        The block pair.
    steady : ndarray, shape (n,)
        Block state in equilibrium with a constant unit input, ``-Fb^-1 gb``.
    """

    kind: str
    a: np.ndarray
    roots: np.ndarray | None
    Fb: np.ndarray
    gb: np.ndarray
    steady: np.ndarray

    @property
    def n(self) -> int:
        return self.gb.size

    @classmethod
    def companion(cls, a: ArrayLike) -> SharedBasis:
        """The seed's companion block (eq. 3.12-3.13) of ``omega`` with coefficients a."""
        Fb, gb = companion_block(a)
        a = np.array(-Fb[-1], dtype=float)
        steady = np.zeros(a.size)
        steady[0] = 1.0 / a[0]
        return cls._frozen("companion", a, None, Fb, gb, steady)

    @classmethod
    def orthonormal(cls, roots: ArrayLike) -> SharedBasis:
        """The input-normal all-pass cascade (:func:`orthonormal_block`) of omega's roots."""
        r = _roots(roots)
        pairs = _pair_roots(r)
        full = np.array([x for p in pairs for x in ((p,) if p.imag == 0 else (p, p.conjugate()))])
        Fb, gb = orthonormal_block(full)
        a = np.poly(full).real[1:][::-1].copy()
        return cls._frozen("orthonormal", a, full, Fb, gb, -np.linalg.solve(Fb, gb))

    @classmethod
    def of(cls, a: ArrayLike | SharedBasis, basis: str = "companion") -> SharedBasis:
        """A basis from ``a`` (a SharedBasis is returned as is; coefficients are read
        as omega's with ``basis`` the coordinates; for ``"orthonormal"`` the roots
        are computed from them, fine at low degree; pass roots via
        :meth:`orthonormal` above n ~ 10)."""
        if isinstance(a, SharedBasis):
            return a
        if basis not in BASES:
            raise ValueError(f"basis: must be one of {BASES}, got {basis!r}")
        if basis == "companion":
            return cls.companion(a)
        comp = cls.companion(a)  # validates a (Hurwitz)
        return cls.orthonormal(np.roots(np.concatenate(([1.0], comp.a[::-1]))))

    @classmethod
    def _frozen(cls, kind, a, roots, Fb, gb, steady) -> SharedBasis:
        for arr in (a, roots, Fb, gb, steady):
            if arr is not None:
                arr.setflags(write=False)
        return cls(kind, a, roots, Fb, gb, steady)

    def same_as(self, other: SharedBasis) -> bool:
        """Same kind and the same omega (coefficients, or roots), exactly."""
        if not isinstance(other, SharedBasis) or other.kind != self.kind:
            return False
        if self.kind == "companion":
            return self.a.shape == other.a.shape and bool(np.all(self.a == other.a))
        return self.roots.shape == other.roots.shape and bool(np.all(self.roots == other.roots))

    def from_companion(self) -> np.ndarray:
        """T (n x n) with ``n_this = T n_companion`` for the same omega, ``T = K K_c^-1``
        with K the Krylov matrix ``[g, F g, ..., F^(n-1) g]`` of each pair.

        Exact in principle, ill conditioned like the companion basis itself: for the
        coefficient readings of small models (n <= ~10, e.g. the SISO units' n = 2).
        """
        if self.kind == "companion":
            return np.eye(self.n)
        Fc, gc = companion_block(self.a)
        K, Kc = np.empty((self.n, self.n)), np.empty((self.n, self.n))
        K[:, 0], Kc[:, 0] = self.gb, gc
        for i in range(1, self.n):
            K[:, i] = self.Fb @ K[:, i - 1]
            Kc[:, i] = Fc @ Kc[:, i - 1]
        return np.linalg.solve(Kc.T, K.T).T

    def basis_functions(self, s: ArrayLike) -> np.ndarray:
        """``phi(s) = (sI - Fb)^-1 gb`` at complex points s, shape (len(s), n)."""
        s = np.atleast_1d(np.asarray(s, dtype=complex))
        eye = np.eye(self.n)
        return np.array([np.linalg.solve(x * eye - self.Fb, self.gb) for x in s])

    def to_dict(self) -> dict:
        """JSON form (kind and omega's roots, or coefficients)."""
        if self.kind == "companion":
            return {"kind": "companion", "a": self.a.tolist()}
        return {"kind": "orthonormal", "roots": [[float(x.real), float(x.imag)]
                                                  for x in self.roots]}

    @classmethod
    def from_dict(cls, d: dict) -> SharedBasis:
        if not isinstance(d, dict) or d.get("kind") not in BASES:
            raise ValueError(f"basis: expected a dict with kind in {BASES}, got {d!r}")
        if d["kind"] == "companion":
            return cls.companion(d["a"])
        try:
            r = np.array([complex(re, im) for re, im in d["roots"]])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"basis.roots: expected [[re, im], ...] ({exc})") from exc
        return cls.orthonormal(r)


def _frequency_grid(roots: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Log-spaced frequencies (rad per time unit) and sqrt of the log-trapezoid weights."""
    mag = np.abs(roots)
    lo = float(mag.min()) * 10.0 ** -_GRID_MARGIN_DECADES
    hi = float(mag.max()) * 10.0 ** _GRID_MARGIN_DECADES
    k = int(math.ceil(_GRID_PER_DECADE * math.log10(hi / lo))) + 1
    w = np.geomspace(lo, hi, k)
    step = math.log(w[1] / w[0])
    return w, np.sqrt(w * step / math.pi)


def _ratio(s: np.ndarray, num_roots: np.ndarray, den_roots: np.ndarray) -> np.ndarray:
    """prod (s - z_i) / (s - p_i) at points s, pairing roots by magnitude (no overflow)."""
    z = num_roots[np.argsort(np.abs(num_roots), kind="stable")]
    p = den_roots[np.argsort(np.abs(den_roots), kind="stable")]
    out = np.ones(s.size, dtype=complex)
    for zi, pi in zip(z, p):
        out *= (s - zi) / (s - pi)
    return out


def orthonormal_theta(basis: SharedBasis, A, B, C, *, pad_root: float | None = None,
                      square: bool = True) -> np.ndarray:
    """Theta (n(m+p) x p) of the realization ``(A, B, C)`` (D = 0) in ``basis``.

    Parameters
    ----------
    basis : SharedBasis
        Orthonormal (``kind == "orthonormal"``).
    A, B, C : array_like, shapes (nx, nx), (nx, m), (p, nx)
        Strictly proper model; its McMillan degree at most n (the realization is
        made minimal when nx > n).
    pad_root : float, optional
        When the degree is below n, the common denominator is padded with
        ``(s + pad_root)``; default: omega's own roots that are left over (an
        exact cancellation with the same effect).
    square : bool
        Require p == m (the seed's case).

    Returns
    -------
    theta : ndarray, shape (n(m+p), p)
        Same layout as :func:`controller.state_shared.theta_from_mfd`: Theta1 rows
        ``j n + k`` for input j, Theta2 block diagonal with one n-vector.

    Raises
    ------
    ValueError
        Wrong shapes, degree above n, non-finite entries, a residual of the solve
        above 1e-8 (the model is not in the basis' span).
    """
    from controller.linear.realization import as_realization, minimal_realization

    if not isinstance(basis, SharedBasis) or basis.kind != "orthonormal":
        raise ValueError("basis: orthonormal_theta needs an orthonormal SharedBasis")
    sys = as_realization(A, B, C)
    if np.any(sys.D != 0):
        raise ValueError("D: the state-shared form needs a strictly proper model (D = 0)")
    n = basis.n
    if sys.order > n:
        sys = minimal_realization(sys.A, sys.B, sys.C)
    p, m = sys.n_outputs, sys.n_inputs
    if p != m and square:
        raise ValueError(f"model: the state-shared form needs a square model (as many outputs "
                         f"as inputs); got {p} outputs x {m} inputs (square=False allows it)")
    if sys.order > n:
        raise ValueError(f"model: McMillan degree {sys.order} exceeds the designer "
                         f"polynomial's degree n = {n}; choose n >= every model's degree")
    lam = np.linalg.eigvals(sys.A) if sys.order else np.zeros(0, complex)
    if lam.size < n:
        if pad_root is not None:
            if not (math.isfinite(pad_root) and pad_root > 0):
                raise ValueError(f"pad_root: must be finite and > 0, got {pad_root}")
            extra = np.full(n - lam.size, -float(pad_root), dtype=complex)
        else:  # omega's roots farthest from the model's poles cancel exactly
            extra = _leftover_roots(basis.roots, lam, n - lam.size)
        lam = np.concatenate((lam, extra))
    w, sw = _frequency_grid(basis.roots)
    s = 1j * w
    ratio = _ratio(s, lam, basis.roots)  # d(s)/omega(s)
    eye = np.eye(sys.order)
    H = np.array([sys.C @ np.linalg.solve(x * eye - sys.A, sys.B) for x in s])  # (K, p, m)
    Phi = basis.basis_functions(s) * sw[:, None]
    rhs = np.concatenate((-(ratio - 1.0)[:, None], (ratio[:, None, None] * H).reshape(s.size, -1)),
                         axis=1) * sw[:, None]
    M = np.vstack((Phi.real, Phi.imag))
    Y = np.vstack((rhs.real, rhs.imag))
    X, *_ = np.linalg.lstsq(M, Y, rcond=None)
    resid = np.linalg.norm(M @ X - Y, axis=0)
    # relative to each column's size; a column that is (nearly) zero (theta2 when the
    # model's poles are omega's, a zero entry of H) against the size of d/omega, or of
    # the largest numerator column
    norms = np.linalg.norm(Y, axis=0)
    floor = np.empty_like(norms)
    floor[0] = np.linalg.norm(ratio * sw)
    floor[1:] = 1e-6 * max(float(norms[1:].max(initial=0.0)), np.finfo(float).tiny)
    scale = np.maximum(np.maximum(norms, floor), np.finfo(float).tiny)
    worst = float(np.max(resid / scale))
    if not np.isfinite(X).all() or worst > _FIT_RESIDUAL_MAX:
        raise ValueError(f"model: not representable in this basis (relative residual "
                         f"{worst:.2g} of the Theta solve); is the model strictly proper "
                         f"with degree <= n = {n}?")
    t2, N = X[:, 0], X[:, 1:].reshape(n, p, m)
    theta = np.zeros((n * (m + p), p))
    theta[: n * m] = N.transpose(2, 0, 1).reshape(n * m, p)  # row j n + k, column i
    for i in range(p):
        theta[n * m + i * n : n * m + (i + 1) * n, i] = t2
    return theta


def _leftover_roots(roots: np.ndarray, lam: np.ndarray, k: int) -> np.ndarray:
    """k of omega's roots (conjugate pairs kept together) farthest from the poles lam."""
    dist = [float(np.min(np.abs(r - lam))) / abs(r) if lam.size else 1.0 for r in roots]
    order = np.argsort(dist)[::-1]
    out: list[complex] = []
    for i in order:
        if len(out) >= k:
            break
        r = roots[i]
        if r.imag == 0:
            out.append(r)
        elif r.imag > 0 and len(out) + 2 <= k:
            out.extend((r, r.conjugate()))
    if len(out) < k:  # only pairs left and an odd count: a real root at the slowest magnitude
        out.extend([-float(np.min(np.abs(roots)))] * (k - len(out)))
    return np.asarray(out, dtype=complex)
