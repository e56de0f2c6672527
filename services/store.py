"""SQLite persistence of one unit's controller node: transitions and a checkpoint.

One file per unit (default ``ssmpc-<unit>.sqlite`` in the state directory),
WAL journal, every write in its own transaction, so a crash leaves either the
old or the new row, never half of one. Tables:

- ``transitions``: one row per transition, the latest state and its record (JSON),
  and the idempotency key of the request that made it (unique per unit, or NULL).
- ``transition_events``: every state change, appended (the complete history).
- ``events``: the unit's event log (:mod:`services.events`): transition state changes,
  operator actions with their identity, alarms raised and cleared; one row per stable
  event id (a replayed event is ignored), time in whole µs of the wall clock (UTC).
- ``checkpoint``: one row per unit: sample, process time and the node's state
  (controller checkpoint, last move, reference, active transition) as JSON.
- ``recent_steps``: one row per unit: the largest single-sample step of each MV over
  the node's latest moves (the ramp-in of a restarted node, ``services.nodes.ramp_in``),
  written more often than the checkpoint because it costs next to nothing.

Integrity. Opening a store runs ``PRAGMA quick_check`` and checks what this
module wrote (every record decodes, names its id and a known state; every event
belongs to a transition; every logged event's detail decodes into an object); a file
that is not an SQLite database, a corrupt page or an inconsistent row is a
:class:`StoreError` (the CLI says ``error: ...`` and exits 2; nothing is changed),
and so is a store that can be read but not written (the WAL's shared-memory index
``-shm`` or the file read-only, a full disk): the write lock is taken once at open.
A write either commits or raises (a busy lock is waited for at most
``busy_timeout_s``): the caller acknowledges only what committed. A checkpoint is
checked at both ends: NaN, infinities (``1e999``) or a non-object are refused
when encoded (ValueError) and when loaded (StoreError).
"""

from __future__ import annotations

import contextlib
import json
import math
import sqlite3
import threading
import time
from pathlib import Path
from typing import Any

from controller.packing import dumps
from services.events import ALARM_CLEARED, ALARM_RAISED, Event, fold_alarms

__all__ = ["StoreError", "UnitStore", "default_store_path"]

_STATES = ("pending", "running", "settled", "aborted", "failed")


class StoreError(ValueError):
    """A store that cannot be used as it is (corrupt, inconsistent, undecodable)."""


def _refuse_constant(name: str):
    raise ValueError(f"non-finite number {name}")


def _finite_float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"number {text} out of range")
    return v


def _decode(text: str):
    """JSON as this module writes it: NaN, infinities and 1e999 refused (ValueError)."""
    return json.loads(text, parse_constant=_refuse_constant, parse_float=_finite_float)

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
CREATE TABLE IF NOT EXISTS recent_steps (
    unit TEXT PRIMARY KEY,
    sample INTEGER NOT NULL,
    wall REAL NOT NULL,
    steps TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS events (
    id TEXT PRIMARY KEY,
    unit TEXT NOT NULL,
    time_us INTEGER NOT NULL,
    process_time REAL,
    kind TEXT NOT NULL,
    detail TEXT NOT NULL,
    identity TEXT NOT NULL
);
CREATE INDEX IF NOT EXISTS events_time ON events (unit, time_us);
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
    """Transitions and checkpoint of one unit in one SQLite file (thread-safe).

    Parameters
    ----------
    path : str or Path
    unit : str
    busy_timeout_s : float
        Longest wait for another connection's write lock before a write fails, s.

    Raises
    ------
    StoreError
        The file is not a usable store (see the module notes).
    """

    def __init__(self, path: str | Path, unit: str, *, busy_timeout_s: float = 1.0) -> None:
        self.path = Path(path)
        self.unit = unit
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        self.busy_timeout_s = float(busy_timeout_s)
        try:
            self._db = sqlite3.connect(str(self.path), check_same_thread=False,
                                       isolation_level=None, timeout=float(busy_timeout_s))
        except sqlite3.Error as exc:
            raise StoreError(f"store: cannot open {self.path}: {exc}") from None
        try:
            self._check_integrity()
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=NORMAL")
            self._db.execute("PRAGMA foreign_keys=ON")
            with self._lock:
                self._db.executescript(_SCHEMA)
                self._migrate()
            self._check_rows()
            self._check_writable()
        except sqlite3.Error as exc:
            self._db.close()
            raise StoreError(f"store: {self.path} is not a usable store: {exc}") from None
        except StoreError:
            self._db.close()
            raise

    def __enter__(self) -> UnitStore:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    @contextlib.contextmanager
    def waiting_at_most(self, seconds: float):
        """Within the block, a write waits at most ``seconds`` (>= 0) for another
        connection's lock instead of ``busy_timeout_s``: a write a request is answered on
        keeps to the request's time budget."""
        ms = max(0, int(float(seconds) * 1000.0))
        with self._lock:
            self._db.execute(f"PRAGMA busy_timeout = {ms}")
        try:
            yield
        finally:
            with self._lock:
                self._db.execute(f"PRAGMA busy_timeout = {int(self.busy_timeout_s * 1000.0)}")

    def _check_integrity(self) -> None:
        """``PRAGMA quick_check``: StoreError naming the first problems unless ``ok``."""
        try:
            rows = [r[0] for r in self._db.execute("PRAGMA quick_check(5)")]
        except sqlite3.DatabaseError as exc:  # "file is not a database", a bad header
            raise StoreError(f"store: {self.path} is corrupt or not a store ({exc}); "
                             "move it aside to start afresh") from None
        if rows != ["ok"]:
            raise StoreError(f"store: {self.path} is corrupt (quick_check: "
                             f"{'; '.join(map(str, rows))}); move it aside to start afresh")

    def _check_rows(self) -> None:
        """Every record decodes and names its id and a known state; every event belongs
        to a transition (what this module wrote, read back)."""
        for tid, state, text in self._db.execute(
                "SELECT id, state, record FROM transitions WHERE unit=?", (self.unit,)):
            try:
                rec = _decode(text)
            except ValueError as exc:
                raise StoreError(f"store: {self.path}: transition {tid!r} does not decode "
                                 f"({exc})") from None
            if not isinstance(rec, dict) or rec.get("id") != tid or state not in _STATES \
                    or rec.get("state") != state:
                raise StoreError(f"store: {self.path}: transition {tid!r} is inconsistent "
                                 "(record, id and state disagree)")
        orphan = self._db.execute(
            "SELECT COUNT(*) FROM transition_events e LEFT JOIN transitions t"
            " ON t.id = e.transition_id WHERE t.id IS NULL").fetchone()[0]
        if orphan:
            raise StoreError(f"store: {self.path}: {orphan} events of unknown transitions")
        for eid, text in self._db.execute("SELECT id, detail FROM events WHERE unit=?",
                                          (self.unit,)):
            try:
                ok = isinstance(_decode(text), dict)
            except ValueError:
                ok = False
            if not ok:
                raise StoreError(f"store: {self.path}: event {eid!r} does not decode into "
                                 "an object")

    def _check_writable(self) -> None:
        """Take the write lock once and let it go: a store that could be read but not
        written (the file, its ``-wal`` or its ``-shm`` shared-memory index read-only, a
        full disk) is a StoreError now, not a degraded store after the first sample.
        Another process holding the lock is not an error here (the writes wait for it)."""
        try:
            self._db.execute("BEGIN IMMEDIATE")
            self._db.execute("ROLLBACK")
        except sqlite3.OperationalError as exc:
            if getattr(exc, "sqlite_errorname", "") in ("SQLITE_BUSY", "SQLITE_LOCKED"):
                return
            raise StoreError(f"store: {self.path} cannot be written ({exc}): the file, its "
                             "-wal or its -shm (shared-memory index) is read-only, or the "
                             "disk is full; fix that or move the store aside") from None

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
                        process_time: float | None = None, detail: str = "",
                        events: tuple[Event, ...] | list[Event] = ()) -> None:
        """Insert or update a transition record; with ``event``, append a state change;
        ``events`` go to the event log (an id already there is left as it is).

        All happen in one transaction.
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
                self._insert_events(events)
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:  # SQLite may have rolled back already
                    self._db.execute("ROLLBACK")
                raise

    def transitions(self) -> list[dict[str, Any]]:
        """All transition records, oldest first."""
        with self._lock:
            rows = self._db.execute(
                "SELECT record FROM transitions WHERE unit=? ORDER BY created_wall, rowid",
                (self.unit,)).fetchall()
        return [_decode(r[0]) for r in rows]

    def transition(self, tid: str) -> dict[str, Any] | None:
        with self._lock:
            row = self._db.execute("SELECT record FROM transitions WHERE id=? AND unit=?",
                                   (tid, self.unit)).fetchone()
        return None if row is None else _decode(row[0])

    def transition_by_key(self, key: str) -> dict[str, Any] | None:
        """The record of the transition made by a request with idempotency ``key``."""
        with self._lock:
            row = self._db.execute(
                "SELECT record FROM transitions WHERE unit=? AND idempotency_key=?",
                (self.unit, key)).fetchone()
        return None if row is None else _decode(row[0])

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

    # -- the event log ---------------------------------------------------------------
    def _insert_events(self, events) -> None:
        """Insert ``events`` (inside the caller's transaction); known ids are ignored."""
        if events:
            self._db.executemany(
                "INSERT OR IGNORE INTO events (id, unit, time_us, process_time, kind, detail,"
                " identity) VALUES (?, ?, ?, ?, ?, ?, ?)",
                [(e.id, self.unit, e.time_us, e.process_time_s, e.kind,
                  json.dumps(e.detail, allow_nan=False), e.identity) for e in events])

    def add_events(self, events: tuple[Event, ...] | list[Event]) -> None:
        """Commit ``events`` to the event log in one transaction (known ids ignored)."""
        if not events:
            return
        with self._lock:
            self._db.execute("BEGIN IMMEDIATE")
            try:
                self._insert_events(events)
                self._db.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    def unit_events(self, since_us: int | None = None, limit: int | None = None
                    ) -> list[Event]:
        """Events at or after ``since_us`` (µs since the epoch; None: all), oldest first
        (ties in the order they were written), at most ``limit``."""
        q = ("SELECT id, time_us, process_time, kind, detail, identity FROM events"
             " WHERE unit=?")
        args: list = [self.unit]
        if since_us is not None:
            q += " AND time_us >= ?"
            args.append(int(since_us))
        q += " ORDER BY time_us, rowid"
        if limit is not None:
            q += " LIMIT ?"
            args.append(int(limit))
        with self._lock:
            rows = self._db.execute(q, args).fetchall()
        return [Event(id=r[0], time_us=r[1], process_time_s=r[2], kind=r[3],
                      detail=_decode(r[4]), identity=r[5]) for r in rows]

    def active_alarms(self) -> dict[str, str]:
        """Alarms raised and not cleared in the event log (key to text)."""
        with self._lock:
            rows = self._db.execute(
                "SELECT kind, detail FROM events WHERE unit=? AND kind IN (?, ?)"
                " ORDER BY time_us, rowid", (self.unit, ALARM_RAISED, ALARM_CLEARED)).fetchall()
        return fold_alarms((k, _decode(d)) for k, d in rows)

    # -- checkpoint ----------------------------------------------------------------
    @staticmethod
    def encode_checkpoint(state: dict[str, Any]) -> str:
        """The stored text of a checkpoint (JSON; NaN/inf refused with ValueError): that
        of ``json.dumps(state, allow_nan=False)``, the packed arrays' base64 put in
        without the encoder's scan (:func:`controller.packing.dumps`)."""
        return dumps(state)

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
                if self._db.in_transaction:  # SQLite may have rolled back already
                    self._db.execute("ROLLBACK")
                raise

    def save_recent_steps(self, sample: int, steps) -> None:
        """Replace the unit's recent MV steps (a list of finite numbers >= 0)."""
        text = json.dumps([float(v) for v in steps], allow_nan=False)
        with self._lock:
            self._db.execute(
                "INSERT INTO recent_steps (unit, sample, wall, steps) VALUES (?, ?, ?, ?)"
                " ON CONFLICT(unit) DO UPDATE SET sample=excluded.sample,"
                " wall=excluded.wall, steps=excluded.steps",
                (self.unit, int(sample), time.time(), text))

    def load_recent_steps(self) -> list[float] | None:
        """The unit's recent MV steps, or None (none stored, or not a list of finite
        numbers >= 0: the ramp-in then uses the checkpoint's)."""
        with self._lock:
            row = self._db.execute("SELECT steps FROM recent_steps WHERE unit=?",
                                   (self.unit,)).fetchone()
        if row is None:
            return None
        try:
            steps = _decode(row[0])
        except ValueError:
            return None
        if not (isinstance(steps, list) and steps
                and all(isinstance(v, int | float) and not isinstance(v, bool) and v >= 0
                        for v in steps)):
            return None
        return [float(v) for v in steps]

    def load_checkpoint(self) -> dict[str, Any] | None:
        """``{"sample", "process_time", "wall", "state"}`` or None.

        Raises
        ------
        StoreError
            The checkpoint does not decode into an object of finite numbers.
        """
        with self._lock:
            row = self._db.execute(
                "SELECT sample, process_time, wall, state FROM checkpoint WHERE unit=?",
                (self.unit,)).fetchone()
        if row is None:
            return None
        try:
            state = _decode(row[3])
        except ValueError as exc:
            raise StoreError(f"store: {self.path}: the checkpoint of unit {self.unit!r} "
                             f"cannot be decoded ({exc}); move the store aside to start "
                             "afresh") from None
        if not isinstance(state, dict) or not isinstance(row[1], float | int) \
                or not math.isfinite(row[1]):
            raise StoreError(f"store: {self.path}: the checkpoint of unit {self.unit!r} is "
                             "not a checkpoint; move the store aside to start afresh")
        return {"sample": row[0], "process_time": row[1], "wall": row[2], "state": state}
