"""controller.packing: exact compact arrays in checkpoints."""

import json

import numpy as np
import pytest

from controller.adaptation import NLSSettings, NormalizedLeastSquares
from controller.packing import SPLICE_MIN_CHARS, dumps, pack_array, unpack_array


def test_round_trip_is_bit_exact_through_json():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((213, 37)) * 10.0 ** rng.integers(-300, 300, (213, 37))
    a[0, 0], a[1, 1] = 0.0, -0.0
    b = unpack_array(json.loads(json.dumps(pack_array(a))))
    assert b.shape == a.shape
    assert np.array_equal(a.view(np.uint64), b.view(np.uint64))  # every bit, signed zeros too


def test_empty_and_list_forms():
    assert unpack_array(pack_array(np.zeros((5, 0)))).shape == (5, 0)
    np.testing.assert_array_equal(unpack_array([[1.0, 2.0], [3.0, 4.0]]),
                                  [[1.0, 2.0], [3.0, 4.0]])  # an older checkpoint


@pytest.mark.parametrize("bad", [
    {"dtype": "<f4", "shape": [1], "b64": "AAAAAA=="},
    {"dtype": "<f8", "shape": [2], "b64": "AAAAAAAAAAA="},  # 8 bytes for 2 values
    {"dtype": "<f8", "shape": [1], "b64": "not base64!"},
    {"dtype": "<f8", "b64": "AAAAAAAAAAA="},
])
def test_malformed_packed_arrays_are_refused(bad):
    with pytest.raises(ValueError, match="packed array"):
        unpack_array(bad)


def test_te_size_estimator_checkpoint_is_packed_and_exact():
    rng = np.random.default_rng(0)
    n = 213
    est = NormalizedLeastSquares(NLSSettings(), np.zeros(n), 0.01)
    for _ in range(7):  # implicit covariance c I - V V' with 35 columns
        est.update(rng.standard_normal((5, n)), rng.standard_normal(5))
    state = est.checkpoint()
    assert isinstance(state["V"], dict) and "b64" in state["V"]
    twin = NormalizedLeastSquares(NLSSettings(), np.zeros(n), 0.01)
    twin.restore(json.loads(json.dumps(state)))
    np.testing.assert_array_equal(twin.P, est.P)
    W, y = rng.standard_normal((5, n)), rng.standard_normal(5)
    est.update(W, y)
    twin.update(W, y)
    np.testing.assert_array_equal(twin.p, est.p)


def test_dumps_is_the_text_of_json_dumps():
    rng = np.random.default_rng(5)
    big = pack_array(rng.standard_normal(400))
    assert len(big["b64"]) >= SPLICE_MIN_CHARS
    state = {"a": big, "small": pack_array([1.0]), "rings": [{"i": 0, "s": big}, 3.5],
             "quote \"\\ \u00e9\x00": ["x\x00y", {"k": (1, big)}], 2: None, "t": (big, 1),
             "nums": [1.0, 2.5e-300], "e": {}, "l": []}
    assert dumps(state) == json.dumps(state, allow_nan=False)
    assert unpack_array(json.loads(dumps(state))["rings"][0]["s"]).shape == (400,)
    assert dumps({"x": 1}) == json.dumps({"x": 1})
    with pytest.raises(ValueError):
        dumps({"a": big, "x": [float("nan")]})
    with pytest.raises(TypeError):
        dumps({"a": big, "x": object()})
