"""Linear-model tooling of seed chapters 2-3: minimal realization, balanced
truncation with the relative error Re (eq. 3.22), the left matrix fraction
description with D(s) = d(s) I (eq. 2.9), zero-order-hold discretization and the
average relative error ARe (sec. 3.6.1). Pure numerics; knows no plant."""

from controller.linear.balanced import (
    BalancedTruncation,
    balanced_truncation,
    hankel_singular_values,
    relative_error,
    select_order,
    stable_unstable_split,
)
from controller.linear.discretize import DiscreteRealization, zoh, zoh_matrices
from controller.linear.errors import average_relative_error
from controller.linear.mfd import LeftMFD, left_mfd
from controller.linear.realization import Realization, as_realization, minimal_realization

__all__ = [
    "BalancedTruncation",
    "balanced_truncation",
    "hankel_singular_values",
    "relative_error",
    "select_order",
    "stable_unstable_split",
    "DiscreteRealization",
    "zoh",
    "zoh_matrices",
    "average_relative_error",
    "LeftMFD",
    "left_mfd",
    "Realization",
    "as_realization",
    "minimal_realization",
]
