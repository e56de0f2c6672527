"""``ssmpc bench state-shared --json``: shape of the document (no timing asserted)."""

from __future__ import annotations

import json

from services.cli import main


def test_bench_state_shared_json(capsys):
    assert main(["bench", "state-shared", "--json", "--samples", "50"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["bench"] == "state-shared" and doc["machine"]
    cases = {c["case"]: c for c in doc["cases"]}
    for basis in ("companion", "orthonormal"):
        te = cases[f"update+estimates te_n40_m5_k4 {basis}"]
        assert te["unit"] == "us" and te["n"] == 50 and te["order"] == 400
        assert te["basis"] == basis and te["p99"] >= te["median"] > 0
        assert cases[f"prediction_form te_n40_m5 {basis}"]["order"] == 400
    assert "update+estimates siso_n2_m1_k4" in cases


def test_bench_rejects_bad_samples(capsys):
    assert main(["bench", "state-shared", "--samples", "0"]) == 2
    assert "samples" in capsys.readouterr().err
