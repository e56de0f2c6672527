"""CLI of the unit plants: ssmpc plants / linearize / sim, including bad input."""

import csv
import json
import math
import shutil
import subprocess
import sys

import numpy as np
import pytest

from services.cli import main

TABLE_TOL = 1.5e-4  # Table 5.3 printed to 4 decimals (see test_plant_cstr)


def last_json(out: str) -> dict:
    return json.loads(out.strip().splitlines()[-1])


def test_plants_table_lists_ops_and_types(capsys):
    assert main(["plants", "--plant", "cstr", "--plant", "bioreactor"]) == 0
    out = capsys.readouterr().out
    assert "cstr" in out and "OPIII" in out and "saddle" in out
    assert "not a valid operating point" in out


def test_plants_json_shape(capsys):
    assert main(["plants", "--plant", "two_phase_reactor", "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    (p,) = doc["plants"]
    assert p["name"] == "two_phase_reactor" and p["time_unit"] == "h"
    assert [o["name"] for o in p["outputs"]] == ["P", "yA3", "F4"]
    assert p["outputs"][0]["upper"] == 3000.0
    ops = {o["name"]: o for o in p["operating_points"]}
    assert ops["OPI"]["stability"] == "stable"
    assert ops["OPII"]["confidence"] == "reconstructed"


def test_plants_unknown_plant(capsys):
    assert main(["plants", "--plant", "nope"]) == 2
    assert "plant" in capsys.readouterr().err


def test_linearize_json_reproduces_table_5_3(capsys):
    assert main(["linearize", "cstr", "--op", "OPII", "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    A, B, C, D = (np.array(doc[k]) for k in "ABCD")
    assert A.shape == (2, 2) and B.shape == (2, 1) and C.shape == (1, 2) and D.shape == (1, 1)
    assert doc["state_names"] == ["x1", "x2"] and doc["input_names"] == ["u"]
    assert doc["output_names"] == ["y"] and doc["state_units"] == ["-", "-"]
    # k3 = -trace, k4 = det (Table 5.3, OPII), independent of the TF code path
    assert -np.trace(A) == pytest.approx(2.1493, abs=TABLE_TOL)
    assert np.linalg.det(A) == pytest.approx(2.3286, abs=TABLE_TOL)
    ev = np.array(doc["eigenvalues"]["real"]) + 1j * np.array(doc["eigenvalues"]["imag"])
    np.testing.assert_allclose(np.sort_complex(ev), np.sort_complex(np.linalg.eigvals(A)))
    assert doc["stability"] == "stable"


def test_linearize_select_and_option(capsys):
    assert main(["linearize", "two_phase_reactor", "--op", "OPI", "--inputs", "x1,x3,x4bar",
                 "--outputs", "F4", "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["input_names"] == ["x1", "x3", "x4bar"] and doc["output_names"] == ["F4"]
    assert np.array(doc["B"]).shape == (4, 3)
    assert main(["linearize", "cstr", "--op", "OPI", "--option", "gamma=inf", "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["stability_detail"] == "saddle"  # facts §3: y = 1.3 is a saddle if gamma = inf


@pytest.mark.parametrize(
    ("argv", "field"),
    [
        (["linearize", "nope", "--op", "OPI"], "plant"),
        (["linearize", "cstr", "--op", "OPIV"], "op"),
        (["linearize", "cstr", "--op", "OPI", "--inputs", "q"], "input"),
        (["linearize", "cstr", "--op", "OPI", "--option", "Da=-1"], "Da"),
        (["linearize", "cstr", "--op", "OPI", "--option", "colour=red"], "option"),
    ],
)
def test_linearize_bad_input(capsys, argv, field):
    assert main(argv) != 0
    err = capsys.readouterr().err
    assert err.startswith("error:") and field in err


def test_sim_writes_csv_plot_and_summary(tmp_path, capsys):
    out, png = tmp_path / "run.csv", tmp_path / "run.png"
    code = main(["sim", "cstr", "--op", "OPI", "--hours", "20", "--sample", "0.5",
                 "--step", "u=0.45@2", "--step", "x1f=1.1@5", "--out", str(out),
                 "--plot", str(png), "--json"])
    assert code == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["rows"] == 41 and doc["plant"] == "cstr" and doc["op"] == "OPI"
    with open(out) as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 41 and set(rows[0]) == {"t", "x1", "x2", "u", "x1f", "y"}
    assert float(rows[0]["y"]) == pytest.approx(1.3)
    assert float(rows[4]["u"]) == pytest.approx(0.45) and float(rows[3]["u"]) < 0.41
    assert float(rows[10]["x1f"]) == pytest.approx(1.1)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert doc["final"]["y"]["y"] == pytest.approx(float(rows[-1]["y"]))


@pytest.mark.parametrize(
    ("extra", "field"),
    [
        (["--op", "OPIV"], "op"),
        (["--step", "q=1@1"], "step"),
        (["--step", "u=nan@1"], "step u value"),
        (["--step", "u=0.5@-1"], "step u time"),
        (["--step", "u=0.5@99"], "step u time"),
        (["--step", "u0.5@1"], "step"),
        (["--sample", "0"], "sample"),
        (["--sample", "-1"], "sample"),
        (["--hours", "0"], "hours"),
        (["--hours", "nan"], "hours"),
        (["--idv", "1@0"], "idv"),
    ],
)
def test_sim_bad_input_leaves_no_file(tmp_path, capsys, extra, field):
    out = tmp_path / "run.csv"
    argv = ["sim", "cstr", "--hours", "10", "--out", str(out)]
    if "--hours" in extra:
        argv = ["sim", "cstr", "--out", str(out)]
    code = main(argv + extra)
    assert code != 0
    err = capsys.readouterr().err
    assert err.startswith("error:") and field in err
    assert list(tmp_path.iterdir()) == []


def test_sim_step_outside_valve_range(tmp_path, capsys):
    out = tmp_path / "run.csv"
    code = main(["sim", "two_phase_reactor", "--op", "OPI", "--hours", "1",
                 "--step", "x1=120@0.5", "--out", str(out)])
    assert code != 0 and "step x1 value" in capsys.readouterr().err
    assert not out.exists()


def test_sim_unwritable_paths(tmp_path, capsys):
    missing = tmp_path / "no" / "run.csv"
    assert main(["sim", "cstr", "--hours", "1", "--out", str(missing)]) != 0
    assert "out" in capsys.readouterr().err
    out = tmp_path / "run.csv"
    assert main(["sim", "cstr", "--hours", "1", "--out", str(out),
                 "--plot", str(tmp_path / "no" / "x.png")]) != 0
    assert "plot" in capsys.readouterr().err
    assert not out.exists()
    assert main(["sim", "cstr", "--hours", "1", "--out", str(tmp_path)]) != 0
    assert "out" in capsys.readouterr().err


def test_sim_unknown_plant(tmp_path, capsys):
    assert main(["sim", "nope", "--hours", "1", "--out", str(tmp_path / "r.csv")]) == 2
    assert "plant" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_sim_bioreactor_step_moves_substrate(tmp_path, capsys):
    out = tmp_path / "bio.csv"
    assert main(["sim", "bioreactor", "--op", "OPI", "--hours", "30", "--step", "D=0.42@1",
                 "--out", str(out), "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["time_unit"] == "h" and doc["rows"] == 501
    y = doc["final"]["y"]["y"]
    # the low-substrate branch moves to mu(x2) = 0.42 (still the stable branch)
    assert 0.00358 < y < 0.01 and math.isfinite(y)


def test_console_script_sim(tmp_path):
    exe = shutil.which("ssmpc")
    cmd = [exe] if exe else [sys.executable, "-m", "services.cli"]
    out = tmp_path / "tp.csv"
    proc = subprocess.run(cmd + ["sim", "two_phase_reactor", "--op", "OPI", "--hours", "2",
                                 "--step", "x1=62@0.5", "--out", str(out), "--json"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    doc = last_json(proc.stdout)
    assert doc["plant"] == "two_phase_reactor" and out.exists()
    bad = subprocess.run(cmd + ["linearize", "cstr", "--op", "OPX"], capture_output=True,
                         text=True, timeout=120)
    assert bad.returncode != 0 and "op" in bad.stderr


def test_plants_marks_calcium_reconstructed(capsys):
    assert main(["plants", "--plant", "calcium"]) == 0
    out = capsys.readouterr().out
    assert "calcium" in out and "[reconstructed]" in out
    assert main(["plants", "--plant", "calcium", "--json"]) == 0
    (p,) = last_json(capsys.readouterr().out)["plants"]
    assert p["reconstructed"] is True and p["time_unit"] == "s"


def test_linearize_calcium_chapter6_outputs(capsys):
    assert main(["linearize", "calcium", "--op", "OPII", "--option", "outputs=x5,x6",
                 "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["output_names"] == ["x5", "x6"] and doc["input_names"] == ["J", "q1"]
    assert np.array(doc["C"]).shape == (2, 5)


def test_bench_unit_plants_document_shape(capsys):
    assert main(["bench", "unit-plants", "--repeat", "1", "--steps", "2", "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["bench"] == "unit-plants" and doc["machine"]
    names = {c["case"] for c in doc["cases"]}
    assert {"calcium step", "two_phase_reactor simulate"} <= names
    for c in doc["cases"]:
        assert {"median", "p99", "max", "n", "unit"} <= set(c)


def test_sim_calcium_plot(tmp_path, capsys):
    out, png = tmp_path / "ca.csv", tmp_path / "ca.png"
    assert main(["sim", "calcium", "--op", "OPII", "--hours", "5", "--sample", "0.05",
                 "--step", "J=1@1", "--out", str(out), "--plot", str(png), "--json"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert doc["time_unit"] == "s" and doc["reconstructed"] is True
    # more trigger influx raises cytosolic Ca (the seed's sign convention, doc §2)
    assert doc["final"]["x"]["x5"] > 0.167 and png.exists()


def test_plants_lists_every_registered_plant(capsys):
    from plant_sim import plant_names

    assert main(["plants", "--json"]) == 0
    docs = last_json(capsys.readouterr().out)["plants"]
    assert [d["name"] for d in docs] == plant_names()
    for d in docs:
        if d["name"] != "te":
            assert d["available"] and all(op["y"] is not None for op in d["operating_points"])
