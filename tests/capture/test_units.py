"""Length units: names and numbers of metres per file unit, and what is refused."""

import pytest

from capture import UNITS, UnitError, resolve_unit


@pytest.mark.parametrize("unit, metres", [("cm", 0.01), ("CMU", 0.056444), (" mm ", 0.001),
                                          ("0.0254", 0.0254), (2.0, 2.0), (1e-6, 1e-6),
                                          (1e3, 1e3)])
def test_names_and_numbers_resolve_to_metres(unit, metres):
    assert resolve_unit(unit) == pytest.approx(metres)
    assert set(UNITS) >= {"m", "cm", "mm", "in", "cmu"}


@pytest.mark.parametrize("unit", ["furlong", "0", "-1", "nan", "inf", 1e300, "1e308", 1e-9])
def test_no_unit_a_body_could_be_measured_in_is_refused_by_name(unit):
    """A unit past a kilometre or under a micrometre per file unit makes no body (a 1e300 m
    skeleton overflows the retargeting's arithmetic), so it is refused where it is given."""
    with pytest.raises(UnitError, match=r"Expected a (length unit|positive, finite number)"):
        resolve_unit(unit)
