"""The Design view judges the surface of every finished fit by the guarantees the export's
report.json holds (no self-crossing, no fold, no slit, above the floor, no cut past the margin
on a dense sampling), once the fit has settled, and shows the verdict beside each person's
misses in the report's words; and a scenario opened in it shows its start (a template's kind,
a grid's size, faces and height) in the panel."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from solver.scene.quality import surface_misses
from solver.scene.run import fit_guarantees
from studio.design import TEMPLATES
from tests.studio.conftest import wait_until

SCENARIOS = Path(__file__).resolve().parents[2] / "fixtures" / "scenarios"
HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
MEETS = "The surface meets its guarantees"
PENDING = "checked once the fit settles"


def _open(view, name: str) -> None:
    """Opens fixtures/scenarios/`name` as the Open scenario (TOML) upload does."""
    data = (SCENARIOS / name).read_bytes()
    view.design.open_scenario(data, name)
    view.selection = []
    view.redraw()
    view._edited()


def _sunk_corner(view) -> None:
    """A 4 x 4 seat with a fixed corner 20 cm under the floor: the fit keeps it there."""
    view.grid_size.value, view.grid_res.value, view.grid_height.value = (0.5, 0.6), (4, 4), 0.42
    view._guarded(view._new_grid)
    view.add_person(HIGH_SIT, position=[0.0, 0.02, -0.1], support="seat")
    view.design.move_vertex(0, [-0.25, -0.2, -0.3])
    view.design.set_fixed(0, True)


def test_the_fit_button_shows_the_surface_misses_in_the_words_of_the_report(design_view):
    """A surface dipping under the floor: after Fit, the view lists its floor miss (the words
    `surface_misses` gives report.json) above the person's misses, as the export's check of
    the same fit finds it; an edit dropping the fit drops the verdict, and an undo brings it
    back at once (the check is kept with the fit)."""
    view = design_view
    _sunk_corner(view)
    view._guarded(view.run_fit)
    assert "**Fitted**" in view.status_text, view.status_text
    wait_until(lambda: any("under the floor" in w for w in view.warning_lines), 30,
               f"the floor miss shown (the view shows {view.warning_lines})")
    last = view.design.last
    expected = surface_misses(fit_guarantees(last.result, last.people,
                                             view.design.scenario().surface.params))
    assert any("under the floor" in m for m in expected), expected
    assert view.warning_lines[:len(expected)] == expected, view.warning_lines
    assert "misses" in view.warnings.content and "of its guarantees" in view.warnings.content
    assert all(m in view.warnings.content for m in expected)
    view._guarded(view._new_grid)  # (a new control mesh: no fit on screen)
    assert not view.design.surface_warnings() and "guarantees" not in view.warnings.content
    view._guarded(view._undo)
    assert view.design.last is last and view.warning_lines[:len(expected)] == expected


def test_a_refit_is_judged_once_it_settles_and_an_opened_scenario_drops_the_verdict(
        design_view):
    """A refit (the worker's, no source) is drawn before it is judged, which says so; once it
    has settled its surface is judged (one seated person on the flat 8 x 6 start: it meets
    every guarantee); opening another scenario leaves no verdict of a surface not on screen."""
    view = design_view
    _open(view, "single_seated.toml")
    assert view.session.fit()  # as the refit worker runs it
    assert view.design.last.guarantees is None and PENDING in view.warnings.content
    assert view.session.judge.wait(60)
    assert view.design.last.guarantees is not None and view.design.last.judge_seconds > 0
    assert view.design.last.guarantees["ok"], view.design.last.guarantees
    assert MEETS in view.warnings.content and PENDING not in view.warnings.content
    assert view.design.surface_warnings() == []
    _open(view, "template_stool.toml")
    assert view.design.last is None and "guarantees" not in view.warnings.content


def test_a_judged_fit_is_not_judged_again_and_a_newer_fit_outdates_a_request(design_view,
                                                                              monkeypatch):
    """The check runs once per fit (kept with it); a request for a fit no longer on screen
    judges nothing."""
    import studio.design

    view = design_view
    _open(view, "single_seated.toml")
    view._guarded(view.run_fit)
    assert view.session.judge.wait(60)
    first = view.design.last
    checked, again = first.guarantees, []
    real = studio.design.fit_guarantees
    monkeypatch.setattr(studio.design, "fit_guarantees",
                        lambda *a, **k: again.append(a) or real(*a, **k))
    view.session.judge.request(first, 0.0)  # (the fit on screen, judged already)
    assert view.session.judge.wait(60) and first.guarantees is checked and not again
    view.design.update_person(0, position=[0.01, 0.0, 0.0])
    view._guarded(view._new_grid)  # (the fit requested below is no longer on screen)
    assert view.design.last is None
    stale = dataclasses.replace(first, guarantees=None, judge_seconds=None)  # (not judged)
    calls = []
    view.design.judge = lambda *args, **kwargs: calls.append(args)  # (would judge it)
    view.session.judge.request(stale, 0.0)
    assert view.session.judge.wait(60)
    assert not calls and stale.guarantees is None


def test_every_template_name_is_found_from_its_scenario_table():
    from studio.design import template_name

    for name, (kind, given, _) in TEMPLATES.items():
        assert template_name({"kind": kind, **given}) == name
    assert template_name({"kind": "bench", "back": True}) == "bench with back"
    assert template_name({"kind": "floor_cushion", "depth": 0.5}) == "floor cushion"


def test_an_opened_template_scenario_shows_its_template_and_a_grid_its_grid(design_view):
    """Open scenario (TOML) shows the start in the panel: the Template list the opened
    template's kind (a bench with a back as such), the grid inputs an opened grid; an undo
    shows the start it goes back to."""
    view = design_view
    assert view.template.value == "chair"
    _open(view, "template_stool.toml")
    assert view.template.value == "stool"
    _open(view, "template_bench.toml")
    assert view.template.value == "bench with back"
    _open(view, "single_seated.toml")
    assert view.grid_size.value == (0.5, 0.6) and view.grid_res.value == (8, 6)
    assert view.grid_height.value == 0.42
    view._guarded(view._undo)
    assert view.template.value == "bench with back"
    view._guarded(view._undo)
    assert view.template.value == "stool"


def test_a_refit_is_not_judged_while_another_fit_runs(design_view):
    """While a fit runs (a drag's refits, one after another), the refit before it waits to be
    judged: the check (0.1 s to seconds) never holds up the surface streamed while dragging."""
    import time

    view = design_view
    _open(view, "single_seated.toml")
    session = view.session
    with session.fit_lock:  # as a fit running on
        session.judge.request(_fitted(view), 0.0)
        time.sleep(0.5)
        assert view.design.last.guarantees is None and session.judge.pending
    assert session.judge.wait(60) and view.design.last.guarantees is not None
    assert MEETS in view.warnings.content


def _fitted(view):
    """The view's session fitted (as the Fit button fits, its check not asked for)."""
    return view.design.fit(warm=True)


def test_an_export_of_a_judged_fit_writes_its_verdict_without_checking_again(tmp_path,
                                                                             monkeypatch):
    """The export of the fit on screen, once judged, writes the judged guarantees into its
    report rather than checking them again (as long again as a warm refit)."""
    import json

    import solver.scene.run as run
    from studio.design import Design

    design = Design()
    design.open_scenario((SCENARIOS / "single_seated.toml").read_text(), "single_seated.toml")
    assert design.fit() is not None
    judged = design.judge()

    def again(*args, **kwargs):
        raise AssertionError("the export checked the judged fit again")

    monkeypatch.setattr(run, "fit_guarantees", again)
    design.export(tmp_path / "export", formats=("obj",))
    report = json.loads((tmp_path / "export" / "report.json").read_text())
    assert report["guarantees"] == json.loads(json.dumps(judged))
    assert report["timing"]["guarantees_s"] == design.last.judge_seconds


def test_relief_does_not_check_again_the_guarantees_of_a_judged_fit(monkeypatch):
    """Relief compares each relieved fit's surface bars with the first fit's: a first fit the
    studio judged already is not checked again (0.1-1.3 s)."""
    import solver.scene.run as run
    from studio.design import Design

    design = Design()
    design.open_scenario((SCENARIOS / "single_seated.toml").read_text(), "single_seated.toml")
    first = design.fit()
    design.judge()
    checked = []
    real = run.fit_guarantees
    monkeypatch.setattr(run, "fit_guarantees",
                        lambda fit, *a, **k: checked.append(fit) or real(fit, *a, **k))
    design.relieve(rounds=2)
    assert checked, "relief checked no fit (nothing to compare with)"
    assert all(fit is not first.result for fit in checked)
