"""Δu model predictive control on the selected model (seed chapter 6, eq. 6.3–6.10).

Modules: :mod:`~controller.mpc.settings` (tuning and limits),
:mod:`~controller.mpc.formulation` (augmented model, prediction matrices, condensed QP),
:mod:`~controller.mpc.qp` (one QP interface, DAQP and proxsuite backends),
:mod:`~controller.mpc.filters` (first-order measurement filter, §6.1.2),
:mod:`~controller.mpc.controller` (deadline-safe per-sample controller) and
:mod:`~controller.mpc.law` (the MPC as the control law of the state-shared
multiple-model controller).
"""

from controller.mpc.controller import LinearModelState, ModelView, MPCController, StateSource
from controller.mpc.filters import FirstOrderFilter
from controller.mpc.formulation import (
    DeltaUFormulation,
    FormulationCache,
    QPVectors,
    augment,
    build_formulation,
    prediction_matrices,
)
from controller.mpc.law import MPCLaw, SharedStateSource
from controller.mpc.qp import DAQPBackend, ProxsuiteBackend, QPResult, QPSolver, make_solver
from controller.mpc.settings import BACKENDS, OFFLINE_BUDGET_MS, MPCSettings, MPCSettingsError

__all__ = [
    "BACKENDS", "DAQPBackend", "DeltaUFormulation", "FirstOrderFilter", "FormulationCache",
    "LinearModelState", "MPCController", "MPCLaw", "SharedStateSource", "MPCSettings",
    "MPCSettingsError", "ModelView", "OFFLINE_BUDGET_MS",
    "ProxsuiteBackend", "QPResult", "QPSolver", "QPVectors", "StateSource", "augment",
    "build_formulation", "make_solver", "prediction_matrices",
]
