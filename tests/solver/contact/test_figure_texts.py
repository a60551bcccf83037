"""The one-line texts the commands and the studio print for a person's peak and flat seat."""

import re

from solver.contact.evaluate import flat_text, peak_text


def test_a_body_that_does_not_rest_says_so_and_shows_no_peak():
    unsettled = {"peak_pressure_kpa": None, "supported": False,
                 "equilibrium": {"stable": False, "reason": "no rest within 40 steps"}}
    assert peak_text(unsettled) == "no rest: no rest within 40 steps"
    # figures that say only that the body does not rest (no equilibrium kept)
    assert peak_text({"peak_pressure_kpa": None, "supported": False}) == \
        "no rest: does not come to rest"


def test_a_peak_is_zero_only_for_a_body_at_rest_on_something_else():
    assert peak_text({"peak_pressure_kpa": None, "supported": True,
                      "equilibrium": {"stable": True}}) == "0 kPa (rests elsewhere)"
    assert peak_text({"peak_pressure_kpa": None}) == "not measured"
    assert peak_text({"peak_pressure_kpa": 7.94, "supported": True}) == "7.9 kPa"


def test_the_flat_seat_text_names_the_seat_peak_its_ratio_is_of():
    """The person's peak may lie on a back; the ratio is the surface's peak on the regions the
    flat seat carries over the flat seat's, and the text gives both numbers it divides and
    names those regions."""
    person = {"peak_pressure_kpa": 8.0, "peak_of_flat": 5.69 / 9.51,
              "flat": {"same_load": {"peak_pressure_kpa": 9.51, "fitted_peak_kpa": 5.69,
                                     "regions": ["pelvis", "thighs"]}}}
    text = flat_text(person)
    assert text == ("9.5 kPa at the same load; the surface's 5.7 kPa on the pelvis and thighs "
                    "is 0.60 of it")
    flat, seat, ratio = (float(x) for x in re.findall(r"\d+\.\d+", text))
    assert abs(seat / flat - ratio) < 0.01
    # no same-load figure: the flat seat's own settle
    assert flat_text({"flat": {"peak_pressure_kpa": None, "supported": False}}) == \
        "no rest: does not come to rest"
