"""The api node's view of the mesh: Zenoh queries to controllers, liveliness of nodes.

The api node holds no plant state. Every read or write is a Zenoh query to
``ssmpc/<unit>/cmd/<action>`` with a timeout, turned into :class:`MeshError`:

- no controller liveliness token for the unit → 503 (controller gone or never there);
- no node of the unit at all → 404 (unknown unit);
- a live controller that does not answer within the timeout → 504.

Liveliness is followed with a subscriber (``history=True``), so listing units
costs no network round trip.
"""

from __future__ import annotations

import threading

from services.io import keys
from services.io.messages import MessageError, Reply, Request

__all__ = ["Mesh", "MeshError"]


class MeshError(Exception):
    """A query that could not be answered: ``status`` is the HTTP code to return."""

    def __init__(self, status: int, detail: str) -> None:
        super().__init__(detail)
        self.status = status
        self.detail = detail


class Mesh:
    """Queries and liveliness over one Zenoh session.

    Parameters
    ----------
    session : zenoh.Session
    timeout_s : float
        Longest wait for a controller's answer.
    """

    def __init__(self, session, timeout_s: float = 2.0) -> None:
        self.session = session
        self.timeout_s = float(timeout_s)
        self._lock = threading.Lock()
        self._alive: set[tuple[str, str]] = set()
        self._sub = session.liveliness().declare_subscriber(
            keys.alive_all(), self._on_liveliness, history=True)

    def _on_liveliness(self, sample) -> None:
        parsed = keys.parse_alive(str(sample.key_expr))
        if parsed is None:
            return
        import zenoh

        with self._lock:
            if sample.kind == zenoh.SampleKind.PUT:
                self._alive.add(parsed)
            else:
                self._alive.discard(parsed)

    def units(self) -> dict[str, dict[str, bool]]:
        """``{unit: {"plant": bool, "controller": bool}}`` for every unit seen alive."""
        with self._lock:
            alive = set(self._alive)
        out: dict[str, dict[str, bool]] = {}
        for unit, role in sorted(alive):
            out.setdefault(unit, {r: False for r in keys.ROLES})[role] = True
        return out

    def alive(self, unit: str, role: str) -> bool:
        with self._lock:
            return (unit, role) in self._alive

    def request(self, unit: str, action: str, args: dict | None = None,
                timeout_s: float | None = None) -> Reply:
        """Send a :class:`Request` to the unit's controller and return its :class:`Reply`."""
        try:
            keys.check_unit_name(unit)
        except ValueError as exc:
            raise MeshError(404, str(exc)) from exc
        if not self.alive(unit, "controller"):
            if self.alive(unit, "plant"):
                raise MeshError(503, f"unit {unit!r}: controller not reachable "
                                     "(liveliness lost)")
            raise MeshError(404, f"unit: unknown unit {unit!r}")
        timeout = self.timeout_s if timeout_s is None else timeout_s
        replies = self.session.get(keys.cmd(unit, action),
                                   payload=Request(action, args or {}).to_bytes(),
                                   timeout=timeout)
        for reply in replies:
            if reply.ok is None:
                continue
            try:
                return Reply.from_bytes(reply.ok.payload.to_bytes())
            except MessageError as exc:
                raise MeshError(502, f"controller sent a malformed reply: {exc}") from exc
        if not self.alive(unit, "controller"):
            raise MeshError(503, f"unit {unit!r}: controller went away")
        raise MeshError(504, f"unit {unit!r}: controller did not answer within {timeout:g} s")

    def request_plant(self, unit: str, action: str, args: dict | None = None,
                      timeout_s: float | None = None) -> Reply:
        """A :class:`Request` to the unit's plant node (``ssmpc/<unit>/plant/cmd/<action>``)."""
        try:
            keys.check_unit_name(unit)
        except ValueError as exc:
            raise MeshError(404, str(exc)) from exc
        if not self.alive(unit, "plant"):
            if self.alive(unit, "controller"):
                raise MeshError(503, f"unit {unit!r}: plant not reachable (liveliness lost)")
            raise MeshError(404, f"unit: unknown unit {unit!r}")
        timeout = self.timeout_s if timeout_s is None else timeout_s
        for reply in self.session.get(keys.plant_cmd(unit, action),
                                      payload=Request(action, args or {}).to_bytes(),
                                      timeout=timeout):
            if reply.ok is None:
                continue
            try:
                return Reply.from_bytes(reply.ok.payload.to_bytes())
            except MessageError as exc:
                raise MeshError(502, f"plant sent a malformed reply: {exc}") from exc
        raise MeshError(504, f"unit {unit!r}: plant did not answer within {timeout:g} s")

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:
            pass
