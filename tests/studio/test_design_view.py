"""The studio's Design view driven over viser's own protocol (tabs without a browser,
`studio.headless`): one session per tab, picking by clicks and boxes, typed placements,
undo and redo, creases and splits, warnings before and after a fit, refits while dragging, the
relaxed pose saved to the library and the export as one zip."""

from __future__ import annotations

import io
import json
import time
import zipfile

import numpy as np
import pytest
from viser import _messages

from posedb import PoseLibrary
from studio.design_view import project, ray_pick
from tests.studio.conftest import wait_until
from studio.web import VIEWS, Studio

from studio.headless import CAMERA, HeadlessTab as Tab
from tests.conftest import high_sit_library

HIGH_SIT = "bvh:bundled:cmu_75_18_high_sit.bvh#frame=39"
STANDING = "bvh:bundled:axis_neuron_standing_yxz.bvh#frame=39"


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    return high_sit_library(tmp_path_factory.mktemp("design-view") / "poses.h5",
                            [(39, "perch", ["sit", "high"])])


@pytest.fixture(scope="module")
def studio(library, tmp_path_factory):
    server = Studio(db=str(library), port=0, out=str(tmp_path_factory.mktemp("out")))
    yield server
    server.stop()


@pytest.fixture
def tab(studio):
    tab = Tab(studio)
    yield tab
    tab.close()




def _seat(view, pose: str = HIGH_SIT) -> None:
    """single_seated's start (0.5 x 0.6 m at 0.42 m) and one seated person on it."""
    view.grid_size.value, view.grid_res.value, view.grid_height.value = (0.5, 0.6), (8, 6), 0.42
    view._guarded(view._new_grid)
    view.live.value = False
    view.add_person(pose, position=[0.0, 0.0, -0.1], facing="capture", support="seat")


def _click(tab, point, modifier=None) -> None:
    """A click on the screen where `point` is seen from the tab's camera: the ray the browser
    would send (from the camera through that pixel)."""
    origin = np.array(CAMERA["position"])
    direction = np.asarray(point) - origin
    tab.send(_messages.ScenePointerMessage("click", tuple(origin), tuple(direction),
                                           ((0.5, 0.5),), modifier))


def test_the_template_button_builds_one_around_the_people(tab):
    """The Control mesh panel's Template and its button: the chair built around the person,
    who is then supported as a chair (the support boxes show it), drawn in the tab."""
    view = tab.view
    view._guarded(view._build_template)
    assert "Add a person first" in view.status_text, view.status_text
    view.add_person(HIGH_SIT, position=[0.0, 0.02, 0.0])
    view.template.value = "chair"
    view._guarded(view._build_template)
    assert view.status_text.startswith("A chair built around the people (108 control "
                                       "vertices, 0 crease edges)"), view.status_text
    assert view.design.people[0]["support"] == "chair"
    assert {r for r, box in view.parts.items() if box.value} == {
        "upper_back", "lower_back", "pelvis", "thighs"}
    view._guarded(view._undo)  # the grid and the person's support again
    assert len(view.design.vertices) == 9 * 7 and view.design.people[0]["support"] == "seat"
    assert {r for r, box in view.parts.items() if box.value} == {"pelvis", "thighs"}


def test_every_tab_gets_the_three_tabs_and_its_own_session(studio):
    assert [label for label, _ in VIEWS] == ["Record", "Library", "Design"]
    first, second = Tab(studio), Tab(studio)
    try:
        a, b = first.view, second.view
        assert a.session is not b.session
        a.add_person(HIGH_SIT)
        a.design.move_vertex(0, [-0.6, 0.5, -0.4])
        assert len(a.design.people) == 1 and b.design.people == []
        assert np.allclose(b.design.vertices[0], [-0.6, 0.45, -0.4])
        assert "Added" not in b.status_text  # a new tab shows none of another's status
        # joining by name shares one session; the first tab in brings its design into it
        for view in (a, b):
            view.join_name.value = "shared bench"
            view._guarded(view._join)
        assert a.session is b.session and len(a.design.people) == 1
        assert "with this tab's design" in a.status_text, a.status_text
        assert np.allclose(b.design.vertices[0], [-0.6, 0.5, -0.4])  # the second sees it
        a.add_person(HIGH_SIT)
        assert len(b.design.people) == 2 and b.selected.options[0].startswith("1: person 1")
        a._guarded(a.design.undo)  # (the person added is one step; the design brought another)
        assert len(b.design.people) == 1
        # a tab with a design of its own is warned before joining leaves it; a second press joins
        third = Tab(studio)
        try:
            c = third.view
            c.add_person(HIGH_SIT)
            c.join_name.value = "shared bench"
            c._guarded(c._join)
            assert c.session is not a.session and "press **Join session** again" in \
                c.status_text, c.status_text
            c._guarded(c._join)
            assert c.session is a.session and len(c.design.people) == 1
        finally:
            third.close()
        assert studio.context.designs["shared bench"] is a.session
    finally:
        first.close()
        wait_until(lambda: first.client_id not in studio.views, 10, "the tab's views to close")
        assert "shared bench" in studio.context.designs  # the second tab still shows it
        second.close()
    wait_until(lambda: "shared bench" not in studio.context.designs, 10, "the session to end")


def test_picks_by_click_shift_click_and_box_then_fix_crease_and_split(tab):
    view = tab.view
    view.add_person(HIGH_SIT)
    v = view.design.vertices
    a, b, c, d = (int(j) for j in view.design.faces[20])  # a quad's corners, in turn
    _click(tab, v[a])
    wait_until(lambda: view.selection == [a], 10, "the click to pick a corner")
    _click(tab, v[d], modifier="shift")
    wait_until(lambda: view.selection == [a, d], 10, "shift-click to add another")
    _click(tab, v[d], modifier="shift")
    wait_until(lambda: view.selection == [a], 10, "shift-click to drop it again")
    # boxes around b and then c, in the image as the tab's camera sees it
    cam = view.client.camera
    uv, front = project(v, cam.position, cam.wxyz, cam.fov, cam.aspect)
    assert front.all() and np.all((uv > 0) & (uv < 1))  # the grid is in view
    for j, expect in ((b, [a, b]), (c, [a, b, c])):
        lo, hi = uv[j] - 0.005, uv[j] + 0.005
        assert np.flatnonzero(np.all((uv >= lo) & (uv <= hi), axis=1)).tolist() == [j]
        tab.send(_messages.ScenePointerMessage("rect-select", None, None,
                                               (tuple(lo), tuple(hi)), "shift"))
        wait_until(lambda: view.selection == expect, 10, f"the box to add {j}")
    view._guarded(lambda: view._fix(True))
    assert view.design.fixed == {a, b, c}
    view._guarded(lambda: view._crease(True))
    spanned = {tuple(sorted(e)) for e in ((a, b), (b, c))}  # the control edges they span
    assert view.design.creases == spanned, view.status_text
    assert set(view.design.scenario().surface.params.creases) == spanned
    view.pick(view.design.faces[0][:3])  # three corners pick one face
    view._guarded(view._split)
    assert "Split control face 0" in view.status_text, view.status_text
    assert len(view.design.vertices) == 80
    view._guarded(view._undo)
    assert len(view.design.vertices) == 63 and view.design.creases == spanned
    view._guarded(view._undo)
    assert view.design.creases == set() and view.design.fixed == {a, b, c}
    view._guarded(view._redo)
    view._guarded(view._redo)
    assert len(view.design.vertices) == 80
    view._guarded(view._redo)
    assert view.status_text == "**Problem:** Nothing to redo"


def test_a_click_far_from_every_vertex_picks_none():
    points = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    assert ray_pick(points, (0, 0, 5), (0, 0, -1)) == 0
    assert ray_pick(points, (0, 0, 5), (0, 1, -1)) is None  # 45 degrees off
    assert ray_pick(points, (0, 0, 5), (0, 0, 1)) is None  # behind the camera


def test_typed_placements_move_people_and_picks(tab):
    view = tab.view
    view.live.value = False
    view.add_person(HIGH_SIT)
    view.add_person(HIGH_SIT)
    view.selected.value = view._labels()[1]
    view.position.value = (0.4, 0.0, -0.1)
    view.rotation.value = (0.0, 90.0, 0.0)
    assert "Problem" not in view.status_text, view.status_text
    assert view.design.people[1]["position"] == [0.4, 0.0, -0.1]
    assert view.design.people[1]["rotation_deg"] == [0.0, 90.0, 0.0]
    assert np.allclose(view._people[1].position, (0.4, 0.0, -0.1))
    assert view.design.people[0]["position"] == [0.0, 0.0, 0.0]
    view.pick([0, 1])
    centre = view.design.vertices[[0, 1]].mean(axis=0)
    view.centroid.value = tuple(centre + [0.0, 0.1, 0.0])
    assert np.allclose(view.design.vertices[[0, 1], 1], 0.55)
    view.position.value = (0.4, 0.0)  # not a position: refused, nothing changes
    assert view.design.people[1]["position"] == [0.4, 0.0, -0.1]


def test_a_standing_pose_on_a_seat_is_warned_before_fitting(tab):
    view = tab.view
    _seat(view)
    assert view.warning_lines == []
    view.add_person(STANDING, position=[0.3, 0.0, 0.3])
    assert any("stands" in w for w in view.warning_lines)
    assert "&#9888;" in view.warnings.content and "stands" in view.warnings.content
    view.selected.value = view._labels()[1]
    view._guarded(view._remove_person)
    assert view.warning_lines == [] and view.warnings.content == ""


# the fits of these take a few seconds each on two loaded cores: under the slow mark
@pytest.mark.slow
def test_a_standing_pose_on_a_seat_is_warned_after_fitting(tab):
    view = tab.view
    _seat(view)
    view.add_person(STANDING, position=[0.3, 0.0, 0.3])
    view._guarded(view.run_fit)
    assert "Fitted" in view.status_text, view.status_text
    assert any("stands" in w for w in view.warning_lines)
    # and the fit's figures that miss the bars are warned too: the standing body is not
    # carried (its coverage is far under 0.95)
    assert any("person 2: coverage" in w for w in view.warning_lines), view.warning_lines


@pytest.mark.slow
def test_fit_shows_the_fitted_net_relax_saves_and_removal_clears(tab, library):
    view = tab.view
    _seat(view, "db:perch")
    view._guarded(view.run_fit)
    assert view._fitted_net is not None and view._surface is not None
    assert not np.allclose(view.design.last.result.control, view.design.vertices)
    view._guarded(view._relax)
    assert 0 in view._relaxed, view.status_text
    before = {p.name for p in PoseLibrary(library).poses()}
    view._guarded(view._save_pose)
    assert "Saved person 1's relaxed pose" in view.status_text, view.status_text
    (new,) = {p.name for p in PoseLibrary(library).poses()} - before
    assert new.startswith("perch-relaxed")
    assert "relaxed" in PoseLibrary(library).pose(new).tags
    view._guarded(view._remove_person)
    assert view._relaxed == {} and view.design.relaxed == {}
    view._guarded(view._undo)  # the person and its relaxed body come back
    assert 0 in view._relaxed and len(view.design.people) == 1


@pytest.mark.slow
def test_the_relieve_button_relieves_the_fit_on_screen_and_says_what_it_did(tab):
    view = tab.view
    _seat(view)
    view._guarded(view._relieve)  # nothing fitted yet: said so
    assert "Fit first" in view.status_text, view.status_text
    view._guarded(view.run_fit)
    plain = view.design.last
    view._guarded(view._relieve)
    assert "Pressure relief:" in view.status_text and "round(s) kept" in view.status_text, \
        view.status_text
    relieved = view.design.last  # (single_seated's seat: its first round is kept)
    assert relieved is not plain and view._drawn_fit is relieved
    assert relieved.persons[0]["peak_of_flat"] < plain.persons[0]["peak_of_flat"]
    assert view.progress.content == ""  # the rounds' news gone with the drawing


@pytest.mark.slow
def test_export_downloads_one_zip_of_every_format(tab):
    view = tab.view
    _seat(view)
    view.name.value = "bench one"
    view._guarded(view._export)  # (no fit yet: it fits first, and shows that fit)
    assert "Exported the fit on screen (fit 1)" in view.status_text, view.status_text
    with zipfile.ZipFile(io.BytesIO(view.exported)) as pack:
        names = set(pack.namelist())
        report = json.loads(pack.read("bench one/report.json"))
    assert {"bench one/surface.obj", "bench one/surface.ply", "bench one/surface.glb",
            "bench one/scene.3dm", "bench one/control.obj",
            "bench one/scenario.toml"} <= names
    assert f"{len(names)} files" in view.status_text
    shown = view.design.last
    assert report["energies"] == shown.result.energies  # the fit on screen, not another
    assert report["persons"][0]["coverage"] == shown.persons[0]["coverage"]
    assert not (view.out / "bench one").exists()  # nothing left on the server
    # a person moved since the fit: the export fits the session as it is now first
    view._guarded(lambda: view.design.update_person(0, position=[0.0, 0.0, -0.08]))
    view._guarded(view._export)
    assert "fit 2" in view.status_text and view.design.fitted, view.status_text


@pytest.mark.slow
def test_dragging_refits_on_the_worker_and_a_newer_drag_cancels(tab):
    view = tab.view
    _seat(view)
    view.live.value = True
    name = f"{view.prefix}/people/p0"
    owner = str(tab.client_id)
    tab.send(_messages.TransformControlsDragStartMessage(name, owner))
    for dz in (0.0, 0.01, 0.02):
        tab.send(_messages.TransformControlsUpdateMessage(name, (1.0, 0.0, 0.0, 0.0),
                                                          (0.0, 0.0, -0.1 + dz), owner))
    tab.send(_messages.TransformControlsDragEndMessage(name, owner))
    wait_until(lambda: view.design.people[0]["position"] == [0.0, 0.0, -0.08], 10, "the drag")
    wait_until(lambda: view.fits >= 1, 60, "a refit after the drag")
    wait_until(lambda: "Fitted" in view.status_text, 10, "the refit drawn")
    fitted_at = view.design.last.people[0].spec.position
    assert fitted_at == (0.0, 0.0, -0.08)  # the fit drawn is the newest placement's
    # an edit while a fit runs cancels it: the fit returns nothing and draws nothing
    fits = view.fits
    view.session.refitter.request()
    wait_until(lambda: view.session.refitter.busy, 10, "the refit to start")
    view._guarded(lambda: view.design.update_person(0, position=[0.0, 0.0, -0.09]))
    view.session.refitter.bump()
    wait_until(lambda: not view.session.refitter.busy, 30, "the cancelled fit to stop")
    assert view.fits == fits


@pytest.mark.slow
def test_a_drag_streams_the_surface_and_the_fit_of_its_end_replaces_it(studio):
    """A person dragged for a second in 0.5 mm steps: the tab receives surfaces while the drag
    goes on (iterates, sent as new vertices of the same node), and after it the finished fit of
    the last position, its limit surface on the iterates' quads."""
    from solver.mesh import quad_triangles

    tab = Tab(studio, watch=("/design/surface",), texts=True)
    try:
        view = tab.view
        _seat(view)
        view._guarded(view.run_fit)
        assert view.fits == 1, view.status_text
        surface = view._surface
        view.live.value = True
        name, owner = f"{view.prefix}/people/p0", str(tab.client_id)
        tab.send(_messages.TransformControlsDragStartMessage(name, owner))
        start = time.perf_counter()
        for step in range(1, 41):
            tab.send(_messages.TransformControlsUpdateMessage(
                name, (1.0, 0.0, 0.0, 0.0), (0.0005 * step, 0.0, -0.1), owner))
            time.sleep(0.03)
        wait_until(lambda: view.design.people[0]["position"] == [0.02, 0.0, -0.1], 30, "the drag")
        dragged = time.perf_counter()
        tab.send(_messages.TransformControlsDragEndMessage(name, owner))
        wait_until(lambda: view.fits >= 2 and not view.session.refitter.busy and
              not view.session.refitter.wanted, 60, "the fit after the drag")
        wait_until(lambda: view.design.last.people[0].spec.position == (0.02, 0.0, -0.1), 60,
              "the fit of the drag's end")
        while_dragging = [t for t in tab.arrivals["/design/surface"] if start <= t <= dragged]
        assert len(while_dragging) >= 2, (len(while_dragging), view.session.shown)
        assert tab.text_arrived("surface of iteration", start) is not None
        # one node throughout, its quads those of the fit; the finished fit's limit surface
        assert view._surface is surface
        result = view.design.last.result
        np.testing.assert_array_equal(surface.faces, quad_triangles(result.surface_faces))
        np.testing.assert_allclose(surface.vertices, view.design.last.limit, atol=1e-6)
        assert view.progress.content == "" and "Fitted" in view.status_text
    finally:
        tab.close()


def test_the_pose_list_follows_a_rename_made_elsewhere(tmp_path):
    """A pose renamed in the library (the Library tab, another process) is listed under its
    new name within a few seconds, the chosen pose kept when it is still there."""
    path = high_sit_library(tmp_path / "poses.h5", [(39, "perch", [])])
    server = Studio(db=str(path), port=0, out=str(tmp_path / "out"))
    tab = Tab(server)
    try:
        view = tab.view
        assert "perch" in view.pose.options
        chosen = view.pose.value  # (the seated recording)
        with PoseLibrary(path).edit() as ed:
            ed.rename("perch", "my favourite perch")
        wait_until(lambda: "my favourite perch" in view.pose.options, 10, "the renamed pose")
        assert "perch" not in view.pose.options and view.pose.value == chosen
    finally:
        tab.close()
        server.stop()


def test_sigma_takes_an_exponent_and_refuses_what_is_no_number_keeping_its_value(tab):
    view = tab.view
    for typed in ("5", "5e", "5e-", "5e-3"):  # key by key, as the text input sends them
        view.sigma.value = typed
    wait_until(lambda: view.design.params["sigma"] == 0.005, 10, "sigma from 5e-3")
    assert view.sigma.value == "5e-3" and "Expected sigma" not in view.status_text
    for typed in ("-1", "1e308", "lots"):
        view.sigma.value = typed
        wait_until(lambda: "Expected sigma" in view.status_text, 10, f"{typed!r} refused")
        assert view.design.params["sigma"] == 0.005 and view.sigma.value == "0.005"
        view._status("")
    view._guarded(view.design.undo)  # one step for the typing: the value before it again
    view._guarded(view.redraw)
    assert view.sigma.value == "0.003" and view.design.params["sigma"] == 0.003


def test_cancel_stops_the_fit_the_fit_button_started(tab):
    """Cancel fit stops a running fit at its next iteration (it needs no lock the running fit
    holds): nothing new is drawn, and the status says so."""
    import threading

    view = tab.view
    _seat(view)
    worker = threading.Thread(target=lambda: view._guarded(view.run_fit))
    worker.start()
    wait_until(lambda: "iteration" in view.progress.content, 30, "the fit's first iteration")
    view.session.cancel_fit()
    worker.join(30)
    assert not worker.is_alive()
    assert "The fit was cancelled" in view.status_text, view.status_text
    assert view.design.last is None and view.fits == 0
    assert "Fit cancelled" in view.progress.content
    view._guarded(view.run_fit)  # and the next fit runs to its end
    assert view.fits == 1 and "Fitted" in view.status_text, view.status_text


def test_a_problem_pops_up_a_notice_and_is_cleared_by_the_next_action(studio):
    """The status line may be scrolled away in a long panel: a problem also shows as a notice;
    the next action clears the problem from the status line."""
    tab = Tab(studio, notices=True)
    try:
        _problems_are_noticed(tab)
    finally:
        tab.close()


def _problems_are_noticed(tab) -> None:
    view = tab.view
    view.name.value = ""
    view._guarded(view._save_toml)
    assert view.status_text.startswith("**Problem:**"), view.status_text
    wait_until(lambda: any(title == "Problem" and "name" in body for title, body in tab.notices),
          10, "the notice")
    view._guarded(lambda: None)  # an action that says nothing
    assert view.status_text == ""
    # a refit's problem (on the worker, no action of the tab's) likewise
    view.session.problem(ValueError("person 1 is 18 m from the surface"))
    assert view.status_text == "**Problem:** the refit failed: person 1 is 18 m from the surface"
    wait_until(lambda: ("Problem", "the refit failed: person 1 is 18 m from the surface")
          in tab.notices, 10, "the refit's notice")
    view._guarded(lambda: None)
    assert view.status_text == ""


def test_showing_record_frames_a_standing_performer_once(studio, tab):
    """The camera first framed for a seat; shown the Record view it steps back to take in a
    standing performer, once (the designer's own orbit is kept after)."""
    from studio.web import FRAMING

    client = studio.server.get_clients()[tab.client_id]
    shown = studio.shown[tab.client_id]
    shown.value = "Record"
    wait_until(lambda: np.allclose(client.camera.position, FRAMING["Record"][0]), 10,
          "the camera to frame a standing performer")
    client.camera.position = (3.0, 2.0, 3.0)  # the designer orbits
    shown.value = "Design"
    shown.value = "Record"
    time.sleep(0.2)
    assert np.allclose(client.camera.position, (3.0, 2.0, 3.0))
