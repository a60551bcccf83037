"""What a recording derives and leaves behind: names it makes from a take's name stay within the
library's 200 characters, a journal `db recover` keeps for a choice of avatar is listed with
that choice, a `--frames` limit holds for a journal its recorder never stored, and a recording
stopped (Ctrl-C) says the frames it stored."""

import importlib
import json

import numpy as np
import pytest

from posedb.library import PoseLibrary
from posedb.record import TakeRecorder, journal_dir, record, recordings, recover
from posedb.suggest import suggest_poses

from tests.conftest import recording
from tests.posedb.test_record_avatars import SKELETON, interleaved, raw_file
from tests.posedb.test_record_marks import CAPTURE, CMU, _play

LIMIT = 200  # characters of a name (`posedb.library.checked_name`)


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "poses.h5"
    PoseLibrary(path, create=True).import_bvh(recording(CMU), name="earlier")
    return path


# -- 1. derived names ---------------------------------------------------------------------------


def test_names_a_recording_derives_from_a_take_name_of_the_limit_stay_within_it(db):
    """A take name of exactly 200 characters is valid; the take renamed `NAME-2` (its name
    taken while it recorded), a pose renamed so, and an unnamed mark's `TAKE-fNNNNN` are
    shortened before their suffix (the recording failed at its commit, and `db recover`
    failed the same way every time)."""
    take, pose = "t" * LIMIT, "p" * LIMIT
    rec = TakeRecorder(db, take, str(recording(CMU)), f"file:{CAPTURE}")
    _play(rec, {20: dict(name=pose), 40: {}})
    lib = PoseLibrary(db)
    lib.import_bvh(recording(CMU), name=take)  # both names taken meanwhile
    lib.add_pose("earlier", 3, pose)
    stored = rec.finish()
    assert stored.name == "t" * (LIMIT - 2) + "-2" and stored.frames == 60
    lib = PoseLibrary(db)
    poses = {p.name: p.frame for p in lib.find_poses(take=stored.id)}
    assert poses == {"p" * (LIMIT - 2) + "-2": 20, "t" * (LIMIT - 7) + "-f00040": 40}
    assert all(len(n) <= LIMIT for n in [t.name for t in lib.takes()] + list(poses))
    assert f"is {'p' * (LIMIT - 2) + '-2'!r} (the name was taken)" in lib.take(stored.id).notes
    assert not list(journal_dir(db).glob("*.raw"))


def test_suffixes_keep_names_shortened_to_the_limit_apart(db):
    """`NAME-2`... `NAME-9` taken too: `NAME-10`, its base shortened by one more character."""
    pose = "q" * LIMIT
    rec = TakeRecorder(db, "live", str(recording(CMU)), f"file:{CAPTURE}")
    _play(rec, {5: dict(name=pose)})
    with PoseLibrary(db).edit() as ed:  # taken meanwhile
        ed.add_pose("earlier", 1, pose)
        for k in range(2, 10):
            ed.add_pose("earlier", k, "q" * (LIMIT - 2) + f"-{k}")
    rec.finish()
    assert PoseLibrary(db).pose("q" * (LIMIT - 3) + "-10").frame == 5


def test_accepted_holds_of_a_take_named_to_the_limit_are_named_within_it(tmp_path):
    """`db suggest --accept` names a hold `TAKE-fNNNNN` (refused over 200 characters)."""
    take = "s" * LIMIT
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    lib.import_bvh(recording(CMU), name=take)
    rows = suggest_poses(lib, take, accept=True)
    assert [(r["name"], r["frame"], r["added"]) for r in rows] == [
        ("s" * (LIMIT - 7) + "-f00039", 39, True)]
    assert PoseLibrary(tmp_path / "poses.h5").pose(rows[0]["name"]).frame == 39


# -- 2. a journal kept for a choice of avatar ----------------------------------------------------


def _unseen_avatar_journal(db):
    """A killed recording of `--avatar Bob` from a stream of Avatar00 and Avatar01 (4 each)."""
    import time

    from capture.rawcapture import DATA

    pieces, _ = interleaved(n=4)
    recorder = TakeRecorder(db, "pair", SKELETON, "tcp://test", lock_timeout=5, avatar="Bob")
    t0 = time.time()
    for k, piece in enumerate(pieces):
        recorder.writer.write(DATA, t0 + (k // 2) / 60, piece)
    recorder.abandon()  # as a killed recorder leaves it
    return recorder.journal


def test_list_and_stats_say_what_recover_needs_for_a_journal_it_kept(db, capsys):
    """`db recover` refuses a journal whose --avatar never came and keeps it; `db list` and
    `db stats` said "interrupted (run `sitrelax db recover`)" of it, which refused it again."""
    from studio.cli import main

    journal = _unseen_avatar_journal(db)
    # before any recover, it is an interrupted recording like any other
    assert [r.as_dict()["state"] for r in recordings(db)] == [
        "interrupted (run `sitrelax db recover`)"]
    [refused] = recover(db, lock_timeout=5)
    assert refused["status"].startswith("failed: No frame of avatar 'Bob' arrived")
    assert main(["db", "list", "--db", str(db), "--kind", "recording", "--json"]) == 0
    [row] = json.loads(capsys.readouterr().out)
    assert main(["db", "stats", "--db", str(db), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["recordings"] == [row]
    # recover's own words: what it refused and the choice it needs, not recover again
    assert row["state"] == "waiting for a choice of avatar: " + \
        refused["status"][len("failed: "):]
    assert f"--journal {journal}` with --avatar NAME_OR_INDEX" in row["state"]
    assert "--every-avatar" in row["state"] and "interrupted" not in row["state"]
    assert [(a["name"], a["frames"]) for a in row["avatars"]] == [("Avatar00", 4),
                                                                  ("Avatar01", 4)]
    assert main(["db", "list", "--db", str(db), "--kind", "recording"]) == 0
    text = capsys.readouterr().out
    assert "--every-avatar" in text and "run `sitrelax db recover`)" not in text
    # stored with a choice: no recording left, nor anything of it beside the library
    [row] = recover(db, journal=journal, avatar=None, lock_timeout=5)
    assert row["takes"] == ["pair-Avatar00", "pair-Avatar01"], row
    assert recordings(db) == [] and list(journal_dir(db).iterdir()) == []


def test_a_journal_deleted_by_hand_leaves_no_note_of_it(db):
    """The advice says to delete the journal to drop the recording: recover's note beside it
    goes with it at the next look at the recordings, and nothing lists it."""
    journal = _unseen_avatar_journal(db)
    recover(db, lock_timeout=5)
    note = journal.with_name(journal.name + ".unseen-avatar.json")
    assert note.exists() and json.loads(note.read_text())["avatars"]
    journal.unlink()
    assert recordings(db) == [] and not note.exists()


# -- 3. a frame limit in the journal -------------------------------------------------------------


def _killed_at_the_commit(monkeypatch):
    """Makes `TakeRecorder.finish` leave the journal as a recorder killed before its commit."""
    monkeypatch.setattr(TakeRecorder, "finish", lambda self, frames=None: self.abandon())


@pytest.mark.parametrize("avatar", [None, "Avatar01"])
def test_recover_stores_a_killed_recording_of_n_frames_as_its_recorder_would(
        tmp_path, monkeypatch, avatar):
    """`capture record --frames 4` of two interleaved avatars stops at the frame that brings
    one to 4 (Avatar00 4, Avatar01 3; with --avatar Avatar01: its 4), though its journal holds
    every frame received (all 10 of each here); killed before its commit, `db recover`
    stored them all."""
    pieces, _ = interleaved(n=10)
    source = raw_file(tmp_path / "two.raw", pieces)
    live = record(source, tmp_path / "live.h5", "pair", SKELETON, frames=4, avatar=avatar,
                  lock_timeout=5)
    want = [(t["name"], t["frames"]) for t in live["takes"]]
    assert want == ([("pair-Avatar00", 4), ("pair-Avatar01", 3)] if avatar is None
                    else [("pair", 4)])
    db = tmp_path / "killed.h5"
    _killed_at_the_commit(monkeypatch)
    record(source, db, "pair", SKELETON, frames=4, avatar=avatar, lock_timeout=5)
    [journal] = journal_dir(db).glob("*.raw")
    from capture.rawcapture import read_raw_capture

    assert sum(map(len, read_raw_capture(journal).data_chunks())) == sum(map(len, pieces))
    [row] = recover(db, lock_timeout=5)
    assert row["takes"] == [name for name, _ in want], row
    lib, lib_live = PoseLibrary(db), PoseLibrary(tmp_path / "live.h5")
    for name, frames in want:
        assert lib.take(name).frames == frames
        np.testing.assert_array_equal(lib.take_data(name).frame_indices,
                                      lib_live.take_data(name).frame_indices)


def _journal_of_five_frames_each(tmp_path):
    """An abandoned recording of two interleaved avatars, 5 frames each: (library, journal)."""
    from capture.rawcapture import DATA

    pieces, _ = interleaved(n=5)
    db = tmp_path / "poses.h5"
    recorder = TakeRecorder(db, "old", SKELETON, "tcp://test", lock_timeout=5)
    for k, piece in enumerate(pieces):
        recorder.writer.write(DATA, 1.7e9 + (k // 2) / 60, piece)
    recorder.abandon()
    return db, recorder.journal


def _rewrite_take_header(journal, change):
    """Writes `journal` again with its header's `take` passed through `change`."""
    import struct

    from capture.rawcapture import MAGIC, read_raw_capture

    capture = read_raw_capture(journal)
    header = dict(capture.header)
    header["take"] = change(dict(header["take"]))
    data = json.dumps(header).encode()
    out = MAGIC + struct.pack("<I", len(data)) + data
    for r in capture.records:
        out += struct.pack("<BdI", r.kind, r.t, len(r.data)) + r.data
    journal.write_bytes(out)


def test_a_journal_written_before_frame_limits_is_recovered_whole(tmp_path):
    """No `frame_limit` in its header: every frame is kept, as before."""
    db, journal = _journal_of_five_frames_each(tmp_path)
    _rewrite_take_header(journal, lambda m: {k: v for k, v in m.items() if k != "frame_limit"})
    [row] = recover(db, lock_timeout=5)
    assert (row["takes"], row["frames"]) == (["old-Avatar00", "old-Avatar01"], 10), row


def test_a_journal_whose_frame_limit_is_no_whole_number_is_refused_and_kept(tmp_path):
    db, journal = _journal_of_five_frames_each(tmp_path)
    _rewrite_take_header(journal, lambda m: m | {"frame_limit": 2.5})
    [row] = recover(db, lock_timeout=5)
    assert row["status"].startswith("failed: ") and "frame limit" in row["status"], row
    assert "got 2.5" in row["status"] and journal.exists()
    assert PoseLibrary(db).takes() == []


# -- 4. the frames a stopped recording says ------------------------------------------------------


class _LiveStream:
    """A transport delivering one record per read, as a stream that goes on (never
    exhausted): the last binary frame read waits in the decoder for what follows it."""

    datagram = False
    exhausted = False
    name = "tcp://test"

    def __init__(self, pieces):
        import time

        from capture.rawcapture import DATA

        t0 = time.time()
        self._records = [(DATA, t0 + k / 120, piece) for k, piece in enumerate(pieces)]

    def poll(self, timeout):
        return [self._records.pop(0)] if self._records else []

    def close(self):
        pass


def test_a_recording_stopped_says_the_frames_it_stored(tmp_path, monkeypatch):
    """Ctrl-C (`stop()`, which `capture record`'s SIGINT handler sets) right after a progress
    report, with the last frame received still held by the decoder: the count reported live,
    the summary's and the take's agree, though the journal holds one more whole frame."""
    import types

    from capture import read_bvh
    from capture.sources import RawFileTransport, Source
    from capture.stream_layout import StreamLayout
    record_module = importlib.import_module("posedb.record")

    clock = {"t": 0.0}

    def monotonic():  # a second passes at each look at the clock: a report after every read
        clock["t"] += 1.0
        return clock["t"]

    import time

    monkeypatch.setattr(record_module, "time",
                        types.SimpleNamespace(monotonic=monotonic, time=time.time))
    pieces, _ = interleaved(n=10)
    monkeypatch.setattr(record_module, "open_transport", lambda url: _LiveStream(pieces))
    journals = []
    real_finish = TakeRecorder.finish

    def finish(self, frames=None):
        journals.append(self.journal.read_bytes())
        return real_finish(self, frames)

    monkeypatch.setattr(TakeRecorder, "finish", finish)
    reports = []
    db = tmp_path / "poses.h5"
    summary = record("tcp://test", db, "pair", SKELETON, avatar="Avatar00", lock_timeout=5,
                     on_progress=lambda s: reports.append(s["frames"]),
                     stop=lambda: len(reports) >= 7)  # 7 reads: Avatar00's 4th frame last
    stored = PoseLibrary(db).take("pair").frames
    assert reports[-1] == summary["frames"] == stored == 3, (reports, summary, stored)
    saved = tmp_path / "journal.raw"
    saved.write_bytes(journals[0])
    with Source(RawFileTransport(saved), StreamLayout(read_bvh(SKELETON).skeleton)) as src:
        whole = [f for f in src if f.avatar_name == "Avatar00"]
    assert len(whole) == stored + 1


def test_a_name_shortened_keeps_each_letter_with_its_marks():
    """Cut by code points, a letter could lose the mark that follows it and become another
    letter (a decomposed accent, a nukta): the cut moves before the letter instead."""
    import unicodedata

    from posedb.library import derived_name

    base = "e\u0301" * 100  # 200 code points: "é" decomposed, a hundred times
    name = derived_name(base, "-f00039")
    assert len(name) <= 200 and name.endswith("e\u0301-f00039")
    assert not unicodedata.combining(name[0])
    # a spacing mark (a Devanagari vowel sign, which NFC keeps apart) stays with its letter
    name = derived_name("a" * 197 + "\u0915\u093f" + "b", "-2")
    assert name == "a" * 197 + "-2"
    assert derived_name("\u0915" + "\u093f" * 210, "-2").endswith("-2")  # (all marks: cut)
