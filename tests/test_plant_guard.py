"""The plant defends itself, as a DCS does: moves clamped to instrument ranges and
rate-limited, a sequence jump beyond the time elapsed refused, an alarm when the
applied move is not the controller's latest; and every measurement names the plant's
incarnation, so the controller re-synchronizes only when the plant really restarted.

Real nodes over real Zenoh (tests/test_service_loop.py's harness).
"""

import time

import numpy as np
import pytest

from services.io import keys
from services.io.messages import Measurement, MVMessage

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]


def _now_us():
    return time.time_ns() // 1000


def _until(cond, timeout=10.0):
    t_end = time.monotonic() + timeout
    while not cond() and time.monotonic() < t_end:
        time.sleep(0.02)
    return cond()


def test_a_forged_move_with_a_huge_sequence_number_neither_acts_nor_freezes(harness):
    h = harness()
    h.wait_samples(5)
    pub = h.s_client.declare_publisher(keys.mv("cstr"))
    time.sleep(0.3)
    forged = MVMessage(unit="cstr", seq=2**62, meas_seq=h.plant.k, u=(0.9,),
                       sender="cstr-controller")
    pub.put(forged.to_bytes())
    assert _until(lambda: h.plant.status()["mv_rejected"].get("jump", 0) == 1)
    applied = h.plant.status()["mv_seq_applied"]
    h.wait_samples(20)  # genuine moves go on being applied: no lock-step waits
    st = h.plant.status()
    assert st["mv_seq_applied"] > applied and st["mv_seq_applied"] < 2**62
    assert st["mv_rejected"]["stale"] == 0 and st["lockstep_timeouts"] == 0
    assert any("sequence jump" in a for a in st["alarms"])
    pub.undeclare()


def test_a_move_that_is_not_the_controllers_latest_raises_an_alarm(harness):
    h = harness()
    h.wait_samples(5)
    pub = h.s_client.declare_publisher(keys.mv("cstr"))
    time.sleep(0.3)
    # just ahead of the controller's numbering: accepted, and the genuine moves that
    # follow look older than it for a moment
    ahead = MVMessage(unit="cstr", seq=_now_us() + 300_000, meas_seq=h.plant.k, u=(0.41,),
                      sender="cstr-controller")
    pub.put(ahead.to_bytes())
    assert _until(lambda: h.plant.status()["mv_rejected"]["stale"] > 0)
    st = h.plant.status()
    assert any("not the controller's latest" in a for a in st["alarms"]), st["alarms"]
    # and the controller sees, in the measurements, a move it did not send
    assert _until(lambda: h.query("status").data["foreign_moves"] >= 1)
    assert any("did not send" in a for a in h.query("status").data["alarms"])
    h.wait_samples(10)  # and the loop goes on afterwards
    pub.undeclare()


def test_moves_beyond_the_instrument_range_are_clamped_on_a_unit_plant(harness):
    h = harness(unit="bioreactor", start_plant=False, telemetry=False)
    h.stop_controller()
    h.start_plant(lockstep_timeout_s=0.02)
    pub = h.s_client.declare_publisher(keys.mv("bioreactor"))
    time.sleep(0.3)
    lo, hi = h.plant.runner.u_lower, h.plant.runner.u_upper  # dilution rate D >= 0
    pub.put(MVMessage(unit="bioreactor", seq=_now_us(), meas_seq=0, u=(-1e9,),
                      sender="bioreactor-controller").to_bytes())
    assert _until(lambda: h.plant.status()["mv_accepted"] >= 1)
    time.sleep(0.2)
    st = h.plant.status()
    assert lo[0] <= st["u"][0] <= hi[0]
    assert st["moves_limited"] >= 1
    assert any("clamped" in a or "limited" in a for a in st["alarms"])
    pub.undeclare()


#: The TE loops' set points and valve targets the plant node applies at most
#: (DESIGN "the plant defends itself"; ranges within the shutdown interlocks of
#: Downs & Vogel, reactor pressure trips above 3000 kPa gauge, reactor temperature
#: above 175 °C).
TE_PRESSURE_TRIP_KPA = 3000.0
TE_TEMPERATURE_TRIP_C = 175.0


def test_forged_te_set_points_do_not_trip_the_plant(harness):
    from controller.units.te.structure import te_mv_names

    h = harness(unit="te", start_plant=False, telemetry=False)
    h.stop_controller()
    h.start_plant(lockstep_timeout_s=0.01)
    names = list(te_mv_names(h.cfg))
    u = np.array(h.plant.runner.u, float)
    u[names.index("reactor_pressure_sp")] = 1e6
    u[names.index("reactor_temperature_sp")] = 1000.0
    pub = h.s_client.declare_publisher(keys.mv("te"))
    time.sleep(0.3)
    pub.put(MVMessage(unit="te", seq=_now_us(), meas_seq=0, u=tuple(u),
                      sender="te-controller").to_bytes())
    assert _until(lambda: h.plant.status()["mv_accepted"] >= 1)
    assert _until(lambda: h.plant.k >= 100, timeout=120)  # one process hour held
    st = h.plant.status()
    assert not st["shutdown"]
    applied = dict(zip(names, st["u"]))
    assert applied["reactor_pressure_sp"] < TE_PRESSURE_TRIP_KPA
    assert applied["reactor_temperature_sp"] < TE_TEMPERATURE_TRIP_C
    assert st["moves_limited"] >= 1
    y = h.plant.runner.y()
    assert y[6] < TE_PRESSURE_TRIP_KPA  # XMEAS 7, reactor pressure
    pub.undeclare()


def test_every_measurement_names_the_plant_incarnation(harness):
    h = harness(start_plant=False)
    h.stop_controller()
    seen = []
    sub = h.s_client.declare_subscriber(
        keys.meas("cstr"), lambda s: seen.append(Measurement.from_bytes(s.payload.to_bytes())))
    time.sleep(0.3)
    h.start_plant(lockstep_timeout_s=0.02)
    assert _until(lambda: len(seen) >= 3)
    first = {m.incarnation for m in seen}
    assert len(first) == 1 and len(first.pop()) >= 16
    h.stop_plant.set()
    h.plant_thread.join(5)
    h.plant.close()
    seen.clear()
    h.stop_plant = type(h.stop_plant)()
    h.start_plant(lockstep_timeout_s=0.02)
    time.sleep(0.3)  # the old run's last messages are in
    seen.clear()
    assert _until(lambda: len(seen) >= 3)
    assert {m.incarnation for m in seen} == {h.plant.incarnation}
    sub.undeclare()


def test_a_foreign_incarnation_is_refused_and_the_loop_goes_on(harness):
    h = harness()
    h.wait_samples(5)
    pub = h.s_client.declare_publisher(keys.meas("cstr"))
    time.sleep(0.3)
    y, u = tuple(h.plant.runner.y()), tuple(h.plant.runner.u)
    pub.put(Measurement(unit="cstr", seq=10**9, t=1e9, y=y, u=u,
                        incarnation="f" * 32).to_bytes())
    assert _until(lambda: h.query("status").data["foreign_measurements"] == 1)
    h.wait_samples(10)  # the genuine samples are still acted on
    st = h.query("status").data
    assert st["sample"] < 10**6 and st["stale_measurements"] == 0
    assert any("incarnation" in a for a in st["alarms"])
    pub.undeclare()


def test_a_fake_plant_liveliness_token_does_not_reopen_old_samples(harness):
    h = harness()
    h.wait_samples(5)
    pub = h.s_client.declare_publisher(keys.meas("cstr"))
    token = h.s_client.liveliness().declare_token(keys.alive("cstr", "plant"))
    time.sleep(0.5)
    y, u = tuple(h.plant.runner.y()), tuple(h.plant.runner.u)
    before = h.query("status").data["stale_measurements"]
    replay = Measurement(unit="cstr", seq=1, t=h.cfg.sample_period_s, y=y, u=u,
                         incarnation=h.plant.incarnation)
    pub.put(replay.to_bytes())
    assert _until(lambda: h.query("status").data["stale_measurements"] == before + 1)
    h.wait_samples(5)
    assert h.query("status").data["sample"] > 5
    token.undeclare()
    pub.undeclare()


def test_a_restarted_plant_is_followed_from_its_first_sample(harness):
    h = harness()
    h.wait_samples(20)
    h.stop_plant.set()
    h.plant_thread.join(5)
    h.plant.close()
    old = h.plant.incarnation
    h.stop_plant = type(h.stop_plant)()
    h.start_plant()
    assert h.plant.incarnation != old
    new = h.plant.incarnation
    # re-synchronized: the controller follows the new incarnation from one of its first
    # samples (the status's sample counter itself may be past any bound by the time it
    # is read: a lock-step loop runs as fast as it goes)
    assert _until(lambda: h.query("status").data["plant_incarnation"] == new)
    followed = [a for a in h.query("status").data["alarms"]
                if a.startswith(f"plant restarted: following its incarnation {new[:8]} ")]
    assert len(followed) == 1
    assert int(followed[0].rsplit(" ", 1)[1]) < 20
    h.wait_samples(5)


def test_te_valve_targets_are_clamped_to_their_range_and_rate():
    from controller.units.te.structure import te_mv_names
    from services.nodes.plant_guard import te_limits
    from services.registry import get_unit

    names = te_mv_names(get_unit("te"))
    limits = te_limits(names)
    held = np.array([50.0 if n.startswith("XMV") else lo for n, lo in zip(names, limits.lower)])
    ask = held.copy()
    ask[0], ask[1] = 250.0, -80.0  # two valves, far out of range
    applied, limited = limits.apply(held, ask)
    assert applied[0] == 100.0 and applied[1] == 0.0  # 50 % per sample at most
    assert set(limited) == {names[0], names[1]}
    same, none = limits.apply(held, held + 1e-3)  # a small genuine move goes as it is
    assert none == [] and np.array_equal(same, held + 1e-3)
