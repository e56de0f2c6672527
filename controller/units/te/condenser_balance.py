"""The condenser's cooling-water energy balance: a soft sensor that tells a
condenser-side disturbance from one inside the reactor.

Loops that move the condenser hard help where the condenser's cooling is what varies
(IDV(12), the cooling water's inlet temperature at random; IDV(18), the condenser's heat
transfer in spikes) and hurt elsewhere: the product flow on the condenser
(``TEController`` ``production_condenser_loop``) tripped the plant under the kinetics'
slow drift (IDV(13)), which also moves the product flow, and the separator temperature
on it at the PI baseline's tuning (``condenser_disturbance_loop``) took G's deviation up
under IDV(20) and IDV(8). The separator temperature, the purge's C and the pressure move
alike under all of them; the cooling water's outlet temperature (XMEAS 22) does not,
once what the controller itself does to it is taken out. This module predicts XMEAS 22
from the measured inputs of the condenser's cooling-water side and reports how much of
its variation the prediction does not explain over the last half hour; the controller
opens those loops only while it reports.

The balance, Downs & Vogel (1993), the TE model's condenser (its FORTRAN ``TEFUNC``)::

    H dT/dt = F c (T_in - T) - UA(f) (T - T_r) s

with T the cooling water's outlet temperature (XMEAS 22, degC), T_r the reactor
temperature (XMEAS 9; the effluent enters the condenser at it), F the cooling-water flow
(:data:`CW_FLOW_PER_PCT` per % of XMV 11), T_in the inlet temperature (its design value
:attr:`CondenserBalanceSettings.inlet_degc`), c = :data:`CW_HEAT_CAPACITY`, s =
:data:`HEAT_UNIT`, H = :data:`CW_HOLDUP` and the heat-transfer coefficient
UA(f) = :data:`UA_MAX` (1 - 1 / (1 + (f / :data:`UA_FLOW`)^4)) of the reactor effluent's
flow f. f is not measured; it is taken as
:attr:`CondenserBalanceSettings.effluent_per_recycle` times the recycle flow (XMEAS 5):
on the plant at Ricker's modes 0-3 (no noise, the MPC at its grade) the ratio implied by
the balance is 120.7, 116.4, 116.4 and 121.0 (kmol/h per kscmh).

The prediction starts at the balance's rest for the first sample's inputs (so that a
standing offset from the plant is not taken for a variation) and is integrated exactly
over each sample with its inputs held. Its residual
e = XMEAS 22 - prediction is followed by exponentially weighted mean and variance over
:attr:`CondenserBalanceSettings.window_h`, and so is the prediction itself; the
indicator is the residual's standard deviation less
:attr:`CondenserBalanceSettings.explained_share` times the prediction's (the balance's
error grows with how far its inputs move it). :attr:`CondenserBalance.active` is true
while the indicator is at or above :attr:`CondenserBalanceSettings.on_degc` and for
:attr:`CondenserBalanceSettings.hold_h` after (the spikes of IDV(18) come and go).

Measured (``ssmpc`` as shipped, the condenser-side disturbance loop opened by this
balance; noise on, seed 1 unless named, 48 h, onset 2 h; the indicator from 3 h on, degC,
and the share of that time reported):

=======================  ==================  ==========================  ========
case                     seeds               indicator p50 / p90 / max   reported
=======================  ==================  ==========================  ========
no disturbance, mode 0   1                   0.04 / 0.05 / 0.09          0
no disturbance, mode 2   1                   0.03 / 0.04 / 0.06          0
IDV(12) at mode 0        1                   1.20 / 1.70 / 2.30          1.00
IDV(12) at mode 2        1                   0.85 / 1.20 / 1.68          1.00
IDV(18) at mode 0        1                   0.52 / 0.95 / 1.19          0.92
IDV(18) at mode 2        1                   0.65 / 1.21 / 1.51          0.92
IDV(5) at modes 0, 2     1                   max 0.68, 0.46 (the step)   0.05
IDV(13) at mode 1        28, 32              max 0.05                    0
IDV(13) at mode 2        5, 17, 25           max 0.05                    0
IDV(1), (8), (15), (20)  1, at mode 2        max 0.04-0.06               0
=======================  ==================  ==========================  ========

On seed 1 at modes 0 and 2, IDV 1-20 alone (the loops off): the indicator passed
0.16 degC only under IDV(5), (12) and (18), the condenser's side. The steps to it, on
runs with the loops off (1 h window): the residual's standard deviation alone, with UA
held at its start value, was 0.76-1.06 degC at the 10th percentile under IDV(12) and up
to 1.7 degC under IDV(13) (the effluent's flow moves UA); with UA from the recycle flow,
up to 1.1 degC under IDV(13), in the MPC's large moves of the condenser, whose effect
the balance then follows only in part; less half the prediction's own deviation, at
most 0.14 degC.
The effluent's flow from the reactor-separator pressure difference instead (f =
385 sqrt(XMEAS 7 - XMEAS 13)) reads IDV(20)'s spikes of the effluent's flow coefficient
as well (a residual deviation of 1.1 degC at the median): not taken.

A failed XMEAS 22 can open the loops, not move the plant by itself: frozen, its residual
mirrors the prediction and reports once the prediction varies by 0.6 degC or more (the
valve moving hard); noisy, it reports. The loops it opens act on their own measurements
within their trims' ranges. A sample that is not finite is skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from controller.units.te.settings_check import (
    check_finite_fields,
    check_range,
    is_finite_number,
)

__all__ = ["CondenserBalanceSettings", "CondenserBalance", "CW_FLOW_PER_PCT",
           "CW_HEAT_CAPACITY", "HEAT_UNIT", "CW_HOLDUP", "UA_MAX", "UA_FLOW"]

#: Cooling-water flow per % of XMV 11 (Downs & Vogel: the valve's range 1200 / 100).
CW_FLOW_PER_PCT = 12.0
#: Cooling water's heat capacity in the balance (Downs & Vogel 500.53).
CW_HEAT_CAPACITY = 500.53
#: Unit of the heat duty in the balance (Downs & Vogel 1e6 / 1.8).
HEAT_UNIT = 1.0e6 / 1.8
#: Cooling water's holdup in the condenser (Downs & Vogel 11138).
CW_HOLDUP = 11138.0
#: Largest heat-transfer coefficient (Downs & Vogel 0.404655).
UA_MAX = 0.404655
#: Effluent flow at which the coefficient is half its largest (Downs & Vogel 3528.73 kmol/h).
UA_FLOW = 3528.73


@dataclass(frozen=True)
class CondenserBalanceSettings:
    """Settings of :class:`CondenserBalance` (see the module docstring).

    Parameters
    ----------
    inlet_degc : float
        The cooling water's design inlet temperature, degC (Downs & Vogel 40).
    effluent_per_recycle : float
        Reactor effluent flow per recycle flow (XMEAS 5), kmol/h per kscmh (> 0).
    window_h : float
        Time constant of the residual's mean and variance, h (> 0).
    on_degc : float
        Residual standard deviation from which a condenser-side disturbance is
        reported, degC (> 0).
    hold_h : float
        How long the report stays after the indicator falls below ``on_degc``, h (>= 0).
    explained_share : float
        Share of the prediction's own standard deviation taken off the residual's: the
        balance's error grows with how far its inputs move it (>= 0).
    """

    inlet_degc: float = 40.0
    effluent_per_recycle: float = 118.5
    window_h: float = 0.5
    on_degc: float = 0.3
    hold_h: float = 2.0
    explained_share: float = 0.5

    def __post_init__(self) -> None:
        label = "condenser balance "
        check_finite_fields(self, label)
        check_range(self, "inlet_degc", "[0, 100]", "degC", label)
        check_range(self, ("effluent_per_recycle", "window_h", "on_degc"), "> 0",
                    label=label)
        check_range(self, "hold_h", ">= 0", "h", label)
        check_range(self, "explained_share", ">= 0", label=label)


class CondenserBalance:
    """The condenser's cooling-water balance, sample by sample.

    Parameters
    ----------
    settings : CondenserBalanceSettings, optional
    sample_h : float
        The supervisory sample, h (> 0).
    """

    def __init__(self, settings: CondenserBalanceSettings | None = None,
                 sample_h: float = 0.01) -> None:
        if not (math.isfinite(sample_h) and sample_h > 0):
            raise ValueError(f"sample_h: need a finite number > 0 h, got {sample_h!r}")
        self.settings = settings or CondenserBalanceSettings()
        self.sample_h = float(sample_h)
        self.reset()

    def reset(self) -> None:
        """Forget the prediction and the residual's statistics (the next sample
        starts them)."""
        #: predicted XMEAS 22 for the next sample, degC (None: not started)
        self.prediction: float | None = None
        #: the residual's exponentially weighted mean and variance, degC, degC^2
        self.mean = 0.0
        self.var = 0.0
        #: the prediction's, degC, degC^2 (what the balance explains)
        self.pred_mean: float | None = None
        self.pred_var = 0.0
        #: hours since the indicator was last at or above ``on_degc`` (inf: never)
        self.since_on_h = math.inf

    @property
    def indicator(self) -> float:
        """The residual's standard deviation over the window less
        :attr:`CondenserBalanceSettings.explained_share` times the prediction's, degC."""
        return (math.sqrt(max(self.var, 0.0))
                - self.settings.explained_share * math.sqrt(max(self.pred_var, 0.0)))

    @property
    def active(self) -> bool:
        """Whether a condenser-side disturbance is reported now."""
        return self.since_on_h <= self.settings.hold_h

    def ua(self, recycle: float) -> float:
        """The heat-transfer coefficient at the recycle flow ``recycle`` (XMEAS 5)."""
        x = self.settings.effluent_per_recycle * max(recycle, 0.0) / UA_FLOW
        x4 = (x * x) * (x * x)
        return UA_MAX * (1.0 - 1.0 / (1.0 + x4))

    def update(self, t_cw_out: float, t_reactor: float, cw_valve_pct: float,
               recycle: float) -> bool:
        """Advance one sample; return :attr:`active`.

        Parameters
        ----------
        t_cw_out : float
            The cooling water's outlet temperature, XMEAS 22, degC.
        t_reactor : float
            Reactor temperature, XMEAS 9, degC.
        cw_valve_pct : float
            The condenser's cooling-water valve, XMV 11, % (as written this sample).
        recycle : float
            Recycle flow, XMEAS 5, kscmh.

        A sample with a value that is not finite leaves everything as it was (but
        the hold's clock).
        """
        s = self.settings
        self.since_on_h += self.sample_h
        if not all(map(math.isfinite, (t_cw_out, t_reactor, cw_valve_pct, recycle))):
            return self.active
        fc, us = self._rates(cw_valve_pct, recycle)
        if self.prediction is None:
            # started at rest: an offset of the balance from the plant is no variation
            self.prediction = self._steady(t_reactor, fc, us)
            self.mean, self.var = t_cw_out - self.prediction, 0.0
            self.pred_mean, self.pred_var = self.prediction, 0.0
        else:
            a = min(self.sample_h / s.window_h, 1.0)
            self.mean, self.var = _ew_step(self.mean, self.var, t_cw_out - self.prediction, a)
            self.pred_mean, self.pred_var = _ew_step(self.pred_mean, self.pred_var,
                                                     self.prediction, a)
            if self.indicator >= s.on_degc:
                self.since_on_h = 0.0
        self.prediction = self._advance(self.prediction, t_reactor, fc, us)
        return self.active

    def _rates(self, cw_valve_pct: float, recycle: float) -> tuple[float, float]:
        """F c and UA s of the balance."""
        fc = CW_FLOW_PER_PCT * min(max(cw_valve_pct, 0.0), 100.0) * CW_HEAT_CAPACITY
        return fc, self.ua(recycle) * HEAT_UNIT

    def _steady(self, t_reactor: float, fc: float, us: float) -> float:
        """The balance's outlet temperature at rest with the rates ``fc``, ``us``
        (:meth:`_rates`), degC."""
        if fc + us <= 0.0:  # no cooling water and no effluent: the design inlet
            return self.settings.inlet_degc
        return (fc * self.settings.inlet_degc + us * t_reactor) / (fc + us)

    def _advance(self, t: float, t_reactor: float, fc: float, us: float) -> float:
        """The balance's outlet temperature one sample on from ``t``, inputs held."""
        if fc + us <= 0.0:
            return t
        t_ss = self._steady(t_reactor, fc, us)
        return t_ss + (t - t_ss) * math.exp(-(fc + us) / CW_HOLDUP * self.sample_h)

    def state(self) -> dict[str, Any]:
        """What a restart needs, JSON-ready."""
        return {"prediction": self.prediction, "mean": self.mean, "var": self.var,
                "pred_mean": self.pred_mean, "pred_var": self.pred_var,
                "since_on_h": (None if math.isinf(self.since_on_h) else self.since_on_h)}

    def restore(self, state: Any) -> None:
        """Go on from :meth:`state`; anything missing or damaged starts afresh."""
        self.reset()
        if not isinstance(state, dict):
            return
        keys = ("prediction", "mean", "var", "pred_mean", "pred_var")
        vals = [state.get(k) for k in keys]
        if not (all(map(is_finite_number, vals)) and vals[2] >= 0.0 and vals[4] >= 0.0):
            return
        (self.prediction, self.mean, self.var, self.pred_mean,
         self.pred_var) = (float(v) for v in vals)
        since = state.get("since_on_h")
        if is_finite_number(since) and since >= 0.0:
            self.since_on_h = float(since)


def _ew_step(mean: float, var: float, x: float, a: float) -> tuple[float, float]:
    """One step of an exponentially weighted mean and variance (weight ``a`` of the
    new value ``x``)."""
    d = x - mean
    return mean + a * d, (1.0 - a) * (var + a * d * d)
