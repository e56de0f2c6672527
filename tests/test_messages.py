"""Strict, versioned message codecs: round trips and every kind of bad payload."""

import json
import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from services.io.messages import (
    SCHEMA_VERSION,
    Measurement,
    MessageError,
    MVMessage,
    Reply,
    Request,
)

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


def _meas_obj(**over):
    obj = {"schema": SCHEMA_VERSION, "kind": "meas", "unit": "cstr", "seq": 3, "t": 0.3,
           "y": [1.3], "u": [0.4], "mv_seq": 2, "shutdown": False, "incarnation": "run-a"}
    obj.update(over)
    return obj


@given(seq=st.integers(0, 2**53), t=finite, y=st.lists(finite, min_size=1, max_size=41),
       u=st.lists(finite, min_size=1, max_size=12))
def test_measurement_round_trip_is_exact(seq, t, y, u):
    msg = Measurement(unit="te", seq=seq, t=t, y=tuple(y), u=tuple(u), mv_seq=-1,
                      incarnation="run-a")
    back = Measurement.from_bytes(msg.to_bytes(), unit="te", ny=len(y), nu=len(u))
    assert back == msg


def test_mv_round_trip():
    msg = MVMessage(unit="cstr", seq=7, meas_seq=6, u=(0.41,), sender="cstr-controller",
                    fallback=True)
    assert MVMessage.from_bytes(msg.to_bytes(), unit="cstr", nu=1) == msg


@pytest.mark.parametrize("text", ['{"y": NaN}', '{"y": Infinity}', '{"y": -Infinity}'])
def test_nan_and_inf_literals_are_rejected(text):
    obj = _meas_obj()
    payload = json.dumps(obj).replace('"y": [1.3]', text[1:-1])
    with pytest.raises(MessageError, match="non-finite"):
        Measurement.from_bytes(payload.encode())


def test_nan_cannot_be_encoded():
    with pytest.raises(MessageError, match="y"):
        Measurement(unit="cstr", seq=0, t=0.0, y=(math.nan,), u=(0.4,), incarnation="r")


@pytest.mark.parametrize("over, field", [
    ({"schema": 1}, "schema"),  # the version before the plant incarnation
    ({"schema": 2}, "schema"),  # the version before the tuning set
    ({"schema": 4}, "schema"),
    ({"schema": "3"}, "schema"),
    ({"incarnation": ""}, "incarnation"),
    ({"incarnation": 7}, "incarnation"),
    ({"incarnation": "x" * 65}, "incarnation"),
    ({"kind": "mv"}, "kind"),
    ({"seq": -1}, "seq"),
    ({"seq": 1.5}, "seq"),
    ({"seq": True}, "seq"),
    ({"t": "0"}, "t"),
    ({"y": [1.3, 2.0]}, "y"),
    ({"y": ["1.3"]}, "y"),
    ({"y": 1.3}, "y"),
    ({"u": [True]}, "u"),
    ({"unit": "te"}, "unit"),
    ({"shutdown": 0}, "shutdown"),
    ({"extra": 1}, "extra"),
])
def test_measurement_decoder_names_the_bad_field(over, field):
    payload = json.dumps(_meas_obj(**over)).encode()
    with pytest.raises(MessageError, match=field):
        Measurement.from_bytes(payload, unit="cstr", ny=1, nu=1)


def test_missing_field_is_named():
    obj = _meas_obj()
    del obj["t"]
    with pytest.raises(MessageError, match="missing.*t"):
        Measurement.from_bytes(json.dumps(obj).encode())


@pytest.mark.parametrize("payload", [b"", b"not json", b"[1, 2]", b"\xff\xfe", b"null"])
def test_garbage_is_a_message_error(payload):
    with pytest.raises(MessageError):
        Measurement.from_bytes(payload)


def test_mv_carries_the_tuning_set_only_when_one_is_selected():
    plain = MVMessage(unit="te", seq=1, meas_seq=0, u=(0.4,), sender="c")
    assert "tuning" not in json.loads(plain.to_bytes())  # the plant's default
    assert MVMessage.from_bytes(plain.to_bytes()).tuning is None
    steady = MVMessage(unit="te", seq=2, meas_seq=1, u=(0.4,), sender="c", tuning="steady")
    assert json.loads(steady.to_bytes())["tuning"] == "steady"
    assert MVMessage.from_bytes(steady.to_bytes()) == steady
    for bad in ("", "x" * 65, 3, None, ["steady"]):
        obj = {**json.loads(steady.to_bytes()), "tuning": bad}
        with pytest.raises(MessageError, match="tuning"):
            MVMessage.from_bytes(json.dumps(obj).encode())
    with pytest.raises(MessageError, match="tuning"):
        MVMessage(unit="te", seq=3, meas_seq=2, u=(0.4,), sender="c", tuning="x" * 65)
    # a node of the previous schema version is refused by name, not half-understood
    obj = {**json.loads(steady.to_bytes()), "schema": 2}
    with pytest.raises(MessageError, match="schema"):
        MVMessage.from_bytes(json.dumps(obj).encode())


def test_mv_wrong_length_and_sender_type():
    good = MVMessage(unit="cstr", seq=1, meas_seq=0, u=(0.4,), sender="c").to_bytes()
    with pytest.raises(MessageError, match="u: expected length 2"):
        MVMessage.from_bytes(good, nu=2)
    obj = json.loads(good)
    obj["sender"] = ""
    with pytest.raises(MessageError, match="sender"):
        MVMessage.from_bytes(json.dumps(obj).encode())


def test_request_and_reply():
    req = Request("transition", {"op": "create", "grade": "OPII"})
    assert Request.from_bytes(req.to_bytes()) == req
    rep = Reply(404, error="unit: unknown")
    back = Reply.from_bytes(rep.to_bytes())
    assert back == rep and not back.ok
    assert Reply(202, {"id": "x"}).ok
    with pytest.raises(MessageError, match="args"):
        Request.from_bytes(json.dumps({"schema": SCHEMA_VERSION, "kind": "request", "action": "x",
                                       "args": [1]}).encode())


@pytest.mark.parametrize("payload", [
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":1' + b"0" * 400 + b',"y":[1],"u":[3]}',
    b'{"schema":2,"kind":"meas","unit":"te","seq":1,"t":1,"y":[1' + b"0" * 400 + b'],"u":[3]}',
    b'{"schema":2,"kind":"meas","unit":"te","seq":1' + b"0" * 5000 + b',"t":1,"y":[1],"u":[3]}',
    b"[" * 100_000 + b"]" * 100_000,
    b'{"schema":2,"kind":"meas","data":' + b"[" * 100_000 + b"]" * 100_000 + b"}",
], ids=["huge-int-t", "huge-int-y", "int-too-long", "deep-list", "deep-field"])
def test_hard_payloads_are_message_errors(payload):
    with pytest.raises(MessageError):
        Measurement.from_bytes(payload)


def test_decoded_measurement_equals_the_constructed_one_and_is_checked_alike():
    """A decoded measurement is set field by field without the constructor's second pass:
    it equals the message built the usual way, and what the constructor refuses the
    decoder refuses too."""
    m = Measurement(unit="te", seq=12, t=432.0, y=(1.5, -2.25e-7, 3e300), u=(0.1, 7.0),
                    mv_seq=-1, shutdown=True, incarnation="x" * 64)
    back = Measurement.from_bytes(m.to_bytes(), unit="te", ny=3, nu=2)
    assert back == m and type(back.y) is tuple and type(back.t) is float
    assert back.to_bytes() == m.to_bytes()
    for bad in ({"seq": -1}, {"t": 1e400}, {"y": [1.0, None]}, {"incarnation": "y" * 65}):
        obj = json.loads(m.to_bytes()) | bad
        with pytest.raises(MessageError):
            Measurement.from_bytes(json.dumps(obj).encode())


def test_mv_bytes_of_a_numpy_move_are_those_of_its_floats():
    """The controller node hands the move as Python floats (``ndarray.tolist``): the same
    numbers and bytes as from the array's own scalars."""
    import numpy as np

    u = np.array([0.1, 1 / 3, 12345.678901234567, -0.0, 5e-324])
    a = MVMessage(unit="te", seq=5, meas_seq=4, u=tuple(u), sender="c").to_bytes()
    b = MVMessage(unit="te", seq=5, meas_seq=4, u=tuple(u.tolist()), sender="c").to_bytes()
    assert a == b
