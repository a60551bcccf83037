"""`Design.fit` warm and cancelled: the studio's refit after a person moves."""

import pytest

from studio.design import Design

HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


@pytest.fixture(scope="module")
def design():
    d = Design(None)
    d.new_grid((0.5, 0.6), (8, 6), 0.42)
    d.add_person(HIGH_SIT, position=[0.0, 0.0, -0.1], support=["seat"])
    d.fit()
    return d


def test_a_warm_fit_starts_from_the_last_result_and_settles(design):
    first = design.last.result
    design.update_person(0, position=[0.0, 0.0, -0.08])  # 2 cm forward
    warm = design.fit(warm=True)
    assert warm.result.stop_reason.startswith("settled"), warm.result.stop_reason
    assert warm.result.iterations < first.iterations
    assert warm.persons[0]["coverage"] >= 0.9


def test_a_warm_fit_of_another_control_mesh_is_a_cold_one(design):
    design.new_grid((0.5, 0.6), (6, 6), 0.42)
    outcome = design.fit(warm=True)
    assert not outcome.result.stop_reason.startswith("settled"), outcome.result.stop_reason
    assert len(outcome.result.control) == 7 * 7


def test_a_cancelled_fit_keeps_the_last_outcome(design):
    last = design.last
    calls = []

    def cancel() -> bool:  # the edit comes after the fit has started
        calls.append(1)
        return len(calls) > 1

    assert design.fit(warm=True, cancel=cancel) is None
    assert design.last is last and len(calls) > 1
