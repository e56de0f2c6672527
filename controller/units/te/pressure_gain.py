"""The reactor-pressure loop's proportional action raised at a steady grade through its
set point (a guard of the TE cascade's MPC strategies).

The plant side runs the reactor pressure on the purge (XMV 6) under the supervisory
controller (:data:`controller.units.te.loops.PRESSURE_LOOP`, -0.15 %/kPa, Ti 0.5 h: a
fifth loop beside seed Table 7.10's, R7.11), and the core writes its set point P_r*. That
gain is the one every grade change, guard and model of the cascade was tuned with
(:mod:`controller.units.te.models` linearizes with it). At a steady grade a loop that
gain leaves the pressure's half-hour means moving by 23-27 kPa under IDV(20) at mode 0
(the reactor effluent's flow coefficient, a 2 h sawtooth), where the decentralized
structure, with no pressure loop, moves by 5 kPa; the reaction follows the pressure and
G in product follows the reaction.

Method
    The supervisory controller cannot retune a loop of the plant side (the DCS's own),
    but it writes the loop's set point every sample. For a PI loop
    ``u = K (e + (1/Ti) integral e)``, ``e = P - r``, a set point written as

        ``r' = r + (f - 1) s (d - d_w)``,  ``d = r - P``,
        ``d_w``: ``d`` through a first-order lag of ``washout_h``,

    makes the loop's error ``e' = P - r' = (1 + (f - 1) s W) e`` with the washout
    ``W = T q / (T q + 1)`` (``T`` = ``washout_h``, ``q`` the Laplace variable): the
    loop acts with ``1 + (f - 1) s`` times its gain on the error's changes faster than
    ``T`` and with its own gain on slower ones, and at a steady state ``e' = 0`` still
    means ``P = r``: the core's P_r* stays the pressure's target (the core is not told
    of the lead; :meth:`SteadyPressureGain.applied` and :meth:`~SteadyPressureGain.take_over`
    take it off a set point the plant holds). ``f`` is
    :attr:`SteadyPressureGainSettings.factor`, ``s`` in [0, 1] the share in force: it
    rises at ``1 / ramp_h`` per hour from ``after_h`` after the last grade change (and
    from the start of a run without one) and falls at the same rate otherwise, so the
    lead starts and ends without a bump. The lead is on the error, as the plant
    side's loop is, so a move of the core's P_r* is led too.

    While the hold through a grade change sets P_r*, the purge is under its floor
    (:class:`controller.units.te.control.TransitionGuards` ``purge_floor_fraction``;
    the set point written is then capped at the pressure, as the core's is) or the
    operator holds the outer loops (warm, or an outer loop's CV off), the share falls;
    while the operator holds P_r* there is no lead. The tracking cap and the floating
    pressure (:mod:`controller.units.te.floating_pressure`) act on the core's P_r*,
    and the lead acts about it: ramped out while they acted, it lost most of what it
    gives (IDV(8) at mode 2 G 0.524 mol % and 187.8 $/h, IDV(20) at mode 0 0.560,
    seeds 1-3, the whole gain tripled). The set point written stays within the
    core's P_r* limits (clipped at the operator's high limit on the pressure too, the
    lead pushed one way only and the pressure settled 26 kPa under a 2650 kPa limit,
    ``fixed``, seed 3). The plant side's loop steps every 1.8 s and the lead is
    written every 36 s sample, so its proportional part lags the loop's by up to one
    sample. A non-finite pressure writes ``r`` unchanged (no lead) for that sample.

Measured (switched on; ``make_te_controller(..., pressure_gain=True)``)
    ``ssmpc``, noise on, seeds 1-3, 48 h, onset 2 h, the acceptance matrix's cases
    run one by one (``run_te``); G standard deviation mol % and run-mean $/h, off ->
    on; the decentralized structure's in the last column:

    ==========  =================  ==================  =============
    case        G std              $/h                 decentralized
    ==========  =================  ==================  =============
    IDV(8)@0    0.548 -> 0.518     148.5 -> 148.1      0.529, 174.6
    IDV(20)@0   0.567 -> 0.543     152.4 -> 152.0      0.510, 170.6
    IDV(17)@0   0.541 -> 0.538     135.4 -> 133.8      0.527, 170.6
    IDV(13)@0   0.713 -> 0.785     162.1 -> 157.9      0.824, 171.4
    IDV(20)@2   0.632 -> 0.616     179.1 -> 179.0      0.523, 181.3
    IDV(8)@2    0.520 -> 0.514     186.5 -> 185.4      0.518, 185.3
    ==========  =================  ==================  =============

    So IDV(8) at mode 0 would be met; the other three misses stay. Under IDV(20) at
    mode 0 (24 h, hours 4-24) the pressure's half-hour means step by 15-21 kPa
    instead of 19-27, and the purge valve's standard deviation doubles (4.9-5.9 ->
    10.8-12.6 %). IDV(13) at modes 1 and 2 (seeds 1-20, 48 h): no trip, the purge's
    lowest flow 0.075 and 0.225 of the grade's (off: -0.024 and 0.279; a flow
    measurement at the valve's seat reads its noise), peak 2896 kPa (off 2903).
    Without the washout (the whole gain tripled, the integral too) the purge closed
    under IDV(13) at mode 1 to under 12.5 % of the grade's flow on all 20 seeds
    (median 4.9 %; 3 seeds off, median 17.4 %): a pressure under its set point for
    hours is the reaction's doing there, and the purge's floor was made for the trip
    that follows. Washouts of 0.5, 2 and 4 h: IDV(13) at mode 0 0.765, 0.801, 0.809
    mol %, at mode 1 the purge under 12.5 % on 7, 1 and 15 seeds. At ``f = 2`` (the
    whole gain) IDV(8) at mode 0 0.534, at ``f = 5`` IDV(13) at mode 0 0.863. The
    whole gain on the plant side's loop itself, through grade changes too (the
    models linearized with it), slowed 1 -> 0 from 2.8 to 5.1 h.

Why off by default
    With it on, the operator's test of a T_r* held 1.5 degC above the base case (the
    MPC planning around it, ``tests/test_te_operator.py``) left the pressure 39 kPa
    under the core's P_r* after 2 h, where without it the pressure is within 20 kPa:
    the core's own moves of P_r* are led as the error's moves, and how the two
    interact while the targets move P_r* by tens of kPa is not measured yet; nor has
    the acceptance matrix been run with it. A lead on the measurement instead (no
    kick on the core's moves) closed the purge under IDV(13) at modes 1 and 2 on 19
    of 20 seeds: where the tracking cap holds P_r* a margin above a falling pressure,
    every fall was led.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.units.te.settings_check import check_finite_fields, check_range, is_finite_number

__all__ = ["SteadyPressureGainSettings", "SteadyPressureGain"]


@dataclass(frozen=True)
class SteadyPressureGainSettings:
    """Settings of :class:`SteadyPressureGain` (see the module docstring).

    Parameters
    ----------
    factor : float
        The pressure loop's gain at a steady grade on the pressure's fast moves, as a
        multiple of the plant side's (>= 1; 1: off).
    washout_h : float
        Time constant of the washout, h (> 0): moves of the pressure slower than it
        get the plant side's gain.
    after_h : float
        Hours after a grade change from which the lead comes in (>= 0).
    ramp_h : float
        Hours the lead takes to come in fully, and to go (> 0).
    """

    factor: float = 3.0
    washout_h: float = 1.0
    after_h: float = 24.0
    ramp_h: float = 0.25

    def __post_init__(self) -> None:
        label = "pressure gain "
        check_finite_fields(self, label)
        check_range(self, "factor", "[1, 10]", label=label)
        check_range(self, "washout_h", "> 0", "h", label)
        check_range(self, "after_h", ">= 0", "h", label)
        check_range(self, "ramp_h", "> 0", "h", label)


class SteadyPressureGain:
    """The reactor pressure's set point with the steady grade's lead, sample by sample.

    Besides the lead it keeps what a bumpless transfer needs: the offset ``w - r`` of
    the set point written, and of the one the plant holds. When the plant holds a set
    point other than the one written (the operator's warm or off, a missed deadline, a
    restart; :meth:`take_over`) the core goes on from that set point less the offset it
    was written with, the lead starts again from nothing, and the offset is carried as
    a bias that runs out over ``ramp_h``: the first set point written is the one the
    plant holds plus the core's move. While the operator holds P_r* (:attr:`operator_held`)
    there is no lead and no bias: the operator's value is written as it is.

    Parameters
    ----------
    settings : SteadyPressureGainSettings, optional
    sample_h : float
        The supervisory sample, h.
    """

    def __init__(self, settings: SteadyPressureGainSettings | None = None,
                 sample_h: float = 0.01) -> None:
        self.settings = settings or SteadyPressureGainSettings()
        self.sample_h = float(sample_h)
        #: share of the lead in force, in [0, 1]
        self.share = 0.0
        #: the transfer's bias in the set point written, kPa, and its fall per sample
        self.bias = 0.0
        self.bias_step = 0.0
        #: the operator holds P_r* (no lead, no bias)
        self.operator_held = False
        self.written = math.nan      # the set point written last, kPa
        self.offset_written = 0.0    # its offset from the core's P_r*, kPa
        self.offset_in_force = 0.0   # the offset of the set point the plant holds, kPa
        self._pending = False        # the last set point written not yet known applied
        #: the error r - P through the washout's lag, kPa (None: not started)
        self.error_lag: float | None = None

    @property
    def gain_multiple(self) -> float:
        """The pressure loop's gain in force, as a multiple of the plant side's."""
        return 1.0 + (self.settings.factor - 1.0) * self.share

    def update(self, setpoint: float, pressure: float, since_h: float, held: bool = False,
               limits: tuple[float, float] = (-math.inf, math.inf)) -> float:
        """Advance one sample and return the set point to write, kPa.

        Parameters
        ----------
        setpoint : float
            The core's P_r* after the guards, kPa.
        pressure : float
            Reactor pressure, XMEAS 7, kPa.
        since_h : float
            Hours since the last grade change (inf in a run without one).
        held : bool
            The hold through a grade change sets P_r* this sample, or the operator
            holds the outer loops: the lead goes, at the ramp's rate.
        limits : (float, float)
            The written set point's range, kPa (the core's P_r* limits; under the
            purge's floor, at most the pressure).
        """
        s = self.settings
        if self._pending:  # no word since: the plant took the last set point written
            self.offset_in_force = self.offset_written
        step = self.sample_h / s.ramp_h
        if self.operator_held:
            self.share = self.bias = 0.0
        elif since_h >= s.after_h and not held:
            self.share = min(self.share + step, 1.0)
        else:
            self.share = max(self.share - step, 0.0)
        self.bias = (min(self.bias + self.bias_step, 0.0) if self.bias < 0.0
                     else max(self.bias - self.bias_step, 0.0))
        out = setpoint
        if math.isfinite(setpoint):
            d = setpoint - pressure
            if math.isfinite(d):
                if self.error_lag is None:
                    self.error_lag = d
                self.error_lag += self.sample_h / (s.washout_h + self.sample_h) \
                    * (d - self.error_lag)
                if self.share > 0.0:
                    out = setpoint + (s.factor - 1.0) * self.share * (d - self.error_lag)
            out = min(max(out + self.bias, limits[0]), limits[1])
        self.written = out
        self.offset_written = out - setpoint if math.isfinite(out - setpoint) else 0.0
        self._pending = True
        return out

    def applied(self, value: float) -> float:
        """The plant holds the set point ``value`` (kPa) over the coming sample; return
        the core's P_r* under it (``value`` less the offset it was written with)."""
        self._pending = False
        if value == self.written:
            self.offset_in_force = self.offset_written
            return value - self.offset_in_force
        return self.take_over(value)

    def take_over(self, value: float) -> float:
        """The plant holds ``value`` (kPa), not the set point last written: return the
        core's P_r* under it and start the lead again from it (see the class)."""
        if self._pending and value == self.written:
            self.offset_in_force = self.offset_written
        self._pending = False
        if self.operator_held or not math.isfinite(self.offset_in_force):
            self.offset_in_force = 0.0
        self.share = 0.0
        self.error_lag = None  # the washout starts again from the error then
        self.bias = self.offset_in_force
        self.bias_step = abs(self.bias) * self.sample_h / self.settings.ramp_h
        return value - self.offset_in_force

    def checkpoint(self) -> dict[str, Any]:
        return {"share": self.share, "bias": self.bias, "bias_step": self.bias_step,
                "written": self.written if math.isfinite(self.written) else None,
                "offset_written": self.offset_written,
                "offset_in_force": self.offset_in_force, "pending": self._pending,
                "operator_held": self.operator_held, "error_lag": self.error_lag}

    def restore(self, state: dict[str, Any] | None) -> None:
        """Restore a checkpoint; an absent or damaged field starts as new (no lead)."""
        st = state or {}

        def num(key, lo=-math.inf, hi=math.inf):
            v = st.get(key, 0.0)
            return min(max(float(v), lo), hi) if is_finite_number(v) else 0.0

        self.share = num("share", 0.0, 1.0)
        self.bias, self.bias_step = num("bias"), num("bias_step", 0.0)
        w = st.get("written")
        self.written = float(w) if is_finite_number(w) else math.nan
        self.offset_written, self.offset_in_force = num("offset_written"), num("offset_in_force")
        self._pending = st.get("pending") is True
        self.operator_held = st.get("operator_held") is True
        lag = st.get("error_lag")
        self.error_lag = float(lag) if is_finite_number(lag) else None
