"""Timing budget, sample clock (fake clock), deadline counting, watchdog."""

import threading
import time

import pytest

from services.timing import DeadlineStats, SampleClock, TimingBudget, Watchdog, thread_switches

pytestmark = pytest.mark.realtime


def test_budget_is_fraction_of_scaled_period():
    b = TimingBudget(sample_period_s=36.0, speed=10_000.0, fraction=0.5)
    assert b.wall_period_s == pytest.approx(3.6e-3)
    assert b.budget_s == pytest.approx(1.8e-3)


@pytest.mark.parametrize("kw, field", [
    ({"sample_period_s": 0.0}, "sample_period_s"),
    ({"speed": -1.0}, "speed"),
    ({"speed": float("inf")}, "speed"),
    ({"fraction": 0.0}, "fraction"),
    ({"fraction": 1.5}, "fraction"),
])
def test_budget_validation_names_field(kw, field):
    args = {"sample_period_s": 1.0, **kw}
    with pytest.raises(ValueError, match=field):
        TimingBudget(**args)


class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_clock_reanchors_instead_of_bursting():
    fake = FakeClock()
    clock = SampleClock(0.5, now=fake)
    fake.now = 100.5  # exactly on the first boundary: no sleep needed
    assert clock.wait_next() == 1
    fake.now = 103.0  # fell behind by several periods
    assert clock.wait_next() == 2
    assert clock.overruns >= 3
    assert clock.deadline() == pytest.approx(103.0)


def test_clock_with_poll_polls_until_the_boundary_instead_of_sleeping():
    fake = FakeClock()
    clock = SampleClock(0.5, now=fake)
    calls = []

    def poll():  # each poll: 0.125 s of fake time (exact in binary)
        calls.append(fake.now)
        fake.now += 0.125

    assert clock.wait_next(poll=poll) == 1
    # polled from 100.0 while before the boundary at 100.5, then returned at it
    assert calls == [100.0, 100.125, 100.25, 100.375]
    assert fake.now == 100.5 and clock.overruns == 0


def test_clock_poll_stops_polling_when_asked():
    fake = FakeClock()
    clock = SampleClock(10.0, now=fake)
    stop = threading.Event()
    calls = []

    def poll():
        calls.append(1)
        if len(calls) == 3:
            stop.set()

    assert clock.wait_next(stop, poll=poll) == 1
    assert len(calls) == 3 and fake.now == 100.0  # returned long before the boundary


def test_thread_switches_count_the_calling_threads_waits():
    out = {}

    def sleeper():  # each sleep gives the CPU up: a voluntary switch of this thread only
        v0, i0 = thread_switches()
        for _ in range(50):
            time.sleep(0.001)
        v1, i1 = thread_switches()
        out["v"], out["i"] = v1 - v0, i1 - i0

    v_main0, _ = thread_switches()
    th = threading.Thread(target=sleeper)
    th.start()
    th.join()
    assert out["v"] >= 50 and out["i"] >= 0
    v_main1, _ = thread_switches()
    # per thread: the main thread only waited in start() and join(), a few times
    assert v_main1 - v_main0 < 25


def test_deadline_stats_counts_misses_and_slack():
    s = DeadlineStats(budget_s=1e-3)
    assert not s.record(0.5e-3)
    assert s.record(2e-3, fallback=True)
    assert (s.samples, s.misses, s.fallbacks) == (2, 1, 1)
    assert s.slack_ms(2e-3) == pytest.approx(-1.0)
    assert s.as_dict()["max_ms"] == pytest.approx(2.0)


def test_deadline_stats_keeps_the_phases_of_missed_samples_only():
    s = DeadlineStats(budget_s=1e-3)
    s.note_phases(0.5e-3, {"sample": 1})  # in time: only the slowest so far
    assert list(s.missed) == [] and s.worst["sample"] == 1.0
    for k in range(2, 2 + DeadlineStats.KEEP_MISSED + 5):
        s.note_phases(1.5e-3, {"sample": k})
    assert len(s.missed) == DeadlineStats.KEEP_MISSED  # bounded: the latest ones
    assert s.missed[-1] == {"total_ms": 1.5, "sample": float(k)}
    assert s.missed[0]["sample"] == 7.0 and s.worst["sample"] == 2.0


def test_miss_cause_is_the_largest_part():
    from services.timing import miss_cause

    assert miss_cause({"queue_ms": 0.2, "cpu_ms": 1.9, "waited_ms": 0.1}) == "computing"
    assert miss_cause({"queue_ms": 0.2, "cpu_ms": 0.5, "waited_ms": 1.4}) == "waiting"
    assert miss_cause({"queue_ms": 2.5, "cpu_ms": 0.5, "waited_ms": 0.0}) == "queued"


def test_watchdog_fires_at_deadline_and_not_when_disarmed():
    wd = Watchdog()
    fired = threading.Event()
    wd.arm(time.perf_counter() + 0.02, fired.set)
    assert fired.wait(2.0)
    assert wd.disarm() is True
    other = threading.Event()
    wd.arm(time.perf_counter() + 0.5, other.set)
    assert wd.disarm() is False
    time.sleep(0.6)
    assert not other.is_set()
    wd.close()


def test_watchdog_counts_a_passed_deadline_as_missed_though_its_thread_did_not_run():
    # a starved watchdog thread: it cannot return from its wait while the test holds its
    # condition's (re-entrant) lock
    wd = Watchdog()
    ran = []
    with wd._cond:
        wd.arm(time.perf_counter() - 0.001, lambda: ran.append("fallback"))
        assert wd.disarm() is True  # the sample missed: the fallback goes out here
        assert ran == ["fallback"]
    time.sleep(0.05)
    assert ran == ["fallback"]  # and only once
    wd.arm(time.perf_counter() + 0.5, lambda: ran.append("late"))
    assert wd.disarm() is False  # in time: nothing runs
    time.sleep(0.6)
    assert ran == ["fallback"]
    wd.close()


def test_deadline_stats_percentiles_of_kept_samples():
    from services.timing import DeadlineStats

    st = DeadlineStats(budget_s=0.002, keep=100)
    assert st.percentiles_ms() == {"p50": None, "p99": None, "max": None, "n": 0}
    for i in range(1, 201):  # 1..200 ms; only the last 100 (101..200) are kept
        st.record(i * 1e-3)
    p = st.percentiles_ms()
    assert p["n"] == 100 and p["max"] == 200.0
    assert p["p50"] == 150.5 and abs(p["p99"] - 199.01) < 1e-9
    assert st.misses == 198  # 3..200 ms: above the 2 ms budget (2 ms itself is in time)


def test_watchdog_with_a_period_hint_wakes_only_at_deadlines():
    # a 1 ms step within a 50 ms budget: a loaded machine's oversleeps stay inside it
    period, budget = 0.1, 0.05
    wd = Watchdog(period_hint_s=period)
    t0 = time.perf_counter() + 0.01
    fired_early = []
    for k in range(15):  # a periodic loop whose steps end well inside the budget
        while time.perf_counter() < t0 + k * period:
            time.sleep(0.0005)
        wd.arm(t0 + k * period + budget, lambda k=k: fired_early.append(k))
        time.sleep(0.001)
        assert wd.disarm() is False
    assert not fired_early
    # after the first arm the thread predicts the deadlines: no more wake-up requests
    assert wd.n_notified <= 2
    # an overrun still fires at its deadline, also one much earlier than predicted
    fired = threading.Event()
    at = []
    n_before = wd.n_notified
    deadline = time.perf_counter() + 0.002
    wd.arm(deadline, lambda: (at.append(time.perf_counter()), fired.set()))
    assert fired.wait(2.0)
    assert wd.disarm() is True
    assert at[0] >= deadline
    assert wd.n_notified == n_before + 1  # it asked for the wake-up (prediction ~150 ms on)
    wd.close()


def test_watchdog_period_hint_is_validated():
    with pytest.raises(ValueError, match="period_hint_s"):
        Watchdog(period_hint_s=0.0)


def test_loop_publishers_are_express_real_time_and_drop():
    import queue

    import zenoh

    from services.io.zenoh_session import SessionSettings, declare_loop_publisher, open_session

    s = open_session(SessionSettings())
    try:
        got: queue.Queue = queue.Queue()
        sub = s.declare_subscriber("ssmpc/test/meas", got.put)
        pub = declare_loop_publisher(s, "ssmpc/test/meas")
        assert pub.priority == zenoh.Priority.REAL_TIME
        assert pub.congestion_control == zenoh.CongestionControl.DROP
        pub.put(b"x")
        sample = got.get(timeout=5.0)
        assert sample.express is True and sample.priority == zenoh.Priority.REAL_TIME
        pub.undeclare()
        sub.undeclare()
    finally:
        s.close()


def test_node_tuning_runs_blas_on_the_calling_thread_only():
    """A node's BLAS must not use worker threads: OpenBLAS's spin-wait between calls
    takes a vCPU from the plant and Zenoh (seen: 100 % of one of two vCPUs at 10,000x)."""
    import json
    import os
    import subprocess
    import sys

    code = (
        "import json, numpy, scipy.linalg\n"
        "from threadpoolctl import threadpool_info\n"
        "before = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
        "from services.nodes.run import _realtime_tuning\n"
        "_realtime_tuning()\n"
        "after = [i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas']\n"
        "print(json.dumps([before, after]))\n")
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True, env=env).stdout
    before, after = json.loads(out.strip().splitlines()[-1])
    assert after and all(n == 1 for n in after)
    if (os.cpu_count() or 1) > 1:
        assert max(before) > 1  # the default this protects against


def test_phase_record_kept_only_when_keeps_says_so():
    """The node builds a sample's phase record only when ``keeps`` is true: the slowest
    sample so far, or one over budget; ``note_phases`` keeps exactly those."""
    stats = DeadlineStats(budget_s=1e-3)
    for elapsed in (0.5e-3, 0.4e-3, 0.6e-3, 2e-3, 1.5e-3, 0.1e-3):
        kept = stats.keeps(elapsed)
        worst, missed = stats.worst, len(stats.missed)
        stats.note_phases(elapsed, {"cpu_ms": 0.0})
        assert kept == (stats.worst is not worst or len(stats.missed) > missed)
    assert stats.worst["total_ms"] == 2.0 and len(stats.missed) == 2
