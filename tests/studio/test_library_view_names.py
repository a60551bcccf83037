"""The Library view chooses a pose it named by the name the library stored (stripped and
composed, NFC), not by the text typed: a decomposed "café" is listed and chosen as the one
pose it became. Its pictures are those of the library on disk, even one made anew at the same
path (whose ids start again)."""

from __future__ import annotations

import contextlib
import io
import unicodedata

from posedb import PoseLibrary
from studio.cli import main
from studio.context import StudioContext
from tests.studio.test_record_library_views import _server, _stop, high_sit_library

DECOMPOSED = unicodedata.normalize("NFD", "café")
COMPOSED = unicodedata.normalize("NFC", "café")


def test_a_pose_renamed_or_saved_under_a_decomposed_name_is_chosen_as_stored(tmp_path):
    from studio.library_view import LibraryView

    library = high_sit_library(tmp_path / "poses.h5")
    server = _server()
    context = StudioContext(db=str(library), out=tmp_path, limit=1 << 20)
    view = LibraryView(server, server.gui.add_tab_group().add_tab("Library"), context)
    try:
        view.pose.value = "early"
        view.rename_to.value = f" {DECOMPOSED} "
        view._guarded(view.do_rename)
        assert view.pose.options == (COMPOSED,)
        assert view.pose.value == COMPOSED
        assert f"Renamed early to **{COMPOSED}**" in view.status.content
        view._guarded(lambda: view.load_take("high_sit"))
        view.frame.value = 20
        view.new_pose.value = DECOMPOSED + "2"
        view._guarded(view.do_save_frame)
        assert view.pose.value == COMPOSED + "2" in view.pose.options
        assert f"Added pose **{COMPOSED}2** at frame 20" in view.status.content
    finally:
        view.close()
        _stop(server)
    assert [p.name for p in PoseLibrary(library).poses()] == [COMPOSED, COMPOSED + "2"]


def test_a_library_made_anew_at_the_same_path_shows_its_own_pictures(tmp_path):
    """Ids start again in a new library: a picture cached for pose-000001 or take-00001 of the
    file that was there before is not shown for the new one's."""
    from capture.recordings import resolve_path
    from studio.library_view import LibraryView

    path = tmp_path / "poses.h5"
    high_sit_library(path, poses=((10, "early", ["test"]),))
    server = _server()
    context = StudioContext(db=str(path), out=tmp_path, limit=1 << 20)
    view = LibraryView(server, server.gui.add_tab_group().add_tab("Library"), context)
    try:
        before = (view.pose_gallery.content, view.take_gallery.content)
        path.unlink()
        # another recording of as many frames, with a pose at the same frame
        other = PoseLibrary(tmp_path / "other.h5", create=True)
        other.import_bvh(resolve_path("bundled:cmu_75_17_medium_sit.bvh"), name="medium")
        piece = tmp_path / "piece.bvh"
        with contextlib.redirect_stdout(io.StringIO()):
            assert main(["db", "export", "medium", "--db", str(tmp_path / "other.h5"),
                         "--out", str(piece), "--start", "150", "--end", "226"]) == 0
        lib = PoseLibrary(path, create=True)
        take = lib.import_bvh(piece, name="seated")
        lib.add_pose(take.id, 10, "low")
        assert take.frames == 77
        assert (take.id, lib.pose("low").id) == ("take-00001", "pose-000001")
        view._guarded(view.do_refresh)
        after = (view.pose_gallery.content, view.take_gallery.content)
    finally:
        view.close()
        _stop(server)

    def picture(content):
        return content.split('base64,')[1].split('"')[0]

    assert picture(after[0]) != picture(before[0])
    assert picture(after[1]) != picture(before[1])
