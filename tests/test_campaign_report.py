"""The campaign report: cells of the matrix, the table, the files."""

from __future__ import annotations

from services.campaign.figures import cell_summaries
from services.campaign.report import write_report


def _row(case, strategy, seed, **kw):
    row = {"run": f"{case}-{strategy}-{seed}", "case": case, "strategy": strategy,
           "seed": seed, "hours": 12, "legs": 1, "tripped": False, "trip": None,
           "time_to_grade_h": None, "peak_pressure_kpa": 2800.0, "mean_cost_usd_h": 150.0,
           "final_cost_usd_h": 120.0, "transition_cost_usd": 900.0,
           "active_model_share": {}, "wall_s": 1.0, "error": None}
    row.update(kw)
    return row


DOC = {"campaign": "c", "unit": "te", "workers": 2, "wall_s": 10.0,
       "summary": {"runs": 9, "tripped": 1, "errors": 1, "executed": 9, "skipped": 0},
       "runs": [
           _row("0-2", "ssmpc", 1, time_to_grade_h=5.0),
           _row("0-2", "ssmpc", 2, time_to_grade_h=7.0),
           _row("0-2", "ssmpc", 3, time_to_grade_h=6.0),
           _row("0-2", "pi", 1, time_to_grade_h=8.0),
           _row("0-2", "pi", 2, tripped=True,
                trip={"at_h": 3.5, "reason": "reactor pressure high"}),
           _row("0-2", "pi", 3, time_to_grade_h=9.0),
           _row("<idv6>", "ssmpc", 1, legs=0, transition_cost_usd=None, peak_pressure_kpa=2950.0),
           _row("<idv6>", "pi", 1, legs=0, error="RuntimeError: x", tripped=None),
           _row("0-3", "ssmpc", 1)]}


def test_cells_sort_the_runs_of_each_case_and_strategy():
    cases, strategies, cells = cell_summaries(DOC)
    assert cases == ["0-2", "<idv6>", "0-3"] and strategies == ["ssmpc", "pi"]
    assert cells[("0-2", "ssmpc")]["kind"] == "grade"
    assert cells[("0-2", "ssmpc")]["time_to_grade_h"] == 6.0          # median of 5, 7, 6
    trip = cells[("0-2", "pi")]
    assert trip["kind"] == "trip" and trip["trips"] == 1 and trip["n"] == 3
    assert trip["first_trip_h"] == 3.5
    assert cells[("<idv6>", "ssmpc")]["kind"] == "held"
    assert cells[("<idv6>", "ssmpc")]["peak_pressure_kpa"] == 2950.0
    assert cells[("<idv6>", "pi")]["kind"] == "error"
    assert cells[("0-3", "ssmpc")]["kind"] == "not reached"
    assert ("0-3", "pi") not in cells


def test_report_files_escape_names_and_hold_one_table_row_per_run(tmp_path):
    paths = write_report(DOC, tmp_path)
    assert open(paths["png"], "rb").read(4) == b"\x89PNG"
    page = (tmp_path / "report.html").read_text()
    assert "<idv6>" not in page and "&lt;idv6&gt;" in page
    assert page.count("<tr>") == 1 + 9
    lines = (tmp_path / "table.csv").read_text().strip().splitlines()
    assert len(lines) == 10 and lines[0].startswith("case,strategy,seed")
    assert "reactor pressure high" in lines[5]
