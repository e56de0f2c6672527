"""Every numba kernel a unit's loop calls is compiled (or loaded from numba's cache) when
its nodes are built, for the argument types the samples pass: no sample compiles one.

A kernel compiled in a sample stalls the loop for as long as the compilation takes
(about a second per kernel on a cold cache): a real-time loop misses its deadlines
meanwhile. numba compiles one version of a kernel per combination of argument types
(dtype, ndim, layout, writeability), so a warm-up with the wrong layout leaves the
sample's own version to compile; a dispatcher's ``signatures`` grows by one per
version compiled or loaded, which is what these tests watch.
"""

from __future__ import annotations

import sys

import pytest
from numba.core.dispatcher import Dispatcher

from controller import hold_kernel, state_kernel, switching_kernel
from controller.units.te import path_kernel, targets_kernel
from controller.units.te.control import make_te_controller, run_te
from controller.units.te.grades import Leg, TransitionPlan

KERNELS = (path_kernel.path_exponents, path_kernel.path_values, targets_kernel.offset_step,
           targets_kernel.target_fields, hold_kernel.hold_forward, hold_kernel.hold_errors,
           hold_kernel.hold_advance, hold_kernel.hold_regressor_parts,
           state_kernel.advance_state, switching_kernel.steady_output_errors)

#: Packages whose kernels are watched: the controller's and the plants'.
PACKAGES = ("controller", "plant_sim")


def loaded_kernels() -> dict[str, Dispatcher]:
    """Every numba dispatcher at module level in the loaded modules of :data:`PACKAGES`,
    by ``module.function`` of its Python function (a kernel imported elsewhere counts
    once)."""
    out = {}
    for name, mod in list(sys.modules.items()):
        if mod is None or name.split(".")[0] not in PACKAGES:
            continue
        for obj in list(vars(mod).values()):
            if isinstance(obj, Dispatcher):
                out[f"{obj.py_func.__module__}.{obj.py_func.__qualname__}"] = obj
    return out


def versions() -> dict[str, tuple]:
    """The argument types each loaded kernel has a compiled version for."""
    return {name: tuple(map(str, k.signatures)) for name, k in loaded_kernels().items()}


def new_versions(before: dict[str, tuple], after: dict[str, tuple]) -> dict[str, list]:
    """The versions in ``after`` that ``before`` did not have, by kernel."""
    out = {}
    for name, sigs in after.items():
        new = [s for s in sigs if s not in before.get(name, ())]
        if new:
            out[name] = new
    return out


@pytest.mark.parametrize("strategy", ["ssmpc", "fixed"])
def test_a_run_compiles_no_kernel(strategy):
    plan = TransitionPlan("mode0", (Leg(0.1, "mode2"),))
    make_te_controller(strategy, plan)
    before = {k.__name__: len(k.signatures) for k in KERNELS}
    assert all(before.values()), before
    run_te(strategy, plan, 0.3, stop_on_trip=False)
    assert {k.__name__: len(k.signatures) for k in KERNELS} == before


#: Every unit of the registry with its default controller, and the other controllers
#: and strategies a unit's configuration can name.
UNIT_CASES = [
    ("cstr", {}), ("bioreactor", {}), ("two_phase_reactor", {}), ("te", {}),
    ("cstr", {"controller": "mrac"}), ("bioreactor", {"controller": "mrac"}),
    ("cstr", {"controller": "pi"}), ("two_phase_reactor", {"controller": "pi"}),
    ("te", {"strategy": "fixed"}), ("te", {"strategy": "pi"}),
]


@pytest.mark.integration
@pytest.mark.timeout(300)
@pytest.mark.parametrize(("unit", "over"), UNIT_CASES,
                         ids=[u + "".join(f"-{v}" for v in o.values()) for u, o in UNIT_CASES])
def test_the_nodes_samples_compile_no_kernel(harness, unit, over):
    """The controller and plant nodes as the service makes them (over Zenoh, lock-step):
    once both are built, their samples add no compiled version to any kernel."""
    h = harness(unit=unit, start_plant=False, **over)
    before = {}
    h.start_plant(on_built=lambda: before.update(versions()))
    assert any(before.values()), "no compiled kernel seen: nothing would be detected"
    start = h.ctrl.k
    h.wait_samples(25, timeout=60.0)
    assert h.ctrl.k >= start + 25 and h.ctrl.failed_samples == 0
    assert new_versions(before, versions()) == {}


def test_a_kernel_compiled_in_a_sample_is_seen():
    """The check itself: a call with a layout the kernel has no version for shows."""
    import numpy as np

    k = hold_kernel.hold_advance
    c, y, h = np.zeros((2, 3)), np.zeros(2), np.zeros(3)
    k(c, y, y, h)
    before = versions()
    k(np.asfortranarray(np.zeros((2, 3))), y, y, h)  # an F-ordered c: another version
    new = new_versions(before, versions())
    assert list(new) == ["controller.hold_kernel.hold_advance"] and len(new[next(iter(new))]) == 1
