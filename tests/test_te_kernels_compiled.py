"""The TE sample path's compiled kernels are compiled (or loaded) when the controller is
built, for the argument types a run passes: no sample compiles one."""

from __future__ import annotations

import pytest

from controller import hold_kernel, state_kernel, switching_kernel
from controller.units.te import path_kernel, targets_kernel
from controller.units.te.control import make_te_controller, run_te
from controller.units.te.grades import Leg, TransitionPlan

KERNELS = (path_kernel.path_exponents, path_kernel.path_values, targets_kernel.offset_step,
           targets_kernel.target_fields, hold_kernel.hold_forward, hold_kernel.hold_errors,
           hold_kernel.hold_advance, hold_kernel.hold_regressor_parts,
           state_kernel.advance_state, switching_kernel.steady_output_errors)


@pytest.mark.parametrize("strategy", ["ssmpc", "fixed"])
def test_a_run_compiles_no_kernel(strategy):
    plan = TransitionPlan("mode0", (Leg(0.1, "mode2"),))
    make_te_controller(strategy, plan)
    before = {k.__name__: len(k.signatures) for k in KERNELS}
    assert all(before.values()), before
    run_te(strategy, plan, 0.3, stop_on_trip=False)
    assert {k.__name__: len(k.signatures) for k in KERNELS} == before
