"""The status's ``variables``: one entry per CV, MV and DV with tag, unit, limits and the
limit a value sits at (the REST status contract), offline and over the real nodes."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from test_service_loop import Harness

from controller.units.baselines import HoldController
from controller.units.config import build_plant, grade_setpoints
from controller.units.variables import at_limit, unit_variables
from services.registry import get_unit

# Downs & Vogel (1993) tags and units, and the controller's limits (alarm limits below
# the 3000 kPa / 175 degC interlocks; set point ranges of the supervisory controller)
TE_FACTS = {
    "XMEAS7": ("XMEAS 7", "kPa gauge", "cv", -math.inf, 2950.0),
    "XMEAS9": ("XMEAS 9", "degC", "cv", -math.inf, 170.0),
    "XMEAS8": ("XMEAS 8", "%", "cv", 10.0, 90.0),
    "XMEAS40": ("XMEAS 40", "mol%", "cv", -math.inf, math.inf),
    "XMV3": ("XMV 3", "%", "mv", 0.0, 100.0),
    "reactor_pressure_sp": ("XMEAS 7 SP", "kPa gauge", "mv", 2500.0, 2950.0),
    "reactor_temperature_sp": ("XMEAS 9 SP", "degC", "mv", 110.0, 130.0),
}


def test_te_variables_have_the_plants_tags_units_and_limits():
    cfg = get_unit("te")
    plant = build_plant(cfg)
    vs = {v.name: v for v in unit_variables(cfg, plant)}
    assert sum(v.kind == "cv" for v in vs.values()) == 41
    assert sum(v.kind == "mv" for v in vs.values()) == 12
    for name, (tag, unit, kind, lo, hi) in TE_FACTS.items():
        v = vs[name]
        assert (v.tag, v.unit, v.kind, v.lo, v.hi) == (tag, unit, kind, lo, hi), name
    assert vs["XMEAS7"].description == "reactor pressure"


@pytest.mark.parametrize("value, lo, hi, expected", [
    (100.0, 0.0, 100.0, "hi"), (99.6, 0.0, 100.0, "hi"), (99.4, 0.0, 100.0, None),
    (0.4, 0.0, 100.0, "lo"), (-1.0, 0.0, 100.0, "lo"), (50.0, 0.0, 100.0, None),
    (2950.0, -math.inf, 2950.0, "hi"), (2900.0, -math.inf, 2950.0, None),
    (1.0, -math.inf, math.inf, None), (None, 0.0, 1.0, None), (math.nan, 0.0, 1.0, None),
])
def test_at_limit_by_hand(value, lo, hi, expected):
    assert at_limit(value, lo, hi) == expected


class _AtHigh(HoldController):
    """Holds the CSTR's jacket temperature at the controller's upper limit (u = 3)."""

    def __init__(self, cfg):
        super().__init__(np.array([3.0]))


@pytest.mark.integration
@pytest.mark.timeout(120)
def test_status_variables_over_the_real_nodes(tmp_path):
    # 10x: a 5 ms budget (at 100x, 0.5 ms: on a loaded machine every sample can miss)
    h = Harness(tmp_path, unit="cstr", speed=10.0, telemetry=False, controller_factory=_AtHigh)
    try:
        h.wait_samples(20, timeout=60)
        # A sample whose deadline passed sends the held move (at the start the grade's), so on a
        # loaded machine the newest move may be a held one: wait for one decided in time.
        t_end = time.monotonic() + 60
        while True:
            st = h.query("status").data
            vs = {v["name"]: v for v in st["variables"]}
            if vs["u"]["value"] == pytest.approx(3.0) or time.monotonic() > t_end:
                break
            time.sleep(0.05)
        assert set(vs) == {"y", "u", "x1f"}
        assert vs["u"]["kind"] == "mv" and vs["u"]["value"] == pytest.approx(3.0)
        assert (vs["u"]["lo"], vs["u"]["hi"], vs["u"]["at_limit"]) == (-3.0, 3.0, "hi")
        assert vs["y"]["kind"] == "cv" and vs["y"]["value"] == pytest.approx(st["cv"]["y"])
        assert vs["y"]["target"] == pytest.approx(st["ref"]["y"])
        assert vs["x1f"]["kind"] == "dv" and vs["x1f"]["value"] is None
        for v in st["variables"]:
            assert {"name", "tag", "description", "unit", "kind", "value", "target", "lo",
                    "hi", "at_limit", "mode"} <= set(v)
        grades = grade_setpoints(h.cfg, build_plant(h.cfg))
        assert grades  # the unit's grades are what the plant offers
    finally:
        h.close()
