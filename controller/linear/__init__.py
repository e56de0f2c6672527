"""Linear-model tooling of seed chapters 2-3: minimal realization, balanced
truncation with the relative error Re (eq. 3.22), the left matrix fraction
description with D(s) = d(s) I (eq. 2.9), zero-order-hold discretization and the
average relative error ARe (sec. 3.6.1). Pure numerics; knows no plant."""

from controller.linear.mfd import LeftMFD, left_mfd
from controller.linear.realization import Realization, as_realization, minimal_realization

__all__ = [
    "LeftMFD",
    "left_mfd",
    "Realization",
    "as_realization",
    "minimal_realization",
]
