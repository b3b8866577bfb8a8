"""Numbers typed on the page are parsed as typed (app/tab/fields.py): never mangled, never clamped."""

from __future__ import annotations

import pytest
from rangereg.app.tab.fields import Range, parse_number, parse_setting, parse_vector, show_number
from rangereg.core.errors import InputError


@pytest.mark.parametrize("text, value", [("2.5e-3", 2.5e-3), ("1e-3", 1e-3), (" -4 ", -4.0), (".5", 0.5),
                                         ("3.", 3.0), ("+7E2", 700.0)])
def test_numbers_are_read_as_typed(text, value):
    assert parse_number(text, "x") == value


@pytest.mark.parametrize("text", ["12,5", "1,5e-3"])
def test_a_decimal_comma_is_refused_with_the_fix(text):
    with pytest.raises(InputError, match="comma.*point"):
        parse_number(text, "tx")


@pytest.mark.parametrize("text", ["", "abc", "inf", "-inf", "nan", "1e400", "0x10", "1 2", "--1", "1e"])
def test_non_numbers_and_non_finite_values_are_refused(text):
    with pytest.raises(InputError, match="tx"):
        parse_number(text, "tx")


def test_a_value_out_of_range_is_refused_not_clamped():
    steps = Range(2, 201, integer=True)
    assert parse_number("201", "steps", steps) == 201
    for text in ("202", "1", "1000000", "3.5"):
        with pytest.raises(InputError, match="steps must be a whole number from 2 to 201"):
            parse_number(text, "steps", steps)


def test_a_huge_seed_is_refused_not_rewritten():
    for text in ("1e30", str(2**40)):
        with pytest.raises(InputError, match="^Seed: "):
            parse_setting(text, "seed", "Seed")
    assert parse_setting("12", "seed", "Seed") == 12


def test_open_ranges():
    ratio = Range(0, 1, lo_open=True, hi_open=True)
    assert parse_number("1e-9", "ratio", ratio) == 1e-9
    for text in ("0", "1", "1.5"):
        with pytest.raises(InputError, match="above 0 and below 1"):
            parse_number(text, "ratio", ratio)


def test_a_setting_is_checked_against_the_one_table_and_named_as_on_the_page():
    assert parse_setting("auto", "t_start", "Start temperature", auto=True) is None
    assert parse_setting(" ", "t_start", "Start temperature", auto=True) is None
    assert parse_setting("2.5e-3", "t_start", "Start temperature", auto=True) == 2.5e-3
    with pytest.raises(InputError, match="^Start temperature: expected a finite number.*or 'auto'"):
        parse_setting("inf", "t_start", "Start temperature", auto=True)
    with pytest.raises(InputError, match="^Seed: expected a whole number"):
        parse_setting("auto", "seed", "Seed")
    with pytest.raises(InputError, match="^Cooling: '0,5' has a comma"):
        parse_setting("0,5", "cooling", "Cooling", auto=True)


def test_vectors():
    assert parse_vector("1 2.5e-3 -3", "viewpoint") == (1.0, 2.5e-3, -3.0)
    assert parse_vector("1, 2, 3", "viewpoint") == (1.0, 2.0, 3.0)
    with pytest.raises(InputError, match="3 numbers"):
        parse_vector("1 2", "viewpoint")


def test_a_shown_number_reads_back_the_same():
    for v in (0.1, -123.456789012, 1e-7, 0.0):
        assert abs(parse_number(show_number(v), "x") - v) <= 1e-10 * max(1, abs(v))
