"""Tennessee Eastman challenge process: an exact, compiled port of ``teprob.f``.

Downs & Vogel (1993), the original Fortran model: 50 states, 41 measurements
(XMEAS), 12 manipulated variables (XMV), disturbances IDV(1)-IDV(20), the
original random-number generator, sampled analyzers, shutdown interlocks and
operating cost. By default the numeric literals are those of the published
build (single precision where the source has no D exponent); ``literals="double"``
gives the all-double variant.

- :class:`TennesseeEastman`: the :class:`~plant_sim.base.PlantModel` view
  (noise-free derivative and measurements, grades ``mode0`` ... ``mode6``).
- :class:`TESimulator`: the Euler driver of the original, with noise, IDVs,
  analyzers, interlocks and cost.
- :func:`~plant_sim.tennessee_eastman.batch.run_batch`: many scenarios on all cores.
"""

from __future__ import annotations

# first: drops stale compiled code before any numba function is loaded
from plant_sim.tennessee_eastman import _numba_cache  # noqa: F401
from plant_sim.tennessee_eastman.batch import Scenario, ScenarioResult, run_batch
from plant_sim.tennessee_eastman.plant import TennesseeEastman
from plant_sim.tennessee_eastman.simulator import Shutdown, SimSettings, TESimulator

__all__ = ["TennesseeEastman", "TESimulator", "SimSettings", "Shutdown", "Scenario",
           "ScenarioResult", "run_batch"]
