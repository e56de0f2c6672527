"""Operator requests the soak found mishandled: a grade request the TE controller must
answer at request time. Modes 4-6 are reachable at their back-off
(``controller.units.te.max_production``): accepted over REST, and the controller runs
on toward them without a failed sample; a grade it does not know is refused at once."""

import pytest
from test_service_loop import Harness

pytestmark = [pytest.mark.integration, pytest.mark.timeout(120)]


def test_max_production_grade_is_accepted_and_an_unknown_one_refused(tmp_path):
    from test_api import AUTH, ApiServer

    h = Harness(tmp_path, unit="te", speed=10_000.0, telemetry=False)
    api = ApiServer(h)
    try:
        h.wait_samples(3, timeout=60)
        bad = api.client.post("/api/v1/units/te/transitions", json={"grade": "mode7"},
                              headers=AUTH)
        assert bad.status_code == 404 and "mode7" in bad.text
        r = api.client.post("/api/v1/units/te/transitions", json={"grade": "mode4"},
                            headers=AUTH)
        assert r.status_code == 202, r.text
        h.wait_samples(20, timeout=60)
        assert api.client.get(r.headers["location"]).json()["state"] == "running"
        assert not any("failed" in a for a in h.query("status").data["alarms"])
    finally:
        api.close()
        h.close()
