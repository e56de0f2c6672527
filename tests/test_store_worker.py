"""The controller node's store worker: a write a request waits for is withdrawn when it
cannot start in time (so a write answered as not committed never commits later), and one
that has started is waited for to its end."""

import threading
import time

import pytest

from services.nodes.controller import _Worker


def test_a_write_that_cannot_start_in_time_is_withdrawn_and_never_runs():
    w = _Worker()
    release = threading.Event()
    ran = []
    w.submit(release.wait, 5.0)  # a write ahead of it, waiting on a lock
    with pytest.raises(TimeoutError, match="withdrawn"):
        w.call(ran.append, "late", timeout=0.1)
    release.set()
    w.wait()
    assert ran == []  # answered "not committed": it did not commit afterwards either
    assert w.call(ran.append, "now", timeout=1.0) is None and ran == ["now"]
    w.close()


def test_a_write_that_has_started_is_waited_for_to_its_end():
    w = _Worker()

    def slow():
        time.sleep(0.3)
        return "committed"

    t0 = time.monotonic()
    assert w.call(slow, timeout=0.05) == "committed"
    assert time.monotonic() - t0 >= 0.3
    with pytest.raises(ValueError, match="boom"):
        w.call(lambda: (_ for _ in ()).throw(ValueError("boom")), timeout=0.05)
    w.close()
