"""NLS identification (eq. 4.1) in the orthonormal shared-state basis vs the companion one.

Chapter-5 style (R4.1 (a)): a plant in the model class (the true model on the sampled
shared state), PRBS input, the adaptive model starting from the other operating point's
model. Both identifiers see the same (u, y); the error is coordinate-free: the identified
model's relative frequency-response error against the true one. "At least as fast": the
geometric mean of the error over the checkpoints and the final error are not larger.
The covariance floor is set out of reach: its reset rule compares lambda_min(P) with
an absolute number, so it acts at different moments in bases whose regressors differ
in scale (see controller.shared_basis).
"""

from __future__ import annotations

import functools

import numpy as np
import pytest

from controller.adaptation import NLSSettings, NormalizedLeastSquares
from controller.linear import Realization, balanced_truncation
from controller.shared_basis import SharedBasis
from controller.state_shared import StateSharedModel

A_POLY = (1.0, 1.0)  # the units' omega(s) = s^2 + s + 1
DT = 0.05
CHECKPOINTS = (100, 250, 500, 1000, 2000, 4000)
#: no checkpoint may be worse than the companion's by more than this factor (measured on
#: the CSTR with the seed's gain: orthonormal 3.3e-2 vs 1.0e-1 at 250 samples, then
#: 5-8 % above it while both stall near 3e-2 at 1000-2000, below again from 4000)
LAG_FACTOR = 1.25
SETTINGS = {
    "seed gain": NLSSettings(kappa=10.0, gain=3.0, rate=1.0, eig_floor=1e-12),
    "least squares": NLSSettings(kappa=1000.0, gain=1.0 / DT, rate=1.0, eig_floor=1e-12),
}


def _linear(plant_name, op, mv=None, cv=None):
    from plant_sim import get_plant
    from plant_sim.linearize import linearize

    lm = linearize(get_plant(plant_name), op)
    if mv is None:
        return lm.A, lm.B, lm.C
    lm = lm.select(mv, cv)
    r = balanced_truncation(lm.A, lm.B, lm.C, order=2).reduced
    return r.A, r.B, r.C


@functools.lru_cache(maxsize=1)
def _cases():
    from controller.units.two_phase_reactor import CV, MV

    return {
        "cstr": (_linear("cstr", "OPI"), _linear("cstr", "OPII"), 1),
        "two_phase_reactor": (_linear("two_phase_reactor", "OPI", MV, CV),
                              _linear("two_phase_reactor", "OPII", MV, CV), 3),
    }


N_SAMPLES = max(CHECKPOINTS)


def _identify(basis, true, guess, m, settings, seed=0, n_samples=N_SAMPLES):
    zeros = np.zeros(m)
    truth = StateSharedModel.model_from_linear("true", *true, zeros, zeros, basis)
    start = StateSharedModel.model_from_linear("adapt", *guess, zeros, zeros, basis,
                                               kind="adaptive")
    ssm = StateSharedModel(basis, m, DT, [truth, start])
    # the plant: the true model on the companion basis' sampled shared state
    plant = StateSharedModel(A_POLY, m, DT, [StateSharedModel.model_from_linear(
        "plant", *true, zeros, zeros, A_POLY)])
    Phi, Gam, Cp, bp = pf = plant.sampled_form(0)
    est = NormalizedLeastSquares(settings, ssm.params_from_theta(start.theta, start.bias), DT)
    rng = np.random.default_rng(seed)
    x, u = np.zeros(Phi.shape[0]), np.zeros(m)
    ssm.initialize(u, Cp @ x + bp)
    w = np.logspace(-2, 2, 41)
    A0, B0, C0, _, _ = ssm.continuous_form(0)
    ref = Realization(A0, B0, C0, None).frequency_response(w)
    errors = []
    for k in range(1, n_samples + 1):
        y = Cp @ x + bp
        est.update(ssm.regressor(), y)
        if k % 10 == 1:
            u = np.sign(rng.standard_normal(m))
        ssm.update(u, y)
        x = Phi @ x + Gam @ u + pf.f
        if k in CHECKPOINTS:
            ssm.set_params(1, est.p)
            A, B, C, _, _ = ssm.continuous_form(1)
            ours = Realization(A, B, C, None).frequency_response(w)
            errors.append(float(np.max(np.abs(ours - ref)) / np.max(np.abs(ref))))
    return np.array(errors)


@pytest.mark.parametrize("setting", sorted(SETTINGS))
@pytest.mark.parametrize("case", ["cstr", "two_phase_reactor"])
def test_orthonormal_basis_identifies_at_least_as_fast(case, setting):
    true, guess, m = _cases()[case]
    comp = _identify(A_POLY, true, guess, m, SETTINGS[setting])
    orth = _identify(SharedBasis.of(A_POLY, "orthonormal"), true, guess, m, SETTINGS[setting])
    assert comp[-1] < 0.5 * comp[0]  # the comparison is between converging runs
    assert np.exp(np.mean(np.log(orth))) <= np.exp(np.mean(np.log(comp))), (comp, orth)
    assert orth[-1] <= comp[-1] and np.all(orth <= LAG_FACTOR * comp), (comp, orth)
