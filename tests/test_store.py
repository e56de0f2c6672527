"""SQLite store: WAL, atomic writes, history complete after a restart (reopen)."""

import sqlite3

import pytest

from services.store import UnitStore


def _rec(tid, state, grade="OPII"):
    return {"id": tid, "grade": grade, "state": state, "progress": 0.0}


def test_transition_history_survives_reopen(tmp_path):
    path = tmp_path / "u.sqlite"
    s = UnitStore(path, "cstr")
    s.save_transition(_rec("a", "pending"), event="pending", process_time=1.0)
    s.save_transition(_rec("a", "running"), event="running", process_time=1.1)
    s.save_transition(_rec("a", "settled"), event="settled", process_time=9.0)
    s.save_transition(_rec("b", "pending", "OPI"), event="pending", process_time=10.0)
    s.save_checkpoint(90, 9.0, {"u_last": [0.4], "nested": {"k": [1, 2]}})
    s.close()

    s2 = UnitStore(path, "cstr")
    assert [r["id"] for r in s2.transitions()] == ["a", "b"]
    assert s2.transition("a")["state"] == "settled"
    assert [e["state"] for e in s2.events("a")] == ["pending", "running", "settled"]
    assert [e["process_time"] for e in s2.events()] == [1.0, 1.1, 9.0, 10.0]
    cp = s2.load_checkpoint()
    assert cp["sample"] == 90 and cp["process_time"] == 9.0
    assert cp["state"] == {"u_last": [0.4], "nested": {"k": [1, 2]}}
    assert s2.transition("zzz") is None
    s2.close()


def test_wal_mode_and_one_file_per_unit(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    mode = sqlite3.connect(tmp_path / "u.sqlite").execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"
    other = UnitStore(tmp_path / "u.sqlite", "te")
    s.save_checkpoint(1, 0.1, {"a": 1})
    assert other.load_checkpoint() is None
    s.close()
    other.close()


def test_failed_write_leaves_nothing_half_done(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    s.save_transition(_rec("a", "pending"), event="pending")
    bad = {"id": "a", "state": "running"}  # no grade: fails inside the transaction
    with pytest.raises(KeyError):
        s.save_transition(bad, event="running")
    assert s.transition("a")["state"] == "pending"
    assert [e["state"] for e in s.events("a")] == ["pending"]
    with pytest.raises(ValueError):
        s.save_checkpoint(1, 0.0, {"x": float("nan")})
    assert s.load_checkpoint() is None
    s.close()


def test_checkpoint_overwrites(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    s.save_checkpoint(1, 0.1, {"v": 1})
    s.save_checkpoint(2, 0.2, {"v": 2})
    assert s.load_checkpoint()["state"] == {"v": 2}
    s.close()


def test_checkpoint_encoded_by_the_caller_is_stored_as_is(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    s.save_checkpoint(3, 1.5, {"x": [1.0, 2.0]})
    text = UnitStore.encode_checkpoint({"x": [4.0], "nested": {"k": 1}})
    s.save_checkpoint(7, 3.5, text)
    cp = s.load_checkpoint()
    assert cp["sample"] == 7 and cp["state"] == {"x": [4.0], "nested": {"k": 1}}
    with pytest.raises(ValueError):
        UnitStore.encode_checkpoint({"x": [float("nan")]})  # refused before any write
    assert s.load_checkpoint()["sample"] == 7


def test_recent_steps_are_replaced_and_read_back(tmp_path):
    s = UnitStore(tmp_path / "u.sqlite", "cstr")
    assert s.load_recent_steps() is None
    s.save_recent_steps(3, [0.5, 0.0])
    s.save_recent_steps(4, [0.25, 1.0])
    assert s.load_recent_steps() == [0.25, 1.0]
    with pytest.raises(ValueError):
        s.save_recent_steps(5, [float("nan")])
    assert s.load_recent_steps() == [0.25, 1.0]
    s._db.execute("UPDATE recent_steps SET steps='[-1, \"x\"]'")  # not steps: ignored
    assert s.load_recent_steps() is None
    s.close()
