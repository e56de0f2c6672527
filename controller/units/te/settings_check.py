"""One check shared by the TE guards' settings dataclasses: every field a finite number.

The guards (:mod:`controller.units.te.overrides`, :mod:`controller.units.te.production_index`,
:mod:`controller.units.te.reactant_trim`, :mod:`controller.units.te.level_sag`,
:mod:`controller.units.te.floating_pressure`) hold only numeric settings; each then checks
its own ranges.
"""

from __future__ import annotations

import math
from dataclasses import fields

__all__ = ["check_finite_fields"]


def check_finite_fields(settings, label: str = "") -> None:
    """Raise ``ValueError`` naming the first field of the dataclass ``settings`` that is
    not a finite int or float (a bool is not a number here).

    Parameters
    ----------
    settings : dataclass instance
    label : str
        Put before the field's name in the message (e.g. ``"level sag "``).
    """
    for f in fields(settings):
        v = getattr(settings, f.name)
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise ValueError(f"{label}{f.name}: must be a finite number, got {v!r}")
