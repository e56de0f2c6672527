"""The chapter-5 tuning of the SISO units (CSTR, bioreactor): multiple models + H∞ or MRAC.

Model set (seed §5.1-5.2): M1 and M2 fixed, linearized at OPI and OPII (each about
its own point through the state-shared bias), M3 free-running and M4 re-initialized
adaptive models starting from the fixed model of the start grade. Shared state:
ω(s) = s² + s + 1, the seed's F = [[0, 1], [-1, -1]], g = [0; 1] (§5.2.3).

Tuning (where the seed's numbers are lost, the choice is the chapter-5 study's,
:mod:`services.reproduce.ch5`, which documents each):

- adaptation (eq. 4.1): κ = 10, γ = 1, λ_min(P) > 1, g = 3; a dead zone of 0.005
  (CSTR) and 0.0005 (bioreactor);
- index (eq. 4.6): μ = 1, ν = 0.1 (seed), forgetting λ = 0.5 and a minimum dwell
  of 2 time units (chosen);
- H∞ weights: CSTR W1 = (s + 3)/(2 (s + 0.02)), W2 = 0.1 (s + 25)/(s + 6000);
  bioreactor the printed W1 with its pole moved to 0.02 (integral action); an
  adaptive model's controller re-synthesized when its parameters moved by > 20 %;
- input limits: CSTR -3 <= u <= 3, bioreactor the plant's range of D.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from controller.adaptation import NLSSettings
from controller.hinf import HInfLaw, HInfWeights
from controller.mrac import MRACLaw
from controller.multimodel import MultiModelController, MultiModelSettings
from controller.state_shared import ModelSpec, StateSharedModel
from controller.switching import IndexSettings
from controller.units.config import time_scale_s

__all__ = ["A_POLY", "BIO_NLS", "BIO_WEIGHTS", "CSTR_WEIGHTS", "INDEX", "KINDS4", "NLS",
           "RESYNTHESIS", "build", "input_limits"]

A_POLY = (1.0, 1.0)  # omega(s) = s^2 + s + 1: F = [[0, 1], [-1, -1]] (seed §5.2.3)
NLS = NLSSettings(kappa=10.0, gain=3.0, rate=1.0, eig_floor=1.0, dead_zone=0.005)
BIO_NLS = replace(NLS, dead_zone=0.0005)
INDEX = IndexSettings(mu=1.0, nu=0.1, forgetting=0.5, min_dwell=2.0)
CSTR_WEIGHTS = HInfWeights.seed_cstr(a=3.0, c=0.1)
BIO_WEIGHTS = HInfWeights.seed_bioreactor(c=0.1)
#: relative parameter change of an adaptive model that re-designs its H∞ controller
RESYNTHESIS = 0.2
KINDS4 = ("fixed", "fixed", "free-running", "re-initialized")


def input_limits(cfg, plant) -> tuple[float, float]:
    """The input range the chapter-5 laws work to: CSTR -3 <= u <= 3 (the seed's is
    lost), bioreactor the plant's range of D (0-1 1/h when the plant gives none)."""
    if cfg.plant != "bioreactor":
        return -3.0, 3.0
    lo, hi = float(plant.input_vars[0].lower), float(plant.input_vars[0].upper)
    return (lo, hi) if math.isfinite(lo) and math.isfinite(hi) else (0.0, 1.0)


def build(cfg, plant, u0, grades, law_name: str) -> MultiModelController:
    """Chapter 5's multiple-model controller on a SISO unit plant (``law_name``:
    ``"hinf"`` or ``"mrac"``), starting at the move ``u0`` (1,)."""
    from plant_sim.linearize import linearize

    if plant.nu != 1 or plant.ny != 1:
        raise ValueError(f"controller: {law_name} is for the SISO units, {cfg.plant} is not SISO")
    bio = cfg.plant == "bioreactor"
    dt = cfg.sample_period_s / time_scale_s(plant)
    lo, hi = input_limits(cfg, plant)
    specs, kinds = [], []
    for name, kind, op in (("M1", "fixed", "OPI"), ("M2", "fixed", "OPII"),
                           ("M3", "free-running", cfg.initial_grade),
                           ("M4", "re-initialized", cfg.initial_grade)):
        lm = linearize(plant, op)
        spec = StateSharedModel.model_from_linear(name, lm.A, lm.B, lm.C, lm.u_op, lm.y_op,
                                                  A_POLY)
        specs.append(ModelSpec(name, spec.theta, spec.bias,
                               "fixed" if kind == "fixed" else "adaptive"))
        kinds.append(kind)
    ssm = StateSharedModel(A_POLY, 1, dt, specs)
    if law_name == "hinf":
        law = HInfLaw(BIO_WEIGHTS if bio else CSTR_WEIGHTS, dt, RESYNTHESIS, lo, hi)
    else:
        law = MRACLaw(dt, lo, hi)
    settings = MultiModelSettings(BIO_NLS if bio else NLS, INDEX, lo, hi, param_margin=0.0)
    start = ["OPI", "OPII"].index(cfg.initial_grade) if cfg.initial_grade in ("OPI",
                                                                              "OPII") else 0
    return MultiModelController(ssm, law, np.asarray(u0, float), settings, kinds=kinds,
                                initial_model=start)
