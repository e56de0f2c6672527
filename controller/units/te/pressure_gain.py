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
    while the operator holds P_r* there is no lead. The guards that set P_r* by a rule
    of their own (the purge's floor, the floating pressure,
    :mod:`controller.units.te.floating_pressure`, and the hold) step it where they
    start and end; on that sample the washout takes the error as it is, so the step
    is not led. Led, the steps between the purge's floor and the tracking cap made a
    limit cycle: with T_r* held 1.5 degC above the base case (the operator's test,
    ``tests/test_te_operator.py``) the set point written swung between 2630 and 2742
    kPa with a period of about 0.75 h and the pressure stood 39 kPa under the core's
    P_r* at 2 h (without the lead it is 10 kPa under, at the tracking cap); and under
    IDV(13) at mode 1 the purge fell under 12.5 % of the grade's flow on 3 of seeds
    1-20 (none with the steps taken out). With the washout following the error for
    as long as such a rule acted, 19 of the 20. The tracking cap (P_r* at most a
    margin above the pressure) moves P_r* with the pressure, and the lead acts about
    it: with the washout following the error while the cap acted too, mode 2's costs
    rose by 1.5-2.5 $/h (IDV(8) at mode 2 187.8 $/h, 1.4 % over the decentralized
    structure's). The set point written stays within the core's P_r* limits
    (clipped at the operator's high limit on the pressure too, the lead pushed one
    way only and the pressure settled 26 kPa under a 2650 kPa limit, ``fixed``, seed
    3). The plant side's loop steps every 1.8 s and the lead is written every 36 s
    sample, so its proportional part lags the loop's by up to one sample. A
    non-finite pressure writes ``r`` unchanged (no lead) for that sample.

Measured (on, against off; ``ssmpc``, noise on, seeds 1-3, 48 h, onset 2 h; G standard
deviation mol % and run-mean $/h)
    The acceptance matrix (``docs/campaigns/te_matrix.json``, 1110 runs, 8 min 12 s)
    with this module on: **57 of 60** disturbance cases (56 off), 0 trips of ``ssmpc``
    and ``fixed``; the 14 transitions' median times as off and their costs within 3 %
    (0 -> 1 392 -> 381 $, 0 -> 3 338 -> 332), peaks as before (at most 2889 kPa), 1 of
    14 met as before. The cases that moved (off -> on; the decentralized structure's
    in the last column):

    ==========  =================  ==================  =============
    case        G std              $/h                 decentralized
    ==========  =================  ==================  =============
    IDV(8)@0    0.548 -> 0.518     148.5 -> 146.5      0.529, 174.6
    IDV(20)@0   0.567 -> 0.552     152.4 -> 152.5      0.510, 170.6
    IDV(17)@0   0.541 -> 0.538     135.4 -> 134.8      0.527, 170.6
    IDV(13)@0   0.713 -> 0.790     162.1 -> 154.5      0.824, 171.4
    IDV(20)@2   0.632 -> 0.619     179.1 -> 179.0      0.523, 181.3
    IDV(8)@2    0.520 -> 0.514     186.5 -> 184.4      0.518, 185.3
    ==========  =================  ==================  =============

    IDV(8) at mode 0 is met; IDV(17) and IDV(20) at mode 0 and IDV(20) at mode 2 still
    miss on G. Before the steps of the guards' rules were marked the same matrix gave
    57 of 60 too (IDV(20)@0 0.543, IDV(13)@0 0.785, IDV(8)@2 185.1 $/h). Under IDV(20)
    at mode 0 (24 h, hours 4-24) the pressure's half-hour means step by 16-21 kPa
    instead of 19-27, and the purge valve's standard deviation doubles (4.9-5.9 ->
    10.2-13.2 %). IDV(13) at modes 1 and 2 (seeds 1-20, 48 h): no trip; the purge's
    lowest flow at least 0.16 and 0.22 of the grade's (off: 3 seeds under 0.125 at
    mode 1, the lowest -0.02, a flow measurement at a shut valve reading its noise;
    0.28 at mode 2), peak 2896 kPa (off 2903). Without the washout (the whole gain
    tripled, the integral too) the purge closed under IDV(13) at mode 1 to under
    12.5 % of the grade's flow on all 20 seeds (median 4.9 %): a pressure under its
    set point for hours is the reaction's doing there, and the purge's floor was made
    for the trip that follows. Washouts of 0.5, 2 and 4 h: IDV(13) at mode 0 0.765,
    0.801, 0.809 mol %, the purge at mode 1 under 12.5 % on 7, 1 and 15 seeds. At
    ``f = 2`` (the whole gain) IDV(8) at mode 0 0.534, at ``f = 5`` IDV(13) at mode 0
    0.863. The whole gain on the plant side's loop itself, through grade changes too
    (the models linearized with it), slowed 1 -> 0 from 2.8 to 5.1 h.

    Beside the matrix, with it on: IDV(8), IDV(1) and IDV(6) through legs
    (``te_idv_through_legs.json``, 750 runs) with no trip of ``ssmpc`` or ``fixed``
    (peak 2896 kPa, as off); IDV(13) at mode 2 on seeds 1-80 with no trip (peak 2896
    kPa; 2903 off); maximum production (``te_max_production.json`` and its return)
    with no trip of the MPC strategies; the settled costs (held at each grade, hours
    24-36 and 36-48) within -0.2 to +0.8 % of Ricker's optimum at mode 1, -0.2 to
    +0.3 % at mode 2 and -0.3 to +2.2 % at mode 3 (off: +1.1, +0.4, +2.1 % at most);
    ``ssmpc reproduce R7.13 R7.14 R7.16`` with the same verdicts; the soak
    (``ssmpc soak --unit te --hours 48 --seed 7``) with no shutdown, no record lost,
    the controller's resume bumpless; the bench's controller step (``ssmpc bench
    te-closed-loop``) 0.195 / 0.404 ms median / p99 (0.195 / 0.412 off).

On by default, and what it moved
    ``make_te_controller`` switches it on for the MPC strategies
    (``pressure_gain=False`` takes it off). Six tests of the cascade's guards (the
    A-rise hold, the A-lost guard, the old slack weights, the constraint window, the
    floating pressure, the A loop's half action) show a trip or an effect that the
    lead removes or shrinks by itself; they run with it off and say so with the
    number measured with it. In the operator's held-T_r* case
    (``tests/test_te_operator.py``) the set point written over the half hour before
    2 h stands 29 kPa from the pressure on the mean and up to 74 kPa (10 and 10 off):
    with the lead the targets' economics lift P_r* there and the tracking cap allows
    40 kPa above the pressure while they do (``TransitionGuards.purge_track_lift_kpa``;
    the core's P_r* 19 kPa above the pressure on the mean, 0-38 kPa), and the lead
    adds 10.5 kPa on the mean. The test holds the pressure to the core's own P_r*. A
    lead on the measurement instead of the error (no lead on the core's moves) closed
    the purge under IDV(13) at modes 1 and 2 on 19 of 20 seeds: where the tracking
    cap holds P_r* a margin above a falling pressure, every fall was led.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.lag import lag_step
from controller.units.te.settings_check import check_finite_fields, check_range, is_finite_number
from controller.units.te.steady_share import ramp_share

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
               limits: tuple[float, float] = (-math.inf, math.inf),
               stepped: bool = False) -> float:
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
        stepped : bool
            A guard's own rule (the purge's floor, the floating pressure, the hold)
            started or ended setting P_r* this sample, which steps it: the washout
            takes the error as it is now, so the step is not led.
        """
        s = self.settings
        if self._pending:  # no word since: the plant took the last set point written
            self.offset_in_force = self.offset_written
        if self.operator_held:
            self.share = self.bias = 0.0
        else:
            self.share = ramp_share(self.share, since_h >= s.after_h and not held,
                                    self.sample_h, s.ramp_h)
        self.bias = (min(self.bias + self.bias_step, 0.0) if self.bias < 0.0
                     else max(self.bias - self.bias_step, 0.0))
        out = setpoint
        if math.isfinite(setpoint):
            d = setpoint - pressure
            if math.isfinite(d):
                if self.error_lag is None or stepped:
                    self.error_lag = d
                self.error_lag = lag_step(self.error_lag, d, self.sample_h, s.washout_h)
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
        """Restore a checkpoint; an absent or damaged field (or a state that is not a
        mapping) starts as new (no lead)."""
        st = state if isinstance(state, dict) else {}

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
