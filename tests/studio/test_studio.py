"""`sitrelax studio`: the design session, and the studio's server (the browser drives it in
test_studio_browser.py)."""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from posedb import PoseLibrary
from studio.design import Design, DesignError

from tests.conftest import listening_addresses

HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"


def test_a_design_fits_relaxes_and_saves_what_reads_back(library, tmp_path):
    d = Design(library)
    assert len(d.vertices) == 9 * 7  # the scenario schema's 8 x 6 start
    d.new_grid((0.5, 0.6), (8, 6), 0.42)  # single_seated's start: the schema's is coarser
    d.add_person("db:perch", position=[0.0, 0.0, -0.1], support=["seat"])
    outcome = d.fit()
    assert outcome.persons[0]["coverage"] >= 0.9
    assert len(outcome.result.surface) == 65 * 49  # an 8 x 6 grid at level 3
    relaxed = d.relax(0)
    assert relaxed.vertices.shape == (13380, 3)
    path = d.save_toml(tmp_path / "design.toml")
    again = tomllib.loads(path.read_text())
    assert again == d.scenario_data()
    d.save_to_library("first")
    stored = {s["name"]: s for s in PoseLibrary(library).scenarios()}["first"]
    assert stored["scenario"] == d.scenario_data()
    assert stored["result"]["persons"][0]["coverage"] == outcome.persons[0]["coverage"]


def test_relief_after_the_fit_on_screen_lowers_the_seat_s_peak_and_saves_its_rounds(library,
                                                                                     tmp_path):
    """The studio's relief is `sitrelax fit`'s (single_seated's start and person): its rounds
    lower the seat's peak against the flat seat's, the relieved fit is the one on screen, and
    the scenario saved of it asks for the rounds; an edit since the fit is refused first."""
    d = Design(library)
    d.new_grid((0.5, 0.6), (8, 6), 0.42)
    d.add_person("db:perch", position=[0.0, 0.0, 0.0], support=["seat"])  # (as single_seated)
    with pytest.raises(DesignError, match="Fit first"):
        d.relieve()
    plain = d.fit()
    record = d.relieve(rounds=2)
    assert record["kept"] >= 1, record
    assert d.last is not plain and d.fitted
    assert d.last.persons[0]["peak_of_flat"] < plain.persons[0]["peak_of_flat"] - 0.02
    assert d.last.relief == {"rounds": 2, "target": 0.5}
    saved = tomllib.loads(d.save_toml(tmp_path / "relieved.toml").read_text())
    assert saved["relief"] == {"rounds": 2, "target": 0.5}
    with pytest.raises(DesignError, match="relieved already"):  # (the file gives it again)
        d.relieve()
    d.update_person(0, position=[0.0, 0.0, 0.01])
    with pytest.raises(DesignError, match="edited since"):
        d.relieve()
    assert "relief" not in tomllib.loads(d.save_toml(tmp_path / "edited.toml").read_text())


def test_design_edits_are_checked(library):
    d = Design(library)
    with pytest.raises(DesignError, match="empty"):
        d.fit()
    with pytest.raises(ValueError, match="nobody"):
        d.add_person("db:nobody")
    assert d.people == []  # nothing half-added
    d.add_person(HIGH_SIT)
    with pytest.raises(DesignError, match="control vertex"):
        d.move_vertex(1000, [0, 0, 0])
    with pytest.raises(ValueError, match="sigma"):
        d.set_parameter("sigma", -1.0)
    assert d.params["sigma"] == 0.003
    with pytest.raises(DesignError, match="Fit first"):
        d.relax(0)
    with pytest.raises(DesignError, match="at most 2000"):
        d.new_grid((3.0, 3.0), (60, 60), 0.4)
    assert len(d.vertices) == 63  # the mesh it had


def test_fixed_vertices_hold_and_moved_ones_start_where_put(library):
    d = Design(library)
    d.add_person(HIGH_SIT)
    d.move_vertex(0, [-0.3, 0.5, -0.35])
    d.set_fixed(0, True)
    control = d.fit().result.control
    assert np.linalg.norm(control[0] - [-0.3, 0.5, -0.35]) < 0.01
    free = np.linalg.norm(control - d.vertices, axis=1)
    assert free.max() > 0.02  # the others did move


def test_the_studio_listens_on_loopback_only_by_default(library, tmp_path):
    import http.client
    import json
    import urllib.request

    from studio.web import Studio

    studio = Studio(db=str(library), port=0, out=str(tmp_path))
    try:
        assert studio.host == "127.0.0.1"
        with urllib.request.urlopen(f"http://127.0.0.1:{studio.port}/", timeout=10) as page:
            assert b"<html" in page.read(2000).lower()  # the client, served from the package
        assert listening_addresses(studio.port) == {"127.0.0.1"}
        # no request body is taken over HTTP: over the limit 413, else 405
        for size, status in ((6 * 1024 * 1024, 413), (1000, 405)):
            conn = http.client.HTTPConnection("127.0.0.1", studio.port, timeout=30)
            conn.request("POST", "/", body=b"x" * size)
            response = conn.getresponse()
            assert response.status == status, (size, response.status)
            assert "detail" in json.loads(response.read())
            conn.close()
    finally:
        studio.stop()


def test_levels_from_a_slider_and_moves_are_taken(library):
    d = Design(library)
    d.add_person(HIGH_SIT)
    d.set_parameter("level", 2.0)
    assert d.params["level"] == 2 and isinstance(d.params["level"], int)
    d.update_person(0, position=[0.05, 0.0, -0.1], rotation_deg=[0.0, 5.0, 0.0])
    assert d.scenario().persons[0].position == (0.05, 0.0, -0.1)
    with pytest.raises(ValueError, match="position"):
        d.update_person(0, position=[0.0, 0.0])
    assert d.people[0]["position"] == [0.05, 0.0, -0.1]


def test_a_template_is_built_around_the_people_as_a_scenario_builds_it(library):
    """A template built around the session's people is the control mesh `sitrelax fit` builds
    from a scenario naming it (`solver.scene.furnish`), creases and all; each person is then
    supported as its use, in one step that Undo takes back. On the high-sit pose (lifted 2 cm,
    as `sitrelax design` lifts a sitter) the chair carries the person where the studio's default
    grid pressed the calves (its peak on them, 1.53 of a flat seat's)."""
    from solver.scene.placement import place_scene
    from solver.scene.scenario import parse_scenario

    d = Design(library)
    with pytest.raises(DesignError, match="Add a person first"):
        d.build_template("chair")
    d.add_person(HIGH_SIT, position=[0.0, 0.02, 0.0])
    grid, faces = d.vertices.copy(), d.faces.copy()
    with pytest.raises(DesignError, match="Expected a template of chair, bench with back"):
        d.build_template("sofa")
    assert d.build_template("chair") == "chair"
    scenario, _ = place_scene(parse_scenario(
        {"surface": {"template": {"kind": "chair", "seams": False}},
         "person": [{"pose": HIGH_SIT, "position": [0.0, 0.02, 0.0], "support": "chair"}]},
        "test"))
    np.testing.assert_array_equal(d.vertices, scenario.surface.vertices)
    np.testing.assert_array_equal(d.faces, scenario.surface.faces)
    assert d.creases == {tuple(sorted(c)) for c in scenario.surface.params.creases}
    assert not d.creases and d.people[0]["support"] == "chair"  # (no seams: no slits)
    assert d.build_template("bench") == "seat"  # backless
    backless = len(d.vertices)
    assert d.build_template("bench with back") == "chair" and len(d.vertices) > backless
    assert not d.creases  # (the seat meets its back without a seam)
    d.undo()
    d.undo()
    d.undo()
    np.testing.assert_array_equal(d.vertices, grid)
    np.testing.assert_array_equal(d.faces, faces)
    assert d.people[0]["support"] == "seat" and not d.creases
    d.build_template("chair")
    person = d.fit().persons[0]
    assert person["coverage"] >= 0.95 and person["contact_coverage"] >= 0.8
    assert person["peak_region"] in ("pelvis", "thighs", "lower_back", "upper_back"), person
    assert person["peak_of_flat"] < 0.8, person
    # people on the floor get no cushion under them: the message says what to change here
    d.update_person(0, position=[0.0, 0.0, 0.0])
    with pytest.raises(DesignError, match=r"^No floor cushion can be built around the people "
                       r"as they are placed: .* lift them \(each person's Position y, e\.g\. "
                       r"0\.45 for a bed, 0\.13 for a floor cushion\)$"):
        d.build_template("floor cushion")
    assert d.people[0]["support"] == "chair" and len(d.vertices) == len(scenario.surface.vertices)
    # a chair is one person's; two facing each other share no bench; a bed for two is as fine
    # across each as a bed for one
    d.add_person(HIGH_SIT, position=[0.7, 0.0, 0.0], rotation_deg=[0.0, 180.0, 0.0])
    with pytest.raises(DesignError, match="A chair is for one person: 2 people share a bench"):
        d.build_template("chair")
    with pytest.raises(DesignError, match=r"face opposite ways: turn them \(Rotation\) to face "
                                          r"one way$"):
        d.build_template("bench with back")
    d.update_person(0, position=[0.0, 0.5, 0.0])
    d.update_person(1, position=[0.7, 0.5, 0.0], rotation_deg=[0.0, 0.0, 0.0])
    assert d.build_template("bed") == "bed" and len(d.vertices) == (2 * 8 + 1) * (16 + 1)


def test_the_support_checkboxes_are_the_body_regions(library, tmp_path):
    """One box per body region, ticked for the schema's default (a seat); a person supported as
    a use shows its regions, and the ticked boxes become the person's support."""
    from posedb.regions import BODY_REGIONS

    from studio.web import Studio

    from studio.headless import HeadlessTab as Tab

    studio = Studio(db=str(library), port=0, out=str(tmp_path))
    tab = Tab(studio)
    try:
        view = tab.view
        assert list(view.parts) == list(BODY_REGIONS)
        assert {r for r, box in view.parts.items() if box.value} == {"pelvis", "thighs"}
        view.add_person(HIGH_SIT)
        view.design.update_person(0, support="chair")
        view._show_person()
        assert {r for r, box in view.parts.items() if box.value} == {
            "upper_back", "lower_back", "pelvis", "thighs"}
        view.parts["upper_back"].value = False
        view.parts["calves"].value = True
        view._apply_person()
        assert view.design.people[0]["support"] == ["lower_back", "pelvis", "thighs", "calves"]
        assert view.design.scenario().persons[0].support == (
            "lower_back", "pelvis", "thighs", "calves")
    finally:
        tab.close()
        studio.stop()
