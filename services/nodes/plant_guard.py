"""What the plant node lets through of a move, as a DCS does: instrument ranges and rate
limits per sample (DESIGN "Security and integrity": the plant defends itself).

A requested move ``u`` is first clamped to each MV's instrument range, then the
change from the move the plant holds is limited to ``max_step`` per sample::

    u_applied = clip(held + clip(clip(u, lower, upper) - held, -max_step, max_step),
                     lower, upper)

Tennessee Eastman (:data:`TE_LIMITS`; facts: Downs & Vogel's interlocks, the
TE supervisory MPC's own move limits ``TEOptions.du_max``):

========================  =================  ============  ==========================
MV                        range              per sample    why
========================  =================  ============  ==========================
``XMV1..XMV12``           0 .. 100 %         50 %          valve range; the MPC's limit
``reactor_pressure_sp``   2300 .. 2950 kPa   20 kPa        trip above 3000 kPa gauge;
                                                           grades 2705-2800 kPa
``reactor_temperature_sp`` 100 .. 150 °C     10 °C         trip above 175 °C; grades
                                                           120.4-128.2 °C
``*_level_sp``            0 .. 100 %         100 %         level instrument range
``D_feed_sp``             0 .. 5811 kg/h     full range    the D valve's full flow
``E_feed_sp``             0 .. 8354 kg/h     full range    the E valve's full flow
``A_feed_sp``             0 .. 1.017 kscmh   full range    the A valve's full flow
``A_and_C_feed_sp``       0 .. 15.25 kscmh   full range    the A+C valve's full flow
``recycle_flow_sp``       0 .. 53.8 kscmh    full range    twice the base case (no
                                                           full scale published)
``purge_rate_sp``         0 .. 0.674 kscmh   full range    twice the base case
``production_sp``         0 .. 45.9 m³/h     full range    twice the base case
``stripper_temperature_sp`` 0 .. 150 °C      full range    the reactor's range
``stripper_steam_sp``     0 .. 460 kg/h      full range    twice the base case
``reactor_coolant_outlet_temperature_sp`` 0 .. 150 °C  full range  the reactor's range
========================  =================  ============  ==========================

The decentralized baseline's set points (the flows and temperatures it controls with
its own PI loops, :mod:`controller.units.te.decentralized`) are held inside their
instruments' ranges, without a rate limit of their own: their loops move the valves,
which keep theirs.

The rate limits equal the MPC's own, so a genuine move never meets them; a forged
one (reactor pressure set point 1e6 kPa tripped the plant on pressure at 3824 kPa
within seconds) is held inside the ranges and crawls at most one limit per sample.
The unit plants clamp to their inputs' physical bounds (``input_vars``) without a
rate limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["InstrumentLimits", "TE_LIMITS", "te_limits"]


@dataclass(frozen=True)
class InstrumentLimits:
    """Range and rate limit of each MV of a plant node.

    Parameters
    ----------
    names : tuple of str, shape (nu,)
    lower, upper : tuple of float, shape (nu,)
        Instrument range, engineering units (``-inf``/``inf``: none).
    max_step : tuple of float, shape (nu,)
        Largest change per sample, engineering units (``inf``: none), > 0.
    """

    names: tuple[str, ...]
    lower: tuple[float, ...]
    upper: tuple[float, ...]
    max_step: tuple[float, ...]

    def __post_init__(self) -> None:
        n = len(self.names)
        for name in ("lower", "upper", "max_step"):
            v = tuple(float(x) for x in getattr(self, name))
            if len(v) != n or any(math.isnan(x) for x in v):
                raise ValueError(f"{name}: need {n} numbers")
            object.__setattr__(self, name, v)
        if any(lo > hi for lo, hi in zip(self.lower, self.upper)):
            raise ValueError("lower: must not exceed upper")
        if any(s <= 0 for s in self.max_step):
            raise ValueError("max_step: must be positive")

    def apply(self, held, u) -> tuple[np.ndarray, list[str]]:
        """The move applied for a requested ``u`` when the plant holds ``held``.

        Returns
        -------
        applied : ndarray, shape (nu,)
        limited : list of str
            Names of the MVs whose request was not applied as it was.
        """
        lo, hi = np.asarray(self.lower), np.asarray(self.upper)
        step = np.asarray(self.max_step)
        u = np.asarray(u, float)
        held = np.asarray(held, float)
        target = np.clip(u, lo, hi)
        change = target - held
        # within the limit the target itself (held + change may differ in the last bit)
        applied = np.where(np.abs(change) <= step, target,
                           np.clip(held + np.clip(change, -step, step), lo, hi))
        limited = [self.names[i] for i in np.flatnonzero(applied != u)]
        return applied, limited


#: ``(lower, upper, max_step)`` of the TE MVs by name (see the module table).
TE_LIMITS = {
    "reactor_pressure_sp": (2300.0, 2950.0, 20.0),
    "reactor_temperature_sp": (100.0, 150.0, 10.0),
    "reactor_level_sp": (0.0, 100.0, 100.0),
    "separator_level_sp": (0.0, 100.0, 100.0),
    "stripper_level_sp": (0.0, 100.0, 100.0),
    **{f"XMV{i}": (0.0, 100.0, 50.0) for i in range(1, 13)},
    # the decentralized baseline's loop set points (XMEAS units)
    **{name: (lo, hi, hi - lo) for name, lo, hi in (
        ("D_feed_sp", 0.0, 5811.0), ("E_feed_sp", 0.0, 8354.0), ("A_feed_sp", 0.0, 1.017),
        ("A_and_C_feed_sp", 0.0, 15.25), ("recycle_flow_sp", 0.0, 53.8),
        ("purge_rate_sp", 0.0, 0.674), ("production_sp", 0.0, 45.9),
        ("stripper_temperature_sp", 0.0, 150.0), ("stripper_steam_sp", 0.0, 460.0),
        ("reactor_coolant_outlet_temperature_sp", 0.0, 150.0))},
}


def te_limits(mv_names) -> InstrumentLimits:
    """The TE unit's :class:`InstrumentLimits` for its MV vector ``mv_names``."""
    try:
        rows = [TE_LIMITS[n] for n in mv_names]
    except KeyError as exc:
        raise ValueError(f"mv_names: no instrument range for TE MV {exc.args[0]!r}") from None
    return InstrumentLimits(tuple(mv_names), *(tuple(c) for c in zip(*rows)))
