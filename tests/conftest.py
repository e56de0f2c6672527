"""Test-session setup shared by every test module."""

import os

import pytest
from hypothesis import settings

# As in the CLI: single-threaded BLAS for small matrices (set before numpy loads).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
os.environ.setdefault("MPLBACKEND", "Agg")

# Property tests judge results, not speed: no per-example wall-clock deadline (the
# suite runs on two workers, and a loaded core must not fail an example that is right).
settings.register_profile("suite", deadline=None)
settings.load_profile("suite")


@pytest.fixture
def stack(tmp_path):
    """A CSTR unit over real Zenoh (test_service_loop.Harness) with a real api server."""
    from test_api import ApiServer
    from test_service_loop import Harness

    h = Harness(tmp_path)
    api = ApiServer(h)
    yield h, api
    api.close()
    h.close()


@pytest.fixture
def te_api(harness):
    """The TE unit over real Zenoh, not in lock step (in warm and off the controller
    writes nothing, and a lock-step plant would wait for a move every sample), at 1000x,
    with a real api server."""
    from test_api import ApiServer

    h = harness(unit="te", speed=1000.0, lockstep=False, telemetry=False)
    api = ApiServer(h)
    yield h, api
    api.close()


@pytest.fixture
def harness(tmp_path):
    """Make a test_service_loop.Harness (controller and plant nodes over real Zenoh) with
    ``harness(**kw)``; every one made is closed after the test."""
    from test_service_loop import Harness

    hs = []

    def make(**kw):
        h = Harness(tmp_path, **kw)
        hs.append(h)
        return h

    yield make
    for h in hs:
        h.close()
