"""Bumpless take-over of a running plant by a multiple-model controller.

A controller that (re)starts on a plant that is already running must start from the
move the plant holds, not from its own last move: the first move it computes then
differs from the held one by no more than one ordinary sample's step. For the
state-shared multiple-model controller (seed §4.3: switching on the shared state is
bumpless) this means: its last move becomes the plant's, and its dynamic states (the
shared state, the law's) are re-initialized at the next sample from ``(u, y)``,
exactly as at its first sample; the models' parameters, covariances and
performance-index values are kept.

The same holds within a run: when the plant keeps another move than the one the
controller computed (a missed deadline: the move held), the controller goes on from
the applied move (:func:`continue_from_applied`), not from the one that never went out.
"""

from __future__ import annotations

import numpy as np

__all__ = ["align_multimodel", "continue_from_applied"]


def align_multimodel(ctl, u) -> bool:
    """Bumpless take-over for a :class:`~controller.multimodel.MultiModelController`.

    Parameters
    ----------
    ctl : object
        The controller; anything else is left alone.
    u : array_like (nu,)
        The move the plant holds.

    Returns
    -------
    bool
        False for an object that is not such a controller (or of another input size).
    """
    u = np.asarray(u, dtype=float)
    if not (isinstance(getattr(ctl, "u_last", None), np.ndarray)
            and hasattr(ctl, "initialized") and ctl.u_last.shape == u.shape):
        return False
    if callable(getattr(ctl, "align", None)):
        ctl.align(u)  # the controller's own take-over (laws re-initialized at u, y)
        return True
    ctl.u_last = u.copy()
    ctl.initialized = False
    return True


def continue_from_applied(ctl, u) -> bool:
    """Tell a controller that the plant got ``u`` instead of its last move.

    Parameters
    ----------
    ctl : object
        The controller; one with ``applied(u)`` (the multiple-model controller, the unit
        controllers) goes on from ``u``, anything else is left alone.
    u : array_like (nu,)
        The move in force.

    Returns
    -------
    bool
        False when the controller has no ``applied``.
    """
    applied = getattr(ctl, "applied", None)
    if not callable(applied):
        return False
    applied(np.asarray(u, dtype=float))
    return True
