"""Nothing accepted is lost: a write is committed before it is acknowledged, a store that
cannot commit makes the controller degraded (alarm, writes 503), a corrupt or
inconsistent store or an undecodable checkpoint is refused at start (``error:``, exit
2), and a failed or settled transition is checkpointed at once so that a restart
cannot bring it back.

Real nodes over real Zenoh and the real HTTP server (test_service_loop's harness,
test_api's ApiServer); the ``ssmpc controller`` command run as a user runs it.
"""

import json
import math
import sqlite3
import subprocess
import sys
import time

import pytest
from test_api import AUTH, ApiServer
from test_service_loop import Harness

from services.io import keys
from services.io.messages import Measurement
from services.store import StoreError, UnitStore

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

POST = "/api/v1/units/cstr/transitions"


@pytest.fixture
def stack2(tmp_path):
    h = Harness(tmp_path, telemetry=False, transition_queue_limit=1000)
    api = ApiServer(h)
    yield h, api
    api.close()
    h.close()


def _disk_full(store):
    """SQLite's own 'database or disk is full' from now on (the file may not grow)."""
    pages = store._db.execute("PRAGMA page_count").fetchone()[0]
    store._db.execute(f"PRAGMA max_page_count={pages}")


def _fill(store):
    """Take up what room the file has left (rows of shrinking size until none fits), in
    the transition tables and in the event log: a table's partly used pages keep their
    room when the file has no free page left, so each table an abort writes is filled."""
    from services.events import Event

    i = 0
    for size in (2000, 200, 20, 1):
        while True:
            i += 1
            try:
                store.save_transition({"id": f"fill{i}", "grade": "OPII", "state": "settled",
                                       "pad": "x" * size}, event="settled")
            except sqlite3.OperationalError:
                break
        while True:
            i += 1
            try:
                store.add_events([Event(id=f"fill{i}", time_us=i, process_time_s=None,
                                        kind="fill", detail={"pad": "x" * size})])
            except sqlite3.OperationalError:
                break


def _until(cond, timeout=10.0):
    t_end = time.monotonic() + timeout
    while not cond() and time.monotonic() < t_end:
        time.sleep(0.02)
    return cond()


def _replies(h, action) -> bool:
    try:
        h.query(action)
    except AssertionError:  # no reply (yet)
        return False
    return True


def test_a_store_that_cannot_commit_answers_503_and_loses_nothing_acknowledged(stack2):
    h, api = stack2
    c = api.client
    h.wait_samples(3)
    _disk_full(h.store)
    accepted, refused = [], []
    for i in range(60):
        r = c.post(POST, json={"grade": "OPII" if i % 2 else "OPIII", "queue": True,
                               "duration_h": 1.0},
                   headers={**AUTH, "Idempotency-Key": f"k{i}"})
        assert r.status_code in (202, 429, 503), (r.status_code, r.text)
        (accepted if r.status_code == 202 else refused).append(r)
        if r.status_code == 503:
            break
    assert refused and refused[-1].status_code == 503, [r.status_code for r in refused]
    assert "store" in refused[-1].json()["detail"]
    st = c.get("/api/v1/units/cstr/status").json()
    assert st["store"] == "degraded" and any("store" in a for a in st["alarms"])
    ids = {r.json()["id"] for r in accepted}
    h.stop_controller()  # and everything acknowledged is on disk
    with UnitStore(h.store_path, "cstr") as store:
        assert ids <= {t["id"] for t in store.transitions()}


def test_an_abort_that_cannot_be_stored_is_503(stack2):
    h, api = stack2
    c = api.client
    h.wait_samples(3)
    tid = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=AUTH).json()["id"]
    _disk_full(h.store)
    _fill(h.store)
    r = c.delete(f"{POST}/{tid}", headers=AUTH)
    assert r.status_code == 503, (r.status_code, r.text)
    assert "store" in r.json()["detail"]


def test_a_failed_transition_is_checkpointed_at_once(stack2):
    """A plant shutdown fails the running transition: the checkpoint says so at once,
    so a controller killed right after does not bring it back as running."""
    h, api = stack2
    c = api.client
    h.wait_samples(3)
    tid = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=AUTH).json()["id"]
    assert _until(lambda: c.get(f"{POST}/{tid}").json()["state"] == "running")
    h.stop_plant.set()  # the plant's last word: it tripped
    h.plant_thread.join(5)
    h.plant.close()
    pub = h.s_client.declare_publisher(keys.meas("cstr"))
    time.sleep(0.3)
    k = h.ctrl.k + 1
    pub.put(Measurement(unit="cstr", seq=k, t=k * h.cfg.sample_period_s, y=tuple(h.ctrl.y),
                        u=tuple(h.ctrl.u_last), shutdown=True,
                        incarnation=h.plant.incarnation).to_bytes())
    assert _until(lambda: c.get(f"{POST}/{tid}").json()["state"] == "failed")
    h.ctrl.flush()  # what the node wrote so far is on disk; then a kill
    h.ctrl.checkpoint = lambda wait=True: None
    h.stop_controller()
    h.start_controller()
    assert _until(lambda: api.mesh.alive("cstr", "controller"))
    view = c.get(f"{POST}/{tid}").json()
    listed = {t["id"]: t["state"] for t in c.get(POST).json()}
    assert view["state"] == "failed" and listed[tid] == "failed"
    assert c.get("/api/v1/units/cstr/status").json()["transition"]["state"] == "failed"
    events = [e["state"] for e in h.store.events(tid)]
    assert events == ["pending", "running", "failed"]
    pub.undeclare()


def test_a_checkpoint_older_than_the_store_does_not_revive_a_transition(tmp_path):
    """The checkpoint says running, the store says failed (a crash between the two
    writes): the store's terminal state wins at start."""
    h = Harness(tmp_path, telemetry=False)
    try:
        h.wait_samples(3)
        tid = h.query("transition", {"op": "create", "grade": "OPII",
                                     "duration_s": 3600.0}).data["id"]
        assert _until(lambda: h.query("transition", {"op": "get", "id": tid}).data["state"]
                      == "running")
        h.ctrl.checkpoint(wait=True)  # the checkpoint: running
        h.ctrl.checkpoint = lambda wait=True: None
        h.stop_controller()
        with UnitStore(h.store_path, "cstr") as store:  # the record: failed
            rec = store.transition(tid)
            rec.update(state="failed", detail="plant shut down")
            store.save_transition(rec, event="failed", process_time=rec["started_t"])
        h.start_controller()
        # the restarted node answers once its queryable has reached the client's session
        # (a loaded machine takes a while)
        assert _until(lambda: _replies(h, "status"), timeout=20.0)
        view = h.query("transition", {"op": "get", "id": tid}).data
        assert view["state"] == "failed"
        assert h.query("status").data["transition"]["state"] == "failed"
    finally:
        h.close()


def _corrupt_page(path):
    """Overwrite the middle of the file's second page (a b-tree page) with garbage."""
    data = bytearray(path.read_bytes())
    page = int.from_bytes(data[16:18], "big") or 65536
    for i in range(page + 8, min(len(data), 2 * page - 8)):
        data[i] = 0xA5
    path.write_bytes(bytes(data))


def _controller(tmp_path, timeout=120):
    return subprocess.run(
        [sys.executable, "-m", "services.cli", "controller", "--unit", "cstr", "--state-dir",
         str(tmp_path), "--no-telemetry", "--duration", "3"],
        capture_output=True, text=True, timeout=timeout)


def _make_store(tmp_path, n=40):
    path = tmp_path / "ssmpc-cstr.sqlite"
    with UnitStore(path, "cstr") as store:
        for i in range(n):
            store.save_transition({"id": f"t{i}", "grade": "OPII", "state": "settled",
                                   "pad": "x" * 200}, event="settled")
        store._db.execute("PRAGMA wal_checkpoint(TRUNCATE)")
    return path


def test_a_corrupt_store_is_refused_at_start(tmp_path):
    path = _make_store(tmp_path)
    _corrupt_page(path)
    with pytest.raises(StoreError, match="corrupt"):
        UnitStore(path, "cstr")
    proc = _controller(tmp_path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: ") and "Traceback" not in proc.stderr
    assert "corrupt" in proc.stderr and "ready" not in proc.stdout


def test_a_file_that_is_not_a_store_is_refused_at_start(tmp_path):
    (tmp_path / "ssmpc-cstr.sqlite").write_bytes(b"not a database at all" * 100)
    proc = _controller(tmp_path)
    assert proc.returncode == 2 and proc.stderr.startswith("error: "), proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize("u_last", ["[1e999]", "[NaN]", "[-Infinity]", '"x"'])
def test_an_undecodable_checkpoint_is_refused_at_start(tmp_path, u_last):
    """Documented choice: start refuses a checkpoint it cannot decode (error, exit 2),
    rather than start without it: the operator decides (move the store aside)."""
    h = Harness(tmp_path, telemetry=False)
    h.wait_samples(3)
    h.close()
    path = h.store_path
    db = sqlite3.connect(str(path))
    text = db.execute("SELECT state FROM checkpoint").fetchone()[0]
    state = json.loads(text)
    raw = json.dumps(state).replace(json.dumps(state["u_last"]), u_last)
    db.execute("UPDATE checkpoint SET state=?", (raw,))
    db.commit()
    db.close()
    if u_last != '"x"':  # non-finite: refused by the store itself; "x" by the node
        with pytest.raises(StoreError, match="checkpoint"):
            UnitStore(path, "cstr").load_checkpoint()
    target = tmp_path / "ssmpc-cstr.sqlite"
    path.rename(target)
    proc = _controller(tmp_path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: ") and "checkpoint" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_a_checkpoint_that_cannot_be_encoded_is_refused_and_the_last_good_one_kept(stack2):
    h, api = stack2
    h.wait_samples(3)
    h.ctrl.checkpoint(wait=True)  # a good one
    with h.ctrl._lock:
        h.ctrl.u_last = h.ctrl.u_last * float("inf")
        h.ctrl.checkpoint(wait=True)
    st = h.query("status").data
    assert any("checkpoint not written" in a for a in st["alarms"])
    cp = h.store.load_checkpoint()  # the previous one, decodable
    assert all(math.isfinite(x) for x in cp["state"]["u_last"])


def test_a_locked_store_answers_503_and_the_controller_recovers(stack2):
    """Another process holds the store's write lock (longer than the busy timeout)."""
    h, api = stack2
    c = api.client
    h.wait_samples(3)
    other = sqlite3.connect(str(h.store_path), isolation_level=None)
    other.execute("BEGIN IMMEDIATE")
    try:
        r = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=AUTH)
        assert r.status_code == 503, (r.status_code, r.text)
        assert c.get("/api/v1/units/cstr/status").json()["store"] == "degraded"
    finally:
        other.execute("ROLLBACK")
        other.close()
    r = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=AUTH)
    assert r.status_code == 202
    assert c.get("/api/v1/units/cstr/status").json()["store"] == "ok"
    assert [t["id"] for t in c.get(POST).json()] == [r.json()["id"]]


def test_an_abort_the_store_cannot_record_leaves_the_transition_running(stack2):
    """A 503 abort changes nothing: the transition keeps running, and once the store
    commits again a restart does not bring the unacknowledged abort back; an abort
    that is acknowledged afterwards is on disk before its 200."""
    h, api = stack2
    c = api.client
    h.wait_samples(3)
    tid = c.post(POST, json={"grade": "OPII", "duration_h": 1.0}, headers=AUTH).json()["id"]
    assert _until(lambda: c.get(f"{POST}/{tid}").json()["state"] == "running")
    _disk_full(h.store)
    _fill(h.store)
    r = c.delete(f"{POST}/{tid}", headers=AUTH)
    assert r.status_code == 503, (r.status_code, r.text)
    h.wait_samples(5)  # the loop goes on with the transition it has
    assert c.get(f"{POST}/{tid}").json()["state"] == "running"
    assert c.get("/api/v1/units/cstr/status").json()["transition"]["state"] == "running"
    h.store._db.execute("PRAGMA max_page_count=1073741823")  # room again
    h.ctrl.checkpoint(wait=True)
    h.stop_controller()
    h.start_controller()
    assert _until(lambda: api.mesh.alive("cstr", "controller"))
    assert c.get(f"{POST}/{tid}").json()["state"] == "running"
    assert "aborted" not in [e["state"] for e in h.store.events(tid)]
    r = c.delete(f"{POST}/{tid}", headers=AUTH)
    assert r.status_code == 200 and r.json()["state"] == "aborted", r.text
    with UnitStore(h.store_path, "cstr") as store:
        assert store.transition(tid)["state"] == "aborted"


def _make_unwritable(path) -> bool:
    """Make ``path`` unwritable for this process: read-only mode, or for root (whom modes
    do not stop) the immutable attribute. False when neither works here."""
    path.chmod(0o444)
    try:
        with open(path, "r+b"):
            pass
    except PermissionError:
        return True
    done = subprocess.run(["chattr", "+i", str(path)], capture_output=True)
    return done.returncode == 0


def _make_writable(path) -> None:
    subprocess.run(["chattr", "-i", str(path)], capture_output=True)
    path.chmod(0o644)


def test_an_unwritable_shared_memory_index_is_refused_at_start(tmp_path):
    """The WAL's shared-memory index (``-shm``) read-only: ``error:`` and exit 2 at start,
    never a signal death or a controller that starts and cannot store anything."""
    path = tmp_path / "ssmpc-cstr.sqlite"
    store = UnitStore(path, "cstr")  # open: its -wal and -shm stay
    store.save_transition({"id": "t0", "grade": "OPII", "state": "settled"}, event="settled")
    shm = tmp_path / "ssmpc-cstr.sqlite-shm"
    assert shm.exists()
    if not _make_unwritable(shm):
        store.close()
        pytest.skip("cannot make a file unwritable here (root without chattr)")
    try:
        proc = _controller(tmp_path)
    finally:
        _make_writable(shm)
        store.close()
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert proc.stderr.startswith("error: ") and "cannot be written" in proc.stderr
    assert "Traceback" not in proc.stderr and "ready" not in proc.stdout


def _checkpoint_state(path):
    db = sqlite3.connect(str(path))
    try:
        return json.loads(db.execute("SELECT state FROM checkpoint").fetchone()[0])
    finally:
        db.close()


def _write_checkpoint_state(path, state):
    db = sqlite3.connect(str(path))
    try:
        db.execute("UPDATE checkpoint SET state=?", (json.dumps(state),))
        db.commit()
    finally:
        db.close()


#: A checkpoint that decodes but whose entries have the wrong shape: a string or a list
#: where the node or a piece of the controller reads a mapping, a mapping where it reads
#: a number or a sequence.
WRONG_SHAPES = [("transitions", "x"), ("controller", "x"), ("controller", [1, 2]),
                ("operator", "x"), ("operator", [1]), ("kpis", "x"), ("kpis", [1, 2]),
                ("recent_steps", {"a": 1}), ("mv_seq", {"a": 1}), ("u_last", {"a": 1})]


def test_a_checkpoint_with_entries_of_the_wrong_shape_is_refused_at_start(tmp_path):
    """Each entry replaced in turn by a value of another JSON type: the controller
    refuses the checkpoint with an ``error:`` naming it (exit 2), never a traceback and
    never a start from part of it."""
    h = Harness(tmp_path, telemetry=False)
    h.wait_samples(3)
    h.close()
    good = _checkpoint_state(h.store_path)
    target = tmp_path / "ssmpc-cstr.sqlite"
    h.store_path.rename(target)
    for key, value in WRONG_SHAPES:
        state = json.loads(json.dumps(good))
        state[key] = value
        _write_checkpoint_state(target, state)
        proc = _controller(tmp_path)
        assert proc.returncode == 2, (key, value, proc.stderr[-2000:])
        assert proc.stderr.startswith("error: ") and "checkpoint" in proc.stderr, (key, value)
        assert "Traceback" not in proc.stderr, (key, value)


@pytest.mark.parametrize("damage", [{"target": [5.0, 1.0]}, {"grade": "OPX"},
                                    {"duration_s": "x"}])
def test_a_pending_record_the_unit_cannot_run_is_refused_at_start(tmp_path, damage):
    """A pending transition in the store but not in the checkpoint is queued again at
    start; one whose record this unit cannot run (a target of the wrong length, an
    unknown grade, a duration that is no number) refuses the start with ``error:``
    naming the store, rather than failing every sample after it."""
    h = Harness(tmp_path, telemetry=False)
    h.wait_samples(3)
    h.close()
    target = tmp_path / "ssmpc-cstr.sqlite"
    h.store_path.rename(target)
    with UnitStore(target, "cstr") as store:
        rec = {"id": "p1", "unit": "cstr", "grade": "OPII", "from_grade": "OPI",
               "target": [5.0], "duration_s": 10.0, "requested_t": 0.0,
               "state": "pending", **damage}
        store.save_transition(rec, event="pending")
    proc = _controller(tmp_path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.startswith("error: ") and "transition record" in proc.stderr
    assert "Traceback" not in proc.stderr
