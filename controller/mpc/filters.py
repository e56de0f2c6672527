"""First-order measurement filter of seed §6.1.2: ``y_f(k) = α y(k) + (1 − α) y_f(k−1)``."""

from __future__ import annotations

import numpy as np

from controller.finite_kernel import all_finite

__all__ = ["FirstOrderFilter"]


class FirstOrderFilter:
    """Exponential smoothing of a measurement vector (seed §6.1.2 uses α = 0.2).

    Parameters
    ----------
    alpha : float
        Weight of the new sample, ``0 < α <= 1``; 1 passes the measurement through.
    y0 : array_like, shape (ny,), optional
        Initial filter state; by default the first sample initialises it.

    Notes
    -----
    A non-finite sample does not enter the state: :meth:`update` returns the previous
    filtered value (the caller decides what a bad sample means).
    """

    def __init__(self, alpha: float, y0=None) -> None:
        alpha = float(alpha)
        if not 0.0 < alpha <= 1.0:
            raise ValueError(f"alpha: must be in (0, 1], got {alpha}")
        self.alpha = alpha
        self.state = None if y0 is None else np.array(y0, dtype=float)

    def update(self, y) -> np.ndarray:
        """Filter one sample ``y`` (shape (ny,)) and return ``y_f(k)``."""
        y = np.asarray(y, dtype=float)
        if not all_finite(y):
            if self.state is None:
                return y.copy()
            return self.state.copy()
        if self.state is None or self.alpha == 1.0:
            self.state = y.copy()
        else:
            self.state = self.alpha * y + (1.0 - self.alpha) * self.state
        return self.state.copy()

    def reset(self, y0=None) -> None:
        self.state = None if y0 is None else np.array(y0, dtype=float)
