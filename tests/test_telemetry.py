"""Rerun telemetry: a real .rrd file read back has the documented paths, timelines and values."""

import itertools

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


def test_a_batch_sent_in_slices_reads_back_like_one_sent_at_once(tmp_path):
    """start_flush/flush_until send a batch entity by entity up to a deadline; samples
    added meanwhile go into the next batch; the file holds every sample once."""
    path = tmp_path / "s.rrd"
    cvs, mvs, names = ["A", "B", "C"], ["U"], ("m1", "m2")
    tel = TelemetryLogger("x", cvs, mvs, path, batch=5)
    for k in range(5):
        tel.add(k, float(k), [k, 2 * k, 3 * k], [0.0, 0.0, 0.0], [k], 0, names,
                [1.0, 2.0], 0.1, 1.0, auto_flush=False)
    tel.start_flush()
    n_entities = len(entity_paths("x", cvs, mvs, names))
    now = [0.0]
    tel.clock = lambda: now[0]
    assert tel.flushing
    assert not tel.flush_until(-1.0)  # past its deadline: nothing sent
    assert tel.samples_logged == 0
    slices = 0
    while tel.flushing:
        # the clock passes the deadline after one entity: one entity per slice
        tel.clock = itertools.chain([0.0], itertools.repeat(2.0)).__next__
        done = tel.flush_until(1.0)
        slices += 1
        assert done == (not tel.flushing)
        if slices == 2:  # a sample added while the batch is out: the next batch
            tel.add(5, 5.0, [5, 10, 15], [0.0, 0.0, 0.0], [5], 1, names, [1.0, 2.0], 0.1,
                    1.0, auto_flush=False)
    assert slices == n_entities and tel.samples_logged == 5
    tel.close()
    assert tel.samples_logged == 6
    _, data, _ = _read(path)
    assert sorted(data["/x/cv/B"]) == [(k, 2.0 * k) for k in range(6)]
    assert sorted(data["/x/model/active"]) == [(k, 0.0) for k in range(5)] + [(5, 1.0)]
