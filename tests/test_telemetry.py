"""Rerun telemetry: a real .rrd file read back has the documented paths, timelines,
values, labels, events and the trend display's blueprint."""

import numpy as np
import pytest

from controller.units.variables import VariableInfo
from services.telemetry import STATE_STEP, TelemetryLogger, entity_paths, key_cvs

rr_chunk = pytest.importorskip("rerun.chunk")

INF = float("inf")
VARIABLES = (
    VariableInfo("XMEAS7", "XMEAS 7", "reactor pressure", "kPa gauge", "cv", -INF, 2950.0),
    VariableInfo("G mol%", "XMEAS 40", "product G", "mol%", "cv", -INF, INF),
    VariableInfo("XMEAS2", "XMEAS 2", "D feed", "kg/h", "cv", -INF, INF),
    VariableInfo("XMV3", "XMV 3", "A feed valve", "%", "mv", 0.0, 100.0),
    VariableInfo("Pr_sp", "XMEAS 7 SP", "reactor pressure set point", "kPa gauge", "mv",
                 2500.0, 2950.0),
)
CVS, MVS = ["XMEAS7", "G mol%", "XMEAS2"], ["XMV3", "Pr_sp"]


def _read(path):
    reader = rr_chunk.RrdReader(str(path))
    data, text, timelines = {}, {}, {}
    for ch in reader.stream():
        if ch.is_static or ch.entity_path.startswith("/__"):
            continue
        rb = ch.to_record_batch()
        samples = rb.column("sample").to_pylist()
        cols = rb.schema.names
        scal = [c for c in cols if c.endswith("scalars")]
        if scal:
            vals = [v[0] for v in rb.column(scal[0]).to_pylist()]
            data.setdefault(ch.entity_path, []).extend(zip(samples, vals))
        txt = [c for c in cols if c.endswith(":text")]
        if txt:
            vals = [v[0] for v in rb.column(txt[0]).to_pylist()]
            text.setdefault(ch.entity_path, []).extend(zip(samples, vals))
        timelines[ch.entity_path] = set(ch.timeline_names)
    return reader, data, text, timelines


def _record(path, n=20, batch=7):
    tel = TelemetryLogger("te", CVS, MVS, path, batch=batch, ref_names=["G mol%"],
                          variables=VARIABLES)
    names = ("mode0", "mode2", "adaptive")
    ys, us = [], []
    for k in range(n):
        y, u = [2700.0 + k, 53.7 - k, 3600.0], [25.0 + k, 2700.0]
        ys.append(y), us.append(u)
        active = 0 if k < 8 else (1 if k < 15 else 2)
        tel.add(k, 36.0 * k, y, [11.66], u, active, names, [1.0, 100.0, 10.0 ** k], 0.2, 1.5)
        if k == 3:
            tel.event(k, 36.0 * k, "transition t1 mode0 -> mode2: running")
    tel.close()
    return names, np.array(ys), np.array(us)


def test_key_cvs_are_the_tracked_then_the_limited():
    assert key_cvs(CVS, ["G mol%"], VARIABLES) == ["G mol%", "XMEAS7"]


def test_recording_has_documented_paths_timelines_and_values(tmp_path):
    path = tmp_path / "u.rrd"
    names, ys, us = _record(path)
    reader, data, text, timelines = _read(path)
    expected = {"/" + p for p in entity_paths("te", CVS, MVS, names, ["G mol%"], VARIABLES)}
    assert set(data) == expected
    assert "/te/cv/G_mol_" in data and "/te/limit/XMEAS7/hi" in data
    assert "/te/limit/XMEAS7/lo" not in data and "/te/mv_pct/Pr_sp" in data
    for p in expected:
        assert timelines[p] == {"sample", "process_time"}
        assert len(data[p]) == 20
    np.testing.assert_array_equal([v for _, v in sorted(data["/te/cv/XMEAS7"])], ys[:, 0])
    # MVs in % of their range: (u - lo) / (hi - lo)
    np.testing.assert_allclose([v for _, v in sorted(data["/te/mv_pct/XMV3"])], us[:, 0])
    np.testing.assert_allclose([v for _, v in sorted(data["/te/mv_pct/Pr_sp"])],
                               100.0 * (2700.0 - 2500.0) / 450.0)
    # the models as named states, J on a log scale, the active model by name at changes
    state = dict(sorted(data["/te/model/state/mode2"]))
    assert state[5] == 1.0 and state[10] == 1.0 + STATE_STEP
    logj = dict(sorted(data["/te/model/log10J/adaptive"]))
    assert logj[12] == pytest.approx(12.0)
    assert sorted(text["/te/model/active"]) == [(0, "mode0"), (8, "mode2"), (15, "adaptive")]
    assert text["/te/events"] == [(3, "transition t1 mode0 -> mode2: running")]
    assert len(reader.blueprints()) == 1


def test_blueprint_is_the_trend_display(tmp_path):
    path = tmp_path / "u.rrd"
    _record(path, n=3)
    reader = rr_chunk.RrdReader(str(path))
    names, origins, queries = set(), set(), []
    for ch in reader.stream(store=reader.blueprints()[0]):
        rb = ch.to_record_batch()
        for c in rb.schema.names:
            if not c.endswith(("display_name", "space_origin", "ViewContents:query")):
                continue
            vals = [v for row in rb.column(c).to_pylist() if row for v in row]
            if c.endswith("display_name"):
                names.update(vals)
            elif c.endswith("space_origin"):
                origins.update(vals)
            elif c.endswith("ViewContents:query"):
                queries.append(vals)
    # one panel per key CV, titled with tag, description and unit, holding its reference
    # and limits; the MVs in % of range; models, J, events, timing
    assert {"XMEAS 40 product G (mol%)", "XMEAS 7 reactor pressure (kPa gauge)", "MVs, % of range",
            "active model", "log10 J (eq. 4.6)", "events", "timing (ms)", "key CVs"} <= names
    assert ["/te/cv/XMEAS7", "/te/ref/XMEAS7", "/te/limit/XMEAS7/**"] in queries
    assert {"/te/mv_pct", "/te/model/state", "/te/model/log10J", "/te/events"} <= origins


def test_labels_carry_engineering_names_and_units(tmp_path):
    path = tmp_path / "u.rrd"
    _record(path, n=2)
    labels = {}
    for ch in rr_chunk.RrdReader(str(path)).stream():
        if not ch.is_static:
            continue
        rb = ch.to_record_batch()
        for c in rb.schema.names:
            if c.endswith(":names"):
                labels[ch.entity_path] = rb.column(c).to_pylist()[0][0]
    assert labels["/te/cv/XMEAS7"] == "XMEAS 7 reactor pressure (kPa gauge)"
    assert labels["/te/mv_pct/XMV3"] == "XMV 3 A feed valve (%), % of range"
    assert labels["/te/limit/XMEAS7/hi"] == "XMEAS7 hi limit 2950"


def test_disabled_sink_is_a_no_op(tmp_path):
    tel = TelemetryLogger("u", ["y"], ["u"], None)
    tel.add(0, 0.0, [1.0], [1.0], [0.0], 0, ("m",), [0.0], 0.1, 0.2)
    tel.event(0, 0.0, "nothing")
    tel.close()
    assert not tel.enabled and list(tmp_path.iterdir()) == []
