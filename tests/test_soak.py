"""The soak over the real services: the CI soak (2 process hours of TE at 3600x, every fault
kind once) and a focused run of the three node kills while a transition runs.

What must hold: no lost transition record, no unhandled error, no preventable
shutdown; after a controller restart the running transition continues, and the resume is
bumpless: judged here from the moves the report records (the 20 samples before the kill,
the move the plant held, the moves after), each of the first computed moves steps by no
more than the largest single-sample move of its MV before the kill.
"""

import json
import subprocess
import sys

import numpy as np
import pytest

from services.soak.faults import default_faults, parse_faults
from services.soak.run import REPORT_KEYS, SoakSettings, bumpless_verdict, run_soak

pytestmark = [pytest.mark.realtime, pytest.mark.integration, pytest.mark.timeout(400)]

CI_HOURS = 2.0
CI_SPEED = 720.0


def _check_shape(r):
    assert set(REPORT_KEYS) <= set(r)
    assert set(r["transitions"]) >= {"requested", "settled", "aborted", "failed"}
    for key in ("deadline_misses", "fallback_moves", "restarts", "bumpless_resumes",
                "records_lost", "unhandled_errors"):
        assert isinstance(r[key], int) and r[key] >= 0, key
    assert isinstance(r["shutdowns"], list)
    assert all(isinstance(n, int) for n in r["faults_injected"].values())


JUDGED_MOVES = 3  # computed moves after a restart that the rule judges


def _resume_steps(resume):
    """(largest step after the restart / largest step before) per MV, from the recorded
    moves alone: the first ``JUDGED_MOVES`` computed moves and any held ones between."""
    before = np.asarray(resume["moves_before"], float)
    assert before.shape[0] == 21, before.shape
    bound = np.abs(before[1:] - before[:-1]).max(axis=0)
    after, computed = [], 0
    for m in resume["moves_after"]:
        after.append(m["u"])
        computed += not m["fallback"]
        if computed == JUDGED_MOVES:
            break
    assert computed == JUDGED_MOVES, resume["moves_after"]
    path = np.vstack([resume["held"], *after])
    steps = np.abs(path[1:] - path[:-1]).max(axis=0)
    return steps, bound


def _check_bumpless(r):
    """Every controller resume met the rule, and the report counts exactly those."""
    resumes = r["details"]["controller_resumes"]
    assert len(resumes) == r["details"]["restarts_by_node"].get("controller", 0)
    met = 0
    for resume in resumes:
        steps, bound = _resume_steps(resume)
        ok = bool(np.all(steps <= bound + 1e-9 * (1 + np.abs(resume["held"]))))
        met += ok
        assert ok, {"over": np.flatnonzero(steps > bound).tolist(), "steps": steps.tolist(),
                    "bound": bound.tolist(), "t_h": resume["t_h"]}
    assert r["bumpless_resumes"] == met


def test_the_bumpless_verdict_counts_a_step_beyond_the_recent_ones():
    before = [[10.0 + 0.5 * k, 2800.0 + (k % 2)] for k in range(21)]  # steps 0.5 and 1
    held = before[-1]
    smooth = [{"fallback": True, "u": held},
              {"fallback": False, "u": [held[0] + 0.5, held[1] - 1.0]},
              {"fallback": False, "u": [held[0] + 0.9, held[1] - 1.5]}]
    assert bumpless_verdict(before, held, smooth)["bumpless"]
    bump = [*smooth[:2], {"fallback": False, "u": [held[0] + 0.9, held[1] - 21.5]}]
    v = bumpless_verdict(before, held, bump)
    assert not v["bumpless"] and v["worst_mv"]["index"] == 1
    first = [{"fallback": False, "u": [held[0] + 0.6, held[1]]}]  # 0.6 > 0.5 at once
    assert not bumpless_verdict(before, held, first)["bumpless"]


def _check_promise(r):
    d = r["details"]
    assert r["records_lost"] == 0, d["records_lost"]
    assert r["unhandled_errors"] == 0, d["unhandled_errors"]
    assert not [s for s in r["shutdowns"] if s["preventable"]], r["shutdowns"]


@pytest.mark.slow
def test_ci_soak_every_fault_kind_once(tmp_path):
    report = tmp_path / "soak.json"
    proc = subprocess.run(
        [sys.executable, "-m", "services.cli", "soak", "--unit", "te", "--hours", str(CI_HOURS),
         "--speed", str(CI_SPEED), "--seed", "3", "--transition-gap-h", "0.3",
         "--state-dir", str(tmp_path / "state"), "--report", str(report)],
        capture_output=True, text=True, timeout=380)
    assert proc.returncode == 0, proc.stderr[-3000:]
    r = json.loads(report.read_text())
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == r
    _check_shape(r)
    _check_promise(r)
    assert r["process_hours"] >= CI_HOURS
    expected = {w.name for w in default_faults(CI_HOURS, 36.0)}
    assert expected <= {k for k, n in r["faults_injected"].items() if n > 0}
    assert r["restarts"] == 3
    _check_bumpless(r)
    assert r["deadline_misses"] >= 1  # the stalled solver
    assert r["transitions"]["requested"] >= 1
    probes = r["details"]["security_probes"]
    assert probes.get("unauthorized write", 0) >= 1 and probes.get("malformed body", 0) >= 1


@pytest.mark.slow
def test_node_kills_during_a_transition(tmp_path):
    faults = tuple(parse_faults("kill:controller@0.4h,kill:plant@0.5h,kill:api@0.6h", 36.0))
    # at 1800x a loaded loop seldom has the slack for a checkpoint (one is forced every
    # 10 wall s, 5 process hours): the ramp-in's steps come from their own small record,
    # written every sample (with the checkpoint's, P_r* 2.85 kPa was allowed against 0.30)
    r = run_soak(SoakSettings(unit="te", hours=1.2, speed=1800.0, seed=5, faults=faults,
                              transition_gap_h=0.05, abort_probability=0.0, idv_gap_h=100.0,
                              state_dir=str(tmp_path / "state")))
    _check_shape(r)
    _check_promise(r)
    d = r["details"]
    assert d["restarts_by_node"] == {"controller": 1, "plant": 1, "api": 1}
    # a restarted plant node counts from sample 0 again and the controller acts on it;
    # a restarted api reaches the controller again
    assert sorted(c["node"] for c in d["node_restart_checks"]) == ["api", "plant"]
    assert all(c["ok"] for c in d["node_restart_checks"]), d["node_restart_checks"]
    # the transition that ran at the controller kill is driven on by the restarted node
    (check,) = d["transition_resume_checks"]
    assert check["before"] == "running" and check["after"] == "running" and check["ok"]
    assert check["active_after"] == check["transition"]
    # the restarted controller took the plant over bumplessly (judged from the moves),
    # and the replay from the killed node's checkpoint ran
    _check_bumpless(r)
    (resume,) = d["controller_resumes"]
    assert "first_move_vs_replay" in resume, resume
    assert r["transitions"]["requested"] >= 1


def test_bad_soak_arguments_are_refused_before_running(tmp_path):
    for argv, word in ((["--faults", "boom:meas@1h"], "kind"),
                       (["--faults", "drop:meas:5@1h"], "percentage"),
                       (["--speed", "-1"], "speed")):
        proc = subprocess.run(
            [sys.executable, "-m", "services.cli", "soak", "--hours", "1",
             "--report", str(tmp_path / "r.json"), *argv],
            capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2 and word in proc.stderr, (argv, proc.stderr)
        assert not (tmp_path / "r.json").exists()


@pytest.mark.slow
def test_a_trip_ends_the_run_and_is_judged_by_its_fault_free_twin(tmp_path):
    # MVs held (controller "hold": regulatory layer only) and IDV(1) on: measured to trip
    # on reactor pressure after ~3 h, whatever the TE MPC of the day does
    r = run_soak(SoakSettings(unit="te", hours=12.0, speed=3600.0, seed=2, faults=(),
                              idvs=(1,), idv_gap_h=0.05, idv_on_h=1000.0,
                              transition_gap_h=1000.0, unpreventable_idvs=(),
                              unit_config={"controller": "hold"},
                              state_dir=str(tmp_path / "state")))
    _check_shape(r)
    (trip,) = r["shutdowns"]
    assert trip["reason"] == "reactor pressure high" and trip["idvs_on"] == [1]
    # the fault-free twin (same plant, seed, controller and IDV offline) trips as well:
    # the trip is the process's and the controller's, not the services'
    assert trip["fault_free_twin_trip_hours"] == pytest.approx(trip["process_hours"], abs=0.5)
    assert trip["preventable"] is False
    # the run ends at the trip, not after 12 h; the report's process time is read after the
    # run's last REST calls, while the plant's clock goes on at 3600x (one wall second is
    # 1 h: 0.54 h after the trip on a loaded 2-core machine)
    assert r["process_hours"] < 12.0 and r["process_hours"] == pytest.approx(
        trip["process_hours"], abs=1.5)
    assert r["records_lost"] == 0 and r["unhandled_errors"] == 0


def test_fault_free_twin_replays_the_idvs_of_a_run():
    from controller.units.config import UnitConfig
    from services.registry import get_unit
    from services.soak.run import fault_free_twin

    cfg = UnitConfig.from_dict({"controller": "hold"}, get_unit("te"))
    empty = {"transitions": [], "events": []}
    # without the disturbance the held plant runs on; with IDV(1) from 0.1 h it trips
    assert fault_free_twin(cfg, 1.0, False, empty, [], 2 * 3600.0) is None
    trip = fault_free_twin(cfg, 1.0, False, empty, [{"t_h": 0.1, "idv": 1, "on": True}],
                           12 * 3600.0)
    assert trip is not None and 2 * 3600.0 < trip < 5 * 3600.0


def test_an_api_port_taken_before_the_api_binds_it_is_replaced(tmp_path, monkeypatch):
    # the port the soak picks for the api is free when picked; here something binds it
    # before the api starts (as an outgoing connection's ephemeral port may)
    import socket
    import sys as _sys

    from services.io import zenoh_session

    taker = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    taker.bind(("127.0.0.1", 0))
    taker.listen(1)
    taken = taker.getsockname()[1]
    real = zenoh_session.free_port
    handed = []

    def free_port(host="127.0.0.1"):
        if _sys._getframe(1).f_code.co_name == "run" and not handed:
            handed.append(taken)
            return taken
        return real(host)

    monkeypatch.setattr(zenoh_session, "free_port", free_port)
    try:
        r = run_soak(SoakSettings(unit="te", hours=0.3, speed=1800.0, seed=3, faults=(),
                                  transition_gap_h=1000.0, idv_gap_h=1000.0,
                                  state_dir=str(tmp_path / "state")))
    finally:
        taker.close()
    assert handed == [taken]
    _check_shape(r)
    assert r["records_lost"] == 0 and r["unhandled_errors"] == 0
    log = (tmp_path / "state" / "api.log").read_text()
    assert "in use" in log and log.count("--- start") == 2
