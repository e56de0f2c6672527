"""Plant model interface: named variables, operating points and the ODE right-hand side.

Every plant of ``plant_sim`` is a :class:`PlantModel`. Continuous models give
``rhs(t, x, u, d) -> dx/dt`` and ``outputs(x, u) -> y``; their operating points
are data (:class:`OperatingPoint`) named as in the seed (``OPI``, ``OPII``,
``OPIII``). Time units are the plant's own (dimensionless for the CSTR, h for
the two-phase reactor and the bioreactor, s for calcium); each model says which
in :attr:`PlantModel.time_unit`.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass, field

import numpy as np

__all__ = [
    "Variable",
    "OperatingPoint",
    "PlantModel",
    "PlantInputError",
    "as_vector",
]


class PlantInputError(ValueError):
    """A value given to a plant is malformed: wrong length, NaN, out of a hard range.

    The message always names the offending field.
    """


@dataclass(frozen=True)
class Variable:
    """A named plant variable.

    Parameters
    ----------
    name : str
        Short identifier used in CSV columns, JSON and key expressions.
    unit : str
        Engineering unit ("-" for dimensionless).
    description : str
        One-line meaning.
    lower, upper : float
        Physical bounds (``-inf``/``inf`` when unbounded). For inputs these are
        the actuator limits.
    """

    name: str
    unit: str = "-"
    description: str = ""
    lower: float = -math.inf
    upper: float = math.inf

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("Variable.name must be non-empty")
        if self.lower > self.upper:
            raise ValueError(f"Variable {self.name}: lower {self.lower} > upper {self.upper}")


@dataclass(frozen=True)
class OperatingPoint:
    """A steady operating point (grade) of a plant.

    Parameters
    ----------
    name : str
        Seed name: ``OPI``, ``OPII``, ``OPIII`` (TE: ``mode0`` … ``mode6``).
    x, u, d : ndarray
        State, input and disturbance vectors, shapes ``(nx,)``, ``(nu,)``, ``(nd,)``.
    description : str
        What the point is, including where its numbers come from.
    stability : str
        ``"stable"``, ``"unstable"`` (saddle etc.) as the seed classifies it, with
        detail such as ``"stable node"``/``"saddle"`` in :attr:`stability_detail`.
    stability_detail : str
        E.g. ``"saddle"``, ``"stable focus"``.
    valid : bool
        False for points the seed lists but calls physically useless (washout).
    confidence : str
        ``"text"``, ``"verified"``, ``"reconstructed"`` as in the facts files.
    """

    name: str
    x: np.ndarray
    u: np.ndarray
    d: np.ndarray = field(default_factory=lambda: np.zeros(0))
    description: str = ""
    stability: str = "stable"
    stability_detail: str = ""
    valid: bool = True
    confidence: str = "verified"

    def __post_init__(self) -> None:
        for attr in ("x", "u", "d"):
            object.__setattr__(self, attr, np.asarray(getattr(self, attr), dtype=float).copy())
            getattr(self, attr).setflags(write=False)


def as_vector(value, n: int, field_name: str, *, allow_nan: bool = False) -> np.ndarray:
    """Validate and convert ``value`` to a float vector of length ``n``.

    Raises
    ------
    PlantInputError
        If the length is wrong or the vector holds NaN/inf (unless ``allow_nan``).
    """
    try:
        arr = np.asarray(value, dtype=float).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise PlantInputError(f"{field_name}: not a numeric vector ({exc})") from exc
    if arr.shape[0] != n:
        raise PlantInputError(f"{field_name}: expected length {n}, got {arr.shape[0]}")
    if not allow_nan and not np.all(np.isfinite(arr)):
        bad = [int(i) for i in np.flatnonzero(~np.isfinite(arr))]
        raise PlantInputError(f"{field_name}: non-finite value at index {bad}")
    return arr


class PlantModel(ABC):
    """A continuous-time nonlinear plant ``dx/dt = f(t, x, u, d)``, ``y = g(x, u)``.

    Subclasses set the class attributes and implement :meth:`rhs` and
    :meth:`outputs`. Both must be pure functions of their arguments.

    Attributes
    ----------
    name : str
        Registry name (``cstr``, ``bioreactor``, ``two_phase_reactor``, ``calcium``, ``te``).
    title : str
        Human-readable title.
    time_unit : str
        Unit of ``t`` in :meth:`rhs` (``"h"``, ``"s"`` or ``"-"``).
    state_vars, input_vars, output_vars, disturbance_vars : tuple of Variable
        Named variables in vector order.
    reconstructed : bool
        True when parameters were reconstructed rather than read from a source.
    """

    name: str = ""
    title: str = ""
    time_unit: str = "-"
    state_vars: tuple[Variable, ...] = ()
    input_vars: tuple[Variable, ...] = ()
    output_vars: tuple[Variable, ...] = ()
    disturbance_vars: tuple[Variable, ...] = ()
    reconstructed: bool = False

    # -- sizes -----------------------------------------------------------------
    @property
    def nx(self) -> int:
        return len(self.state_vars)

    @property
    def nu(self) -> int:
        return len(self.input_vars)

    @property
    def ny(self) -> int:
        return len(self.output_vars)

    @property
    def nd(self) -> int:
        return len(self.disturbance_vars)

    # -- model -------------------------------------------------------------------
    @abstractmethod
    def rhs(self, t: float, x: np.ndarray, u: np.ndarray, d: np.ndarray) -> np.ndarray:
        """Time derivative ``dx/dt``, shape ``(nx,)``, in state units per :attr:`time_unit`."""

    @abstractmethod
    def outputs(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Measured outputs ``y``, shape ``(ny,)``."""

    @property
    @abstractmethod
    def operating_points(self) -> dict[str, OperatingPoint]:
        """Operating points keyed by seed name."""

    # -- helpers -------------------------------------------------------------------
    def operating_point(self, name: str) -> OperatingPoint:
        """Look up an operating point; unknown names raise :class:`PlantInputError`."""
        ops = self.operating_points
        if name not in ops:
            raise PlantInputError(
                f"op: unknown operating point {name!r} for plant {self.name!r}; "
                f"known: {', '.join(ops)}"
            )
        return ops[name]

    def default_disturbance(self) -> np.ndarray:
        """Nominal disturbance vector, shape ``(nd,)``."""
        return np.zeros(self.nd)

    def variables(self, kind: str) -> tuple[Variable, ...]:
        """The variables of one ``kind``: state, input, output or disturbance."""
        table = {
            "state": self.state_vars,
            "input": self.input_vars,
            "output": self.output_vars,
            "disturbance": self.disturbance_vars,
        }
        if kind not in table:
            raise PlantInputError(f"kind: expected one of {', '.join(table)}, got {kind!r}")
        return table[kind]

    def index(self, kind: str, name: str) -> int:
        """Position of a named variable; ``kind`` is state, input, output or disturbance."""
        seq = self.variables(kind)
        for i, v in enumerate(seq):
            if v.name == name:
                return i
        raise PlantInputError(
            f"{kind}: unknown name {name!r} for plant {self.name!r}; "
            f"known: {', '.join(v.name for v in seq)}"
        )

    def names(self, kind: str) -> list[str]:
        """Names of the variables of one ``kind``, in vector order."""
        return [v.name for v in self.variables(kind)]
