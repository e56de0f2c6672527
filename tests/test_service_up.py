"""``ssmpc up`` as a user runs it: three processes, a REST transition, clean shutdown, .rrd."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from services.io.zenoh_session import free_port
from services.telemetry import entity_paths

pytestmark = [pytest.mark.integration, pytest.mark.timeout(180)]

REPO = Path(__file__).resolve().parents[1]


def _children(pid):
    out = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        text = (task / "children").read_text().split()
        out.update(int(x) for x in text)
    return out


def _alive(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0]
    except FileNotFoundError:
        return False
    return state != "Z"


def test_up_transition_and_clean_shutdown(tmp_path):
    port = free_port()
    proc = subprocess.Popen(
        # 5x: 10 ms samples with a 5 ms deadline for the controller (at 20x, on a 2-core
        # machine with one core taken by another job, the transition once failed to settle)
        [sys.executable, "-m", "services.cli", "up", "--unit", "cstr", "--speed", "5",
         "--port", str(port), "--state-dir", str(tmp_path), "--duration", "150"],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        t_end = time.monotonic() + 120
        lines = []
        while time.monotonic() < t_end:
            line = proc.stdout.readline()
            assert line, f"up exited early: {proc.stderr.read()}"
            lines.append(line)
            if line.startswith("ssmpc up:"):
                break
        # it says what it starts, then each node's ready line: the router first, the
        # plant only once the controller is ready, the API alongside the controller
        ready = [ln.split()[1] for ln in lines if ln.startswith("ready")]
        assert ready == ["router", "controller", "plant", "api"]
        starting = [ln.split()[2] for ln in lines if ln.startswith("starting the")]
        assert starting == ["router", "controller", "api", "plant"]
        assert lines.index(next(ln for ln in lines if ln.startswith("ready controller"))) \
            < lines.index(next(ln for ln in lines if ln.startswith("starting the plant")))
        children = _children(proc.pid)
        assert len(children) == 4  # router, controller, plant, api
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=10) as c:
            assert c.get("/health").status_code == 200
            r = c.post("/api/v1/units/cstr/transitions", json={"grade": "OPII"})
            assert r.status_code == 202
            loc = r.headers["location"]
            t_end = time.monotonic() + 60
            while time.monotonic() < t_end:
                v = c.get(loc).json()
                if v["state"] != "pending" and v["state"] != "running":
                    break
                time.sleep(0.2)
            assert v["state"] == "settled"
            st = c.get("/api/v1/units/cstr/status").json()
            assert abs(st["cv"]["y"] - 5.0) < 0.05
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 0
        time.sleep(0.2)
        assert not [p for p in children if _alive(p)], "orphan node processes"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # the recording and the store are complete after the shutdown
    rr_chunk = pytest.importorskip("rerun.chunk")
    reader = rr_chunk.RrdReader(str(tmp_path / "ssmpc-cstr.rrd"))
    paths = {ch.entity_path for ch in reader.stream() if not ch.is_static}
    expected = {"/" + p for p in entity_paths("cstr", ["y"], ["u"], [])}
    assert expected <= paths
    assert any(p.startswith("/cstr/model/J/") for p in paths)
    from services.store import UnitStore

    store = UnitStore(tmp_path / "ssmpc-cstr.sqlite", "cstr")
    assert [e["state"] for e in store.events()] == ["pending", "running", "settled"]
    store.close()
    assert os.path.getsize(tmp_path / "ssmpc-cstr.rrd") > 0


@pytest.mark.parametrize("busy_poll", [False, True])
def test_up_ctrl_c_stops_every_process(tmp_path, busy_poll):
    """Ctrl-C in a terminal: SIGINT to the whole foreground process group (also with a
    controller that polls without sleeping)."""
    port = free_port()
    proc = subprocess.Popen(
        [sys.executable, "-m", "services.cli", "up", "--unit", "cstr", "--speed", "5",
         "--port", str(port), "--state-dir", str(tmp_path), "--duration", "120"]
        + (["--busy-poll"] if busy_poll else []),
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
        start_new_session=True)
    try:
        t_end = time.monotonic() + 120
        while time.monotonic() < t_end:
            line = proc.stdout.readline()
            assert line, "up exited early"
            if line.startswith("ssmpc up:"):
                break
        children = _children(proc.pid)
        assert len(children) == 4  # router, controller, plant, api
        cmdlines = [open(f"/proc/{c}/cmdline", "rb").read().split(b"\0") for c in children]
        polling = [c for c in cmdlines if b"controller" in c and b"--busy-poll" in c]
        assert len(polling) == (1 if busy_poll else 0)
        os.killpg(proc.pid, signal.SIGINT)
        assert proc.wait(timeout=30) == 0
        time.sleep(0.2)
        assert not [p for p in children if _alive(p)]
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert (tmp_path / "ssmpc-cstr.rrd").stat().st_size > 0


def test_a_new_up_run_keeps_the_previous_store_aside(tmp_path):
    from services.nodes.supervisor import _move_aside

    for suffix in (".sqlite", ".sqlite-wal", ".rrd"):
        (tmp_path / f"ssmpc-te{suffix}").write_text(suffix)
    (tmp_path / "ssmpc-cstr.sqlite").write_text("other unit")
    moved = _move_aside(str(tmp_path), "te")
    assert len(moved) == 3
    assert not (tmp_path / "ssmpc-te.sqlite").exists()
    assert (tmp_path / "ssmpc-cstr.sqlite").exists()
    assert sorted(Path(m).read_text() for m in moved) == [".rrd", ".sqlite", ".sqlite-wal"]


def test_restarted_controller_continues_its_recording_in_a_new_file(tmp_path):
    rr_chunk = pytest.importorskip("rerun.chunk")
    for _ in range(2):
        proc = subprocess.run(
            [sys.executable, "-m", "services.cli", "controller", "--unit", "cstr",
             "--state-dir", str(tmp_path), "--duration", "1"],
            cwd=REPO, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
    files = sorted(tmp_path.glob("ssmpc-cstr*.rrd"))
    assert [f.name for f in files] == ["ssmpc-cstr.1.rrd", "ssmpc-cstr.rrd"]
    ids = {rr_chunk.RrdReader(str(f)).recordings()[0].recording_id for f in files}
    assert len(ids) == 1


def test_up_says_what_it_is_doing_while_a_node_starts(monkeypatch):
    # a node that takes a while to get ready (a first start compiles with numba)
    from services.nodes import supervisor

    monkeypatch.setattr(supervisor, "PROGRESS_EVERY_S", 0.3)
    proc = subprocess.Popen([sys.executable, "-c",
                             "import time; time.sleep(1.2); print('ready slow te', flush=True)"],
                            stdout=subprocess.PIPE, text=True, bufsize=1)
    notes = []
    line = supervisor._wait_ready(proc, "slow", time.monotonic() + 30, notes.append)
    proc.wait(5)
    assert line == "ready slow te"
    assert len(notes) >= 2 and notes == sorted(notes)  # elapsed seconds, growing
