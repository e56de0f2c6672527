"""SQLite persistence of one unit's controller node: transitions and a checkpoint.

One file per unit (default ``ssmpc-<unit>.sqlite`` in the state directory),
WAL journal, every write in its own transaction, so a crash leaves either the
old or the new row, never half of one. Tables:

- ``transitions``: one row per transition, the latest state and its record (JSON),
  and the idempotency key of the request that made it (unique per unit, or NULL).
- ``transition_events``: every state change, appended (the complete history).
- ``checkpoint``: one row per unit: sample, process time and the node's state
  (controller checkpoint, last move, reference, active transition) as JSON.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

__all__ = ["UnitStore", "default_store_path"]

_SCHEMA = """
CREATE TABLE IF NOT EXISTS transitions (
    id TEXT PRIMARY KEY,
    unit TEXT NOT NULL,
    grade TEXT NOT NULL,
    state TEXT NOT NULL,
    created_wall REAL NOT NULL,
    updated_wall REAL NOT NULL,
    record TEXT NOT NULL,
    idempotency_key TEXT
);
CREATE TABLE IF NOT EXISTS transition_events (
    seq INTEGER PRIMARY KEY AUTOINCREMENT,
    transition_id TEXT NOT NULL REFERENCES transitions(id),
    state TEXT NOT NULL,
    process_time REAL,
    wall REAL NOT NULL,
    detail TEXT NOT NULL DEFAULT ''
);
CREATE TABLE IF NOT EXISTS checkpoint (
    unit TEXT PRIMARY KEY,
    sample INTEGER NOT NULL,
    process_time REAL NOT NULL,
    wall REAL NOT NULL,
    state TEXT NOT NULL
);
"""


def default_store_path(unit: str, state_dir: str | Path = ".") -> Path:
    return Path(state_dir) / f"ssmpc-{unit}.sqlite"


class UnitStore:
    """Transitions and checkpoint of one unit in one SQLite file (thread-safe)."""

    def __init__(self, path: str | Path, unit: str) -> None:
        self.path = Path(path)
        self.unit = unit
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self._db = sqlite3.connect(str(self.path), check_same_thread=False, isolation_level=None)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute("PRAGMA foreign_keys=ON")
        with self._lock:
            self._db.executescript(_SCHEMA)
            self._migrate()

    def _migrate(self) -> None:
        """Bring a store made by an older version up to this schema (columns added)."""
        cols = {r[1] for r in self._db.execute("PRAGMA table_info(transitions)")}
        if "idempotency_key" not in cols:
            self._db.execute("ALTER TABLE transitions ADD COLUMN idempotency_key TEXT")
        self._db.execute("CREATE UNIQUE INDEX IF NOT EXISTS transitions_idempotency"
                         " ON transitions (unit, idempotency_key)")

    def close(self) -> None:
        with self._lock:
            self._db.close()

    # -- transitions -------------------------------------------------------------
    def save_transition(self, record: dict[str, Any], *, event: str | None = None,
                        process_time: float | None = None, detail: str = "") -> None:
        """Insert or update a transition record; with ``event``, append a state change.

        Both happen in one transaction.
        """
        now = time.time()
        key = (record.get("idempotency") or {}).get("key")
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute(
                    "INSERT INTO transitions (id, unit, grade, state, created_wall, updated_wall,"
                    " record, idempotency_key) VALUES (?, ?, ?, ?, ?, ?, ?, ?)"
                    " ON CONFLICT(id) DO UPDATE SET"
                    " state=excluded.state, updated_wall=excluded.updated_wall,"
                    " record=excluded.record",
                    (record["id"], self.unit, record["grade"], record["state"], now, now,
                     json.dumps(record, allow_nan=False), key),
                )
                if event is not None:
                    self._db.execute(
                        "INSERT INTO transition_events (transition_id, state, process_time, wall,"
                        " detail) VALUES (?, ?, ?, ?, ?)",
                        (record["id"], event, process_time, now, detail),
                    )
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def transitions(self) -> list[dict[str, Any]]:
        """All transition records, oldest first."""
        with self._lock:
            rows = self._db.execute(
                "SELECT record FROM transitions WHERE unit=? ORDER BY created_wall, rowid",
                (self.unit,)).fetchall()
        return [json.loads(r[0]) for r in rows]

    def transition(self, tid: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT record FROM transitions WHERE id=? AND unit=?",
                                   (tid, self.unit)).fetchone()
        return None if row is None else json.loads(row[0])

    def transition_by_key(self, key: str) -> dict[str, Any] | None:
        """The record of the transition made by a request with idempotency ``key``."""
        with self._lock:
            row = self._db.execute(
                "SELECT record FROM transitions WHERE unit=? AND idempotency_key=?",
                (self.unit, key)).fetchone()
        return None if row is None else json.loads(row[0])

    def events(self, tid: str | None = None) -> list[dict[str, Any]]:
        """State changes (all, or of one transition), in the order they happened."""
        q = "SELECT transition_id, state, process_time, wall, detail FROM transition_events"
        args: tuple = ()
        if tid is not None:
            q += " WHERE transition_id=?"
            args = (tid,)
        with self._lock:
            rows = self._db.execute(q + " ORDER BY seq", args).fetchall()
        return [dict(zip(("transition_id", "state", "process_time", "wall", "detail"), r))
                for r in rows]

    # -- checkpoint ----------------------------------------------------------------
    @staticmethod
    def encode_checkpoint(state: dict[str, Any]) -> str:
        """The stored text of a checkpoint (JSON; NaN/inf refused with ValueError)."""
        return json.dumps(state, allow_nan=False)

    def save_checkpoint(self, sample: int, process_time: float, state: dict[str, Any] | str
                        ) -> None:
        """Replace the unit's checkpoint in one transaction; ``state`` is the dict or its
        :meth:`encode_checkpoint` text (encoded by the caller, e.g. on a thread that has
        the time)."""
        payload = state if isinstance(state, str) else self.encode_checkpoint(state)
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._db.execute(
                    "INSERT INTO checkpoint (unit, sample, process_time, wall, state)"
                    " VALUES (?, ?, ?, ?, ?) ON CONFLICT(unit) DO UPDATE SET"
                    " sample=excluded.sample, process_time=excluded.process_time,"
                    " wall=excluded.wall, state=excluded.state",
                    (self.unit, int(sample), float(process_time), time.time(), payload),
                )
                self._db.execute("COMMIT")
            except BaseException:
                self._db.execute("ROLLBACK")
                raise

    def load_checkpoint(self) -> dict[str, Any] | None:
        """``{"sample", "process_time", "wall", "state"}`` or None."""
        with self._lock:
            row = self._db.execute(
                "SELECT sample, process_time, wall, state FROM checkpoint WHERE unit=?",
                (self.unit,)).fetchone()
        if row is None:
            return None
        return {"sample": row[0], "process_time": row[1], "wall": row[2],
                "state": json.loads(row[3])}
