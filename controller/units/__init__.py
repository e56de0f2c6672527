"""The tuned controller of each unit: product code, pure (no network, no service).

A unit's controller is the method of :mod:`controller` tuned for one plant of
:mod:`plant_sim`: its models, grades, tuning and, for TE, the cascade around it.
The service (:mod:`services.registry`), the seed studies and the campaigns all build
their controllers from here, so the same code runs online and offline.

- :mod:`controller.units.config` — the validated unit configuration, grades, scales
  and ranges;
- :mod:`controller.units.baselines` — decoupled PI and "hold" for any square unit;
- :mod:`controller.units.takeover` — bumpless take-over of a running plant;
- :mod:`controller.units.siso` — chapter 5: CSTR and bioreactor (multiple models,
  H∞ or MRAC);
- :mod:`controller.units.two_phase_reactor` — chapter 6: state-shared Δu MPC;
- :mod:`controller.units.te` — chapter 7: the Tennessee Eastman cascade, grade plans,
  models, strategies and baselines.
"""
