"""Every closed loop of the library runs with BLAS on one thread, whoever calls it.

Each test first raises BLAS to two threads (as a caller's process may have it: OpenBLAS
starts with one thread per core) and then checks, from inside the loop's controller
step, that the loop runs single-threaded, and that the caller's setting is back after.
"""

from __future__ import annotations

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from controller.blas import blas_threads
from controller.interfaces import ControlDecision

pytestmark = pytest.mark.realtime


@pytest.fixture
def two_blas_threads():
    with threadpool_limits(limits=2, user_api="blas"):
        if blas_threads() < 2:
            pytest.skip("this machine's BLAS runs one thread at most")
        yield
        assert blas_threads() == 2  # the runner restored the caller's setting


class _Spy:
    """A controller that holds its input and notes the BLAS threads at every step."""

    def __init__(self, nu=1):
        self.seen = []
        self.u = np.zeros(nu)

    def step(self, k, t, y, reference):
        self.seen.append(blas_threads())
        return ControlDecision(u=self.u.copy(), status="hold")

    def checkpoint(self):
        return {}

    def restore(self, state):
        pass


def test_run_closed_loop_is_single_threaded(two_blas_threads):
    from controller.loop import run_closed_loop
    from controller.reference import ReferenceTrajectory, SetpointSchedule

    spy = _Spy()
    ref = ReferenceTrajectory(SetpointSchedule([0.0], [[0.0]]), 1.0, 0.1, initial=[0.0])
    run_closed_loop(lambda x, u, t, dt: x, lambda x, t: x[:1], np.zeros(1), spy, ref, 1.0)
    assert spy.seen and set(spy.seen) == {1}


def test_run_te_is_single_threaded(two_blas_threads, monkeypatch):
    from controller.units.te import control
    from controller.units.te.grades import TransitionPlan

    seen = []
    original = control.TEController.step

    def spy(self, *a, **k):
        seen.append(blas_threads())
        return original(self, *a, **k)

    monkeypatch.setattr(control.TEController, "step", spy)
    control.run_te("pi", TransitionPlan("mode0"), 0.05)
    assert seen and set(seen) == {1}


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_controller_and_plant_nodes_run_single_threaded(tmp_path, two_blas_threads):
    from test_service_loop import Harness

    spies = []

    def factory(cfg):
        spies.append(_Spy())
        return spies[-1]

    h = Harness(tmp_path, unit="cstr", speed=100.0, telemetry=False, controller_factory=factory)
    try:
        h.wait_samples(10, timeout=60)
        seen = list(spies[0].seen)  # while both nodes run
    finally:
        h.close()
    assert seen and set(seen) == {1}
