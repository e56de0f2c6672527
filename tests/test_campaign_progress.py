"""The campaign's progress line: runs done / total, trips, errors, ETA."""

from __future__ import annotations

import io

from services.campaign.progress import Progress, format_duration


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_progress_counts_trips_and_errors_and_estimates_the_time_left():
    clock, out = Clock(), io.StringIO()
    p = Progress("grades", total=10, skipped=2, stream=out, clock=clock)
    p.note_skipped_row({"tripped": True})
    p.start()
    clock.t += 30.0
    p.update({"tripped": False, "error": None})
    clock.t += 30.0
    p.update({"tripped": True, "error": None})
    # 2 runs in 60 s, 6 left: 3 minutes
    assert p.line() == ("campaign grades: 4/10 runs (2 already done), 2 trips, 0 errors, "
                        "ETA 3m00s")
    p.update({"tripped": None, "error": "RuntimeError: x"})
    assert "3 errors" not in p.line() and "1 errors" in p.line()


def test_progress_on_a_pipe_writes_lines_not_redraws_and_ends_with_done():
    clock, out = Clock(), io.StringIO()
    p = Progress("c", total=2, stream=out, clock=clock)
    p.start()
    clock.t += 1.0
    p.update({"tripped": False})
    clock.t += 1.0
    p.update({"tripped": False})
    p.finish()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert lines[0].startswith("campaign c: 0/2 runs") and lines[-1].endswith("done in 2s")
    assert len(lines) == 2   # the one in between came within 5 s of the first


def test_format_duration():
    assert format_duration(12.4) == "12s"
    assert format_duration(200) == "3m20s"
    assert format_duration(3720) == "1h02m"
