"""Typed, versioned messages exchanged over Zenoh between the nodes.

Every payload is one compact JSON object with an explicit ``schema`` version
and a ``kind``. Decoders are strict: they reject malformed JSON, NaN/inf
(including the ``NaN``/``Infinity`` literals Python's ``json`` would accept),
a wrong schema version or kind, missing or extra fields, wrong types and
vectors of the wrong length, always with a :class:`MessageError` that names
the field. A node that receives a bad message counts it and keeps going.

Messages
--------
:class:`Measurement`   plant → controller on ``ssmpc/<unit>/meas``, once per sample.
:class:`MVMessage`     controller → plant on ``ssmpc/<unit>/mv``.
:class:`Request`       query payload on ``ssmpc/<unit>/cmd/**`` (api → controller, → plant).
:class:`Reply`         the answer to a :class:`Request`: ok + data, or an error code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

__all__ = [
    "SCHEMA_VERSION",
    "MessageError",
    "Measurement",
    "MVMessage",
    "Request",
    "Reply",
    "encode",
    "decode_object",
]

#: Version of every message schema in this module; bumped on incompatible change.
#: 2: :class:`Measurement` carries the plant's ``incarnation`` (required). A node
#: refuses every message of another version (it names both), so nodes of versions
#: 1 and 2 do not talk to each other: upgrade the nodes of a unit together.
#: 3: :class:`MVMessage` may carry the plant side's ``tuning`` set (optional).
SCHEMA_VERSION = 3

#: Longest name of a tuning set an MV message may carry, characters.
TUNING_NAME_MAX = 64


class MessageError(ValueError):
    """A payload that does not decode into a valid message; the text names the field."""


def _reject_constant(name: str):
    raise MessageError(f"payload: non-finite number {name!r} is not allowed")


#: The encoder and decoder of every message, made once: ``json.dumps`` and ``json.loads``
#: with keyword arguments build a new one per call (a few us of a sample's path each);
#: these are the same settings, so the text and the checks are the same.
_ENCODER = json.JSONEncoder(separators=(",", ":"), allow_nan=False)


def encode(obj: dict) -> bytes:
    """Compact JSON, refusing NaN/inf (``allow_nan=False``)."""
    try:
        return _ENCODER.encode(obj).encode()
    except ValueError as exc:
        raise MessageError(f"payload: cannot encode ({exc})") from exc


_DECODER = json.JSONDecoder(parse_constant=_reject_constant)


def decode_object(payload: bytes | bytearray | memoryview | str, kind: str) -> dict:
    """Parse ``payload`` into a dict and check ``schema`` and ``kind``.

    Raises
    ------
    MessageError
        Not JSON, not an object, NaN/inf literals, wrong schema version or kind.
    """
    if isinstance(payload, bytes | bytearray | memoryview):
        try:
            payload = bytes(payload).decode("utf-8")
        except UnicodeDecodeError as exc:
            raise MessageError(f"payload: not UTF-8 ({exc})") from exc
    try:
        obj = _DECODER.decode(payload)
    except json.JSONDecodeError as exc:
        raise MessageError(f"payload: not JSON ({exc})") from exc
    except RecursionError as exc:
        raise MessageError("payload: nested too deeply") from exc
    except ValueError as exc:  # e.g. an integer literal longer than Python converts
        raise MessageError(f"payload: unreadable number ({exc})") from exc
    if not isinstance(obj, dict):
        raise MessageError(f"payload: expected a JSON object, got {type(obj).__name__}")
    version = obj.get("schema")
    if version != SCHEMA_VERSION:
        raise MessageError(
            f"schema: unsupported version {version!r} (this node speaks {SCHEMA_VERSION})"
        )
    if obj.get("kind") != kind:
        raise MessageError(f"kind: expected {kind!r}, got {obj.get('kind')!r}")
    return obj


def _check_fields(obj: dict, kind: str, required: set[str], optional: set[str] = frozenset()):
    keys = set(obj) - {"schema", "kind"}
    missing = required - keys
    if missing:
        raise MessageError(f"{kind}: missing field(s) {', '.join(sorted(missing))}")
    extra = keys - required - set(optional)
    if extra:
        raise MessageError(f"{kind}: unknown field(s) {', '.join(sorted(extra))}")


def _int(obj: dict, name: str, *, minimum: int | None = None) -> int:
    v = obj[name]
    if isinstance(v, bool) or not isinstance(v, int):
        raise MessageError(f"{name}: expected an integer, got {type(v).__name__}")
    if minimum is not None and v < minimum:
        raise MessageError(f"{name}: must be >= {minimum}, got {v}")
    return v


def _number(v, label: str) -> float:
    """A finite JSON number (not a bool) as float; ``label`` names the field in errors."""
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise MessageError(f"{label}: expected a number, got {type(v).__name__}")
    try:
        v = float(v)
    except OverflowError as exc:
        raise MessageError(f"{label}: number out of range") from exc
    if not math.isfinite(v):
        raise MessageError(f"{label}: non-finite value")
    return v


def _float(obj: dict, name: str) -> float:
    return _number(obj[name], name)


def _str(obj: dict, name: str) -> str:
    v = obj[name]
    if not isinstance(v, str) or not v:
        raise MessageError(f"{name}: expected a non-empty string")
    return v


def _tuning_name(v) -> str:
    """A tuning set's name: a string of 1..:data:`TUNING_NAME_MAX` characters (whether
    the plant knows it is the plant's check)."""
    if not (isinstance(v, str) and 0 < len(v) <= TUNING_NAME_MAX):
        raise MessageError(f"tuning: expected a string of 1..{TUNING_NAME_MAX} characters")
    return v


def _incarnation(v) -> str:
    """A plant incarnation: a string of 1..64 characters (the constructor's check and the
    decoder's, one rule)."""
    if not (isinstance(v, str) and 0 < len(v) <= 64):
        raise MessageError("incarnation: expected a string of 1..64 characters")
    return v


_FLOAT = {float}


def _vector(obj: dict, name: str, length: int | None) -> tuple[float, ...]:
    v = obj[name]
    if not isinstance(v, list):
        raise MessageError(f"{name}: expected a list of numbers, got {type(v).__name__}")
    if set(map(type, v)) == _FLOAT and all(map(math.isfinite, v)):
        out = tuple(v)  # the usual message: one C-level pass per check
    else:  # element by element, to name the bad one
        out = tuple(_number(x, f"{name}[{i}]") for i, x in enumerate(v))
    if length is not None and len(out) != length:
        raise MessageError(f"{name}: expected length {length}, got {len(out)}")
    return out


def _finite_tuple(values, name: str) -> tuple[float, ...]:
    if type(values) is tuple and set(map(type, values)) <= _FLOAT and all(
            map(math.isfinite, values)):
        return values  # already checked (a decoded message): no second conversion
    out = tuple(map(float, values))
    if not all(map(math.isfinite, out)):
        i = next(i for i, x in enumerate(out) if not math.isfinite(x))
        raise MessageError(f"{name}[{i}]: non-finite value")
    return out


@dataclass(frozen=True)
class Measurement:
    """One sample of the plant, published at each sample boundary.

    Attributes
    ----------
    unit : str
        Unit name (key expression segment).
    seq : int
        Sample number k >= 0, increasing by one per sample.
    t : float
        Process time at the sample, s.
    y : tuple of float, shape (ny,)
        Measured outputs in the plant's engineering units.
    u : tuple of float, shape (nu,)
        MVs applied over the interval that ended at this sample.
    mv_seq : int
        ``seq`` of the MV message those ``u`` came from (-1: initial values).
    shutdown : bool
        True once the plant has tripped (TE interlocks); outputs then freeze.
    incarnation : str
        Identity of this run of the plant node (random at its start, 1..64
        characters): a measurement of another incarnation comes from a restarted
        plant, or from someone else (the controller follows it only after the plant's
        liveliness says it restarted).
    """

    unit: str
    seq: int
    t: float
    y: tuple[float, ...]
    u: tuple[float, ...]
    mv_seq: int = -1
    shutdown: bool = False
    incarnation: str = ""

    KIND = "meas"

    def __post_init__(self) -> None:
        _incarnation(self.incarnation)
        object.__setattr__(self, "y", _finite_tuple(self.y, "y"))
        object.__setattr__(self, "u", _finite_tuple(self.u, "u"))
        if self.seq < 0:
            raise MessageError(f"seq: must be >= 0, got {self.seq}")
        if not math.isfinite(self.t):
            raise MessageError("t: non-finite value")

    def to_bytes(self) -> bytes:
        return encode({"schema": SCHEMA_VERSION, "kind": self.KIND, "unit": self.unit,
                       "seq": self.seq, "t": self.t, "y": list(self.y), "u": list(self.u),
                       "mv_seq": self.mv_seq, "shutdown": self.shutdown,
                       "incarnation": self.incarnation})

    @classmethod
    def from_bytes(cls, payload, *, unit: str | None = None, ny: int | None = None,
                   nu: int | None = None) -> Measurement:
        """Strict decode; ``unit``, ``ny`` and ``nu`` when given must match."""
        obj = decode_object(payload, cls.KIND)
        _check_fields(obj, cls.KIND, {"unit", "seq", "t", "y", "u", "incarnation"},
                      {"mv_seq", "shutdown"})
        msg_unit = _str(obj, "unit")
        if unit is not None and msg_unit != unit:
            raise MessageError(f"unit: expected {unit!r}, got {msg_unit!r}")
        shutdown = obj.get("shutdown", False)
        if not isinstance(shutdown, bool):
            raise MessageError("shutdown: expected a boolean")
        fields = (("unit", msg_unit), ("seq", _int(obj, "seq", minimum=0)),
                  ("t", _float(obj, "t")), ("y", _vector(obj, "y", ny)),
                  ("u", _vector(obj, "u", nu)),
                  ("mv_seq", _int({"mv_seq": obj.get("mv_seq", -1)}, "mv_seq", minimum=-1)),
                  ("shutdown", shutdown),
                  ("incarnation", _incarnation(_str(obj, "incarnation"))))
        # every field is checked as __post_init__ checks it (seq >= 0, t and the vectors
        # finite floats, the incarnation 1..64 characters): set without a second pass
        msg = object.__new__(cls)
        for name, value in fields:
            object.__setattr__(msg, name, value)
        return msg


@dataclass(frozen=True)
class MVMessage:
    """Manipulated variables from the controller for the interval after sample ``meas_seq``.

    Attributes
    ----------
    unit : str
        Unit name.
    seq : int
        The controller's own message counter (strictly increasing; a plant ignores
        a message whose ``seq`` is not newer than the last one it applied).
    meas_seq : int
        The measurement sample this move answers.
    u : tuple of float, shape (nu,)
        Absolute MV values in engineering units.
    sender : str
        Identity of the controller; the plant accepts MVs only from its expected sender.
    fallback : bool
        True when the move is not a fresh optimum (deadline miss, hold, solver failure).
    tuning : str, optional
        The tuning set of the plant side's loops for the interval (a name the unit's
        plant knows, 1..:data:`TUNING_NAME_MAX` characters); None: the plant's default.
        Encoded only when given.
    """

    unit: str
    seq: int
    meas_seq: int
    u: tuple[float, ...]
    sender: str
    fallback: bool = False
    tuning: str | None = None

    KIND = "mv"

    def __post_init__(self) -> None:
        object.__setattr__(self, "u", _finite_tuple(self.u, "u"))
        if self.seq < 0:
            raise MessageError(f"seq: must be >= 0, got {self.seq}")
        if self.tuning is not None:
            _tuning_name(self.tuning)

    def to_bytes(self) -> bytes:
        obj = {"schema": SCHEMA_VERSION, "kind": self.KIND, "unit": self.unit,
               "seq": self.seq, "meas_seq": self.meas_seq, "u": list(self.u),
               "sender": self.sender, "fallback": self.fallback}
        if self.tuning is not None:
            obj["tuning"] = self.tuning
        return encode(obj)

    @classmethod
    def from_bytes(cls, payload, *, unit: str | None = None, nu: int | None = None) -> MVMessage:
        obj = decode_object(payload, cls.KIND)
        _check_fields(obj, cls.KIND, {"unit", "seq", "meas_seq", "u", "sender"},
                      {"fallback", "tuning"})
        msg_unit = _str(obj, "unit")
        if unit is not None and msg_unit != unit:
            raise MessageError(f"unit: expected {unit!r}, got {msg_unit!r}")
        fallback = obj.get("fallback", False)
        if not isinstance(fallback, bool):
            raise MessageError("fallback: expected a boolean")
        tuning = _tuning_name(obj["tuning"]) if "tuning" in obj else None  # absent: default
        return cls(unit=msg_unit, seq=_int(obj, "seq", minimum=0),
                   meas_seq=_int(obj, "meas_seq", minimum=-1), u=_vector(obj, "u", nu),
                   sender=_str(obj, "sender"), fallback=fallback,
                   tuning=tuning)


@dataclass(frozen=True)
class Request:
    """A query to a node: ``action`` (e.g. ``status``, ``create``) and JSON ``args``."""

    action: str
    args: dict[str, Any] = field(default_factory=dict)

    KIND = "request"

    def to_bytes(self) -> bytes:
        return encode({"schema": SCHEMA_VERSION, "kind": self.KIND, "action": self.action,
                       "args": self.args})

    @classmethod
    def from_bytes(cls, payload) -> Request:
        obj = decode_object(payload, cls.KIND)
        _check_fields(obj, cls.KIND, {"action"}, {"args"})
        args = obj.get("args", {})
        if not isinstance(args, dict):
            raise MessageError("args: expected a JSON object")
        return cls(action=_str(obj, "action"), args=args)


@dataclass(frozen=True)
class Reply:
    """Answer to a :class:`Request`.

    ``code`` follows HTTP meaning so the api node can pass it on: 200/202 ok,
    400 bad request, 404 unknown, 409 conflict, 422 invalid, 500 internal.
    """

    code: int
    data: Any = None
    error: str = ""

    KIND = "reply"

    @property
    def ok(self) -> bool:
        return 200 <= self.code < 300

    def to_bytes(self) -> bytes:
        return encode({"schema": SCHEMA_VERSION, "kind": self.KIND, "code": self.code,
                       "data": self.data, "error": self.error})

    @classmethod
    def from_bytes(cls, payload) -> Reply:
        obj = decode_object(payload, cls.KIND)
        _check_fields(obj, cls.KIND, {"code"}, {"data", "error"})
        error = obj.get("error", "")
        if not isinstance(error, str):
            raise MessageError("error: expected a string")
        return cls(code=_int(obj, "code", minimum=100), data=obj.get("data"), error=error)
