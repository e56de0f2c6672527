"""Unit registry: unit names -> their validated configuration and tuned controller.

The registry only maps names to the product's units (:mod:`controller.units`); the
configuration itself (:class:`~controller.units.config.UnitConfig`), the grades and
every tuning live in the core. A unit's configuration can be read from a JSON file
(``--unit-config``) on top of the registry defaults (:data:`UNITS`).

Controllers (``UnitConfig.controller``):

- ``"pi"`` — :class:`~controller.units.baselines.PIBaseline`, a discrete multivariable
  PI with static decoupling (velocity form): an honest baseline for any square unit.
- ``"hold"`` — :class:`~controller.units.baselines.HoldController`: MVs held ("MPC
  off"; for TE the regulatory layer alone keeps the levels and the reactor temperature).
- ``"hinf"``, ``"mrac"`` — the SISO units (cstr, bioreactor): the state-shared
  multiple-model controller with the H-infinity (§5.2) or MRAC (§5.1) law, tuned as
  chapter 5 (:mod:`controller.units.siso`).
- ``"ssmpc"`` — two-phase reactor: the state-shared MPC of chapter 6
  (:mod:`controller.units.two_phase_reactor`).
- ``"te"`` — the TE supervisory controller (:mod:`controller.units.te`;
  ``UnitConfig.strategy``: ``ssmpc`` by default, ``fixed`` or ``pi``).

Defaults (:data:`UNITS`): cstr and bioreactor ``hinf``, two_phase_reactor ``ssmpc``,
te ``te``/``ssmpc``.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from controller.units.config import UnitConfig, build_plant, grade_setpoints
from controller.units.te.structure import TE_XMEAS

__all__ = ["CONTROLLER_BUILDERS", "UNITS", "build_controller", "get_unit", "load_unit_config",
           "unit_names"]


# Registry defaults. Sample periods: the seed's where printed, otherwise a choice
# that resolves the plant's dominant dynamics with ~20 samples.
UNITS: dict[str, UnitConfig] = {
    # Chapter 5 tunings (controller.units.siso): sample 0.05, reference time constant 5
    # (duration 20 = 4 tau), H-infinity law on the state-shared multiple models.
    "cstr": UnitConfig(
        unit="cstr", plant="cstr", sample_period_s=0.05, initial_grade="OPI",
        controller="hinf", transition_duration_s=20.0, pi_gain=3.0, pi_integral_time_s=1.0,
        cv_scales=(1.0,), description="exothermic CSTR (dimensionless time taken as seconds)"),
    "bioreactor": UnitConfig(
        unit="bioreactor", plant="bioreactor", sample_period_s=72.0, initial_grade="OPI",
        controller="hinf", transition_duration_s=8 * 3600.0, pi_gain=0.5,
        pi_integral_time_s=7200.0, description="substrate-inhibited bioreactor (0.02 h sample)"),
    # Chapter 6 (controller.units.two_phase_reactor): state-shared MPC, 0.1 h sample.
    "two_phase_reactor": UnitConfig(
        unit="two_phase_reactor", plant="two_phase_reactor", sample_period_s=360.0,
        initial_grade="OPI", mvs=("x1", "x2", "x3"), controller="ssmpc",
        transition_duration_s=4 * 3600.0, pi_gain=0.5, pi_integral_time_s=3600.0,
        cv_scales=(100.0, 10.0, 30.0), settle_tolerance=0.1,
        description="Ricker two-phase reactor (level loop in the plant)"),
    # Seed ch. 7: the supervisory controller (controller.units.te) reads all 41 XMEAS
    # and writes the free valves and the inner loops' set points; a transition is
    # followed on G in product (XMEAS40), settled within +-1 mol% (seed R7.16 check).
    # 36 s sample = 20 Euler steps. Strategy "ssmpc": the state-shared MPC (seed
    # §7.7), the default; "pi" is its decentralized baseline, "fixed" the fixed-model
    # MPC of §7.5.
    "te": UnitConfig(
        unit="te", plant="te", sample_period_s=36.0, initial_grade="mode0", controller="te",
        strategy="ssmpc",
        cvs=TE_XMEAS, track=("XMEAS40",), cv_scales=(10.0,),
        transition_duration_s=12 * 3600.0, settle_tolerance=0.1, settle_samples=50,
        status_every=10, checkpoint_every=100, telemetry_every=100,
        description="Tennessee Eastman with the Table 7.10 regulatory layer (1.8 s Euler)"),
}


def unit_names() -> list[str]:
    return list(UNITS)


def get_unit(unit: str) -> UnitConfig:
    """Registry default of ``unit``; unknown names raise ValueError listing the known ones."""
    if unit not in UNITS:
        raise ValueError(f"unit: unknown unit {unit!r}; known: {', '.join(UNITS)}")
    return UNITS[unit]


def load_unit_config(unit: str, path: str | Path | None = None, **overrides) -> UnitConfig:
    """Registry default, then the JSON file at ``path``, then keyword overrides."""
    cfg = get_unit(unit) if unit in UNITS or path is None else None
    if path is not None:
        try:
            data = json.loads(Path(path).read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"unit_config: cannot read {str(path)!r}: {exc}") from exc
        if not isinstance(data, dict):
            raise ValueError("unit_config: expected a JSON object")
        data.setdefault("unit", unit)
        cfg = UnitConfig.from_dict(data, cfg)
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if overrides:
        cfg = replace(cfg, **overrides)
    return cfg

# Each builder imports its unit's controller when it is called: the commands that only
# read a configuration (``ssmpc up``, the api node, the operator's tools) do not load
# the numerical core.
def _build_pi(cfg, plant, u0, grades):
    from controller.units.baselines import build_pi

    return build_pi(cfg, plant, u0, grades)


def _build_hold(cfg, plant, u0, grades):
    from controller.units.baselines import HoldController

    return HoldController(u0)


def _build_siso(law: str) -> Callable:
    def build(cfg, plant, u0, grades):
        from controller.units import siso

        return siso.build(cfg, plant, u0, grades, law)

    return build


def _build_two_phase(cfg, plant, u0, grades):
    from controller.units import two_phase_reactor

    return two_phase_reactor.build(cfg, plant, u0, grades)


def _build_te(cfg, plant, u0, grades):
    from controller.units.te import service as te_service

    return te_service.build(cfg, plant, u0, grades)


#: Controller builders by ``UnitConfig.controller``: ``fn(cfg, plant, u0, grades)``.
CONTROLLER_BUILDERS: dict[str, Callable] = {
    "pi": _build_pi,
    "hold": _build_hold,
    "hinf": _build_siso("hinf"),
    "mrac": _build_siso("mrac"),
    "ssmpc": _build_two_phase,
    "te": _build_te,
}


def build_controller(cfg: UnitConfig, plant=None, u0=None, grades=None):
    """The unit's :class:`~controller.interfaces.SampleController`, starting at ``u0``."""
    plant = plant if plant is not None else build_plant(cfg)
    grades = grades if grades is not None else grade_setpoints(cfg, plant)
    if u0 is None:
        u0 = grades[cfg.initial_grade]["mv"]
    return CONTROLLER_BUILDERS[cfg.controller](cfg, plant, np.asarray(u0, float), grades)
