"""The support vocabulary: body regions, the coarse parts as their unions, the uses' defaults."""

import pytest

from posedb.regions import (BODY_REGIONS, DEFAULT_SUPPORT, SUPPORT_GROUPS, SUPPORT_NAMES,
                            SUPPORT_USES, SupportNameError, support_regions)


def test_the_vocabulary_is_consistent():
    assert len(set(SUPPORT_NAMES)) == len(SUPPORT_NAMES)  # no name means two things
    for regions in list(SUPPORT_GROUPS.values()) + list(SUPPORT_USES.values()):
        assert set(regions) <= set(BODY_REGIONS)
    # the groups split the regions they cover without overlap
    grouped = [r for regions in SUPPORT_GROUPS.values() for r in regions]
    assert len(grouped) == len(set(grouped))
    assert DEFAULT_SUPPORT in SUPPORT_USES


@pytest.mark.parametrize("names, regions", [
    ("seat", ("pelvis", "thighs")),
    (" Seat ", ("pelvis", "thighs")),
    (["torso"], ("upper_back", "lower_back", "pelvis")),
    (("legs", "arms"), ("thighs", "calves", "upper_arms", "forearms")),
    ("chair", ("upper_back", "lower_back", "pelvis", "thighs")),
    (["lounger", "calves"], ("head", "upper_back", "lower_back", "pelvis", "thighs", "calves")),
    (["hands", "head", "hands"], ("head", "hands")),
    ("bed", ("head", "upper_back", "lower_back", "pelvis", "thighs", "calves", "feet",
             "upper_arms")),
])
def test_names_expand_to_regions_in_order(names, regions):
    assert support_regions(names) == regions


def test_a_chair_is_a_seat_with_a_back_and_a_bed_carries_all_but_forearms_and_hands():
    seat, chair = set(support_regions("seat")), set(support_regions("chair"))
    assert seat < chair and chair - seat == {"upper_back", "lower_back"}
    assert "calves" not in support_regions("lounger")
    assert set(BODY_REGIONS) - set(support_regions("bed")) == {"forearms", "hands"}


@pytest.mark.parametrize("names, message", [
    (["tail"], r"Expected body regions \(head, upper_back, .*\), parts \(torso, arms, legs\) "
               r"or uses \(seat, .*\), got 'tail'"),
    ("shoulders", "got 'shoulders'"),
    ([], "at least one body region"),
    ("", "got ''"),
    ([3], "got 3"),
    ([{}], r"got \{\}"),
    ([["seat"]], r"got \['seat'\]"),
    (None, "Expected a body region, a use or a list of regions, got None"),
])
def test_unknown_names_are_refused_by_name(names, message):
    with pytest.raises(SupportNameError, match=message):
        support_regions(names)
    assert issubclass(SupportNameError, ValueError)
