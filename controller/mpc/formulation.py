"""The augmented Δu prediction model and its condensed QP (seed eq. 6.3–6.10).

For a discrete model ``x(k+1) = Φ x(k) + Γ u(k)``, ``y(k) = C x(k) (+ offset)`` the
augmented state ``x_a = [Δx; y]`` obeys (eq. 6.3)::

    x_a(k+1) = Φ_a x_a(k) + Ψ_a Δu(k),   y(k) = C_a x_a(k)
    Φ_a = [[Φ, 0], [CΦ, I]],  Ψ_a = [Γ; CΓ],  C_a = [0 I]

Stacking ``P`` predictions with ``M`` moves gives ``Y = S_x x_a + S_u ΔU`` (eq. 6.4–6.5).
The cost ``Σ‖Y − R‖²_Ξ + ‖ΔU‖²_Λ`` (eq. 6.6), halved, is the QP (eq. 6.10)::

    min ½ zᵀ H z + fᵀ z,   z = [ΔU; ε]
    -du_max <= Δu <= du_max,  0 <= ε                     (simple bounds)
    u_min - u(k-1) <= Σ_{j<=i} Δu(k+j) <= u_max - u(k-1)  (eq. 6.9)
    S_u ΔU - s ε <= y_max - S_x x_a,  S_u ΔU + s ε >= y_min - S_x x_a

with one shared slack ε ≥ 0 on the soft output limits (exact penalty ρ ε plus a small
quadratic term). The output rows hold for the predictions ``y(k+j)`` with ``j >=``
:attr:`~controller.mpc.settings.MPCSettings.output_limit_start` (the constraint window;
1 by default: every prediction). Everything that depends only on the model and the
settings is built once in :func:`build_formulation`; a sample only forms the vectors
(:meth:`DeltaUFormulation.qp_vectors`). :class:`FormulationCache` keeps one
formulation per model so a model switch costs a dictionary look-up.
"""

from __future__ import annotations

import weakref
from collections.abc import Hashable
from dataclasses import dataclass

import numpy as np

from controller.mpc.settings import MPCSettings
from controller.mpc.vector_kernel import clip_move, qp_vectors_kernel, stacked_bounds

#: What the QP solvers read as no bound (DAQP's DAQP_INF).
_OPEN = 1e30

__all__ = [
    "augment",
    "prediction_matrices",
    "DeltaUFormulation",
    "QPVectors",
    "build_formulation",
    "FormulationCache",
]


def _input_matrix(Gamma, n: int) -> np.ndarray:
    """``Gamma`` as an (n, nu) float matrix; the given array itself when it already is
    one (the formulation cache recognizes an unchanged model by identity)."""
    Gamma = np.asarray(Gamma, dtype=float)
    if Gamma.ndim != 2 or Gamma.shape[0] != n:
        Gamma = Gamma.reshape(n, -1)
    return Gamma


def augment(Phi, Gamma, C):
    """Augmented Δu model of eq. 6.3.

    Parameters
    ----------
    Phi : ndarray, shape (n, n)
    Gamma : ndarray, shape (n, nu)
    C : ndarray, shape (ny, n)

    Returns
    -------
    Phi_a : ndarray, shape (n+ny, n+ny)
    Psi_a : ndarray, shape (n+ny, nu)
    C_a : ndarray, shape (ny, n+ny)
    """
    Phi = np.atleast_2d(np.asarray(Phi, dtype=float))
    Gamma = _input_matrix(Gamma, Phi.shape[0])
    C = np.atleast_2d(np.asarray(C, dtype=float))
    n, ny = Phi.shape[0], C.shape[0]
    if Phi.shape != (n, n):
        raise ValueError(f"Phi: must be square, got shape {Phi.shape}")
    if C.shape[1] != n:
        raise ValueError(f"C: expected {n} columns, got {C.shape[1]}")
    Phi_a = np.zeros((n + ny, n + ny))
    Phi_a[:n, :n] = Phi
    Phi_a[n:, :n] = C @ Phi
    Phi_a[n:, n:] = np.eye(ny)
    Psi_a = np.vstack([Gamma, C @ Gamma])
    C_a = np.hstack([np.zeros((ny, n)), np.eye(ny)])
    return Phi_a, Psi_a, C_a


def prediction_matrices(Phi_a, Psi_a, C_a, P: int, M: int, *, terminal: bool = False):
    """Stacked prediction ``Y = S_x x_a + S_u ΔU`` (eq. 6.5) and the horizon-end state.

    Only products with the thin matrices ``C_a`` (ny rows) and ``Ψ_a`` (nu columns) are
    formed, so the cost is O(P n² (ny + nu)), not O(P n³): it matters for the
    400-state shared models of the TE.

    Returns
    -------
    S_x : ndarray, shape (P*ny, na)
    S_u : ndarray, shape (P*ny, M*nu)
        Block (i, j) is ``C_a Φ_a^(i-j) Ψ_a`` for ``j <= i``, ``j < M`` (i = 0 is y(k+1)).
    T_x : ndarray, shape (na, na) or None
        ``Φ_a^P`` (only with ``terminal=True``): the state at ``k+P`` is
        ``T_x x_a + T_u ΔU``.
    T_u : ndarray, shape (na, M*nu) or None
    """
    na, nu = Psi_a.shape
    ny = C_a.shape[0]
    S_x = np.zeros((P * ny, na))
    S_u = np.zeros((P * ny, M * nu))
    blocks = []
    CP = np.array(C_a, dtype=float)  # C_a Φ_a^d
    for d in range(P):
        blocks.append(CP @ Psi_a)
        CP = CP @ Phi_a
        S_x[d * ny:(d + 1) * ny] = CP
    for i in range(P):
        for j in range(min(i + 1, M)):
            S_u[i * ny:(i + 1) * ny, j * nu:(j + 1) * nu] = blocks[i - j]
    if not terminal:
        return S_x, S_u, None, None
    pw_psi = [np.array(Psi_a, dtype=float)]  # Φ_a^d Ψ_a
    for _ in range(P - 1):
        pw_psi.append(Phi_a @ pw_psi[-1])
    T_x = np.linalg.matrix_power(Phi_a, P)
    T_u = np.zeros((na, M * nu))
    for j in range(M):
        T_u[:, j * nu:(j + 1) * nu] = pw_psi[P - 1 - j]
    return S_x, S_u, T_x, T_u


@dataclass(frozen=True)
class QPVectors:
    """The per-sample data of the QP: ``min ½zᵀHz + fᵀz`` s.t. ``lb <= z <= ub``,
    ``bl <= A z <= bu``."""

    f: np.ndarray
    lb: np.ndarray
    ub: np.ndarray
    bl: np.ndarray
    bu: np.ndarray


@dataclass(frozen=True, eq=False)
class DeltaUFormulation:
    """Condensed QP of one model under one :class:`MPCSettings` (built once).

    Attributes
    ----------
    settings : MPCSettings
    Phi, Gamma, C : ndarray
        The model it was built from (kept to detect a changed model).
    Phi_a, Psi_a, C_a : ndarray
        Augmented model, eq. 6.3.
    S_x, S_u : ndarray
        Prediction matrices, eq. 6.5.
    H : ndarray, shape (nz, nz)
        Hessian of the halved cost, ``S_uᵀ Ξ S_u + Λ (+ T_uᵀ W T_u)``, slack last.
    A : ndarray, shape (m, nz)
        General constraint rows (input limits, then soft output limits).
    nz : int
        Number of variables, ``M*nu`` plus one slack when there are output limits.
    """

    settings: MPCSettings
    Phi: np.ndarray
    Gamma: np.ndarray
    C: np.ndarray
    Phi_a: np.ndarray
    Psi_a: np.ndarray
    C_a: np.ndarray
    S_x: np.ndarray
    S_u: np.ndarray
    H: np.ndarray
    A: np.ndarray
    F_x: np.ndarray
    F_r: np.ndarray
    nz: int
    n_moves: int
    has_slack: bool
    input_rows: np.ndarray
    ymax_rows: np.ndarray
    ymin_rows: np.ndarray
    lb0: np.ndarray
    ub0: np.ndarray
    Gamma_d: np.ndarray | None = None
    S_d: np.ndarray | None = None
    F_ut: np.ndarray | None = None

    def __post_init__(self) -> None:
        # Per-sample constants, so qp_vectors allocates only what changes.
        s = self.settings
        rows = self.input_rows
        n_in, n_max = rows.size, self.ymax_rows.size
        parts = _settings_parts(s)
        if (rows is parts.input_rows and self.ymax_rows is parts.ymax_rows
                and self.ymin_rows is parts.ymin_rows):  # built by build_formulation
            bl0, bu0, in_idx = parts.bl0, parts.bu0, parts.in_idx
        else:
            bl0, bu0 = _row_bounds(s, rows, self.ymax_rows, self.ymin_rows)
            in_idx = rows % s.nu
        consts = {"_in_idx": in_idx, "_n_in": n_in, "_n_max": n_max, "_bl0": bl0,
                  "_bu0": bu0, "_Sx_max": np.ascontiguousarray(self.S_x[self.ymax_rows]),
                  "_Sx_min": np.ascontiguousarray(self.S_x[self.ymin_rows]),
                  "_F_ut": (np.zeros((0, 0)) if self.F_ut is None
                            else np.ascontiguousarray(self.F_ut)),
                  "_no_dev": np.zeros(0),
                  # np.tile(v, M) of an (nu,) vector as one take (the same copy)
                  "_tile_M": parts.tile_M}
        for k, v in consts.items():
            object.__setattr__(self, k, v)
        self._warm_kernels()

    def _warm_kernels(self) -> None:
        """Call the sample's compiled kernels once with this formulation's argument
        types, so that their compilation (or their load from numba's cache, ~10-50 ms
        the first time in a process) never falls into a sample."""
        s = self.settings
        n = self.Phi.shape[0]
        zero_u = np.zeros(s.nu)
        _, vec = self.sample_vectors(np.zeros(n), np.zeros(n), np.zeros(s.ny), zero_u,
                                     np.zeros((s.P, s.ny)))
        n_bounds = vec.lb.size + vec.bl.size
        stacked_bounds(vec.f, vec.lb, vec.ub, vec.bl, vec.bu, np.empty(n_bounds),
                       np.empty(n_bounds))
        clip_move(np.zeros(s.nu), s.du_max, zero_u, s.u_min, s.u_max)

    @property
    def n_rows(self) -> int:
        """Number of general constraint rows."""
        return self.A.shape[0]

    def augmented_state(self, dx, y) -> np.ndarray:
        """``x_a = [Δx; y]``, shape ``(n+ny,)``."""
        return np.concatenate([np.asarray(dx, dtype=float).ravel(),
                               np.asarray(y, dtype=float).ravel()])

    def bounds(self, u_min=None, u_max=None, y_min=None, y_max=None):
        """``(bl, bu)`` of the general rows for input and soft output limits other than
        the settings' (None: the settings'), e.g. an operator's limits of this sample.

        Only the rows the settings made are there (a limit finite where the settings'
        is infinite needs a formulation built with a finite one); a non-finite value
        in such a row leaves it open (±1e30, the solvers' infinity).
        """
        f = (lambda v: None if v is None else np.asarray(v, dtype=float))  # noqa: E731
        rows = self.input_rows
        bl, bu = _row_bounds(self.settings, rows, self.ymax_rows, self.ymin_rows,
                             f(u_min), f(u_max), f(y_min), f(y_max))
        n_fixed = rows.size + self.ymax_rows.size  # open rows the settings have open stay inf
        bl[:rows.size] = np.maximum(bl[:rows.size], -_OPEN)
        bu[:n_fixed] = np.minimum(bu[:n_fixed], _OPEN)
        bl[n_fixed:] = np.maximum(bl[n_fixed:], -_OPEN)
        return bl, bu

    def qp_vectors(self, x_a, u_prev, reference, dd=None, u_target=None,
                   limits=None) -> QPVectors:
        """QP vectors at one sample.

        Parameters
        ----------
        x_a : ndarray, shape (n+ny,)
            Augmented state ``[Δx(k); y(k)]``.
        u_prev : ndarray, shape (nu,)
            Inputs applied over the last sample, ``u(k-1)``.
        reference : ndarray, shape (P, ny) or (ny,)
            Reference for ``y(k+1) … y(k+P)``; a single row is held over the horizon.
        dd : ndarray, shape (nd,), optional
            Change of the measured disturbance at this sample, ``d(k) − d(k−1)``
            (feedforward; future changes are taken as zero). Needs ``Gamma_d``.
        u_target : ndarray, shape (nu,), optional
            Input targets at this sample (default ``settings.u_target``); only used
            when ``settings.u_target_weight`` has a positive entry.
        limits : tuple (u_min, u_max, y_min, y_max), optional
            This sample's limits in place of the settings' (see :meth:`bounds`).
        """
        s = self.settings
        R = np.asarray(reference, dtype=float)
        if R.ndim == 1:
            R = np.broadcast_to(R, (s.P, s.ny))
        f = np.empty(self.nz)
        off = None
        if dd is not None and self.S_d is not None:
            off = self.S_d @ np.asarray(dd, dtype=float)  # predicted effect of Δd(k)
            f[:self.n_moves] = self.F_x @ x_a - self.F_r @ (R.reshape(-1) - off)
        else:
            f[:self.n_moves] = self.F_x @ x_a - self.F_r @ R.reshape(-1)
        if self.F_ut is not None:
            ut = s.u_target if u_target is None else np.asarray(u_target, dtype=float)
            f[:self.n_moves] += self.F_ut @ np.tile(np.asarray(u_prev, dtype=float) - ut, s.M)
        if self.has_slack:
            f[-1] = s.slack_linear
        if limits is None:
            bl = self._bl0.copy()
            bu = self._bu0.copy()
        else:
            bl, bu = self.bounds(*limits)
        n_in, n_max = self._n_in, self._n_max
        if n_in:
            up = np.asarray(u_prev, dtype=float)[self._in_idx]
            bl[:n_in] -= up
            bu[:n_in] -= up
        if self.has_slack:
            bu[n_in:n_in + n_max] -= self._Sx_max @ x_a
            bl[n_in + n_max:] -= self._Sx_min @ x_a
            if off is not None:
                bu[n_in:n_in + n_max] -= off[self.ymax_rows]
                bl[n_in + n_max:] -= off[self.ymin_rows]
        return QPVectors(f=f, lb=self.lb0, ub=self.ub0, bl=bl, bu=bu)

    def sample_vectors(self, x, x_prev, y, u_prev, reference,
                       u_target=None) -> tuple[np.ndarray, QPVectors]:
        """``(x_a, qp_vectors(x_a, u_prev, reference, u_target=u_target))`` with
        ``x_a = [x − x_prev; y]``, the settings' limits and no measured disturbance, in
        one compiled call (:mod:`controller.mpc.vector_kernel`; the same numbers).

        Parameters
        ----------
        x, x_prev : ndarray, shape (n,)
        y : ndarray, shape (ny,)
        u_prev : ndarray, shape (nu,)
        reference : ndarray, shape (P, ny)
        u_target : ndarray, shape (nu,), optional
        """
        s = self.settings
        if self.F_ut is not None:
            ut = s.u_target if u_target is None else u_target
            dev = (np.asarray(u_prev, dtype=float) - ut).take(self._tile_M)
        else:
            dev = self._no_dev
        x_a, f, bl, bu = qp_vectors_kernel(
            np.ascontiguousarray(x, dtype=float), np.ascontiguousarray(x_prev, dtype=float),
            np.ascontiguousarray(y, dtype=float), self.F_x, self.F_r,
            np.ascontiguousarray(reference, dtype=float).reshape(-1), self._F_ut, dev,
            float(s.slack_linear), self.has_slack, self._bl0, self._bu0, self._in_idx,
            np.ascontiguousarray(u_prev, dtype=float), self._Sx_max, self._Sx_min)
        return x_a, QPVectors(f=f, lb=self.lb0, ub=self.ub0, bl=bl, bu=bu)

    def predict(self, x_a, dU, dd=None) -> np.ndarray:
        """Predicted outputs ``y(k+1) … y(k+P)`` for the moves ``dU``, shape (P, ny)."""
        s = self.settings
        Y = self.S_x @ x_a + self.S_u @ np.asarray(dU, dtype=float).ravel()
        if dd is not None and self.S_d is not None:
            Y = Y + self.S_d @ np.asarray(dd, dtype=float)
        return Y.reshape(s.P, s.ny)


@dataclass(frozen=True, eq=False)
class _SettingsParts:
    """What a formulation takes from its settings alone (the same for every model), made
    once per :class:`MPCSettings` object (:func:`_settings_parts`): ``np.tile`` and
    ``np.kron`` cost some 10 µs a call, fifteen of them half of a TE-size build."""

    Xi_bar: np.ndarray
    Lambda_diag: np.ndarray
    TtW: np.ndarray | None
    T_ut: np.ndarray | None
    lb0: np.ndarray
    ub0: np.ndarray
    input_block: np.ndarray
    input_rows: np.ndarray
    ymax_rows: np.ndarray
    ymin_rows: np.ndarray
    scale: np.ndarray | None
    bl0: np.ndarray
    bu0: np.ndarray
    in_idx: np.ndarray
    tile_M: np.ndarray


def _row_bounds(s: MPCSettings, input_rows, ymax_rows, ymin_rows, u_min=None, u_max=None,
                y_min=None, y_max=None):
    """Constant parts ``(bl0, bu0)`` of the general constraints' bounds: the input
    limits on ``input_rows``, then the output limits' rows (``-inf``/``+inf`` where a
    row has only the other side). The limits are the settings' unless given."""
    u_min = s.u_min if u_min is None else u_min
    u_max = s.u_max if u_max is None else u_max
    ymax = np.tile(s.y_max if y_max is None else y_max, s.P)[ymax_rows]
    ymin = np.tile(s.y_min if y_min is None else y_min, s.P)[ymin_rows]
    bl0 = np.concatenate([np.tile(u_min, s.M)[input_rows], np.full(ymax.size, -np.inf),
                          ymin])
    bu0 = np.concatenate([np.tile(u_max, s.M)[input_rows], ymax,
                          np.full(ymin.size, np.inf)])
    return bl0, bu0


#: id(settings) -> (weak reference to the settings, their parts); settings are immutable
_PARTS: dict[int, tuple[weakref.ref, _SettingsParts]] = {}


def _settings_parts(s: MPCSettings) -> _SettingsParts:
    """The settings-only arrays of :func:`build_formulation` and of a formulation's
    per-sample constants, made on the first call for ``s`` and kept while ``s`` lives
    (read-only arrays, shared by the formulations of every model)."""
    entry = _PARTS.get(id(s))
    if entry is not None and entry[0]() is s:
        return entry[1]
    nmv = s.M * s.nu
    has_slack = s.has_output_limits
    nz = nmv + (1 if has_slack else 0)
    T = np.kron(np.tril(np.ones((s.M, s.M))), np.eye(s.nu))  # the moves' running sums
    T_ut = TtW = None
    if np.any(s.u_target_weight > 0):
        T_ut = T
        TtW = T_ut.T * np.tile(s.u_target_weight, s.M)
    lb0 = np.full(nz, -np.inf)
    ub0 = np.full(nz, np.inf)
    lb0[:nmv] = -np.tile(s.du_max, s.M)
    ub0[:nmv] = np.tile(s.du_max, s.M)
    if has_slack:
        lb0[-1] = 0.0
    finite_u = np.isfinite(np.tile(s.u_min, s.M)) | np.isfinite(np.tile(s.u_max, s.M))
    input_rows = np.flatnonzero(finite_u)
    input_block = np.hstack([T[input_rows], np.zeros((input_rows.size, nz - nmv))])
    # the constraint window: no output limit on the predictions before output_limit_start
    window = np.repeat(np.arange(1, s.P + 1) >= s.output_limit_start, s.ny)
    ymax_rows = np.flatnonzero(np.isfinite(np.tile(s.y_max, s.P)) & window)
    ymin_rows = np.flatnonzero(np.isfinite(np.tile(s.y_min, s.P)) & window)
    scale = np.tile(s.slack_scale, s.P) if has_slack else None
    bl0, bu0 = _row_bounds(s, input_rows, ymax_rows, ymin_rows)
    parts = _SettingsParts(
        Xi_bar=np.tile(s.Xi, s.P), Lambda_diag=np.diag(np.tile(s.Lambda, s.M)), TtW=TtW,
        T_ut=T_ut, lb0=lb0, ub0=ub0, input_block=input_block, input_rows=input_rows,
        ymax_rows=ymax_rows, ymin_rows=ymin_rows, scale=scale, bl0=bl0, bu0=bu0,
        in_idx=input_rows % s.nu, tile_M=np.tile(np.arange(s.nu), s.M))
    # read-only where a formulation's own array was; writeable where a kernel takes it
    # (numba compiles a read-only argument as another type)
    for arr in (parts.Xi_bar, parts.Lambda_diag, parts.T_ut, parts.lb0, parts.ub0,
                parts.input_block, parts.scale):
        if arr is not None:
            arr.setflags(write=False)
    if len(_PARTS) >= 64:  # settings come and go (retunes): forget the dead ones
        for key in [k for k, (ref, _) in list(_PARTS.items()) if ref() is None]:
            del _PARTS[key]
    _PARTS[id(s)] = (weakref.ref(s), parts)
    return parts


def build_formulation(Phi, Gamma, C, settings: MPCSettings,
                      terminal_weight=None, Gamma_d=None) -> DeltaUFormulation:
    """Build the condensed QP of eq. 6.10 for one model.

    Parameters
    ----------
    Phi, Gamma, C : array_like
        Discrete model ``x(k+1) = Φ x + Γ u``, ``y = C x``; shapes (n, n), (n, nu), (ny, n).
    settings : MPCSettings
    terminal_weight : ndarray, shape (n+ny, n+ny), optional
        Extra weight W on the augmented state at ``k+P`` (``½ x_a(k+P)ᵀ W x_a(k+P)``
        in the halved cost). With ``M = P`` and ``W = X − C_aᵀΞC_a``, X the solution
        of the Riccati equation, the MPC is the LQR of the augmented model.
    Gamma_d : array_like, shape (n, nd), optional
        Measured-disturbance input ``x(k+1) = Φx + Γu + Γ_d d``; enables feedforward of
        ``Δd(k)`` through ``S_d`` (block i: ``C_a Φ_a^i [Γ_d; CΓ_d]``).

    Raises
    ------
    ValueError
        If the model shapes do not agree with ``settings.nu``/``settings.ny`` or hold
        non-finite values.
    """
    s = settings
    Phi_a, Psi_a, C_a = augment(Phi, Gamma, C)
    Phi = np.atleast_2d(np.asarray(Phi, dtype=float))
    Gamma = _input_matrix(Gamma, Phi.shape[0])
    C = np.atleast_2d(np.asarray(C, dtype=float))
    if Gamma.shape[1] != s.nu:
        raise ValueError(f"Gamma: expected {s.nu} input columns, got {Gamma.shape[1]}")
    if C.shape[0] != s.ny:
        raise ValueError(f"C: expected {s.ny} output rows, got {C.shape[0]}")
    for name, m in (("Phi", Phi), ("Gamma", Gamma), ("C", C)):
        if not np.isfinite(m).all():
            raise ValueError(f"{name}: non-finite entries")
    S_x, S_u, T_x, T_u = prediction_matrices(Phi_a, Psi_a, C_a, s.P, s.M,
                                             terminal=terminal_weight is not None)
    parts = _settings_parts(s)
    nmv = s.M * s.nu
    SuT_Xi = S_u.T * parts.Xi_bar
    Hu = SuT_Xi @ S_u + parts.Lambda_diag
    F_x = SuT_Xi @ S_x
    F_r = SuT_Xi
    F_ut = None
    if parts.TtW is not None:
        # Input targets: u(k+j) = u(k-1) + Σ_{i<=j} Δu(k+i), cost ‖u − u_t‖²_W.
        Hu = Hu + parts.TtW @ parts.T_ut
        F_ut = parts.TtW  # f += F_ut @ tile(u_prev − u_target)
    if terminal_weight is not None:
        W = np.asarray(terminal_weight, dtype=float)
        na = Phi_a.shape[0]
        if W.shape != (na, na):
            raise ValueError(f"terminal_weight: expected shape {(na, na)}, got {W.shape}")
        Hu = Hu + T_u.T @ W @ T_u
        F_x = F_x + T_u.T @ W @ T_x
    Hu = 0.5 * (Hu + Hu.T)

    has_slack = s.has_output_limits
    nz = nmv + (1 if has_slack else 0)
    H = np.zeros((nz, nz))
    H[:nmv, :nmv] = Hu
    if has_slack:
        H[-1, -1] = s.slack_quadratic

    # Simple bounds (rates on the moves, ε >= 0) and the rows of the input limits
    # (eq. 6.9: lower block-triangular sums of the moves) are the settings'.
    lb0, ub0 = parts.lb0, parts.ub0
    input_rows, ymax_rows, ymin_rows = parts.input_rows, parts.ymax_rows, parts.ymin_rows
    blocks = []
    if input_rows.size:
        blocks.append(parts.input_block)
    if has_slack:
        scale = parts.scale
        blocks.append(np.hstack([S_u[ymax_rows], -scale[ymax_rows, None]]))
        blocks.append(np.hstack([S_u[ymin_rows], scale[ymin_rows, None]]))
    A = np.vstack(blocks) if blocks else np.zeros((0, nz))
    S_d = None
    if Gamma_d is not None:
        Gamma_d = np.asarray(Gamma_d, dtype=float).reshape(Phi.shape[0], -1)
        if not np.isfinite(Gamma_d).all():
            raise ValueError("Gamma_d: non-finite entries")
        Psi_d = np.vstack([Gamma_d, C @ Gamma_d])
        S_d = np.zeros((s.P * s.ny, Gamma_d.shape[1]))
        v = Psi_d
        for i in range(s.P):
            S_d[i * s.ny:(i + 1) * s.ny] = C_a @ v
            v = Phi_a @ v
        Gamma_d.setflags(write=False)
        S_d.setflags(write=False)
    for arr in (Phi, Gamma, C, Phi_a, Psi_a, C_a, S_x, S_u, H, A, F_x, F_r, lb0, ub0):
        arr.setflags(write=False)
    return DeltaUFormulation(
        settings=s, Phi=Phi, Gamma=Gamma, C=C, Phi_a=Phi_a, Psi_a=Psi_a, C_a=C_a,
        S_x=S_x, S_u=S_u, H=H, A=np.ascontiguousarray(A), F_x=F_x, F_r=F_r, nz=nz,
        n_moves=nmv, has_slack=has_slack, input_rows=input_rows, ymax_rows=ymax_rows,
        ymin_rows=ymin_rows, lb0=lb0, ub0=ub0, Gamma_d=Gamma_d, S_d=S_d, F_ut=F_ut,
    )


class FormulationCache:
    """One :class:`DeltaUFormulation` per model key, rebuilt only when the model changes.

    A look-up compares the stored (Φ, Γ, C) with the given ones (a few µs for the
    sizes here), so an adapted model is rebuilt and a fixed one never is.
    """

    def __init__(self, settings: MPCSettings, terminal_weight=None) -> None:
        self.settings = settings
        self.terminal_weight = terminal_weight
        self._store: dict[Hashable, DeltaUFormulation] = {}
        self.builds = 0

    def get(self, key: Hashable, Phi, Gamma, C,
            Gamma_d=None) -> tuple[DeltaUFormulation, bool]:
        """The formulation for ``key``; the flag is True when it was (re)built now."""
        form = self._store.get(key)
        if form is not None and _same(form.Phi, Phi) and _same(form.Gamma, Gamma) and _same(
                form.C, C) and ((Gamma_d is None and form.Gamma_d is None) or (
                Gamma_d is not None and form.Gamma_d is not None
                and _same(form.Gamma_d, Gamma_d))):
            return form, False
        form = build_formulation(Phi, Gamma, C, self.settings, self.terminal_weight, Gamma_d)
        self._store[key] = form
        self.builds += 1
        return form, True

    def __contains__(self, key) -> bool:
        return key in self._store

    def __len__(self) -> int:
        return len(self._store)


def _same(a: np.ndarray, b) -> bool:
    # the form is stored as given (read-only), so the usual look-up is an identity
    if a is b:
        return True
    b = np.asarray(b)
    return a.size == b.size and np.array_equal(a, b.reshape(a.shape))
