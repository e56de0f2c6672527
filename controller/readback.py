"""Values read back from a checkpoint or a stored record, checked before they are used.

A checkpoint crosses a process boundary (JSON in SQLite) and may come back from another
version of the product or a damaged file. A piece whose state is a vector of its own
moves or set points takes it back through :func:`finite_vector`, so that a value of the
wrong type, length or finiteness is a ``ValueError`` naming it (the controller node
refuses such a checkpoint with ``error:``) rather than a controller that restores and
then fails every sample.

Limits: bookkeeping only; a vector of a few dozen numbers is checked in microseconds.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["count_below", "finite_number", "finite_vector"]


def finite_number(v) -> bool:
    """Whether ``v`` is a finite int or float (a bool is not a number here); the TE
    settings check it as :func:`controller.units.te.settings_check.is_finite_number`."""
    return isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)


def count_below(v, stop: float = math.inf) -> bool:
    """Whether ``v`` is a count below ``stop``: an int (a bool is not one here) with
    ``0 <= v < stop``."""
    return isinstance(v, int) and not isinstance(v, bool) and 0 <= v < stop


def finite_vector(v, n: int, name: str) -> np.ndarray:
    """``v`` as ``n`` finite floats, shape (n,).

    Raises
    ------
    ValueError
        Naming ``name``, when ``v`` is not a sequence of ``n`` finite numbers.
    """
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{name}: expected {n} finite numbers")
    return a
