"""Poses marked while a take records: written to the journal as they are made, stored with the
take in its one commit, and kept by `recover` when the recorder dies before that commit."""

import json

import numpy as np
import pytest

from capture.rawcapture import raw_marks
from capture.sources import RawFileTransport, Source
from posedb.library import DuplicateNameError, PoseLibrary
from posedb.record import TakeRecorder, journal_dir, marked_frame, recordings, recover
from posedb.tags import TagError

from tests.capture.test_stream_fixtures import STREAMS
from tests.conftest import recording

CMU = "cmu_75_18_high_sit.bvh"
CAPTURE = STREAMS / "skipped_indices.raw"  # 60 CMU frames, sender indices with a gap of 8


def _play(recorder: TakeRecorder, marks: dict[int, dict]) -> list:
    """Feeds the capture through a source into the recorder's journal, marking the last frame
    of a read when it is the k-th frame received, as the studio marks the frame on screen."""
    source = Source(RawFileTransport(CAPTURE), recorder.layout, raw=recorder.writer)
    got = []
    while not source.exhausted:
        for frame in source.read(0.0):
            got.append(frame)
            if len(got) - 1 in marks:
                recorder.mark(frame.received_at, **marks[len(got) - 1])
        recorder.tick()
    source.raw = None  # the recorder closes its journal itself
    source.close()
    return got


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "poses.h5"
    PoseLibrary(path, create=True).import_bvh(recording(CMU), name="earlier", tags=["old"])
    return path


def test_marked_poses_are_stored_with_the_take_in_one_commit(db):
    rec = TakeRecorder(db, "live", str(recording(CMU)), f"file:{CAPTURE}", tags=["session"])
    frames = _play(rec, {10: dict(name="perch", tags=["sit", "high"], supports="chair"),
                         40: dict(tags=["lean"], supports=["pelvis", "feet"])})
    assert PoseLibrary(db).poses() == []  # nothing in the library before the take is stored
    take = rec.finish()
    lib = PoseLibrary(db)
    assert take.frames == len(frames) == 60
    poses = {p.name: p for p in lib.find_poses(take="live")}
    assert set(poses) == {"perch", "live-f00040"}  # an unnamed mark is named by its frame
    perch = poses["perch"]
    assert perch.frame == 10 and perch.tags == ("high", "session", "sit")
    assert perch.supports == ("upper_back", "lower_back", "pelvis", "thighs")
    assert poses["live-f00040"].supports == ("pelvis", "feet")
    assert lib.search_poses("lean and session") == ["live-f00040"]
    # each pose's rotations are the take's at its frame (the take is an independent decode)
    data = lib.take_data("live")
    _, _, rot, root = lib.pose_data("perch")
    np.testing.assert_array_equal(rot, data.local_rotations[10])
    np.testing.assert_array_equal(root, data.root_positions[10])
    # the frame the source showed when marking is the frame stored: its sender index agrees
    assert data.frame_indices[10] == frames[10].frame_index
    assert not list(journal_dir(db).glob("*.raw"))


def test_marks_survive_a_recorder_that_dies_before_its_commit(db):
    rec = TakeRecorder(db, "crashed", str(recording(CMU)), f"file:{CAPTURE}")
    _play(rec, {5: dict(name="kept", tags=["sit"])})
    rec.abandon()  # what a killed process leaves: the journal written, its lock released
    assert [m["name"] for _, m in raw_marks(rec.journal)] == ["kept"]
    assert [r.running for r in recordings(db)] == [False]
    assert [r["status"] for r in recover(db)] == ["recovered"]
    lib = PoseLibrary(db)
    kept = lib.pose("kept")
    assert kept.frame == 5 and kept.tags == ("sit",)
    assert lib.take(kept.take).name == "crashed"


def test_bad_marks_are_refused_and_nothing_is_written(db):
    lib = PoseLibrary(db)
    lib.add_pose("earlier", 3, "taken")
    rec = TakeRecorder(db, "live", str(recording(CMU)), f"file:{CAPTURE}")
    try:
        with pytest.raises(TagError, match="tag"):
            rec.mark(1.0, tags=["not a tag"])
        with pytest.raises(DuplicateNameError, match="'taken' already exists"):
            rec.mark(1.0, name="taken")
        with pytest.raises(ValueError, match="body region"):
            rec.mark(1.0, supports=["wings"])
        with pytest.raises(ValueError, match="receive time"):
            rec.mark(float("nan"))
        rec.mark(1.0, name="once")
        with pytest.raises(DuplicateNameError, match="marked already"):
            rec.mark(2.0, name="once")
        assert [m["name"] for _, m in raw_marks(rec.journal)] == ["once"]
    finally:
        rec.discard()
    assert not list(journal_dir(db).glob("*.raw"))


def test_a_name_taken_before_the_commit_gets_a_suffix_and_a_note(db):
    rec = TakeRecorder(db, "live", str(recording(CMU)), f"file:{CAPTURE}")
    _play(rec, {20: dict(name="perch")})
    PoseLibrary(db).add_pose("earlier", 3, "perch")  # someone else, meanwhile
    take = rec.finish()
    lib = PoseLibrary(db)
    assert lib.pose("perch-2").take == take.id and lib.pose("perch-2").frame == 20
    assert "'perch' is 'perch-2'" in lib.take("live").notes


def test_a_mark_names_the_last_frame_received_by_its_time():
    received = np.array([10.0, 10.0, 10.5, 11.0])  # two frames of one read share a time
    assert marked_frame(received, 10.0) == 1
    assert marked_frame(received, 10.7) == 2
    assert marked_frame(received, 9.0) == 0
    assert marked_frame(received, 99.0) == 3


def test_db_list_of_one_take_leaves_out_other_takes_recordings(db, capsys):
    """`db list --take T`: that take, its poses and its recording, not another's."""
    from studio.cli import main

    rec = TakeRecorder(db, "crashed", str(recording(CMU)), f"file:{CAPTURE}")
    _play(rec, {})
    rec.abandon()
    for take, kinds in (("earlier", ["take"]), ("crashed", ["recording"])):
        assert main(["db", "list", "--db", str(db), "--take", take, "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)
        assert [r["kind"] for r in rows] == kinds
