"""Shape of the MPC benchmarks' JSON (no timing is asserted)."""

from __future__ import annotations

import json

from services.cli import main


def test_bench_qp_json_shape(capsys):
    assert main(["bench", "qp", "--json", "--samples", "30", "--repeat", "1"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["bench"] == "qp" and doc["machine"]
    # the machine's load before and after, beside the numbers it shaped
    for when in ("before", "after"):
        assert len(doc["load"][when]) == 3 and min(doc["load"][when]) >= 0
    names = [c["case"] for c in doc["cases"]]
    assert names[:3] == ["daqp", "daqp cold", "proxsuite"]
    for c in doc["cases"]:
        assert {"case", "unit", "median", "p99", "max", "n"} <= set(c)
        assert c["n"] == 30 and c["variables"] == 29
    daqp = doc["cases"][0]
    assert daqp["default"] and daqp["failures"] == 0


def test_bench_mpc_step_two_phase_case_shape():
    from services.bench.mpc_step import two_phase_case

    c = two_phase_case(samples=150, adapt=True)
    # two transitions of 150 samples (the fewest), the first 50 samples not timed
    assert c["case"] == "two-phase" and c["unit"] == "ms" and c["n"] == 250
    assert "fallbacks" in c  # counted; its value depends on machine load
    for part in ("errors", "adapt", "switch", "mpc", "update", "cpu"):
        assert f"{part}_median_ms" in c and f"{part}_p99_ms" in c
    # the samples the thread was switched out of, to read a wall tail by
    assert isinstance(c["preempted_samples"], int) and 0 <= c["preempted_samples"] <= c["n"]
    # the samples right after a QP rebuild, counted apart (at most one per rebuild)
    assert 0 < c["after_rebuild_samples"] <= c["rebuilds"]
    assert c["after_rebuild_mpc_median_ms"] > 0


def test_bench_mpc_step_two_phase_targets_case_shape():
    from services.bench.mpc_step import two_phase_case

    c = two_phase_case(samples=150, adapt=True, targets=True)
    assert c["case"] == "two-phase targets" and c["unit"] == "ms" and c["n"] == 250
    assert {"targets_median_ms", "targets_p99_ms", "mpc_median_ms", "relaxed_samples"} <= set(c)
