"""The state-shared model of seed chapter 3 (eq. 3.10-3.16).

All models share one non-minimal state ``n = [n1; n2]`` driven by the measured
inputs and outputs (eq. 3.10)::

    n1' = F n1 + G u,     n2' = F n2 + G y,     y_j = Theta_j^T n + b_j

``(F, G)`` is the designer's block-companion pair built from a Hurwitz
polynomial ``omega(s) = s^n + a_n s^(n-1) + ... + a_2 s + a_1`` (eq. 3.12-3.13);
each model j is only a measurement matrix ``Theta_j`` (2nm x m), which follows
uniquely from model j's left MFD ``H_j(s) = d_j(s)^-1 N_j(s)`` (eq. 3.14-3.16).

**Extension of the seed: the bias b_j.** The seed's models are deviation
models about one point. Here each linearization holds about its own operating
point (u_j*, y_j*) while the shared state is driven by absolute u and y, so
every model carries an affine offset ``b_j = y_j* - Theta_j^T n_ss(u_j*, y_j*)``,
with ``n_ss`` the steady shared state for constant (u, y). At its own steady
state each model then reproduces y_j* exactly.

**Sampling.** The state is advanced once per sample of length ``dt`` with u
and y held over the sample (zero-order hold): ``n1 <- Fd n1 + Gd u``,
``n2 <- Fd n2 + Gd y`` with ``(Fd, Gd)`` the exact ZOH discretization of
``(F, G)``. After ``update(u_k, y_k)`` the state is ``n(t_(k+1))``, so
``estimates()`` are the models' values of y at the *next* sample; compare them
with ``y_(k+1)`` (call :meth:`errors` before the next update).

For prediction (MPC) each model closes the loop through its own output:
:meth:`sampled_form` is exactly the sampled update fed with the model's own
estimate (cheap, consistent with how the state moves), :meth:`prediction_form`
the exact ZOH discretization of the continuous model (one matrix exponential,
cached). They differ by O(dt) in the n2 coupling.

Coefficient vectors are **lowest power first**: ``a = (a1, ..., an)`` with a1
the constant term, as printed in the seed.

**Coordinates.** ``(F, G)`` may also be written in orthonormal coordinates
(``basis="orthonormal"`` or a :class:`SharedBasis` from omega's roots; see
:mod:`controller.shared_basis`): the same shared state up to an invertible
change of coordinates, every model still a read-out Theta_j with the same
block structure, so parameters, regressor, adaptation and prediction forms
work unchanged. Coefficient-specific readings (``mfd_from_theta``, "theta2 =
a - d") hold in the companion basis only.

**Numerical limits (measured, double precision).** In the companion basis Theta
holds polynomial coefficients and the shared state the signals
``s^k/omega(s) u``, so the representation itself, not only its computation,
degrades with the degree n and with the spread R = |fastest pole| / |slowest
pole| of the models and omega (time unit chosen so the poles are O(1)).
Relative error of the state-shared frequency response against the model's own
(m = 5, random stable models, omega with roots spread like the model's)::

    companion    R = 3:    n = 10: 3e-13   n = 20: 9e-9    n = 30: 2e-4    n = 40: 0.8
                 R = 10:   n = 10: 6e-12   n = 15: 6e-9    n = 20: 6e-6    n = 30: 34
                 R = 100:  n = 5: 1e-13    n = 10: 3e-8    n = 15: 3e-3    n = 20: 8e2
    orthonormal  R = 10:   n = 10: 1e-14   n = 20: 4e-14   n = 30: 1e-13   n = 40: 5e-13
                 R = 100:  n = 10: 3e-13   n = 20: 6e-14   n = 30: 2e-13   n = 40: 5e-13
                 R = 1000: n = 10: 1e-13   n = 20: 1e-13   n = 30: 3e-13   n = 40: 1e-12

(re-measured on fresh draws: companion R = 10: 2e-11, 1e-8, 8e-6, 10;
R = 100: 3e-12, 4e-8, 7e-3, 5e2; R = 1000: n = 10: 1e-4, n = 15: 2e3;
``tests/test_state_shared_limits.py`` holds the stored companion table.)
The seed's TE model (n = 40, order 400, R7.15) is not representable in the
companion basis; in the orthonormal basis with omega's roots at one grade's
poles it is, to 1e-11 (:mod:`controller.units.te.linear_models`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg
from numpy.typing import ArrayLike

from controller.finite_kernel import all_finite
from controller.linear.mfd import LeftMFD, left_mfd
from controller.packing import pack_array, unpack_array
from controller.shared_basis import (
    BASES,
    SharedBasis,
    companion_block,
    finite_vector,
    hurwitz_coefficients,
    orthonormal_theta,
)
from controller.state_kernel import advance_state, model_errors, write_params
from controller.state_kernel import regressor as state_regressor

_F8 = np.dtype(np.float64)

__all__ = [
    "companion_pair",
    "companion_block",
    "designer_polynomial",
    "LeftMFD",
    "left_mfd",
    "theta_from_mfd",
    "mfd_from_theta",
    "ModelSpec",
    "PredictionForm",
    "StateSharedModel",
    "MODEL_KINDS",
    "BASES",
    "SharedBasis",
]

MODEL_KINDS = ("fixed", "adaptive")


def designer_polynomial(roots: ArrayLike) -> np.ndarray:
    """Coefficients ``a = (a1, ..., an)`` (lowest power first) of prod (s - r_i).

    Complex roots must come in conjugate pairs. Convenience for choosing omega.
    """
    r = np.atleast_1d(np.asarray(roots, dtype=complex))
    c = np.poly(r)
    if np.max(np.abs(c.imag)) > 1e-9 * max(1.0, np.max(np.abs(c.real))):
        raise ValueError("roots: complex roots must come in conjugate pairs")
    return hurwitz_coefficients(c.real[1:][::-1], "roots")


def companion_pair(a: ArrayLike, m: int) -> tuple[np.ndarray, np.ndarray]:
    """The designer's pair (F, G) of eq. 3.12-3.13.

    Parameters
    ----------
    a : array_like, shape (n,)
        ``(a1, ..., an)``: ``omega(s) = s^n + a_n s^(n-1) + ... + a_2 s + a_1``
        (lowest power first). Must be Hurwitz.
    m : int
        Number of inputs = number of outputs.

    Returns
    -------
    F : ndarray, shape (n m, n m)
        blockdiag of m companion blocks.
    G : ndarray, shape (n m, m)
        blockdiag of m columns e_n.

    Raises
    ------
    ValueError
        If omega is not Hurwitz, ``a`` is empty or non-finite, or ``m < 1``.
    """
    m = _positive_int(m, "m")
    Fb, gb = companion_block(a)
    return np.kron(np.eye(m), Fb), np.kron(np.eye(m), gb[:, None])


def _positive_int(value, field: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{field}: must be a positive integer, got {value!r}")
    return int(value)


def theta_from_mfd(mfd: LeftMFD, a: ArrayLike, *, pad_root: float | None = None,
                   square: bool = True) -> np.ndarray:
    """Theta (2nm x m) of eq. 3.16 from a left MFD ``d(s)^-1 N(s)`` (eq. 3.14-3.15).

    ``Theta = [Theta1; Theta2]``. Theta1 (nm x m) holds the numerator
    coefficients: ``Theta1[j n + k, i] = N[i, j, k]`` (output i, input j, power
    s^k). Theta2 (nm x m) is block diagonal with the same column
    ``a - d[:n]`` (``theta2_i = a_i - d_i``) in every block.

    Parameters
    ----------
    mfd : LeftMFD
        Square (m x m), strictly proper (D0 = 0), degree of d at most n.
        With ``square=False`` a p x m MFD gives Theta of shape (n(m+p), p)
        (an extension of the seed: n1 is driven by the m inputs, n2 by the p
        outputs, D(s) = d(s) I_p).
    a : array_like, shape (n,)
        Designer polynomial coefficients (lowest power first).
    pad_root : float, optional
        When deg d < n, multiply d and N by ``(s + pad_root)^(n - deg d)``
        (a stable pole-zero cancellation) to reach degree n. Without it a
        lower degree is an error.

    Raises
    ------
    ValueError
        Non-square MFD, nonzero feedthrough, degree above n (or below without
        ``pad_root``), non-Hurwitz omega.
    """
    a = hurwitz_coefficients(a)
    n = a.size
    if not isinstance(mfd, LeftMFD):
        raise ValueError(f"mfd: expected a LeftMFD, got {type(mfd).__name__}")
    p, m = mfd.shape
    if p != m and square:
        raise ValueError(
            f"mfd: the state-shared form needs a square model (as many outputs as "
            f"inputs); got {p} outputs x {m} inputs (square=False allows it)"
        )
    if np.any(mfd.D0 != 0):
        raise ValueError("mfd.D0: the state-shared form needs a strictly proper model (D = 0)")
    d, N = mfd.d, mfd.N
    deg = mfd.degree
    if deg > n:
        raise ValueError(
            f"mfd.d: degree {deg} exceeds the designer polynomial's degree n = {n}; "
            "choose n >= the McMillan degree of every model"
        )
    if deg < n:
        if pad_root is None:
            raise ValueError(
                f"mfd.d: degree {deg} is below n = {n}; pass pad_root > 0 to pad with "
                "a stable cancelling factor"
            )
        if not (math.isfinite(pad_root) and pad_root > 0):
            raise ValueError(f"pad_root: must be finite and > 0, got {pad_root}")
        q = np.array([1.0])
        for _ in range(n - deg):
            q = np.convolve(q, [pad_root, 1.0])  # (s + r), lowest power first
        d = np.convolve(d, q)
        Np = np.zeros((p, m, n))
        for i in range(p):
            for j in range(m):
                Np[i, j] = np.convolve(np.concatenate((N[i, j], [0.0])), q)[:n]
        N = Np
    theta = np.zeros((n * (m + p), p))
    # Theta1[j*n + k, i] = N[i, j, k]
    theta[: n * m, :] = N.transpose(1, 2, 0).reshape(n * m, p)
    t2 = a - d[:n]
    for i in range(p):
        theta[n * m + i * n : n * m + (i + 1) * n, i] = t2
    return theta


def mfd_from_theta(theta: ArrayLike, a: ArrayLike, m: int, p: int | None = None) -> LeftMFD:
    """Inverse of :func:`theta_from_mfd` for a structured Theta (eq. 3.16 read backwards).

    ``m`` inputs, ``p`` outputs (default m).
    """
    a = hurwitz_coefficients(a)
    n = a.size
    m = _positive_int(m, "m")
    p = m if p is None else _positive_int(p, "p")
    theta = _theta_matrix(theta, n, m, "theta", p)
    t2 = _theta2_column(theta, n, m, "theta", p)
    d = np.concatenate((a - t2, [1.0]))
    N = theta[: n * m].reshape(m, n, p).transpose(2, 0, 1)
    return LeftMFD(d, N, np.zeros((p, m)))


def _theta_matrix(theta, n: int, m: int, field: str, p: int | None = None) -> np.ndarray:
    p = m if p is None else p
    try:
        th = np.array(theta, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{field}: not a numeric matrix ({exc})") from exc
    if th.shape != (n * (m + p), p):
        raise ValueError(f"{field}: expected shape {(n * (m + p), p)} (n(m+p) x p, = 2nm x m "
                         f"when square), got {th.shape}")
    if not np.isfinite(th).all():
        raise ValueError(f"{field}: non-finite entries")
    return th


def _theta2_column(theta: np.ndarray, n: int, m: int, field: str,
                   p: int | None = None) -> np.ndarray:
    """The n distinct entries of Theta2; raise if Theta2 lacks the D = dI structure."""
    p = m if p is None else p
    t2 = theta[n * m :]
    col = t2[0:n, 0].copy()
    expected = np.kron(np.eye(p), col[:, None])
    scale = max(1.0, float(np.max(np.abs(col))) if col.size else 1.0)
    if np.max(np.abs(t2 - expected)) > 1e-12 * scale:
        raise ValueError(
            f"{field}: Theta2 must be block diagonal with the same n-vector in every "
            "block (D(s) = d(s) I, eq. 3.16)"
        )
    return col


@dataclass(frozen=True)
class ModelSpec:
    """One model of the state-shared set: ``y = Theta^T n + bias``.

    Parameters
    ----------
    name : str
    theta : ndarray, shape (2nm, m) (n(m+p) x p for p outputs)
        Measurement matrix (eq. 3.16).
    bias : ndarray, shape (m,) (p,)
        Affine offset (see module notes); zero for deviation models.
    kind : {"fixed", "adaptive"}
    """

    name: str
    theta: np.ndarray
    bias: np.ndarray | None = None
    kind: str = "fixed"

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise ValueError("name: must be a non-empty string")
        if self.kind not in MODEL_KINDS:
            raise ValueError(f"kind: must be one of {MODEL_KINDS}, got {self.kind!r}")
        try:
            th = np.array(self.theta, dtype=float)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"theta: not a numeric matrix ({exc})") from exc
        if th.ndim != 2 or th.shape[1] < 1 or th.shape[0] <= th.shape[1]:
            raise ValueError(f"theta: expected shape (2nm, m), got {th.shape}")
        if not np.isfinite(th).all():
            raise ValueError("theta: non-finite entries")
        m = th.shape[1]
        b = np.zeros(m) if self.bias is None else finite_vector(self.bias, m, "bias")
        th.setflags(write=False)
        b.setflags(write=False)
        object.__setattr__(self, "theta", th)
        object.__setattr__(self, "bias", b)


class PredictionForm(tuple):
    """``(Phi, Gamma, C, b)`` of one model on the shared state; unpacks as a 4-tuple.

    ``n(k+1) = Phi n(k) + Gamma u(k) + f``, ``y(k) = C n(k) + b``.

    The attribute ``f`` (shape (2nm,)) is the constant state increment per
    sample caused by the bias (``f = 0`` when ``b = 0``): model j's output feeds
    n2 through ``G y = G (C n + b)``, so the bias enters the dynamics too.
    **Use f in predictions** unless the model has zero bias.
    """

    def __new__(cls, Phi, Gamma, C, b, f):
        obj = super().__new__(cls, (Phi, Gamma, C, b))
        obj.f = f
        return obj

    @property
    def Phi(self) -> np.ndarray:
        return self[0]

    @property
    def Gamma(self) -> np.ndarray:
        return self[1]

    @property
    def C(self) -> np.ndarray:
        return self[2]

    @property
    def b(self) -> np.ndarray:
        return self[3]


@dataclass
class _Slot:
    """One model: its spec (None after :meth:`StateSharedModel.set_params`, built again
    from the stacked parameters when read), name, kind and cached prediction form."""

    spec: ModelSpec | None
    name: str
    kind: str
    prediction: PredictionForm | None = field(default=None)

    @classmethod
    def of(cls, spec: ModelSpec) -> _Slot:
        return cls(spec, spec.name, spec.kind)


class StateSharedModel:
    """Shared state and the measurement matrices of all models (eq. 3.10).

    Parameters
    ----------
    a : array_like, shape (n,), or SharedBasis
        Designer polynomial ``omega`` (lowest power first), Hurwitz; or the
        basis itself (:meth:`SharedBasis.orthonormal` from omega's roots, the
        well-conditioned choice above n ~ 10).
    m : int
        Inputs = outputs (the seed's square case).
    dt : float
        Sample time, > 0, in the models' time unit.
    models : sequence of ModelSpec, optional
    p : int, optional
        Number of outputs when it differs from the number of inputs m (an
        extension of the seed: n1 has nm states driven by u, n2 has np states
        driven by y, Theta is n(m+p) x p). Default m.
    basis : {"companion", "orthonormal"}
        Coordinates of the shared state when ``a`` holds coefficients (see
        :mod:`controller.shared_basis`); ignored when ``a`` is a SharedBasis.

    Attributes
    ----------
    n : ndarray, shape (2nm,)
        The shared state [n1; n2] (a copy; use :meth:`set_state` to change it).
    F, G : ndarray
        Continuous pair (nm x nm, nm x m), the n1 (input) part.
    Fd, Gd : ndarray
        Exact ZOH discretization of (F, G) for dt.
    F_y, G_y, Fd_y, Gd_y : ndarray
        The same for the n2 (output) part; the very same arrays when p = m.
    n_params : int
        ``n (m^2 + 1)``: free parameters of one structured model (without bias);
        ``n (m p + 1)`` in general.
    order : int
        ``2 n m`` (``n (m + p)``).
    """

    def __init__(self, a: ArrayLike | SharedBasis, m: int, dt: float,
                 models: Sequence[ModelSpec] | None = None, *, p: int | None = None,
                 basis: str = "companion") -> None:
        self.basis = SharedBasis.of(a, basis)
        self.a = self.basis.a
        self.m = _positive_int(m, "m")
        self.p = self.m if p is None else _positive_int(p, "p")
        try:
            dt = float(dt)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"dt: not a number ({dt!r})") from exc
        if not (math.isfinite(dt) and dt > 0):
            raise ValueError(f"dt: must be finite and > 0, got {dt}")
        self.dt = dt
        self.n_deg = self.a.size
        n, m, p = self.n_deg, self.m, self.p
        self.Fb, self.gb = self.basis.Fb, self.basis.gb
        self.F = np.kron(np.eye(m), self.Fb)
        self.G = np.kron(np.eye(m), self.gb[:, None])
        self.Fbd, self.gbd = _zoh_block(self.Fb, self.gb, dt)
        self.Fd = np.kron(np.eye(m), self.Fbd)
        self.Gd = np.kron(np.eye(m), self.gbd[:, None])
        if p == m:
            self.F_y, self.G_y, self.Fd_y, self.Gd_y = self.F, self.G, self.Fd, self.Gd
        else:
            self.F_y = np.kron(np.eye(p), self.Fb)
            self.G_y = np.kron(np.eye(p), self.gb[:, None])
            self.Fd_y = np.kron(np.eye(p), self.Fbd)
            self.Gd_y = np.kron(np.eye(p), self.gbd[:, None])
        for arr in (self.Fb, self.gb, self.F, self.G, self.Fbd, self.gbd, self.Fd, self.Gd,
                    self.F_y, self.G_y, self.Fd_y, self.Gd_y):
            arr.setflags(write=False)
        self.order = n * (m + p)
        self.n_params = n * (m * p + 1)
        # Shared state as an (m+p, n) matrix (rows 0..m-1 = n1 blocks, then the n2 blocks),
        # stored with one extra column holding the latest [u; y] so that one sample is a
        # single matmul: Z[:, :n] <- Z @ [Fbd^T; gbd^T].
        self._Z = np.zeros((m + p, n + 1))
        self._M = np.vstack((self.Fbd.T, self.gbd[None, :]))
        # update() in one compiled call where numpy's Z @ M is the BLAS dgemm numba's is
        # (n > 1; controller.state_kernel.advance_state)
        self._advance_compiled = n > 1
        self._slots: list[_Slot] = []
        self._T = np.zeros((0, self.order))  # stacked Theta_j^T, (k p, n(m+p))
        self._theta2_view: tuple | None = None  # (the stack, theta2_all's view of it)
        self._Taug = np.zeros((0, (m + p) * (n + 1)))  # the same, zeros at the [u; y] column
        self._B = np.zeros((0, p))
        for spec in models or ():
            self.add_model(spec)
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """Call the sample's compiled kernels (:mod:`controller.state_kernel`) once with
        the argument types a sample passes: C-ordered writeable float64 arrays of this
        model's ndim (numba specializes on dtype, ndim, layout and writeability, not on
        sizes) and Python ints. Their compilation, or their load from numba's on-disk
        cache (about a second each on a cold cache, 10-50 ms warm), then happens here,
        when the controller is built, never in a sample. Scratch arrays of one model's
        shapes: the state and the models are not touched."""
        n, m, p = self.n_deg, self.m, self.p
        Z = np.zeros_like(self._Z)  # (m+p, n+1)
        if self._advance_compiled:
            advance_state(Z, self._M, np.zeros(m), np.zeros(p))
        state_regressor(Z, n, m, p, self.n_params + p)
        T, Taug, B = np.zeros((p, self.order)), np.zeros((p, Z.size)), np.zeros((1, p))
        model_errors(np.zeros(p), Taug, Z.reshape(-1), B)
        write_params(T, Taug, B, 0, np.zeros(self.n_params + p), n, m, p)

    # -- models ------------------------------------------------------------------
    @property
    def _N(self) -> np.ndarray:
        return self._Z[:, : self.n_deg]

    @property
    def n(self) -> np.ndarray:
        """The shared state [n1; n2], shape (2nm,) (a copy; assigning sets the state)."""
        return self._N.reshape(-1).copy()

    @n.setter
    def n(self, value: ArrayLike) -> None:
        self.set_state(value)

    @property
    def k(self) -> int:
        """Number of models."""
        return len(self._slots)

    @property
    def names(self) -> list[str]:
        return [s.name for s in self._slots]

    @property
    def kinds(self) -> list[str]:
        return [s.kind for s in self._slots]

    def kind(self, j: int) -> str:
        """Kind of model ``j``: ``kinds[j]`` without building the list (per-sample reads)."""
        return self._slots[j].kind

    def model(self, j: int) -> ModelSpec:
        j = self._index(j)
        slot = self._slots[j]
        if slot.spec is None:  # set by set_params: the stacked rows hold it
            rows = slice(j * self.p, (j + 1) * self.p)
            slot.spec = ModelSpec(slot.name, self._T[rows].T.copy(), self._B[j].copy(),
                                  slot.kind)
        return slot.spec

    def theta(self, j: int) -> np.ndarray:
        return self.model(j).theta

    def coefficient_theta(self, j: int) -> np.ndarray:
        """Model j's Theta in the companion coordinates of the same omega (eq. 3.16:
        numerator coefficients and ``a - d``), for readings that need coefficients.

        The very array of :meth:`theta` in the companion basis; otherwise
        ``(I (x) T)' Theta`` with ``T = SharedBasis.from_companion()`` (small n only).
        """
        th = self.theta(j)
        if self.basis.kind == "companion":
            return th
        T = self.basis.from_companion()
        return np.kron(np.eye(self.m + self.p), T).T @ th

    def theta_rows(self, j: int) -> np.ndarray:
        """Model j's ``Theta_j^T``, shape (p, 2nm): a read-only view of the stacked
        parameters (no :class:`ModelSpec` built), current after :meth:`set_params`."""
        j = self._index(j)
        view = self._T[j * self.p : (j + 1) * self.p]
        view.flags.writeable = False
        return view

    def theta2_all(self) -> np.ndarray:
        """theta2 (= a - d, eq. 3.16) of every model, shape (k, n): the first output
        block's (all blocks hold the same vector for structured models). A read-only
        view of the stacked parameters, current after :meth:`set_theta`."""
        cached = self._theta2_view
        if cached is not None and cached[0] is self._T:  # the same stack: the same view
            return cached[1]
        nm = self.n_deg * self.m
        view = self._T[:: self.p, nm : nm + self.n_deg]
        view.flags.writeable = False
        self._theta2_view = (self._T, view)
        return view

    def bias(self, j: int) -> np.ndarray:
        return self.model(j).bias

    def _index(self, j) -> int:
        if type(j) is int and 0 <= j < len(self._slots):  # the per-sample reads
            return j
        if isinstance(j, bool) or not isinstance(j, int | np.integer) or not 0 <= j < self.k:
            raise ValueError(f"j: model index must be in 0..{self.k - 1}, got {j!r}")
        return int(j)

    def _check_spec(self, spec: ModelSpec) -> None:
        if not isinstance(spec, ModelSpec):
            raise ValueError(f"spec: expected a ModelSpec, got {type(spec).__name__}")
        if spec.theta.shape != (self.order, self.p):
            raise ValueError(
                f"theta of model {spec.name!r}: expected shape {(self.order, self.p)} "
                f"(n(m+p) x p with n={self.n_deg}, m={self.m} inputs, p={self.p} outputs), "
                f"got {spec.theta.shape}"
            )

    def add_model(self, spec: ModelSpec) -> int:
        """Append a model; returns its index."""
        self._check_spec(spec)
        if spec.name in self.names:
            raise ValueError(f"name: a model named {spec.name!r} already exists")
        self._slots.append(_Slot.of(spec))
        self._restack()
        return self.k - 1

    def _restack(self) -> None:
        if self._slots:
            self._T = np.ascontiguousarray(
                np.concatenate([self.model(j).theta.T for j in range(self.k)], axis=0))
            self._B = np.stack([self.model(j).bias for j in range(self.k)])
        else:
            self._T = np.zeros((0, self.order))
            self._B = np.zeros((0, self.p))
        km, n, q = self._T.shape[0], self.n_deg, self.m + self.p
        self._Taug = np.zeros((km, q, n + 1))
        self._Taug[:, :, :n] = self._T.reshape(km, q, n)
        self._Taug = self._Taug.reshape(km, -1)

    def set_theta(self, j: int, theta: ArrayLike, bias: ArrayLike | None = None) -> None:
        """Replace model j's Theta (and bias; kept when None). The shared state is untouched."""
        j = self._index(j)
        old = self.model(j)
        spec = ModelSpec(old.name, theta, old.bias if bias is None else bias, old.kind)
        self._check_spec(spec)
        self._slots[j] = _Slot.of(spec)
        q = self.m + self.p
        rows = slice(j * self.p, (j + 1) * self.p)
        self._T[rows] = spec.theta.T
        self._Taug.reshape(-1, q, self.n_deg + 1)[rows, :, : self.n_deg] = (
            spec.theta.T.reshape(self.p, q, self.n_deg))
        self._B[j] = spec.bias

    def set_params(self, j: int, p: ArrayLike) -> None:
        """Set model j from a structured parameter vector (see :meth:`params_from_theta`).

        The adaptive models' per-sample path: the parameters go straight into the
        stacked matrices the estimates read (the same values :meth:`set_theta` would
        write); the model's :class:`ModelSpec` is built again only when read.
        """
        j = self._index(j)
        n, m, q = self.n_deg, self.m, self.p
        p = np.asarray(p, dtype=float).reshape(-1)
        if p.shape != (self.n_params + q,) or not all_finite(p):
            theta, bias = self.theta_from_params(p)  # raises naming the field
            self.set_theta(j, theta, bias)
            return
        # Theta_j^T rows of the stack (q, n(m+q)): [Theta1 rows | theta2 block diagonal]
        write_params(self._T, self._Taug, self._B, j, p, n, m, q)
        old = self._slots[j]
        self._slots[j] = _Slot(None, old.name, old.kind)

    @staticmethod
    def model_from_linear(name: str, A, B, C, u_op: ArrayLike, y_op: ArrayLike,
                          a: ArrayLike | SharedBasis, kind: str = "fixed", *,
                          pad_root: float | None = None, square: bool = True) -> ModelSpec:
        """A ModelSpec from a linearization about (u_op, y_op).

        ``(A, B, C)`` is the deviation model ``dx' = A dx + B du``, ``dy = C dx``
        (D = 0). With ``a`` omega's coefficients (companion basis) Theta follows
        from its left MFD (eq. 3.16); with ``a`` an orthonormal
        :class:`SharedBasis` it is solved for from the realization itself
        (:func:`controller.shared_basis.orthonormal_theta`). The bias makes the
        model hold about its own point: ``b = y_op - Theta^T n_ss(u_op, y_op)``.
        ``square=False`` admits p outputs != m inputs (see the ``p`` option).
        """
        basis = a if isinstance(a, SharedBasis) else None
        if basis is not None and basis.kind == "orthonormal":
            theta = orthonormal_theta(basis, A, B, C, pad_root=pad_root, square=square)
            p = theta.shape[1]
            m = theta.shape[0] // basis.n - p
        else:
            a = basis.a if basis is not None else a
            mfd = left_mfd(A, B, C)
            theta = theta_from_mfd(mfd, a, pad_root=pad_root, square=square)
            basis = SharedBasis.companion(a)
            p, m = mfd.shape
        u_op = finite_vector(u_op, m, "u_op")
        y_op = finite_vector(y_op, p, "y_op")
        n_ss = _steady_state(basis, u_op, y_op)
        return ModelSpec(name, theta, y_op - theta.T @ n_ss, kind)

    # -- parameter vector -------------------------------------------------------------
    def params_from_theta(self, theta: ArrayLike, bias: ArrayLike | None = None) -> np.ndarray:
        """Structured parameter vector ``p = [vec Theta1^T; theta2; bias]``, length N_theta + m.

        ``p[i*nm:(i+1)*nm]`` = Theta1[:, i] (output i's numerator coefficients),
        then the n entries ``theta2 = a - d`` (eq. 3.16), then the m biases
        (one per output). Raises if Theta2 lacks the block structure of
        D(s) = d(s) I.
        """
        n, m, q = self.n_deg, self.m, self.p
        th = _theta_matrix(theta, n, m, "theta", q)
        t2 = _theta2_column(th, n, m, "theta", q)
        b = np.zeros(q) if bias is None else finite_vector(bias, q, "bias")
        return np.concatenate((th[: n * m].T.reshape(-1), t2, b))

    def theta_from_params(self, p: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """Inverse of :meth:`params_from_theta`: (Theta (2nm, m), bias (m,))."""
        n, m, q = self.n_deg, self.m, self.p
        p = finite_vector(p, self.n_params + q, "p")
        nm = n * m
        theta = np.zeros((self.order, q))
        theta[:nm] = p[: nm * q].reshape(q, nm).T
        t2 = p[nm * q : nm * q + n]
        for i in range(q):
            theta[nm + i * n : nm + (i + 1) * n, i] = t2
        return theta, p[nm * q + n :].copy()

    def regressor(self) -> np.ndarray:
        """W (m, N_theta + m) with ``y_j = W @ p_j`` for every structured model j
        (p rows when the outputs differ in number from the inputs)."""
        return state_regressor(self._Z, self.n_deg, self.m, self.p, self.n_params + self.p)

    # -- state ---------------------------------------------------------------------------
    def _uy(self, u, y) -> np.ndarray:
        try:
            uy = np.concatenate((np.asarray(u, dtype=float).reshape(-1),
                                 np.asarray(y, dtype=float).reshape(-1)))
            fast = uy.size == self.m + self.p and all_finite(uy)
        except (TypeError, ValueError):
            fast = False
        if fast and np.size(u) == self.m:
            return uy
        # slow path: precise messages naming the field
        return np.concatenate((finite_vector(u, self.m, "u"), finite_vector(y, self.p, "y")))

    def initialize(self, u: ArrayLike, y: ArrayLike) -> None:
        """Set n to the steady state for constant u and y (``F n1 + G u = 0`` etc.)."""
        uy = self._uy(u, y)
        self._Z[:] = 0.0
        if self.basis.kind == "companion":
            self._Z[:, 0] = uy / self.a[0]
        else:
            self._Z[:, : self.n_deg] = np.outer(uy, self.basis.steady)

    def set_state(self, n: ArrayLike) -> None:
        """Overwrite the shared state, shape (2nm,)."""
        self._N[:] = finite_vector(n, self.order, "n").reshape(self.m + self.p, self.n_deg)

    def update(self, u: ArrayLike, y: ArrayLike) -> None:
        """Advance one sample with u and y held (ZOH): exact for piecewise-constant signals.

        Raises ValueError (state untouched) for wrong lengths or NaN/inf.
        """
        if (self._advance_compiled and isinstance(u, np.ndarray) and isinstance(y, np.ndarray)
                and u.shape == (self.m,) and y.shape == (self.p,)
                and u.dtype == _F8 and y.dtype == _F8 and u.flags.carray and y.flags.carray
                and advance_state(self._Z, self._M, u, y)):  # one compiled call
            return
        uy = self._uy(u, y)  # raises naming the field
        Z = self._Z
        Z[:, -1] = uy
        Z[:, :-1] = Z @ self._M

    def estimates(self) -> np.ndarray:
        """All models' outputs ``y_j = Theta_j^T n + b_j``, shape (k, m)."""
        return (self._Taug @ self._Z.reshape(-1)).reshape(-1, self.p) + self._B

    def errors(self, y: ArrayLike) -> np.ndarray:
        """``y - y_j`` for every model, shape (k, m)."""
        if (isinstance(y, np.ndarray) and y.dtype == np.float64 and y.shape == (self.p,)
                and self.k):
            e = model_errors(y, self._Taug, self._Z.reshape(-1), self._B)  # one call
            if e.shape[0] == self.k:
                return e
        return finite_vector(y, self.p, "y")[None, :] - self.estimates()

    # -- prediction form ---------------------------------------------------------------
    def continuous_form(self, j: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                                                np.ndarray]:
        """Model j as a continuous system on the shared state: (A, B, C, b, f_c).

        ``n' = A n + B u + f_c``, ``y = C n + b`` with
        ``A = [[F, 0], [G Th1^T, F + G Th2^T]]``, ``B = [G; 0]``,
        ``f_c = [0; G b]``, ``C = [Th1^T, Th2^T]``.
        """
        spec = self.model(j)
        nm, N = self.n_deg * self.m, self.order
        th1, th2 = spec.theta[:nm], spec.theta[nm:]
        A = np.zeros((N, N))
        A[:nm, :nm] = self.F
        A[nm:, :nm] = self.G_y @ th1.T
        A[nm:, nm:] = self.F_y + self.G_y @ th2.T
        B = np.zeros((N, self.m))
        B[:nm] = self.G
        f = np.zeros(N)
        f[nm:] = self.G_y @ spec.bias
        return A, B, spec.theta.T.copy(), spec.bias.copy(), f

    def prediction_form(self, j: int) -> PredictionForm:
        """Discrete (Phi, Gamma, C, b) of model j on the shared state, for MPC.

        Exact ZOH discretization of :meth:`continuous_form` with dt:
        ``n(k+1) = Phi n(k) + Gamma u(k) + f``, ``y(k) = C n(k) + b``; the
        returned tuple also carries ``.f`` (zero when the bias is zero). Cached
        per model until its Theta changes.
        """
        slot = self._slots[self._index(j)]
        if slot.prediction is None:
            A, B, C, b, fc = self.continuous_form(j)
            Phi, Gam, fd = _zoh_affine(A, B, fc, self.dt)
            for arr in (Phi, Gam, C, b, fd):
                arr.setflags(write=False)
            slot.prediction = PredictionForm(Phi, Gam, C, b, fd)
        return slot.prediction

    def sampled_form(self, j: int) -> PredictionForm:
        """Model j closed over the *sampled* shared-state update: (Phi, Gamma, C, b), ``.f``.

        ``n(k+1) = Fd-update of n(k) with u(k) and y(k) = C n(k) + b`` held over the
        sample: ``Phi = [[Fd, 0], [Gd Th1^T, Fd + Gd Th2^T]]``, ``Gamma = [Gd; 0]``,
        ``f = [0; Gd b]``. This is exactly how :meth:`update` moves the state when
        fed model j's own output, so predictions stay consistent with the measured
        state; :meth:`prediction_form` is instead the exact ZOH discretization of the
        continuous model (they differ by O(dt) in the n2 coupling). No matrix
        exponential: cheap enough to rebuild every sample for adaptive models.
        """
        spec = self.model(j)
        nm, N = self.n_deg * self.m, self.order
        th1, th2 = spec.theta[:nm], spec.theta[nm:]
        Phi = np.zeros((N, N))
        Phi[:nm, :nm] = self.Fd
        Phi[nm:, :nm] = self.Gd_y @ th1.T
        Phi[nm:, nm:] = self.Fd_y + self.Gd_y @ th2.T
        Gam = np.zeros((N, self.m))
        Gam[:nm] = self.Gd
        f = np.zeros(N)
        f[nm:] = self.Gd_y @ spec.bias
        return PredictionForm(Phi, Gam, spec.theta.T.copy(), spec.bias.copy(), f)

    # -- persistence ----------------------------------------------------------------
    def checkpoint(self) -> dict:
        """JSON-serialisable snapshot; :meth:`restore` is exact.

        The shared state and the model parameters are packed
        (:func:`controller.packing.pack_array`);
        plain lists, as older checkpoints hold them, are accepted by :meth:`restore`.
        """
        doc = {
            "a": self.a.tolist(),
            "m": self.m,
            "p": self.p,
            "dt": self.dt,
            "n": pack_array(self._N.reshape(-1)),
            "models": [
                {"name": spec.name, "kind": spec.kind, "theta": pack_array(spec.theta),
                 "bias": spec.bias.tolist()}
                for spec in (self.model(j) for j in range(self.k))
            ],
        }
        if self.basis.kind != "companion":
            doc["basis"] = self.basis.to_dict()
        return doc

    def restore(self, state: dict) -> None:
        """Restore state and models from :meth:`checkpoint` (same a, m, dt required)."""
        if not isinstance(state, dict):
            raise ValueError("state: expected a dict from checkpoint()")
        for key in ("a", "m", "dt", "n", "models"):
            if key not in state:
                raise ValueError(f"state: missing key {key!r}")
        if self.basis.kind == "companion":
            if "basis" in state and state["basis"].get("kind") != "companion":
                raise ValueError("state.basis: the checkpoint's basis is not this model's "
                                 "(companion)")
            a = finite_vector(state["a"], None, "state.a")
            if a.shape != self.a.shape or np.any(a != self.a):
                raise ValueError("state.a: designer polynomial differs from this model's")
        elif not self.basis.same_as(SharedBasis.from_dict(state.get("basis", {}))):
            raise ValueError("state.basis: the checkpoint's basis (kind and omega's roots) "
                             "differs from this model's")
        if state["m"] != self.m:
            raise ValueError(f"state.m: expected {self.m}, got {state['m']!r}")
        if state.get("p", state["m"]) != self.p:
            raise ValueError(f"state.p: expected {self.p}, got {state.get('p')!r}")
        if float(state["dt"]) != self.dt:
            raise ValueError(f"state.dt: expected {self.dt}, got {state['dt']!r}")
        n = state["n"]  # packed, or a list (older checkpoints)
        if isinstance(n, dict):
            n = unpack_array(n)
        n = finite_vector(n, self.order, "state.n")
        specs = [ModelSpec(d["name"], unpack_array(d["theta"]), d["bias"], d["kind"])
                 for d in state["models"]]
        for s in specs:
            self._check_spec(s)
        self._Z[:, : self.n_deg] = n.reshape(self.m + self.p, self.n_deg)
        self._slots = [_Slot.of(s) for s in specs]
        self._restack()

    @classmethod
    def from_checkpoint(cls, state: dict) -> StateSharedModel:
        """A new model from :meth:`checkpoint` output."""
        if not isinstance(state, dict) or "a" not in state:
            raise ValueError("state: expected a dict from checkpoint()")
        basis = SharedBasis.from_dict(state["basis"]) if "basis" in state else state["a"]
        obj = cls(basis, state["m"], state["dt"], p=state.get("p"))
        obj.restore(state)
        return obj


def _steady_state(basis: SharedBasis, u: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Shared state in equilibrium with constant u and y: ``-Fb^-1 gb v`` per block
    (companion: first entry of each block = v/a1)."""
    N = np.zeros((u.size + y.size, basis.n))
    v = np.concatenate((u, y))
    if basis.kind == "companion":
        N[:, 0] = v / basis.a[0]
    else:
        N[:] = np.outer(v, basis.steady)
    return N.reshape(-1)


def _zoh_block(Fb: np.ndarray, gb: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact ZOH of one companion block via expm of the augmented matrix."""
    n = Fb.shape[0]
    M = np.zeros((n + 1, n + 1))
    M[:n, :n] = Fb * dt
    M[:n, n] = gb * dt
    E = scipy.linalg.expm(M)
    return E[:n, :n].copy(), E[:n, n].copy()


def _zoh_affine(A: np.ndarray, B: np.ndarray, f: np.ndarray, dt: float):
    """Exact ZOH of ``x' = A x + B u + f``: (Phi, Gamma, f_d)."""
    nx, nu = B.shape
    M = np.zeros((nx + nu + 1, nx + nu + 1))
    M[:nx, :nx] = A * dt
    M[:nx, nx : nx + nu] = B * dt
    M[:nx, -1] = f * dt
    E = scipy.linalg.expm(M)
    return E[:nx, :nx].copy(), E[:nx, nx : nx + nu].copy(), E[:nx, -1].copy()
