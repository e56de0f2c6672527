"""all_finite answers as np.isfinite(a).all() does, on every array the sample can
hand it, compiled or not."""

import hypothesis.extra.numpy as hnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from controller.finite_kernel import all_finite


@given(hnp.arrays(np.float64, hnp.array_shapes(min_dims=1, max_dims=3, max_side=12),
                  elements=st.floats(allow_nan=True, allow_infinity=True)))
def test_agrees_with_numpy_on_float_arrays(a):
    assert all_finite(a) is bool(np.isfinite(a).all())


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", [0, 3, 207])
def test_one_non_finite_entry_anywhere_is_found(bad, where):
    p = np.linspace(-1e300, 1e300, 208)  # huge but finite: no overflow in the check
    assert all_finite(p) is True
    p[where] = bad
    assert all_finite(p) is False


@pytest.mark.parametrize("a", [
    np.array([1.0, np.nan, 3.0, 4.0])[::2],        # a strided view: [1, 3]
    np.asfortranarray(np.array([[1.0, 2.0], [np.inf, 4.0]])),
    np.broadcast_to(np.array([1.0, np.nan]), (10, 2)),
    np.array([1, 2, 3]),                            # integers
    np.array([1.0, np.nan], dtype=np.float32),
    np.zeros(0),
])
def test_other_layouts_and_dtypes_answer_as_numpy(a):
    assert all_finite(a) is bool(np.isfinite(a).all())
