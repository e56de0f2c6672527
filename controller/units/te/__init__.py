"""The Tennessee Eastman unit's controller (seed chapter 7).

- :mod:`~controller.units.te.grades` — grades (seed Table 7.3), reachability,
  first-order transition plans, run metrics;
- :mod:`~controller.units.te.leg_references` — the MPC's own, faster references of the
  reactor level and temperature through a leg;
- :mod:`~controller.units.te.max_production` — the back-off grades of Ricker's
  maximum-production modes 4-6;
- :mod:`~controller.units.te.loops` — the inner PI loops the plant side runs;
- :mod:`~controller.units.te.models` — the linear models of the cascade the MPC acts
  on, and their state-shared model;
- :mod:`~controller.units.te.composition_core` — the MPC on the D share and G in
  product that plans a grade change;
- :mod:`~controller.units.te.linear_models` — the chapter-3 models (Table 7.10's
  loops as printed; R7.10-R7.15);
- :mod:`~controller.units.te.pi_baseline` — the seed's decentralized PI baseline;
- :mod:`~controller.units.te.control` — the supervisory controller (strategies
  ``ssmpc``, ``fixed``, ``pi``) and the offline closed loop :func:`run_te`;
- :mod:`~controller.units.te.structure` — the unit's MV vector, loops and grades as
  the service sees them;
- :mod:`~controller.units.te.service` — the controller behind that MV vector.
"""
