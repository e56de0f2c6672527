"""Linearization of a plant at an operating point by numerical Jacobians.

``dx/dt ≈ A dx + B du + E dd``, ``dy ≈ C dx + D du`` about ``(x*, u*, d*)``.

Each Jacobian column is a central difference refined by Richardson extrapolation
on a sequence of halved steps (Ridders' method); the step sequence starts at 1 %
of the variable's magnitude (or of the plant's ``state_scale``/``input_scale``
when the variable is zero), and the extrapolation with the smallest error estimate
is kept. :attr:`LinearModel.error` records the largest estimate.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from plant_sim.base import OperatingPoint, PlantInputError, PlantModel, as_vector

__all__ = ["LinearModel", "linearize", "jacobian", "classify_stability", "classify_point"]


def classify_stability(eigenvalues, rtol: float = 1e-9) -> tuple[str, str]:
    """Stability of an equilibrium from the eigenvalues of its Jacobian.

    Returns
    -------
    (stability, detail) : tuple of str
        ``stability`` is ``"stable"``, ``"unstable"`` or ``"marginal"``; ``detail``
        is ``"stable node"``, ``"stable focus"``, ``"saddle"``, ``"unstable node"``,
        ``"unstable focus"`` or ``"marginal"``. "Focus" means some eigenvalues are
        complex; "node" that all are real.
    """
    ev = np.asarray(eigenvalues, dtype=complex).reshape(-1)
    tol = rtol * max(float(np.max(np.abs(ev))) if ev.size else 0.0, 1.0)
    re = ev.real
    if np.any(np.abs(re) <= tol):
        return "marginal", "marginal"
    complex_ = bool(np.any(np.abs(ev.imag) > tol))
    kind = "focus" if complex_ else "node"
    if np.all(re < 0):
        return "stable", f"stable {kind}"
    if np.all(re > 0):
        return "unstable", f"unstable {kind}"
    return "unstable", "saddle"


def classify_point(model: PlantModel, x, u, d) -> tuple[str, str]:
    """:func:`classify_stability` of the state Jacobian of ``model`` at ``(x, u, d)``."""
    xv = np.asarray(x, float)
    A, _ = jacobian(lambda z: model.rhs(0.0, z, np.asarray(u, float), np.asarray(d, float)),
                    xv, getattr(model, "state_scale", None))
    return classify_stability(np.linalg.eigvals(A))


def jacobian(fun: Callable[[np.ndarray], np.ndarray], z0, scale=None, *,
             first_step: float = 1e-2, n_halvings: int = 8) -> tuple[np.ndarray, float]:
    """Jacobian of ``fun`` at ``z0`` by Richardson-extrapolated central differences.

    Parameters
    ----------
    fun : callable ``(n,) -> (m,)``
    z0 : array_like, shape (n,)
    scale : array_like, shape (n,), optional
        Magnitude to use for variables that are zero at ``z0`` (default 1).
    first_step : float
        First step relative to ``max(|z0_j|)`` (or ``scale_j`` when ``z0_j == 0``).
    n_halvings : int
        Length of the Richardson tableau.

    Returns
    -------
    J : ndarray, shape (m, n)
    error : float
        Largest estimated absolute error of an entry.
    """
    z0 = np.asarray(z0, dtype=float)
    scale = np.ones_like(z0) if scale is None else np.asarray(scale, dtype=float)
    f0 = np.asarray(fun(z0), dtype=float)
    J = np.empty((f0.size, z0.size))
    worst = 0.0
    for j in range(z0.size):
        mag = abs(z0[j]) if z0[j] != 0 else scale[j]
        h = first_step * mag
        J[:, j], err = _ridders(fun, z0, j, h, n_halvings)
        worst = max(worst, err)
    return J, worst


def _ridders(fun, z0, j, h, n):
    """Ridders' extrapolation of the central difference d fun / d z_j (vector-valued)."""
    con, con2 = 2.0, 4.0
    tab = [[None] * n for _ in range(n)]

    def cd(step):
        zp = z0.copy()
        zm = z0.copy()
        zp[j] += step
        zm[j] -= step
        return (np.asarray(fun(zp), float) - np.asarray(fun(zm), float)) / (2 * step)

    tab[0][0] = cd(h)
    best = tab[0][0]
    err = np.inf
    for i in range(1, n):
        h /= con
        tab[0][i] = cd(h)
        fac = con2
        for k in range(1, i + 1):
            tab[k][i] = (tab[k - 1][i] * fac - tab[k - 1][i - 1]) / (fac - 1.0)
            fac *= con2
            e = max(float(np.max(np.abs(tab[k][i] - tab[k - 1][i]))),
                    float(np.max(np.abs(tab[k][i] - tab[k - 1][i - 1]))))
            if e <= err:
                err = e
                best = tab[k][i]
        if float(np.max(np.abs(tab[i][i] - tab[i - 1][i - 1]))) >= 2.0 * err:
            break
    return best, err


@dataclass(frozen=True)
class LinearModel:
    """Continuous-time linear model of a plant about an operating point.

    Attributes
    ----------
    A, B, C, D : ndarray
        Shapes (nx, nx), (nx, nu), (ny, nx), (ny, nu); deviation variables.
    E : ndarray, shape (nx, nd)
        Disturbance input matrix.
    state_names, input_names, output_names, disturbance_names : tuple of str
    state_units, input_units, output_units : tuple of str
    x_op, u_op, d_op, y_op : ndarray
        The linearization point.
    op : str
        Operating-point name (``""`` for an ad-hoc point).
    plant : str
    time_unit : str
    error : float
        Largest estimated absolute error of a Jacobian entry.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    E: np.ndarray
    state_names: tuple[str, ...]
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    disturbance_names: tuple[str, ...]
    state_units: tuple[str, ...]
    input_units: tuple[str, ...]
    output_units: tuple[str, ...]
    x_op: np.ndarray
    u_op: np.ndarray
    d_op: np.ndarray
    y_op: np.ndarray
    op: str = ""
    plant: str = ""
    time_unit: str = "-"
    error: float = 0.0

    def eigenvalues(self) -> np.ndarray:
        """Eigenvalues of ``A`` sorted by real part (most negative first)."""
        ev = np.linalg.eigvals(self.A)
        return ev[np.lexsort((ev.imag, ev.real))]

    def stability(self) -> tuple[str, str]:
        """``(stability, detail)`` from :func:`classify_stability`."""
        return classify_stability(self.eigenvalues())

    def select(self, inputs: Sequence[str] | None = None,
               outputs: Sequence[str] | None = None) -> LinearModel:
        """Sub-model with the named inputs and outputs, in the given order."""
        ii = (list(range(len(self.input_names))) if inputs is None
              else [self._pos(self.input_names, n, "input") for n in inputs])
        oo = (list(range(len(self.output_names))) if outputs is None
              else [self._pos(self.output_names, n, "output") for n in outputs])
        return replace(
            self, B=self.B[:, ii], C=self.C[oo, :], D=self.D[np.ix_(oo, ii)],
            input_names=tuple(self.input_names[i] for i in ii),
            input_units=tuple(self.input_units[i] for i in ii),
            output_names=tuple(self.output_names[i] for i in oo),
            output_units=tuple(self.output_units[i] for i in oo),
            u_op=self.u_op[ii], y_op=self.y_op[oo])

    @staticmethod
    def _pos(names, name, kind) -> int:
        if name not in names:
            raise PlantInputError(f"{kind}: unknown name {name!r}; known: {', '.join(names)}")
        return names.index(name)

    def to_transfer_function(self, input: str | int = 0,
                             output: str | int = 0) -> tuple[np.ndarray, np.ndarray]:
        """SISO transfer function from one input to one output.

        Returns
        -------
        num, den : ndarray
            Polynomial coefficients in descending powers of s; ``den`` is monic and
            leading numerator coefficients below 1e-12 of the largest are dropped.
        """
        i = input if isinstance(input, int) else self._pos(self.input_names, input, "input")
        o = output if isinstance(output, int) else self._pos(self.output_names, output,
                                                             "output")
        from scipy.signal import ss2tf  # lazy: scipy.signal costs ~1 s to import

        num, den = ss2tf(self.A, self.B, self.C, self.D, input=i)
        num = np.asarray(num[o], dtype=float)
        den = np.asarray(den, dtype=float)
        num = num / den[0]
        den = den / den[0]
        big = float(np.max(np.abs(num))) if num.size else 0.0
        k = 0
        while k < num.size - 1 and abs(num[k]) <= 1e-12 * big:
            k += 1
        return num[k:], den

    def as_dict(self) -> dict:
        """JSON-ready form: matrices as nested lists, names, units, eigenvalues."""
        ev = self.eigenvalues()
        stab, detail = self.stability()
        return {
            "plant": self.plant, "op": self.op, "time_unit": self.time_unit,
            "A": self.A.tolist(), "B": self.B.tolist(), "C": self.C.tolist(),
            "D": self.D.tolist(), "E": self.E.tolist(),
            "state_names": list(self.state_names), "state_units": list(self.state_units),
            "input_names": list(self.input_names), "input_units": list(self.input_units),
            "output_names": list(self.output_names), "output_units": list(self.output_units),
            "disturbance_names": list(self.disturbance_names),
            "x_op": self.x_op.tolist(), "u_op": self.u_op.tolist(),
            "d_op": self.d_op.tolist(), "y_op": self.y_op.tolist(),
            "eigenvalues": {"real": ev.real.tolist(), "imag": ev.imag.tolist()},
            "stability": stab, "stability_detail": detail,
            "jacobian_error": self.error,
        }


def linearize(model: PlantModel, op: OperatingPoint | str, *, u=None, d=None,
              x=None) -> LinearModel:
    """Linearize ``model`` at an operating point (or at a given ``x``, ``u``, ``d``).

    Parameters
    ----------
    model : PlantModel
    op : OperatingPoint or str
        Operating point or its name; ``x``, ``u``, ``d`` override its vectors.

    Returns
    -------
    LinearModel
    """
    if isinstance(op, str):
        op = model.operating_point(op)
    xv = as_vector(op.x if x is None else x, model.nx, "x")
    uv = as_vector(op.u if u is None else u, model.nu, "u")
    dv = as_vector(op.d if d is None else d, model.nd, "d")
    nx, nu = model.nx, model.nu
    sx = np.asarray(getattr(model, "state_scale", np.ones(nx)), float)
    su = np.asarray(getattr(model, "input_scale", np.ones(nu)), float)
    sd = np.ones(model.nd)

    A, e1 = jacobian(lambda z: model.rhs(0.0, z, uv, dv), xv, sx)
    B, e2 = jacobian(lambda z: model.rhs(0.0, xv, z, dv), uv, su)
    C, e3 = jacobian(lambda z: model.outputs(z, uv), xv, sx)
    D, e4 = jacobian(lambda z: model.outputs(xv, z), uv, su)
    if model.nd:
        E, e5 = jacobian(lambda z: model.rhs(0.0, xv, uv, z), dv, sd)
    else:
        E, e5 = np.zeros((nx, 0)), 0.0
    return LinearModel(
        A=A, B=B, C=C, D=D, E=E,
        state_names=tuple(model.names("state")), input_names=tuple(model.names("input")),
        output_names=tuple(model.names("output")),
        disturbance_names=tuple(model.names("disturbance")),
        state_units=tuple(v.unit for v in model.state_vars),
        input_units=tuple(v.unit for v in model.input_vars),
        output_units=tuple(v.unit for v in model.output_vars),
        x_op=xv, u_op=uv, d_op=dv, y_op=np.asarray(model.outputs(xv, uv), float),
        op=op.name, plant=model.name, time_unit=model.time_unit,
        error=max(e1, e2, e3, e4, e5),
    )
