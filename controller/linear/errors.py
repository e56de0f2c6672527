"""Average relative error ARe of sec. 3.6.1 (eq. 3.26, reconstructed).

``ARe_j = (100 % / k) sum_i |yp(i, j) - ybar_p(j) - yhat(i, j)| / |ybar_p(j)|``:
the deviation of a reference response yp from its nominal value ybar_p,
compared with a model's deviation estimate yhat, normalized by the nominal
value (the seed's formula is lost in OCR; facts/seed_results.md gives this as
the most likely form, the only one that makes the printed 0.001-0.3 % plausible).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["average_relative_error"]


def average_relative_error(y_ref: ArrayLike, y_est: ArrayLike, nominal: ArrayLike) -> np.ndarray:
    """ARe (%) per output.

    Parameters
    ----------
    y_ref : array_like, shape (k, p)
        Reference response in absolute units (e.g. the nonlinear plant).
    y_est : array_like, shape (k, p)
        Compared response in absolute units (a deviation model's estimate plus
        the nominal value).
    nominal : array_like, shape (p,)
        Nominal output ybar_p; no entry may be zero.

    Returns
    -------
    ndarray, shape (p,)
        ``100 mean_i |y_ref - y_est| / |nominal|``.
    """
    yr = np.atleast_2d(np.asarray(y_ref, dtype=float))
    ye = np.atleast_2d(np.asarray(y_est, dtype=float))
    nom = np.asarray(nominal, dtype=float).reshape(-1)
    if yr.shape != ye.shape:
        raise ValueError(f"y_est: shape {ye.shape} differs from y_ref {yr.shape}")
    if yr.shape[1] != nom.size:
        raise ValueError(f"nominal: expected length {yr.shape[1]}, got {nom.size}")
    if yr.shape[0] == 0:
        raise ValueError("y_ref: no samples")
    if np.any(nom == 0) or not np.isfinite(nom).all():
        raise ValueError("nominal: entries must be finite and nonzero (ARe divides by them)")
    if not (np.isfinite(yr).all() and np.isfinite(ye).all()):
        raise ValueError("y_ref, y_est: non-finite samples")
    return 100.0 * np.mean(np.abs(yr - ye), axis=0) / np.abs(nom)
