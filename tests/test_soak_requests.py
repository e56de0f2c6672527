"""Operator requests the soak found mishandled: a grade request the TE controller must
answer at request time. Modes 4-6 are reachable at their back-off
(``controller.units.te.max_production``): accepted, and the controller runs on toward
them without a failed sample; a grade it does not know is refused at once."""

import pytest
from test_service_loop import Harness

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def test_max_production_grade_is_accepted_and_an_unknown_one_refused(tmp_path):
    h = Harness(tmp_path, unit="te", speed=10_000.0, telemetry=False)
    try:
        h.wait_samples(3, timeout=60)
        bad = h.query("transition", {"op": "create", "grade": "mode7"})
        assert bad.code in (404, 422) and "mode7" in bad.error
        reply = h.query("transition", {"op": "create", "grade": "mode4"})
        assert reply.code == 202, reply.error
        h.wait_samples(20, timeout=60)
        assert not any("failed" in a for a in h.query("status").data["alarms"])
    finally:
        h.close()
