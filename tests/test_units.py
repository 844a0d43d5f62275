"""Tests of warpe_cl.units: parsing and formatting quantities with units."""
import math

import pytest

from warpe_cl.units import UnitError, format_quantity, parse_quantity, unit_list


@pytest.mark.parametrize("text, dimension, expected", [
    ("100 mm", "length", 0.1),
    ("200 um", "length", 2e-4),
    ("200 µm", "length", 2e-4),
    ("200 μm", "length", 2e-4),          # Greek mu, as some keyboards type it
    ("200 micron", "length", 2e-4),
    ("1064 nm", "length", 1.064e-6),
    ("500 km", "length", 5e5),
    ("500km", "length", 5e5),            # no space
    ("  3 cm ", "length", 0.03),
    ("1 m", "length", 1.0),
    ("-1 mm", "length", -1e-3),          # sign kept; ranges are the caller's business
    ("12.5 ns", "time", 12.5),
    ("1e-6 ns", "time", 1e-6),
    ("1E5 ns", "time", 1e5),
    ("2 us", "time", 2000.0),
    ("2 µs", "time", 2000.0),
    ("3 ms", "time", 3e6),
    ("1 s", "time", 1e9),
    ("500 ps", "time", 0.5),
    (".5 ns", "time", 0.5),
    ("12 deg", "angle", 12.0),
    ("0.25°", "angle", 0.25),
    ("1 degree", "angle", 1.0),
    ("2 degrees", "angle", 2.0),
])
def test_parse(text, dimension, expected):
    assert parse_quantity(text, dimension) == pytest.approx(expected, rel=1e-15)


@pytest.mark.parametrize("text, expected_deg", [
    ("1 rad", 180 / math.pi),
    ("5 mrad", 5e-3 * 180 / math.pi),
    ("30 urad", 30e-6 * 180 / math.pi),
    ("30 µrad", 30e-6 * 180 / math.pi),
])
def test_parse_radians(text, expected_deg):
    assert parse_quantity(text, "angle") == pytest.approx(expected_deg, rel=1e-14)


def test_powers_of_ten_are_exact():
    # Division by an exact power of ten: "100 um" is the float 1e-4, not 1.0000000000000002e-4.
    assert parse_quantity("100 um", "length") == 1e-4
    assert parse_quantity("1064 nm", "length") == 1064e-9
    assert parse_quantity("0.1 m", "length") == 0.1


@pytest.mark.parametrize("value", [100, 12.5, "100", " 7 ", "1e-6"])
def test_bare_number_is_refused(value):
    with pytest.raises(UnitError) as info:
        parse_quantity(value, "length")
    message = str(info.value)
    assert "no unit" in message
    assert "a length" in message
    assert "mm" in message and "km" in message        # the allowed units are listed
    assert "\n" not in message


def test_bare_number_message_names_dimension_and_units():
    with pytest.raises(UnitError, match=r"a time with a unit \(s, ms, us, µs, ns, ps\)"):
        parse_quantity(3, "time")
    with pytest.raises(UnitError, match="an angle with a unit"):
        parse_quantity("3", "angle")


@pytest.mark.parametrize("text, dimension, other", [
    ("12 deg", "length", "an angle"),
    ("5 mm", "time", "a length"),
    ("3 ns", "angle", "a time"),
    ("1 rad", "length", "an angle"),
])
def test_wrong_dimension(text, dimension, other):
    with pytest.raises(UnitError) as info:
        parse_quantity(text, dimension)
    assert other in str(info.value)
    assert info.value.dimension == dimension


def test_unknown_unit_with_hint():
    with pytest.raises(UnitError, match='unknown unit "MM" \\(did you mean mm\\?\\)'):
        parse_quantity("100 MM", "length")
    with pytest.raises(UnitError, match='unknown unit "furlong"'):
        parse_quantity("3 furlong", "length")


@pytest.mark.parametrize("value", ["mm", "abc", "", "1e999 m", "nan m", True, None, [1], {"a": 1}])
def test_not_a_quantity(value):
    with pytest.raises(UnitError):
        parse_quantity(value, "length")


def test_unit_error_is_value_error():
    assert issubclass(UnitError, ValueError)


def test_unknown_dimension_is_programming_error():
    with pytest.raises(ValueError, match="unknown dimension"):
        parse_quantity("1 m", "mass")


def test_unit_list():
    assert unit_list("length") == "m, cm, mm, um, µm, micron, nm, km"


@pytest.mark.parametrize("value, dimension, expected", [
    (0.1, "length", "100 mm"),
    (1e-4, "length", "100 um"),
    (1.064e-6, "length", "1064 nm"),
    (1.0, "length", "1 m"),
    (5e5, "length", "500 km"),
    (2.5e-3, "length", "2.5 mm"),
    (0.0, "length", "0 m"),
    (1e7, "length", "1e+07 m"),
    (3.0, "angle", "3 deg"),
    (0.25, "angle", "0.25 deg"),
    (1e5, "time", "1e+05 ns"),
    (1e-6, "time", "1e-06 ns"),
    (12.5, "time", "12.5 ns"),
    (0.0, "time", "0 ns"),
])
def test_format(value, dimension, expected):
    assert format_quantity(value, dimension) == expected


@pytest.mark.parametrize("dimension", ["length", "time", "angle"])
@pytest.mark.parametrize("value", [1e-12, 3.3e-9, 1e-6, 0.1234567891234, 1 / 3, 2.0 / 7e3,
                                   0.30000000000000004, 1.0, 42.0, 1e3, 99999.0, 1e5, 12345678.9,
                                   -0.002, 100000.00000000001])
def test_format_round_trip_exact(value, dimension):
    assert parse_quantity(format_quantity(value, dimension), dimension) == value


def test_format_refuses_non_finite():
    with pytest.raises(ValueError):
        format_quantity(float("inf"), "length")
