"""Operator requests the soak found mishandled: a grade the TE control structure cannot
hold (modes 4-6 leave a feed valve at 100 %, ``te_grades.check_reachable``)."""

import pytest
from test_service_loop import Harness

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def test_unreachable_te_grade_is_refused_at_request_time(tmp_path):
    h = Harness(tmp_path, unit="te", speed=10_000.0, telemetry=False)
    try:
        h.wait_samples(3, timeout=60)
        reply = h.query("transition", {"op": "create", "grade": "mode4"})
        assert reply.code == 422 and "mode4" in reply.error
        h.wait_samples(3, timeout=60)
        assert not any("failed" in a for a in h.query("status").data["alarms"])
    finally:
        h.close()
