"""The process settings of a sample loop (services.realtime_process), as nodes make
them after set-up: the set-up frozen out of the collector, rare young collections,
BLAS on the calling thread. Each check runs in a fresh interpreter (the settings are
process-wide)."""

import json
import subprocess
import sys

import pytest

from services.realtime_process import SampleProcessSettings

_PROBE = """
import gc, json, sys
from threadpoolctl import threadpool_info
import numpy
setup = [{{"model": i}} for i in range(20000)]  # what a node's set-up leaves behind
{settle}
collections = []
gc.callbacks.append(lambda phase, info: phase == "start" and collections.append(
    info["generation"]))
samples = [{{"k": k}} for k in range(5000)]  # 5000 samples' worth of small objects
print(json.dumps({{"frozen": gc.get_freeze_count(), "threshold": gc.get_threshold(),
                  "switch": sys.getswitchinterval(), "collections": len(collections),
                  "blas": [i["num_threads"] for i in threadpool_info()
                           if i["user_api"] == "blas"]}}))
"""


def _probe(settle: str) -> dict:
    out = subprocess.run([sys.executable, "-c", _PROBE.format(settle=settle)],
                         capture_output=True, text=True, timeout=120, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def test_a_node_freezes_its_setup_and_collects_rarely():
    plain = _probe("")
    node = _probe("from services.nodes.run import _realtime_tuning\n_realtime_tuning()")
    # as Python leaves it, 5000 new objects set off young collections
    assert plain["frozen"] == 0 and plain["collections"] > 0
    # after the node's tuning the set-up is in the permanent generation and the same
    # allocations set off none
    assert node["frozen"] >= 20000
    assert node["collections"] == 0
    assert node["threshold"][0] >= 10 * plain["threshold"][0]
    assert node["switch"] < plain["switch"]
    assert node["blas"] and all(n == 1 for n in node["blas"])


def test_the_mpc_step_bench_times_samples_under_the_node_settings(monkeypatch):
    """The benchmark of the controller's sample settles the process as a node does
    (its samples are timed as the node runs them, no other way)."""
    from services.bench import mpc_step

    calls = []
    monkeypatch.setattr(mpc_step, "settle_for_samples", lambda: calls.append(1))
    case = mpc_step.two_phase_case(1, adapt=False)
    assert calls == [1] and case["n"] >= 1


@pytest.mark.parametrize("kwargs", [
    {"gc_thresholds": (0, 50, 100)}, {"gc_thresholds": (700, 10)},
    {"gc_thresholds": (700.0, 10, 10)}, {"gc_thresholds": (True, 10, 10)},
    {"switch_interval_s": 0.0}, {"switch_interval_s": float("nan")},
    {"switch_interval_s": "fast"}, {"blas_threads": 0}, {"blas_threads": 1.5},
])
def test_bad_settings_are_refused_by_name(kwargs):
    with pytest.raises(ValueError, match=next(iter(kwargs))):
        SampleProcessSettings(**kwargs)
