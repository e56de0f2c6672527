"""The TE guards' shared settings checks (controller.units.te.settings_check)."""

from __future__ import annotations

from dataclasses import dataclass

import pytest

from controller.units.te.settings_check import check_finite_fields, check_range


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


def test_an_optional_setting_may_be_off_but_not_malformed():
    off = _S(a=None)
    check_finite_fields(off, optional=("a",))  # None: the setting is off
    check_range(off, ("a", "b"), "(0, 2)")  # passes its range; b is still checked
    with pytest.raises(ValueError, match=r"^b: must be in \(0, 2\)"):
        check_range(_S(a=None, b=3.0), ("a", "b"), "(0, 2)")
    with pytest.raises(ValueError, match=r"^a: must be a finite number, got None"):
        check_finite_fields(off)  # not optional: None is refused
    for bad in (float("nan"), float("inf"), True, "1"):
        with pytest.raises(ValueError, match=r"^a: must be a finite number or None, got "):
            check_finite_fields(_S(a=bad), optional=("a",))


def test_the_transition_guards_check_their_optional_limits_the_same_way():
    from controller.units.te.control import TransitionGuards

    off = TransitionGuards(a_rise_hold_kpa=None, purge_floor_fraction=None,
                           purge_track_lift_kpa=None)
    assert off.a_rise_hold_kpa is None
    with pytest.raises(ValueError, match=r"^a_rise_hold_kpa: must be in \(2000, 3000\) kPa"):
        TransitionGuards(a_rise_hold_kpa=3000.0)
    with pytest.raises(ValueError, match=r"^purge_floor_fraction: must be a finite number "
                                         r"or None, got nan"):
        TransitionGuards(purge_floor_fraction=float("nan"))


def test_a_named_option_must_be_one_of_its_choices_and_a_flag_a_bool():
    @dataclass
    class S:
        gain: float = 1.0
        kind: str = "equation"
        on: bool = True

    opts = {"kind": ("equation", "steady_output")}
    check_finite_fields(S(), flags=("on",), choices=opts)
    with pytest.raises(ValueError, match="kind: must be one of 'equation', 'steady_output'"):
        check_finite_fields(S(kind="other"), flags=("on",), choices=opts)
    with pytest.raises(ValueError, match="on: must be true or false"):
        check_finite_fields(S(on=1), flags=("on",), choices=opts)
    with pytest.raises(ValueError, match="kind: must be a finite number"):
        check_finite_fields(S(), flags=("on",))  # a text field without its choices
