"""The TE guards' shared settings checks (controller.units.te.settings_check)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from controller.units.te.settings_check import check_range


@dataclass
class _S:
    a: float = 0.0
    b: float = 1.0


@pytest.mark.parametrize("interval, a, ok", [
    ("[0, 1]", 0.0, True), ("[0, 1]", 1.0, True), ("[0, 1]", 1.0001, False),
    ("(0, 1]", 0.0, False), ("(0, 1]", 1.0, True), ("[0, 1)", 1.0, False),
    ("(2000, 3000)", 2000.0, False), ("(2000, 3000)", 2999.9, True),
    ("> 0", 0.0, False), (">= 0", 0.0, True), ("< 5", 5.0, False), ("<= 100", 100.0, True),
    ("> -1.5e3", -1499.0, True), ("> -1.5e3", -1500.0, False),
])
def test_a_value_is_checked_against_the_range_it_names(interval, a, ok):
    s = _S(a=a)
    if ok:
        check_range(s, "a", interval)
    else:
        with pytest.raises(ValueError, match=r"^a: must be "):
            check_range(s, "a", interval)


def test_the_message_names_the_first_field_out_of_range_with_unit_label_and_note():
    with pytest.raises(ValueError) as exc:
        check_range(_S(a=2.0, b=-3.0), ("a", "b"), ">= 0", "h", "guard ", note="why")
    assert str(exc.value) == "guard b: must be >= 0 h (why), got -3.0"
    with pytest.raises(ValueError) as exc:
        check_range(_S(a=150.0), "a", "[0, 100]", "%")
    assert str(exc.value) == "a: must be in [0, 100] %, got 150.0"


@pytest.mark.parametrize("bad", ["0..1", "[0 1]", "=> 0", "(a, b)", ""])
def test_a_malformed_range_is_a_programming_error_named(bad):
    with pytest.raises(ValueError, match="not an interval"):
        check_range(_S(), "a", bad)
