"""Rerun telemetry: a real .rrd file read back has the documented paths, timelines and values."""

import numpy as np
import pytest

from services.telemetry import TelemetryLogger, entity_paths

rr_chunk = pytest.importorskip("rerun.chunk")


def _read(path):
    reader = rr_chunk.RrdReader(str(path))
    data = {}
    timelines = {}
    for ch in reader.stream():
        if ch.is_static or ch.entity_path.startswith("/__"):
            continue
        rb = ch.to_record_batch()
        col = [c for c in rb.schema.names if c.endswith("scalars")][0]
        vals = [v[0] for v in rb.column(col).to_pylist()]
        samples = rb.column("sample").to_pylist()
        data.setdefault(ch.entity_path, []).extend(zip(samples, vals))
        timelines[ch.entity_path] = set(ch.timeline_names)
    return reader, data, timelines


def test_recording_has_documented_paths_timelines_and_values(tmp_path):
    path = tmp_path / "u.rrd"
    tel = TelemetryLogger("te", ["XMEAS7", "G mol%"], ["XMV3"], path, batch=7)
    names = ("mode0", "mode2", "adaptive")
    n = 20
    ys = []
    for k in range(n):
        y = [2700.0 + k, 53.7 - k]
        ys.append(y)
        tel.add(k, 36.0 * k, y, [2705.0, 11.66], [25.0 + k], k % 3, names,
                [1.0, 2.0, 0.5 + k], 0.2, 1.5)
    tel.close()
    reader, data, timelines = _read(path)
    expected = {"/" + p for p in entity_paths("te", ["XMEAS7", "G mol%"], ["XMV3"], names)}
    assert set(data) == expected
    assert "/te/cv/G_mol_" in data and "/te/model/J/adaptive" in data
    for p in expected:
        assert timelines[p] == {"sample", "process_time"}
        assert len(data[p]) == n
    cv0 = sorted(data["/te/cv/XMEAS7"])
    np.testing.assert_array_equal([v for _, v in cv0], [y[0] for y in ys])
    active = sorted(data["/te/model/active"])
    assert [v for _, v in active] == [k % 3 for k in range(n)]
    assert len(reader.blueprints()) == 1


def test_disabled_sink_is_a_no_op(tmp_path):
    tel = TelemetryLogger("u", ["y"], ["u"], None)
    tel.add(0, 0.0, [1.0], [1.0], [0.0], 0, ("m",), [0.0], 0.1, 0.2)
    tel.close()
    assert not tel.enabled and list(tmp_path.iterdir()) == []
