"""`Design.fit` warm and cancelled: the studio's refit after a person moves."""

import numpy as np
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


def _seated() -> Design:
    """single_seated's start (0.5 x 0.6 m at 0.42 m) with one seated person, not fitted."""
    d = Design(None)
    d.new_grid((0.5, 0.6), (8, 6), 0.42)
    d.add_person(HIGH_SIT, position=[0.0, 0.0, -0.1], support=["seat"])
    return d


def test_every_accepted_iterate_reaches_iterates_with_the_fits_own_faces():
    d = _seated()
    seen = []
    outcome = d.fit(iterates=seen.append)
    r = outcome.result
    assert [it.iteration for it in seen] == list(range(1, len(seen) + 1))
    assert len(seen) == len(r.energies) + sum(len(p["energies"])
                                              for p in r.energy_terms["repairs"])
    for it in seen:
        assert it.control.shape == d.vertices.shape and it.surface.shape == r.surface.shape
        np.testing.assert_array_equal(it.faces, d.faces)
        np.testing.assert_array_equal(it.surface_faces, r.surface_faces)
    if "crossed itself" not in r.stop_reason:  # the result is the last iterate
        np.testing.assert_array_equal(seen[-1].control, r.control)
        np.testing.assert_allclose(seen[-1].surface, r.surface)
    # the outcome keeps the limit surface (what is exported) on the same quads
    np.testing.assert_allclose(outcome.limit, r.limit_surface())
    assert 1e-5 < np.abs(outcome.limit - r.surface).max() < 0.02


def _counting(monkeypatch):
    """Counts the evaluations and records each fit's warm start (studio.design's names)."""
    import studio.design as design_module

    calls = {"evaluations": 0, "warm": []}
    fit_people, evaluate_fit = design_module.fit_people, design_module.evaluate_fit

    def fit(*args, **kwargs):
        calls["warm"].append(kwargs.get("warm"))
        return fit_people(*args, **kwargs)

    def evaluate(*args, **kwargs):
        calls["evaluations"] += 1
        return evaluate_fit(*args, **kwargs)

    monkeypatch.setattr(design_module, "fit_people", fit)
    monkeypatch.setattr(design_module, "evaluate_fit", evaluate)
    return calls


def test_a_cancelled_fit_is_not_evaluated_and_the_next_warm_fit_goes_on_from_it(monkeypatch):
    d = _seated()
    calls = _counting(monkeypatch)
    seen = []
    # a newer edit after the first accepted iterate
    assert d.fit(warm=True, iterates=seen.append, cancel=lambda: bool(seen)) is None
    assert calls == {"evaluations": 0, "warm": [None]}  # cold (nothing fitted yet)
    assert d.last is None and d.resume is not None
    np.testing.assert_array_equal(d.resume.control, seen[-1].control)
    resumed = d.resume
    d.update_person(0, position=[0.0, 0.0, -0.09])  # the drag goes on
    outcome = d.fit(warm=True)
    assert calls["warm"][-1] is resumed  # warm, from the cancelled fit's iterate
    assert calls["evaluations"] == 1 and d.resume is None and d.last is outcome
    assert outcome.persons[0]["coverage"] >= 0.9


def test_no_fit_goes_on_from_another_mesh_a_removed_person_or_an_undone_state():
    d = _seated()
    seen = []
    d.fit(iterates=seen.append, cancel=lambda: bool(seen))
    assert d.resume is not None
    d.set_fixed(0, True)
    d.undo()
    assert d.resume is None  # the undone state goes on from its own fit (none here)
    # an edit that drops the fits while a fit runs: that fit is not kept to go on from
    seen.clear()

    def remove_then_cancel() -> bool:
        if seen:
            d.add_person(HIGH_SIT, position=[0.0, 0.0, -0.1])
            d.remove_person(1)
            return True
        return False

    assert d.fit(iterates=seen.append, cancel=remove_then_cancel) is None
    assert seen and d.resume is None
    seen.clear()
    d.fit(iterates=seen.append, cancel=lambda: bool(seen))
    assert d.resume is not None
    d.new_grid((0.5, 0.6), (8, 6), 0.42)  # the same quads, a fresh start
    assert d.resume is None and d._warm_start() is None


def test_a_person_moved_is_placed_as_posing_it_there_would(monkeypatch):
    """`Design.place` moves a person posed before at another position only (no posing); the
    result is what `place_person` makes at the new position."""
    import studio.design as design_module
    from solver.scene.placement import place_person

    d = _seated()
    table = d.people[0]
    before = d.place(table)
    moved = dict(table, position=[0.07, 0.02, -0.13])
    fresh = place_person(d._parse(d._data(people=[moved])).persons[0])
    with monkeypatch.context() as patch:
        patch.setattr(design_module, "place_person", None)  # posing again would fail
        placed = d.place(moved)
    assert placed is not before and placed.spec == fresh.spec
    np.testing.assert_allclose(placed.vertices, fresh.vertices, rtol=0, atol=1e-12)
    np.testing.assert_allclose(placed.transform, fresh.transform, rtol=0, atol=1e-12)
    for name in ("normals", "importance", "areas"):
        np.testing.assert_allclose(getattr(placed, name), getattr(fresh, name), rtol=0,
                                   atol=1e-12, err_msg=name)
    np.testing.assert_array_equal(placed.supported, fresh.supported)
    assert placed.label == fresh.label and placed.mass_kg == fresh.mass_kg
    # turned, the person is posed again
    turned = dict(moved, rotation_deg=[0.0, 30.0, 0.0])
    assert not np.allclose(d.place(turned).normals, placed.normals)
