"""Property-based fuzzing of every message decoder: whatever arrives on the wire, a decoder
returns a valid message or raises :class:`MessageError` naming the problem — nothing else.

The strategies build payloads at three depths: arbitrary bytes, arbitrary JSON values,
and well-formed envelopes (right schema and kind) whose fields are replaced by arbitrary
JSON values, which is where type confusion would slip through.
"""

import json
import math

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from services.io.messages import (
    SCHEMA_VERSION,
    Measurement,
    MessageError,
    MVMessage,
    Reply,
    Request,
    decode_object,
)

FUZZ = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.too_slow])

# JSON values: numbers include huge integers and floats beyond double range (1e999
# parses to inf), strings include unicode; nested up to a few levels.
scalars = (st.none() | st.booleans() | st.integers() | st.integers(min_value=10**300)
           | st.floats(allow_nan=False) | st.text(max_size=20))
json_values = st.recursive(scalars, lambda kids: st.lists(kids, max_size=5)
                           | st.dictionaries(st.text(max_size=8), kids, max_size=5),
                           max_leaves=20)

DECODERS = {
    "meas": lambda p: Measurement.from_bytes(p, unit="te", ny=2, nu=1),
    "meas-any": Measurement.from_bytes,
    "mv": lambda p: MVMessage.from_bytes(p, unit="te", nu=1),
    "mv-any": MVMessage.from_bytes,
    "request": Request.from_bytes,
    "reply": Reply.from_bytes,
}
KIND = {"meas": "meas", "meas-any": "meas", "mv": "mv", "mv-any": "mv", "request": "request",
        "reply": "reply"}
FIELDS = {
    "meas": ("unit", "seq", "t", "y", "u", "mv_seq", "shutdown", "incarnation"),
    "mv": ("unit", "seq", "meas_seq", "u", "sender", "fallback"),
    "request": ("action", "args"),
    "reply": ("code", "data", "error"),
}
VALID = {
    "meas": {"unit": "te", "seq": 1, "t": 36.0, "y": [1.0, 2.0], "u": [3.0], "mv_seq": 0,
             "shutdown": False, "incarnation": "run-a"},
    "mv": {"unit": "te", "seq": 1, "meas_seq": 0, "u": [1.0], "sender": "te-controller",
           "fallback": False},
    "request": {"action": "status", "args": {}},
    "reply": {"code": 200, "data": None, "error": ""},
}


def _decode_or_message_error(name, payload):
    try:
        msg = DECODERS[name](payload)
    except MessageError as exc:
        assert str(exc), "a MessageError must say what is wrong"
        return None
    # a message that decodes is valid: finite numbers, right kind
    for attr in ("t",):
        if hasattr(msg, attr):
            assert math.isfinite(getattr(msg, attr))
    for attr in ("y", "u"):
        if hasattr(msg, attr):
            assert all(math.isfinite(v) for v in getattr(msg, attr))
    return msg


@pytest.mark.parametrize("name", sorted(DECODERS))
@FUZZ
@given(payload=st.binary(max_size=300))
def test_arbitrary_bytes(name, payload):
    _decode_or_message_error(name, payload)


@pytest.mark.parametrize("name", sorted(DECODERS))
@FUZZ
@given(value=json_values)
def test_arbitrary_json(name, value):
    _decode_or_message_error(name, json.dumps(value).encode())


@pytest.mark.parametrize("name", sorted(DECODERS))
@FUZZ
@given(data=st.data())
@example(data=None)
def test_well_formed_envelope_with_fuzzed_fields(name, data):
    kind = KIND[name]
    obj = {"schema": SCHEMA_VERSION, "kind": kind, **VALID[kind]}
    if data is not None:
        for f in data.draw(st.sets(st.sampled_from(FIELDS[kind]), max_size=3)):
            if data.draw(st.booleans()):
                obj[f] = data.draw(json_values)
            else:
                obj.pop(f)
        if data.draw(st.booleans()):
            obj[data.draw(st.text(min_size=1, max_size=6))] = data.draw(json_values)
    _decode_or_message_error(name, json.dumps(obj).encode())


@pytest.mark.parametrize("name", sorted(DECODERS))
@pytest.mark.parametrize("payload", [
    # an integer beyond double range where a float is expected
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":1' + b"0" * 400 + b',"y":[1,2],"u":[3]}',
    b'{"schema":2,"kind":"mv","unit":"te","seq":1,"meas_seq":0,"u":[1' + b"0" * 400
    + b'],"sender":"x"}',
    # nesting deeper than the JSON parser's recursion limit
    b"[" * 100_000 + b"]" * 100_000,
    b'{"schema":2,"kind":"reply","code":200,"data":' + b"[" * 100_000 + b"]" * 100_000 + b"}",
    # NaN/Infinity literals and an overflowing exponent
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":NaN,"y":[1,2],"u":[3]}',
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":1e999,"y":[1,2],"u":[3]}',
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":1,"y":[1,-Infinity],"u":[3]}',
], ids=["huge-int-t", "huge-int-u", "deep-list", "deep-reply-data", "nan-literal",
        "exponent-overflow", "infinity-literal"])
def test_known_hard_payloads_are_message_errors(name, payload):
    with pytest.raises(MessageError):
        DECODERS[name](payload)


@FUZZ
@given(value=json_values, kind=st.sampled_from(["meas", "mv", "request", "reply"]))
def test_decode_object_only_raises_message_error(value, kind):
    try:
        obj = decode_object(json.dumps(value), kind)
    except MessageError:
        return
    assert obj["kind"] == kind and obj["schema"] == SCHEMA_VERSION
