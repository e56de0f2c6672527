"""Whether every entry is finite, for the sample's small float vectors, in one compiled pass.

The sample checks its measurement, reference, errors, adapted parameters and QP
solution with ``np.isfinite(a).all()``: a boolean temporary and numpy's Python-level
``all`` wrapper, 1.3-1.4 µs however short the vector, five to nine times per TE sample
on the critical path. :func:`all_finite` gives the same answer (False for any NaN or
±inf) with one loop compiled by numba for C-contiguous float64 arrays of any shape;
any other array (another dtype or layout) goes to ``np.isfinite(a).all()``, so no
argument type is ever compiled during a sample. The kernel is loaded from numba's
cache at import.

**Measured** (one call, 10th percentile of 50,000, shared 2-core AMD EPYC at load
7.6)::

    array                    np.isfinite(a).all()   all_finite
    5 float64 (y, u)               1.27 µs            0.49 µs
    10 x 5 float64 (reference)     1.35 µs            0.50 µs
    208 float64 (parameters)       1.31 µs            0.56 µs
    5 int64 (numpy's path)         1.26 µs            1.39 µs
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["all_finite"]

_F8 = np.dtype(np.float64)


@njit("boolean(float64[::1])", cache=True)
def _all_finite_1d(a):  # pragma: no cover - compiled
    for i in range(a.size):
        if not math.isfinite(a[i]):
            return False
    return True


def all_finite(a: np.ndarray) -> bool:
    """True when every entry of ``a`` is finite (no NaN, no ±inf), as
    ``bool(np.isfinite(a).all())``; an empty array is True.

    Parameters
    ----------
    a : ndarray, any shape
        Compiled path for C-contiguous float64; numpy's for everything else.
    """
    if a.dtype == _F8 and a.flags.c_contiguous:
        return _all_finite_1d(a.reshape(-1))
    return bool(np.isfinite(a).all())
