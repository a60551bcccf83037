"""Commands that are safe to run again, refused commands that write nothing, the JSON answers of
every `db` command, and a failed import that leaves a recording its library."""

import json

import h5py
import pytest

import posedb.cli as dbcli
from posedb.library import PoseLibrary
from posedb.record import TakeRecorder, journal_dir

from tests.capture.test_stream_fixtures import STREAMS
from tests.conftest import high_sit_library, recording
from tests.posedb.test_record_marks import _play

MEDIUM = "cmu_75_17_medium_sit"  # holds proposed at frames 10 (0.6 s) and 215 (1.8 s)
CMU = "cmu_75_18_high_sit.bvh"
CAPTURE = STREAMS / "skipped_indices.raw"  # 60 CMU frames


def _main(*args) -> int:
    from studio.cli import main

    return main([str(a) for a in args])


def _answer(capsys) -> dict | list:
    return json.loads(capsys.readouterr().out)


@pytest.fixture
def medium(tmp_path, capsys):
    path = tmp_path / "poses.h5"
    assert _main("db", "import", f"bundled:{MEDIUM}.bvh", "--db", path) == 0
    capsys.readouterr()
    return path


# -- `db suggest --accept` again ----------------------------------------------------------------


def test_accepting_the_holds_again_skips_those_accepted_and_adds_the_new(medium, capsys):
    # the first run (only the long hold) ...
    assert _main("db", "suggest", MEDIUM, "--accept", "--min-duration", "1", "--db",
                 medium, "--json") == 0
    (first,) = _answer(capsys)
    assert (first["frame"], first["name"]) == (215, f"{MEDIUM}-f00215")
    # ... and the second (both holds): the accepted one skipped and said so, the new one added
    assert _main("db", "suggest", MEDIUM, "--accept", "--tag", "sit", "--db", medium) == 0
    out = capsys.readouterr().out
    assert f"propose frame 10 -> pose {MEDIUM}-f00010 (tags: sit)" in out
    assert f"propose frame 215 -> already pose {MEDIUM}-f00215, skipped" in out
    assert first["added"] is True
    lib = PoseLibrary(medium)
    assert sorted((p.frame, p.name, p.tags) for p in lib.poses()) == [
        (10, f"{MEDIUM}-f00010", ("sit",)), (215, f"{MEDIUM}-f00215", ())]
    # an accepted pose renamed since is still the hold's: skipped under its new name, and a
    # run that adds nothing leaves the file as it was (no commit)
    assert _main("db", "pose", "rename", f"{MEDIUM}-f00215", "deep_sit", "--db", medium) == 0
    capsys.readouterr()
    before = medium.read_bytes()
    assert _main("db", "suggest", MEDIUM, "--accept", "--db", medium, "--json") == 0
    rows = _answer(capsys)
    assert [(r["frame"], r["name"], r["added"]) for r in rows] == [
        (10, f"{MEDIUM}-f00010", False), (215, "deep_sit", False)]
    lib = PoseLibrary(medium)
    assert [r["pose"] for r in rows] == [lib.pose(f"{MEDIUM}-f00010").id,
                                         lib.pose("deep_sit").id]
    assert rows[0]["tags"] == ["sit"]
    assert medium.read_bytes() == before and len(lib.poses()) == 2


def test_accepting_refuses_a_name_held_by_another_pose_and_writes_nothing(medium, capsys):
    """The name a hold would take is another frame's pose: the whole batch is refused, the
    hold before it (frame 10) not half-written."""
    PoseLibrary(medium).add_pose(MEDIUM, 3, f"{MEDIUM}-f00215")
    before = medium.read_bytes()
    assert _main("db", "suggest", MEDIUM, "--accept", "--db", medium, "--json") == 2
    assert "already exists" in _answer(capsys)["error"]
    assert medium.read_bytes() == before
    assert [p.frame for p in PoseLibrary(medium).poses()] == [3]


# -- `db check --json` --------------------------------------------------------------------------


def test_check_answers_its_exit_status_in_its_json(medium, capsys):
    assert _main("db", "check", "--db", medium, "--json") == 0
    assert _answer(capsys) | {"path": None} == {"path": None, "ok": True, "problems": [],
                                                 "exit_status": 0}
    with h5py.File(medium, "r+") as f:  # damage: a frame time no reader can divide by
        f["takes/take-00001"].attrs["frame_time"] = 0.0
    assert _main("db", "check", "--db", medium, "--json", "--quick") == 1
    answer = _answer(capsys)
    assert answer["ok"] is False and answer["exit_status"] == 1 and answer["problems"]


# -- --json on rename, delete and export --------------------------------------------------------


def test_rename_delete_and_export_answer_in_json_what_they_changed(tmp_path, capsys):
    path = high_sit_library(tmp_path / "poses.h5", poses=((39, "perch", ()), (10, "up", ())))
    db = ("--db", path, "--json")
    lib = PoseLibrary(path)
    perch, take = lib.pose("perch").id, lib.take("high_sit").id
    assert _main("db", "pose", "rename", perch, "Cafe\u0301", *db) == 0  # (given by its id)
    assert _answer(capsys) == {"kind": "pose", "id": perch, "name": "Caf\u00e9",
                               "old_name": "perch"}
    assert _main("db", "pose", "rename", "high_sit", "sit", *db) == 0  # (a take, found second)
    assert _answer(capsys) == {"kind": "take", "id": take, "name": "sit",
                               "old_name": "high_sit"}
    assert _main("db", "take", "rename", "sit", "high", *db) == 0
    assert _answer(capsys) == {"kind": "take", "id": take, "name": "high", "old_name": "sit"}
    out = tmp_path / "part.bvh"
    assert _main("db", "export", "high", "--out", out, "--start", 5, "--end", 9, *db) == 0
    assert _answer(capsys) == {"kind": "take", "id": take, "name": "high", "path": str(out),
                               "start": 5, "end": 9, "frames": 5}
    assert out.exists()
    assert _main("db", "pose", "delete", "Caf\u00e9", *db) == 0
    assert _answer(capsys) == {"kind": "pose", "id": perch, "name": "Caf\u00e9",
                               "deleted": True}
    assert _main("db", "take", "delete", "high", *db) == 0
    assert _answer(capsys) == {"kind": "take", "id": take, "name": "high", "deleted": True,
                               "poses_deleted": ["up"]}
    assert PoseLibrary(path).takes() == []
    # an error of theirs is JSON too, as every command's
    assert _main("db", "pose", "delete", "nosuch", *db) == 2
    assert _answer(capsys) == {"error": f"No pose 'nosuch' in {path}", "exit_status": 2}
    # and the human text is as before
    lib = PoseLibrary(high_sit_library(tmp_path / "text.h5"))
    assert _main("db", "pose", "rename", "perch", "seat", "--db", lib.path) == 0
    assert capsys.readouterr().out == "renamed perch to seat\n"


# -- a refused `capture record` writes nothing ---------------------------------------------------


@pytest.mark.parametrize("bad, said", [
    (("--take", "a/b"), "without '/'"),
    (("--notes", "n\udcffx"), "as UTF-8 text"),
    (("--tag", "a b"), "Expected a tag"),
    (("--skeleton", "bundled:nothing"), "No bundled recording 'nothing'"),
    (("--skeleton", str(STREAMS / "expected.json")), "HIERARCHY"),
    (("source", "bogus://x"), "Expected a source URL"),
])
def test_a_refused_recording_writes_nothing(tmp_path, capsys, bad, said):
    folder = tmp_path / "new"
    folder.mkdir()
    options = {"source": f"file:{CAPTURE}", "--take": "live",
               "--skeleton": str(recording(CMU)), "--notes": "", "--tag": "ok"}
    options[bad[0]] = bad[1]
    args = ["capture", "record", options.pop("source"), "--db", folder / "poses.h5"]
    for key, value in options.items():
        args += [key, value]
    assert _main(*args) == 2
    assert said in capsys.readouterr().err
    assert list(folder.iterdir()) == []  # no library, no lock file, no journal folder


@pytest.mark.parametrize("limit, said", [
    (dict(duration=-1.0), "duration in seconds > 0, got -1.0"),
    (dict(duration=float("nan")), "duration in seconds > 0, got nan"),
    (dict(frames=0), "whole number of frames >= 1, got 0"),
    (dict(frames=2.5), "whole number of frames >= 1, got 2.5"),
])
def test_a_recording_limit_that_cannot_end_it_as_meant_is_refused_writing_nothing(
        tmp_path, capsys, limit, said):
    """Before: `--duration -1` or `--frames 0` "recorded" nothing into a new empty library,
    and `--duration nan` recorded until the source ended."""
    from posedb.record import record
    from posedb.schema import LibraryError

    folder = tmp_path / "new"
    folder.mkdir()
    with pytest.raises(LibraryError, match=said):
        record(f"file:{CAPTURE}", folder / "poses.h5", "live", str(recording(CMU)), **limit)
    (option, value), = limit.items()
    with pytest.raises(SystemExit) as stop:  # (argparse refuses it, naming the option)
        _main("capture", "record", f"file:{CAPTURE}", "--db", folder / "poses.h5", "--take",
              "live", "--skeleton", recording(CMU), f"--{option}", value, "--json")
    assert stop.value.code == 2
    assert f"argument --{option}: expected" in _answer(capsys)["error"]
    assert list(folder.iterdir()) == []


# -- a failed import and a recording into the same new library -----------------------------------


def _empty_bvh(tmp_path):
    """A header-only file: an import of it fails after making the library it goes into."""
    empty = tmp_path / "empty.bvh"
    empty.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition "
                     "Zposition Zrotation Xrotation Yrotation\n End Site\n {\n  OFFSET 0 1 0\n }"
                     "\n}\nMOTION\nFrames: 0\nFrame Time: 0.01\n")
    return empty


def _finish_and_list(recorder: TakeRecorder, path) -> None:
    """Plays the capture into the recorder, stores the take, and reads it back."""
    assert len(_play(recorder, {})) == 60
    assert recorder.finish().frames == 60
    assert [t.name for t in PoseLibrary(path).takes()] == ["live"]
    assert not list(journal_dir(path).glob("*.raw"))


def test_a_failed_import_keeps_the_new_library_a_recording_started_into(tmp_path, capsys,
                                                                        monkeypatch):
    """Steps in order: the import makes the library and fails; a recording starts into it
    (the library empty, its journal beside it); the import's clean-up then finds the
    library empty, and must leave it to the recording."""
    path = tmp_path / "poses.h5"
    started = []
    drop = dbcli._drop_if_empty

    def a_recording_starts_first(db):
        started.append(TakeRecorder(db, "live", str(recording(CMU)), f"file:{CAPTURE}"))
        drop(db)

    monkeypatch.setattr(dbcli, "_drop_if_empty", a_recording_starts_first)
    assert _main("db", "import", "--db", path, _empty_bvh(tmp_path), "--unit", "cm") == 2
    assert "Expected at least one frame" in capsys.readouterr().err
    assert path.exists() and PoseLibrary(path).takes() == []
    _finish_and_list(started[0], path)


def test_a_recording_starting_as_a_failed_import_removes_the_library_makes_it_again(
        tmp_path, monkeypatch):
    """Steps in order: a failed import has made the library (empty); a recording opens it;
    the import's clean-up removes it, before the recording's journal exists; the recording
    then makes its journal, waits for the library's lock (the clean-up holds it while it
    looks and removes) and makes the library again."""
    path = tmp_path / "poses.h5"
    PoseLibrary(path, create=True)  # (as the failed import left it)
    check = TakeRecorder._check_free
    events = []

    def the_import_cleans_up_meanwhile(self, library):
        check(self, library)
        dbcli._drop_if_empty(str(library))
        assert not path.exists()  # (the clean-up did remove it)

    monkeypatch.setattr(TakeRecorder, "_check_free", the_import_cleans_up_meanwhile)
    recorder = TakeRecorder(path, "live", str(recording(CMU)), f"file:{CAPTURE}",
                            on_event=events.append)
    assert path.exists() and PoseLibrary(path).takes() == []
    assert any("made" in e and "again" in e for e in events), events
    _finish_and_list(recorder, path)


def test_a_failed_import_still_removes_the_empty_library_nothing_else_uses(tmp_path, capsys):
    path = tmp_path / "poses.h5"
    journal_dir(path).mkdir()  # (a folder of journals, none of them left: no recording)
    assert _main("db", "import", "--db", path, _empty_bvh(tmp_path), "--unit", "cm") == 2
    assert not path.exists()


def test_a_recording_starting_waits_for_the_clean_up_holding_the_lock_then_makes_the_library(
        tmp_path):
    """The same, ordered by the library's own lock: the clean-up holds it, having found the
    library empty and no journal; the recorder, its journal made, waits for the lock; the
    clean-up removes the library and lets go; the recorder makes the library again."""
    import os
    import threading
    import time

    from posedb.locking import try_exclusive

    path = tmp_path / "poses.h5"
    PoseLibrary(path, create=True)  # (as the failed import left it)
    cleanup = try_exclusive(path.resolve())
    assert cleanup is not None
    started = []
    thread = threading.Thread(target=lambda: started.append(
        TakeRecorder(path, "live", str(recording(CMU)), f"file:{CAPTURE}")))
    thread.start()
    try:
        deadline = time.monotonic() + 20
        while not list(journal_dir(path).glob("*.raw")) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert list(journal_dir(path).glob("*.raw")), "the recorder made no journal"
        os.unlink(path)  # what the clean-up found empty (before the journal) goes
    finally:
        cleanup.release()
    thread.join(20)
    assert started and path.exists()
    _finish_and_list(started[0], path)
