"""Run identity: a hash of everything that makes one campaign run different.

A run is (unit, case contents, strategy, seed, hours, noise) plus the settings of
the code that runs it: for TE the supervisory sample, the plant's Euler step, the
plant side's inner loops and the loops the core's models close
(:mod:`controller.units.te.loops`), the MPC tuning
(:class:`controller.units.te.control.TEMPCOptions`), the ratio loop
(:class:`~controller.units.te.control.RatioSettings`), the separator-temperature loop
(:data:`~controller.units.te.control.SEPARATOR_LOOP`), the production loop on the
condenser (:data:`~controller.units.te.control.PRODUCTION_CONDENSER_LOOP`) and the
condenser-side disturbance loop
(:data:`~controller.units.te.control.CONDENSER_DISTURBANCE_LOOP`), whether each is on,
and the cooling-water balance that opens them, the
transition guards
(:class:`~controller.units.te.control.TransitionGuards`), the guards' own settings
(feed overrides, production index, level sag, floating pressure), the steady-state
targets' limits, the grade references' time constants and the MPC's faster leg
references; for a unit plant its
registry configuration (:class:`controller.units.config.UnitConfig`).
:data:`RUN_FORMAT` names the run and metrics code; it changes when they change what a
run produces. The identity is
the SHA-256 of the canonical JSON (sorted keys, no spaces) of all that, first 16
hex digits: a case renamed keeps its runs, a case whose legs move gets new ones.
"""

from __future__ import annotations

import hashlib
import inspect
import json
from dataclasses import asdict, dataclass
from functools import cached_property, lru_cache

from services.campaign.spec import CampaignSpec, Case

__all__ = ["RUN_FORMAT", "RunSpec", "plan_runs", "run_settings"]

#: Version of what a run computes and records (bump when runs.py or metrics.py change it).
RUN_FORMAT = "campaign-run-3"


@lru_cache(maxsize=8)
def _settings_json(unit: str) -> str:
    if unit == "te":
        from controller.units.te.condenser_balance import CondenserBalanceSettings
        from controller.units.te.control import (
            COMPOSITION_MPC,
            CONDENSER_DISTURBANCE_LOOP,
            CONDENSER_DISTURBANCE_TRIM_LIMITS,
            CONDENSER_TRIM_WASHOUT_H,
            FEED_BALANCE_MPC,
            GUARDS_MPC,
            LEG_REFERENCES_MPC,
            LOOP_TUNING_MPC,
            PRESSURE_GAIN_MPC,
            PRODUCTION_CONDENSER_LOOP,
            PRODUCTION_CONDENSER_MEAN_H,
            PRODUCTION_CONDENSER_TRIM_LIMITS,
            RATIO_MPC,
            SAMPLE_H,
            SEP_TRIM_LIMITS,
            SEPARATOR_LOOP,
            SEPARATOR_LOOP_STEADY_AFTER_H,
            RatioSettings,
            TEMPCOptions,
            TransitionGuards,
            make_te_controller,
        )
        from controller.units.te.d_share_path import DSharePathSettings
        from controller.units.te.floating_pressure import FloatingPressureSettings
        from controller.units.te.grades import TAU_DEFAULT_H
        from controller.units.te.level_sag import LevelSagSettings
        from controller.units.te.loops import INNER_LOOPS, LOOP_TUNING_SETS, MODEL_LOOPS
        from controller.units.te.overrides import FeedOverrideSettings
        from controller.units.te.production_index import ProductionIndexSettings
        from controller.units.te.reactant_trim import ReactantTrimSettings
        from controller.units.te.targets import CoreTargetSettings

        s = {"sample_h": SAMPLE_H, "plant_dt_s": 1.8,
             "inner_loops": [asdict(lp) for lp in INNER_LOOPS],
             "model_loops": [asdict(lp) for lp in MODEL_LOOPS],
             "mpc": asdict(TEMPCOptions()),
             "ratio": asdict(RatioSettings()), "ratio_mpc": asdict(RATIO_MPC),
             "tau_h": dict(TAU_DEFAULT_H),
             "guards": asdict(TransitionGuards()), "guards_mpc": asdict(GUARDS_MPC),
             "reactants": asdict(ReactantTrimSettings()),
             "d_share_path": asdict(DSharePathSettings()),
             "composition": asdict(COMPOSITION_MPC),
             "leg_references": asdict(LEG_REFERENCES_MPC),
             "pressure_gain": {**asdict(PRESSURE_GAIN_MPC),
                               "on": _default_of(make_te_controller, "pressure_gain")},
             "feed_balance": {**asdict(FEED_BALANCE_MPC),
                              "on": _default_of(make_te_controller, "feed_balance")},
             "loop_tuning": {**asdict(LOOP_TUNING_MPC), "sets": LOOP_TUNING_SETS,
                             "on": _default_of(make_te_controller, "loop_tuning")},
             "feeds": asdict(FeedOverrideSettings()),
             "production": asdict(ProductionIndexSettings()),
             "level_sag": asdict(LevelSagSettings()),
             "floating_pressure": asdict(FloatingPressureSettings()),
             "core_targets": asdict(CoreTargetSettings()),
             "separator_loop": {**asdict(SEPARATOR_LOOP), "trim": list(SEP_TRIM_LIMITS),
                                "after_h": SEPARATOR_LOOP_STEADY_AFTER_H},
             "production_condenser_loop": {
                 **asdict(PRODUCTION_CONDENSER_LOOP),
                 "trim": list(PRODUCTION_CONDENSER_TRIM_LIMITS),
                 "washout_h": CONDENSER_TRIM_WASHOUT_H,
                 "mean_h": PRODUCTION_CONDENSER_MEAN_H,
                 "on": _default_of(make_te_controller, "production_condenser_loop")},
             "condenser_disturbance_loop": {
                 **asdict(CONDENSER_DISTURBANCE_LOOP),
                 "trim": list(CONDENSER_DISTURBANCE_TRIM_LIMITS),
                 "on": _default_of(make_te_controller, "condenser_disturbance_loop")},
             "condenser_balance": asdict(CondenserBalanceSettings())}
    else:
        from services.registry import get_unit

        s = {"unit_config": asdict(get_unit(unit))}
    return json.dumps(s, sort_keys=True, separators=(",", ":"), default=str)


def _default_of(func, name: str):
    """The default of ``func``'s keyword ``name`` (the options a campaign run leaves as
    they are)."""
    return inspect.signature(func).parameters[name].default


def run_settings(unit: str) -> dict:
    """The code-relevant settings of a unit's runs (part of every run's identity)."""
    return json.loads(_settings_json(unit))


@dataclass(frozen=True)
class RunSpec:
    """One run of a campaign: a case, a strategy and a seed of one unit."""

    unit: str
    case: Case
    strategy: str
    seed: int

    @property
    def hours(self) -> float:
        return self.case.hours

    @property
    def noise(self) -> bool:
        return self.case.noise

    def identity_document(self) -> dict:
        """Everything the identity hashes."""
        return {"format": RUN_FORMAT, "unit": self.unit, "case": self.case.contents(),
                "strategy": self.strategy, "seed": self.seed, "hours": self.case.hours,
                "noise": self.case.noise, "settings": run_settings(self.unit)}

    @cached_property
    def run_id(self) -> str:
        text = json.dumps(self.identity_document(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def plan_runs(spec: CampaignSpec) -> list[RunSpec]:
    """The runs of a spec, case by case, strategy by strategy, seed by seed."""
    return [RunSpec(spec.unit, case, strategy, seed)
            for case in spec.cases for strategy in spec.strategies for seed in case.seeds]
