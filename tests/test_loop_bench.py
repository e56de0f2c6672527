"""Shape of ``ssmpc bench loop``'s JSON (no timing is asserted)."""

from __future__ import annotations

import json

import pytest

from services.cli import main

pytestmark = pytest.mark.realtime


def test_bench_loop_jitter_and_speed_rungs(capsys):
    # a slow unit at a low speed: one rung, real nodes over Zenoh, jitter before and after
    assert main(["bench", "loop", "--json", "--unit", "cstr", "--cases", "jitter,speed",
                 "--speeds", "2", "--rung-seconds", "1", "--jitter-seconds", "0.2",
                 "--stall-probe"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert doc["bench"] == "loop" and doc["machine"]
    cases = [c["case"] for c in doc["cases"]]
    assert cases == ["jitter", "speed", "jitter"]
    before, speed, after = doc["cases"]
    assert before["when"] == "before the speed ladder" and after["when"].startswith("after")
    for j in (before, after):
        assert j["unit"] == "us" and j["n"] >= 50 and 0 <= j["median"] <= j["max"]
        assert j["over_2ms"] <= j["over_1ms"] <= j["n"]
    rung = speed["rungs"][0]
    assert speed["median"] in (0.0, 2.0) and rung["speed"] == 2.0 and rung["samples"] > 0
    for key in ("sample_ms", "slowest_sample", "plant_loop_latency_us",
                "plant_publish_lag_us", "controller_gc_pauses", "plant_advance_max_ms"):
        assert key in rung
    assert set(rung["miss_causes"]) == {"queued", "computing", "waiting"}
    assert sum(rung["miss_causes"].values()) == len(rung["missed_samples"])
    assert set(rung["waiting_misses"]) == {"preempted", "blocked"}
    assert all(0 <= n <= rung["miss_causes"]["waiting"] for n in rung["waiting_misses"].values())
    assert len(rung["missed_samples"]) <= rung["deadline_misses"]
    assert set(rung["held_causes"]) == {"published_late", "answered_late", "no_answer"}
    assert sum(rung["held_causes"].values()) == len(rung["held_samples"]) <= rung["held"]
    assert set(rung["held_split"]) == {"to_controller", "controller", "back"}
    assert sum(rung["held_split"].values()) <= len(rung["held_samples"])
    assert rung["slowest_sample"]["controller_ms"] > 0
    probe, w = rung["probe_stalls"], rung["with_probe_stall"]
    assert probe["wakeups"] >= 300 and probe["over_2ms"] <= probe["over_1ms"]
    assert w["of_missed"] == len(rung["missed_samples"]) and 0 <= w["missed"] <= w["of_missed"]
    assert w["of_held"] == len(rung["held_samples"]) and 0 <= w["held"] <= w["of_held"]
    # how the CPUs idle is part of the result (it moves loop latencies by ~30 % in a VM)
    assert speed["busy_poll"] is False  # how the controller waited is part of the result
    assert speed["plant_busy_poll"] is False and rung["plant_busy_poll"] is False
    assert speed["telemetry"] is False and rung["telemetry_samples"] is None
    for c in (before, speed, after):
        assert set(c["cpu_idle"]) == {"governor", "driver", "guest_halt_poll_ns"}


def test_bench_loop_with_telemetry_and_both_nodes_polling(capsys):
    assert main(["bench", "loop", "--json", "--unit", "cstr", "--cases", "speed",
                 "--speeds", "2", "--rung-seconds", "1.5", "--telemetry", "--busy-poll",
                 "--plant-busy-poll"]) == 0
    doc = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    (speed,) = doc["cases"]
    rung = speed["rungs"][0]
    assert speed["telemetry"] is True
    assert speed["busy_poll"] is True and speed["plant_busy_poll"] is True
    assert rung["plant_busy_poll"] is True  # the plant node says it polled
    # cstr: 0.05 s samples at 2x = 40 per wall second, batches of 50 or 1 s of wall time
    assert rung["telemetry_samples"] >= 20


def test_held_cause_names_the_part_that_was_late():
    from services.nodes.plant import held_cause

    rec = {"period_ms": 3.6, "publish_lag_ms": 0.1, "answered_after_ms": 4.0}
    assert held_cause(rec) == "answered_late"
    assert held_cause({**rec, "publish_lag_ms": 2.5, "answered_after_ms": 1.2}) == "published_late"
    assert held_cause({**rec, "answered_after_ms": None}) == "no_answer"


def test_bench_loop_refuses_unknown_cases_and_bad_durations(capsys):
    assert main(["bench", "loop", "--cases", "speed,warp"]) == 2
    assert "cases: unknown case(s) warp" in capsys.readouterr().err
    assert main(["bench", "loop", "--cases", "jitter", "--jitter-seconds", "0"]) == 2
    assert "jitter_seconds" in capsys.readouterr().err


def test_scheduling_jitter_probe_sleeps_to_boundaries():
    from services.bench.loop import scheduling_jitter

    us = scheduling_jitter(0.05, period_s=0.005)
    assert 5 <= len(us) <= 11  # 10 boundaries in 50 ms (fewer if the probe overslept)
    assert min(us) >= 0


def test_cpu_idle_settings_read_from_sysfs(tmp_path):
    from services.machine import cpu_idle_settings

    assert cpu_idle_settings(str(tmp_path)) == {
        "governor": None, "driver": None, "guest_halt_poll_ns": None}
    idle = tmp_path / "devices/system/cpu/cpuidle"
    idle.mkdir(parents=True)
    (idle / "current_governor").write_text("haltpoll\n")
    (idle / "current_driver").write_text("haltpoll\n")
    poll = tmp_path / "module/haltpoll/parameters"
    poll.mkdir(parents=True)
    (poll / "guest_halt_poll_ns").write_text("200000\n")
    assert cpu_idle_settings(str(tmp_path)) == {
        "governor": "haltpoll", "driver": "haltpoll", "guest_halt_poll_ns": 200000}


def test_samples_are_matched_to_overlapping_probe_stalls():
    from services.bench.loop import _sample_windows, coincident

    # stalls as (end, length), wall clock s
    stalls = [(100.010, 0.003), (200.000, 0.0015)]
    missed = [{"at_unix_s": 100.0085, "total_ms": 2.0},   # inside the first stall
              {"at_unix_s": 150.0, "total_ms": 2.0},      # far from both
              {"at_unix_s": 200.0012, "total_ms": 0.5}]   # starts 1.2 ms after the 2nd
    held = [{"at_unix_s": 100.0160, "period_ms": 3.6},   # period 100.0124-100.016: +2.4 ms
            {"at_unix_s": 199.9990, "period_ms": 3.6}]   # period holds the second stall
    m, h = _sample_windows(missed, held)
    assert coincident(m, stalls) == 1  # within the 1 ms margin: only the first
    assert coincident(m, stalls, margin_s=2e-3) == 2
    assert coincident(h, stalls) == 1
    assert coincident(h, stalls, margin_s=3e-3) == 2
    assert coincident(m, []) == 0


def test_stall_probe_counts_its_wakeups_and_keeps_long_ones():
    import time

    from services.bench.loop import StallProbe

    with StallProbe(period_s=2e-3, threshold_s=1e-3) as probe:
        time.sleep(0.1)
    s = probe.summary()
    assert 20 <= s["wakeups"] <= 51
    assert all(length > 1e-3 for _, length in probe.stalls)
    assert s["over_1ms"] == len(probe.stalls) and s["over_2ms"] <= s["over_1ms"]


def test_held_split_sets_the_plant_record_beside_the_controllers():
    from services.bench.loop import held_split

    held = {"sample": 7, "published_s": 100.0, "answered_s": 100.0046}
    ctrl = {"arrived_s": 100.0002, "published_s": 100.0013}
    split = held_split(held, ctrl)
    assert split["to_controller"] == pytest.approx(0.2)
    assert split["controller"] == pytest.approx(1.1)
    assert split["back"] == pytest.approx(3.3)
    assert split["largest"] == "back"
    assert held_split({**held, "answered_s": None}, ctrl) is None  # never answered
    assert held_split(held, None) is None  # the controller no longer has it


def test_sample_times_ring_keeps_the_latest_and_checks_its_query():
    from services.timing import SampleTimes

    st = SampleTimes(capacity=4)
    for k in range(6):
        st.note(k, 10.0 + k, 10.5 + k)
    assert st.lookup([0, 1, 2, 5, 99]) == {2: {"arrived_s": 12.0, "published_s": 12.5},
                                          5: {"arrived_s": 15.0, "published_s": 15.5}}
    for bad in ("3", [1.5], [-1], [True], list(range(SampleTimes.MAX_LOOKUP + 1))):
        with pytest.raises(ValueError, match="seqs"):
            st.lookup(bad)


@pytest.mark.parametrize("io", ["zenoh", "opcua"])
def test_bench_nodes_started_again_on_fresh_ports_when_one_was_taken(tmp_path, monkeypatch,
                                                                     capsys, io):
    # each port the bench picks is free when picked; here something binds the first one
    # each node is given before the node starts (as an outgoing connection may)
    import socket

    from services.bench import loop
    from services.io import zenoh_session

    # the picks in order: zenoh: controller's listen, plant's listen, api's HTTP port,
    # api's listen; opcua: plant's OPC UA port, plant's listen, controller's listen
    take = {"zenoh": {0, 2, 4}, "opcua": {0, 4}}[io]
    takers, handed = [], []
    real = zenoh_session.free_port

    def taken_first(host="127.0.0.1") -> int:
        if len(handed) in take:
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            s.listen(1)
            takers.append(s)
            handed.append(s.getsockname()[1])
        else:
            handed.append(real(host))
        return handed[-1]

    monkeypatch.setattr(zenoh_session, "free_port", taken_first)
    try:
        nodes = loop._Nodes("cstr", 1.0, lockstep=True, api=(io == "zenoh"),
                            state_dir=str(tmp_path), io=io)
        try:
            assert all(p.poll() is None for p in nodes.procs)
            assert len(nodes.procs) == (3 if io == "zenoh" else 2)
            taken = {handed[i] for i in take}
            assert str(nodes.port) not in map(str, taken)
            assert not any(ep.endswith(f":{t}") for ep in (nodes.ep_c, nodes.ep_p)
                           for t in taken)
        finally:
            nodes.close()
    finally:
        for s in takers:
            s.close()
    assert "in use" in capsys.readouterr().err.lower()


def test_a_node_that_fails_for_another_reason_is_not_started_again(tmp_path, monkeypatch):
    from services.bench import loop
    from services.nodes import supervisor
    from services.output import CLIError

    started = []
    real = supervisor._spawn
    monkeypatch.setattr(supervisor, "_spawn", lambda argv, **kw: started.append(argv[0])
                        or real(argv, **kw))
    with pytest.raises(CLIError, match="controller"):
        loop._Nodes("cstr", 1.0, lockstep=True, api=False, state_dir=str(tmp_path),
                    unit_config=str(tmp_path / "missing.json"))
    assert started == ["controller"]
