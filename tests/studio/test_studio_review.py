"""A designer's review of the studio's views, driven in Python (no browser): what a refused
input leaves on the panel, what a disconnect says and shows, a one-frame take on the
timeline, a bad search followed by an edit."""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import pytest

from capture import read_bvh
from capture.recordings import resolve_path
from posedb import PoseLibrary
from studio.context import StudioContext

from tests.studio.test_record_library_views import _server, _stop, high_sit_library
from tests.studio.test_studio_browser import _wait


@pytest.fixture
def library(tmp_path) -> Path:
    return high_sit_library(tmp_path / "poses.h5", [(39, "perch", ["sit", "high"]),
                                                    (10, "early", ["test"])])


@pytest.fixture
def library_view(library, tmp_path):
    from studio.library_view import LibraryView

    server = _server()
    view = LibraryView(server, server.gui.add_tab_group().add_tab("Library"),
                       StudioContext(db=str(library), out=tmp_path, limit=1 << 20))
    yield view
    view.close()
    _stop(server)


def test_an_edit_after_a_refused_search_says_it_was_made(library_view, library):
    view = library_view
    view.search_text.value = "sit and ("
    view._guarded(view.do_search)
    assert "In tag expression" in view.status.content
    view.pose.value, view.rename_to.value = "perch", "perch2"
    view._guarded(view.do_rename)
    assert [p.name for p in PoseLibrary(library).poses()] == ["perch2", "early"]
    assert view.status.content == "Renamed perch to **perch2**.", view.status.content
    assert "perch2" in view.pose.options and view.expr == ""  # the last expression kept


def test_a_one_frame_take_is_held_on_its_frame(library_view, library):
    """A one-frame take (as a relaxed pose saved from the Design view is stored) has no frame
    to scrub to: the slider is held, and a frame past its end draws and saves its only one."""
    bvh = read_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"))
    with PoseLibrary(library).edit() as ed:
        ed.add_take(bvh.skeleton, bvh.motion.channels[39:40], bvh.motion.frame_time,
                    name="single", source="test", origin="relaxed")
    view = library_view
    view._guarded(view.do_refresh)
    view.take.value = "single"
    assert view.data.take.name == "single"
    view.frame.value = 1  # (the slider's end: a slider needs two values)
    assert "Internal error" not in view.status.content, view.status.content
    assert view.frame.disabled
    view.new_pose.value = "only"
    view._guarded(view.do_save_frame)
    assert "Added pose **only** at frame 0 of single" in view.status.content, \
        view.status.content
    assert PoseLibrary(library).pose("only").frame == 0


def test_disconnecting_while_recording_stores_the_take_and_says_what_it_stored(library,
                                                                                 tmp_path):
    """Disconnect stores the take as Stop take does (named, the next name ready), the pose
    names as stored (one taken meanwhile got a suffix), and no figures or skeleton of the
    stream gone are left on the panel; a source that cannot be reached says why."""
    from studio.record import URL_CHOICE, RecordView

    server = _server()
    view = RecordView(server, server.gui.add_tab_group().add_tab("Record"),
                      StudioContext(db=str(library), out=tmp_path, limit=1 << 20))
    try:
        view._guarded(view.do_connect)
        view._guarded(view.do_start)
        _wait(lambda: view.stream.frames_in_take > 20, 10, "frames of the take")
        view.pose_name.value = "held"
        view._guarded(view.do_mark)
        assert view.marked, view.status.content
        PoseLibrary(library).add_pose("high_sit", 5, "held")  # the name taken meanwhile
        _wait(lambda: "recording take-1" in view.readout.content, 5, "the readout")
        view._guarded(view.do_disconnect)
        assert view.stream is None
        assert view.status.content.startswith("Disconnected. Stored take **take-1**: "), \
            view.status.content
        assert view.status.content.endswith("1 marked pose(s): held-2."), view.status.content
        assert view.last_take.name == "take-1" and view.take_name.value == "take-2"
        time.sleep(0.6)  # (a readout tick)
        assert view.readout.content == "Not connected."
        assert not view.figure.bones.visible and not view.figure.joints.visible
        # connecting elsewhere while a take records stores it first, and says so
        view._guarded(view.do_connect)
        view._guarded(view.do_start)
        _wait(lambda: view.stream.frames_in_take > 5, 10, "frames of the second take")
        view.choice.value, view.url.value = URL_CHOICE, "tcp://127.0.0.1:1"
        view._guarded(view.do_connect)
        assert view.status.content.startswith("Disconnected. Stored take **take-2**: ") and \
            view.status.content.endswith(" Connected to tcp://127.0.0.1:1."), \
            view.status.content
        _wait(lambda: "cannot connect to 127.0.0.1:1" in view.readout.content, 5,
              f"the reason in the readout (it reads {view.readout.content!r})")
    finally:
        view.close()
        _stop(server)
    lib = PoseLibrary(library)
    assert [p.name for p in lib.find_poses(take="take-1")] == ["held-2"]


def test_a_refused_person_edit_leaves_the_panel_showing_the_person(design_view):
    view = design_view
    view.add_person("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39")
    for box in view.parts.values():
        box.value = False
    view._guarded(view._apply_person)
    assert "expected at least one body region" in view.status_text
    assert view.design.people[0]["support"] == "seat"
    assert {r for r, box in view.parts.items() if box.value} == {"pelvis", "thighs"}
    view.position.value = (2000.0, 0.0, 0.0)
    assert "expected a number <= 1000" in view.status_text
    assert view.design.people[0]["position"] == [0.0, 0.0, 0.0]
    assert view.position.value == (0.0, 0.0, 0.0)


def test_a_typed_centroid_out_of_bounds_is_refused_at_once(design_view):
    """Vertices typed beyond the scenario's bound are refused when typed (not by every fit
    after), and the field shows where the picks stay."""
    view = design_view
    before = view.design.vertices.copy()
    view.pick([0, 1])
    centre = tuple(float(c) for c in before[[0, 1]].mean(axis=0))
    view.centroid.value = (0.0, 2000.0, 0.0)
    assert "from -1000 to 1000 m" in view.status_text, view.status_text
    np.testing.assert_array_equal(view.design.vertices, before)
    np.testing.assert_allclose(view.centroid.value, centre)


def test_joining_the_session_a_tab_is_in_says_so(design_view):
    view = design_view
    view.join_name.value = "shared"
    view._guarded(view._join)
    view._status("")
    view._guarded(view._join)
    assert view.status_text == "This tab is in the session 'shared' already."


def test_a_save_does_not_silently_replace_what_another_tab_saved(tmp_path, library):
    """Every tab starts with the same Name: a second tab's Save TOML or Save to library warns
    before it replaces the first tab's, and replaces it when pressed again; a tab saves its
    own again freely."""
    from studio.headless import HeadlessTab
    from studio.web import Studio

    studio = Studio(db=str(library), port=0, out=str(tmp_path / "out"))
    tabs = [HeadlessTab(studio), HeadlessTab(studio)]
    try:
        first, second = (tab.view for tab in tabs)
        for view in (first, second):
            view.live.value = False
            view.add_person("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39",
                            position=[0.123 if view is first else -0.321, 0.0, 0.0])
        path = studio.out / "studio-design.toml"
        for save, stored in ((lambda v: v._save_toml,
                              lambda: path.read_text()),
                             (lambda v: v._save_db,
                              lambda: json.dumps(PoseLibrary(library).scenarios()[0]))):
            first._guarded(save(first))
            assert "0.123" in stored() and "exists already" not in first.status_text
            second._guarded(save(second))
            assert "exists already, not saved by this tab: press" in second.status_text
            assert "0.123" in stored() and "-0.321" not in stored()  # the first tab's, kept
            second._guarded(save(second))  # pressed again: replaced
            assert "-0.321" in stored(), second.status_text
            second._guarded(save(second))  # its own now: saved again without a word
            assert "exists already" not in second.status_text
        assert [s["name"] for s in PoseLibrary(library).scenarios()] == ["studio-design"]
    finally:
        for tab in tabs:
            tab.close()
        studio.stop()


def test_relief_that_has_no_peak_to_lower_says_so(design_view):
    """A body that does not come to rest has no peak set against a flat seat's: no round runs,
    and the status line does not claim the peaks are at the aim."""
    view = design_view
    view.add_person("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", position=[0.0, -0.3, 0.0])
    view._guarded(view.run_fit)
    assert view.design.last.persons[0]["peak_of_flat"] is None, view.status_text
    view._guarded(view._relieve)
    assert view.status_text.startswith("No round ran: no seated body rests on the surface"), \
        view.status_text


def test_a_tab_opened_on_an_unreadable_library_gets_its_views_and_says_why(tmp_path, library):
    from studio.headless import HeadlessTab
    from studio.library_view import LibraryView
    from studio.web import Studio

    studio = Studio(db=str(library), port=0, out=str(tmp_path / "out"))
    try:
        library.write_bytes(b"not a library" * 100)  # damaged while the studio runs
        tab = HeadlessTab(studio, timeout=20)
        try:
            assert "the pose library cannot be read" in tab.view.status_text
            assert "recording: cmu_75_18_high_sit.bvh" in tab.view.pose.options
            library_view = studio.view(tab.client_id, LibraryView)
            assert "not an HDF5 file" in library_view.status.content
        finally:
            tab.close()
    finally:
        studio.stop()


def test_a_view_that_cannot_be_built_is_said_in_its_tab_and_the_others_work(tmp_path,
                                                                             monkeypatch):
    """The tab's other views are built, and closed with the tab."""
    from studio import web
    from studio.headless import HeadlessTab
    from studio.library_view import LibraryView

    closed = []

    class Broken:
        prefix = "/broken"

        def __init__(self, client, tab, context):
            raise RuntimeError("no such device")

    class Watched(LibraryView):
        def close(self) -> None:
            closed.append(self)
            super().close()

    monkeypatch.setattr(web, "VIEWS", (("Record", Broken), ("Library", Watched),
                                       ("Design", web.DesignView)))
    studio = web.Studio(port=0, out=str(tmp_path / "out"))
    try:
        tab = HeadlessTab(studio, timeout=20, texts=True)
        _wait(lambda: tab.text_arrived("the Record view could not be built: RuntimeError: "
                                       "no such device", 0.0) is not None, 10, "the message")
        assert tab.view.status_text.startswith("Add people")
        tab.close()
        assert len(closed) == 1
    finally:
        studio.stop()


def test_cancel_with_no_fit_running_says_so_and_cancels_one_that_runs(design_view):
    import threading

    view = design_view
    view.add_person("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39", position=[0.0, 0.0, -0.1])
    view._cancel()
    assert view.status_text == "No fit is running: nothing to cancel."
    worker = threading.Thread(target=lambda: view._guarded(view.run_fit))
    worker.start()
    _wait(lambda: "iteration" in view.progress.content, 30, "the fit's first iteration")
    view._cancel()
    worker.join(30)
    assert "The fit was cancelled" in view.status_text, view.status_text


def test_a_deleted_pose_is_not_left_drawn(library_view, library):
    """With the last pose listed deleted, the view draws the take on the timeline again, not
    the pose that is gone."""
    from capture import skeleton_fk

    view = library_view
    view.frame.value = 60
    timeline = np.asarray(view.figure.joints.points).copy()
    for name in ("early", "perch"):
        view.pose.value = name
        view._guarded(view.do_delete)
    assert view.pose.value == "(none)" and "Deleted pose perch" in view.status.content
    np.testing.assert_allclose(view.figure.joints.points, timeline, atol=2e-3)
    data = PoseLibrary(library).take_data("high_sit")
    assert not np.allclose(timeline, skeleton_fk(data.skeleton, data.motion().channels[39])
                           .positions - view._centre, atol=2e-2)


def test_clicks_and_boxes_pick_no_hidden_vertices(studio):
    """With another view shown in the 3D view, a click or a box there picks nothing of the
    Design view's control net, which is not drawn."""
    from viser import _messages

    from studio.headless import CAMERA, HeadlessTab

    tab = HeadlessTab(studio)
    try:
        view = tab.view
        origin = np.array(CAMERA["position"])

        def click(j: int) -> None:
            tab.send(_messages.ScenePointerMessage(
                "click", tuple(origin), tuple(view.design.vertices[j] - origin), ((0.5, 0.5),),
                None))

        studio.shown[tab.client_id].value = "Library"
        status = view.status_text
        click(5)
        tab.send(_messages.ScenePointerMessage("rect-select", None, None,
                                               ((0.0, 0.0), (1.0, 1.0)), "shift"))
        time.sleep(0.5)
        assert view.selection == [] and view.status_text == status
        studio.shown[tab.client_id].value = "Design"
        click(5)
        _wait(lambda: view.selection == [5], 10, "the click to pick a vertex")
    finally:
        tab.close()


def test_two_tabs_joining_one_new_session_at_once_share_it(studio, monkeypatch):
    import threading

    from studio import design_view
    from studio.headless import HeadlessTab

    class Slow(design_view.Session):  # a session made slowly: both tabs make one at once
        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            time.sleep(0.3)

    tabs = [HeadlessTab(studio), HeadlessTab(studio)]
    try:
        monkeypatch.setattr(design_view, "Session", Slow)
        views = [tab.view for tab in tabs]
        for view in views:
            view.join_name.value = "at once"
        joins = [threading.Thread(target=lambda v=view: v._guarded(v._join)) for view in views]
        for join in joins:
            join.start()
        for join in joins:
            join.join(10)
        assert views[0].session is views[1].session is studio.context.designs["at once"]
        assert len(views[0].session.views) == 2
    finally:
        for tab in tabs:
            tab.close()
