"""The adaptive model under the kinetics' drift (IDV(13)) does not cost G's steadiness.

IDV(13) moves the plant away from every operating point the fixed models were
linearized at, the case the seed's adaptive model is for. With its normalized least
squares at 10 1/h the adaptive model followed the drift sample by sample and the MPC's
moves followed its parameters: on plant seed 17 at mode 2 G's standard deviation in the
product was 1.83 mol % with ``ssmpc`` against 0.57 with ``fixed``
(``docs/te_kinetics_drift.md``); with the reactor level's set point now waiting for the
level on its way back (``controller.units.te.level_sag``), 0.74 against 0.56. At the
product's gain the two are equal there, and the adaptive model is still the one the
index runs on.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from controller.units.te.control import TEMPCOptions, plant_seed_for, run_te
from controller.units.te.grades import TransitionPlan

SEED = 17  # the seed of docs/te_kinetics_drift.md's 40 on which the fast gain did worst
#: how much less steady (mol %) than ``fixed`` G may be with the adaptive model
G_STD_TOL_MOL = 0.05


@lru_cache(maxsize=4)
def _drift_run(strategy: str, nls_gain: float | None = None):
    options = {} if nls_gain is None else {"mpc": TEMPCOptions(nls_gain=nls_gain)}
    run = run_te(strategy, TransitionPlan("mode2"), 48.0, noise=True, idv={13: 2.0},
                 seed=SEED, plant_seed=plant_seed_for(SEED), **options)
    assert run.shutdown is None, run.shutdown
    after = run.t >= 2.0
    return run, float(np.std(run.xmeas[after, 39]))


def test_the_adaptive_model_holds_g_as_steadily_as_the_fixed_models_under_the_drift():
    _, g_fixed = _drift_run("fixed")
    run, g_ssmpc = _drift_run("ssmpc")
    assert g_ssmpc <= g_fixed + G_STD_TOL_MOL, (g_ssmpc, g_fixed)
    # and it is the adaptive model's doing: the index runs on it
    j = run.model_names.index("reinit")
    assert float(np.mean(run.active[run.t >= 2.0] == j)) >= 0.9


def test_the_fast_adaptation_it_replaces_did_not():
    """The same run with the adaptive gain of before: the test above can fail (measured
    0.74 against 0.56 mol %; 1.83 against 0.57 before the level's set point waited for
    the level, the guard that takes most of the difference)."""
    _, g_fixed = _drift_run("fixed")
    _, g_fast = _drift_run("ssmpc", 10.0)
    assert g_fast > g_fixed + 0.1, (g_fast, g_fixed)
