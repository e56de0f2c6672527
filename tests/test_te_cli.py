"""``ssmpc sim te`` and ``ssmpc bench te-sim`` through the CLI entry point."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from services.cli import main

REF = Path(__file__).resolve().parent / "data" / "te_reference"  # origin: its README.md
TRAJ_RTOL = 1e-9


def _last_json(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    return json.loads(out[-1])


def test_sim_te_one_hour_csv_matches_reference_layout_and_values(tmp_path, capsys):
    out = tmp_path / "run.csv"
    assert main(["sim", "te", "--hours", "1", "--out", str(out), "--json"]) == 0
    doc = _last_json(capsys)
    assert doc["shutdown"] is None
    assert doc["speed"]["sim_hours_per_wall_s"] > 0
    ref_path = REF / "a_base_1h_nonoise_dt1.8s.csv"
    assert out.read_text().splitlines()[0] == ref_path.read_text().splitlines()[0]
    ours = np.loadtxt(out, delimiter=",", skiprows=1)
    ref = np.loadtxt(ref_path, delimiter=",", skiprows=1)
    assert ours.shape == ref.shape
    scale = np.max(np.abs(ref), axis=0)
    scale[scale == 0] = 1.0
    assert np.max(np.abs(ours - ref) / scale) <= TRAJ_RTOL


def test_sim_te_runs_to_the_interlock_and_reports_it(tmp_path, capsys):
    out = tmp_path / "trip.csv"
    assert main(["sim", "te", "--hours", "6", "--record-every", "0.5", "--idv", "6@0.1",
                 "--out", str(out), "--json"]) == 0
    doc = _last_json(capsys)
    sd = doc["shutdown"]
    assert sd["reason"] == "reactor pressure high"
    assert 0.1 < sd["time_h"] < 1.0
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    assert rows[0, 0] == 0.0 and rows[1, 0] == pytest.approx(0.5)
    assert rows[-1, 0] == sd["time_h"]  # the final row is the trip
    assert rows[-1, 7] > 3000.0  # XMEAS7 at the trip


@pytest.mark.parametrize("argv, field", [
    (["--idv", "21@0"], "idv"),
    (["--idv", "x"], "idv"),
    (["--dt", "0"], "dt"),
    (["--dt", "-1"], "dt"),
    (["--mode", "9"], "mode"),
    (["--record-every", "0"], "record-every"),
    (["--hours", "-1"], "hours"),
])
def test_sim_te_bad_input_is_an_error_and_writes_nothing(tmp_path, capsys, argv, field):
    out = tmp_path / "bad.csv"
    base = ["sim", "te", "--hours", "1", "--out", str(out)]
    code = main(base + argv)
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("error:") and field in err
    assert list(tmp_path.iterdir()) == []


def test_bench_te_sim_json_shape(capsys):
    assert main(["bench", "te-sim", "--json", "--runs", "5", "--batch", "2"]) == 0
    doc = _last_json(capsys)
    assert doc["bench"] == "te-sim" and doc["machine"]
    names = [c["case"] for c in doc["cases"]]
    assert names[:3] == ["single noise off", "single noise on", "batch"]
    for c in doc["cases"]:
        assert c["unit"] == "sim-h/s" and c["n"] >= 5 and c["median"] > 0
        assert c["cpu_median"] > 0
