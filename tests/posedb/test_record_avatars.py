"""`capture record` from a stream carrying several avatars (several people in suits, one frame
per avatar per sample, interleaved): each avatar becomes its own take, or `--avatar` keeps one,
and an avatar that never came is an error naming those that did, with nothing written.

The stream is the independent sender's (`tests/capture/test_stream_independent_sender`), and
the raw captures used as `file:` sources are written here from the format's description in
`capture.rawcapture`."""

import json
import struct
import subprocess
import sys

import numpy as np
import pytest

from posedb.library import PoseLibrary
from posedb.record import journal_dir, record

from tests.capture.test_stream_independent_sender import (SKELETON, binary_frame, payloads,
                                                          serve_tcp, string_frame)

NAMES = ("Avatar00", "Avatar01")


def interleaved(n=10, start=100, seed=0):
    sent = {a: payloads(n, 354, seed=seed + a) for a in (0, 1)}
    pieces = [binary_frame(sent[a][k], start + k, avatar=a, name=NAMES[a])
              for k in range(n) for a in (0, 1)]
    return pieces, sent


def raw_file(path, pieces, period=1 / 60, per_period=2):
    """A raw capture: magic, u32 header length, JSON header, then records (u8 kind, f64 t,
    u32 length, bytes); each piece one data record, `per_period` of them per period."""
    header = json.dumps({"source": "test", "transport": "stream",
                         "time_origin": 1.7e9}).encode()
    out = b"SITRAW\x00\x01" + struct.pack("<I", len(header)) + header
    for k, piece in enumerate(pieces):
        out += struct.pack("<BdI", 0, (k // per_period) * period, len(piece)) + piece
    path.write_bytes(out)
    return f"file:{path}"


def test_each_avatar_becomes_its_own_take(tmp_path):
    pieces, sent = interleaved()
    db = tmp_path / "poses.h5"
    s = record(raw_file(tmp_path / "two.raw", pieces), db, "bench", SKELETON, lock_timeout=5)
    assert (s["frames"], s["restarts"], s["dropped"]) == (20, 0, 0), s
    assert [(a["name"], a["frames"], a["take"]) for a in s["avatars"]] == [
        ("Avatar00", 10, "bench-Avatar00"), ("Avatar01", 10, "bench-Avatar01")]
    assert [t["name"] for t in s["takes"]] == ["bench-Avatar00", "bench-Avatar01"]
    lib = PoseLibrary(db)
    assert sorted(t.name for t in lib.takes()) == ["bench-Avatar00", "bench-Avatar01"]
    for a in (0, 1):
        data = lib.take_data(f"bench-{NAMES[a]}")
        np.testing.assert_array_equal(data.frame_indices, np.arange(100, 110))
        assert lib.take(f"bench-{NAMES[a]}").frame_time == pytest.approx(1 / 60)
        assert f"avatar {NAMES[a]} (index {a})" in lib.take(f"bench-{NAMES[a]}").notes
    assert not list(journal_dir(db).glob("*.raw"))


@pytest.mark.parametrize("avatar", ["Avatar01", "1"])
def test_avatar_keeps_only_that_one(tmp_path, avatar):
    pieces, sent = interleaved()
    db = tmp_path / "poses.h5"
    s = record(raw_file(tmp_path / "two.raw", pieces), db, "alice", SKELETON, avatar=avatar,
               lock_timeout=5)
    assert s["frames"] == 10 and s["take"]["name"] == "alice", s
    assert [(a["name"], a["frames"], a["kept"]) for a in s["avatars"]] == [
        ("Avatar00", 10, False), ("Avatar01", 10, True)]
    lib = PoseLibrary(db)
    assert [t.name for t in lib.takes()] == ["alice"]
    data = lib.take_data("alice")
    assert data.channels.shape[0] == 10
    np.testing.assert_array_equal(data.frame_indices, np.arange(100, 110))


def test_frames_limit_counts_the_kept_avatar(tmp_path):
    pieces, _ = interleaved()
    db = tmp_path / "poses.h5"
    s = record(raw_file(tmp_path / "two.raw", pieces), db, "alice", SKELETON,
               avatar="Avatar00", frames=4, lock_timeout=5)
    assert s["frames"] == 4 and s["take"]["frames"] == 4, s


def test_an_avatar_that_never_came_is_an_error_and_nothing_is_written(tmp_path):
    from capture.avatars import AvatarNotSeenError

    pieces, _ = interleaved(n=3)
    db = tmp_path / "poses.h5"
    PoseLibrary(db, create=True)
    with pytest.raises(AvatarNotSeenError, match=r"No frame of avatar 'Bob'.*Avatar00 "
                                                 r"\(index 0, 3 frames\), Avatar01 \(index 1, "
                                                 r"3 frames\).*--avatar"):
        record(raw_file(tmp_path / "two.raw", pieces), db, "bob", SKELETON, avatar="Bob",
               lock_timeout=5)
    assert PoseLibrary(db).takes() == []
    assert not list(journal_dir(db).glob("*"))


def test_one_avatar_keeps_the_take_name(tmp_path):
    sent = payloads(6, 354, seed=3)
    pieces = [binary_frame(v, k, avatar=1, name="Avatar01") for k, v in enumerate(sent)]
    s = record(raw_file(tmp_path / "one.raw", pieces, per_period=1),
               tmp_path / "poses.h5", "solo", SKELETON, lock_timeout=5)
    assert [t["name"] for t in s["takes"]] == ["solo"] and s["take"]["frames"] == 6, s


def test_string_frames_of_two_avatars_over_tcp_become_two_takes(tmp_path):
    sent = {a: payloads(8, 354, seed=20 + a) for a in (0, 1)}
    pieces = [b"".join(string_frame(sent[a][k], avatar=a, name=NAMES[a]) for a in (0, 1))
              for k in range(8)]
    port = serve_tcp(pieces + [0.2])
    db = tmp_path / "poses.h5"
    s = record(f"tcp://127.0.0.1:{port}", db, "pair", SKELETON, duration=0.7, lock_timeout=5)
    assert [(a["name"], a["frames"]) for a in s["avatars"]] == [("Avatar00", 8),
                                                                 ("Avatar01", 8)], s
    lib = PoseLibrary(db)
    for a in (0, 1):
        np.testing.assert_allclose(lib.take_data(f"pair-{NAMES[a]}").channels[:, :6],
                                   sent[a][:, :6], rtol=1e-6)


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "studio.cli", *args], capture_output=True,
                          text=True, timeout=30)


def test_cli_record_refuses_an_unseen_avatar_in_json_and_help_says_how(tmp_path):
    pieces, _ = interleaved(n=3)
    db = tmp_path / "poses.h5"
    run = _cli("capture", "record", raw_file(tmp_path / "two.raw", pieces), "--db", str(db),
               "--take", "t", "--skeleton", SKELETON, "--avatar", "Avatar09", "--json")
    assert run.returncode == 2, run.stderr
    out = json.loads(run.stdout)
    assert "Avatar09" in out["error"] and "Avatar00" in out["error"]
    assert [(a["name"], a["frames"]) for a in out["avatars"]] == [("Avatar00", 3),
                                                                  ("Avatar01", 3)]
    assert "Avatar00 (index 0, 3 frames)" in run.stderr
    assert not db.exists() and not journal_dir(db).exists()  # the command made them: gone
    help_text = _cli("capture", "record", "--help").stdout
    assert "--avatar" in help_text and "own take" in help_text


def test_recover_turns_an_interrupted_two_avatar_journal_into_two_takes(tmp_path):
    import time

    from capture.rawcapture import DATA
    from posedb.record import TakeRecorder, recover

    pieces, _ = interleaved(n=5)
    db = tmp_path / "poses.h5"
    recorder = TakeRecorder(db, "pair", SKELETON, "tcp://test", lock_timeout=5)
    t0 = time.time()
    for k, piece in enumerate(pieces):
        recorder.writer.write(DATA, t0 + (k // 2) / 60, piece)
    recorder.abandon()  # as a killed recorder leaves it
    rows = recover(db, lock_timeout=5)
    assert [(r["takes"], r["frames"]) for r in rows] == [(["pair-Avatar00", "pair-Avatar01"],
                                                          10)], rows
    assert "one take per avatar" in rows[0]["status"]
    assert sorted(t.name for t in PoseLibrary(db).takes()) == ["pair-Avatar00", "pair-Avatar01"]


def test_cli_record_names_each_avatar_and_its_take(tmp_path):
    pieces, _ = interleaved(n=4)
    db = tmp_path / "poses.h5"
    run = _cli("capture", "record", raw_file(tmp_path / "two.raw", pieces), "--db", str(db),
               "--take", "sofa", "--skeleton", SKELETON)
    assert run.returncode == 0, run.stderr
    assert "recorded 2 avatars, each into a take of its own" in run.stdout
    assert "Avatar00 (index 0): 4 frames, 0 dropped  -> take sofa-Avatar00" in run.stdout
    assert "Avatar01 (index 1): 4 frames, 0 dropped  -> take sofa-Avatar01" in run.stdout


def test_derived_take_names_the_library_refuses_fall_back_to_the_avatars_index(tmp_path):
    """A take name of 195 characters with two avatars (`<take>-Avatar00` is over 200), or a
    take `take` with an avatar named `00002` (`take-00002` is an id's form): the recording is
    stored (it failed at the end, and `db recover` failed the same way every time)."""
    pieces, _ = interleaved()
    db = tmp_path / "poses.h5"
    s = record(raw_file(tmp_path / "long.raw", pieces), db, "x" * 195, SKELETON,
               lock_timeout=5)
    names = [t["name"] for t in s["takes"]]
    assert names == ["x" * 192 + "-avatar0", "x" * 192 + "-avatar1"], names
    sent = {a: payloads(3, 354, seed=a) for a in (0, 1)}
    odd = [binary_frame(sent[a][k], 100 + k, avatar=a, name=("00002", "Avatar01")[a])
           for k in range(3) for a in (0, 1)]
    s = record(raw_file(tmp_path / "odd.raw", odd), db, "take", SKELETON, lock_timeout=5)
    assert [t["name"] for t in s["takes"]] == ["take-avatar0", "take-Avatar01"]
    assert not list(journal_dir(db).glob("*.raw"))


def test_an_avatar_chosen_by_index_is_one_avatar_even_beside_one_named_so():
    """`--avatar 1` with avatar 0 named "1" and avatar 1 named Avatar01: digits are an index,
    so only avatar 1 is kept (both were, and mixed into one count)."""
    from capture.avatars import AvatarKey, avatar_selector

    chosen = avatar_selector("1")
    assert [chosen.matches(AvatarKey(0, "1")), chosen.matches(AvatarKey(1, "Avatar01"))] == \
        [False, True]
    assert avatar_selector("Avatar01").matches(AvatarKey(1, "Avatar01"))


def _killed_recording(tmp_path, *args, n=5):
    """Records a stream of two avatars (`n` frames each, then the sender stays connected and
    silent) with `capture record ... args` in a process of its own, killed with SIGKILL once
    its journal holds every byte sent. Returns (library, journal, frames sent per avatar)."""
    import signal
    import time

    from capture.rawcapture import read_raw_capture

    pieces, sent = interleaved(n=n)
    port = serve_tcp(pieces + [30.0])
    db = tmp_path / "poses.h5"
    recorder = subprocess.Popen(
        [sys.executable, "-m", "studio.cli", "capture", "record", f"tcp://127.0.0.1:{port}",
         "--db", str(db), "--take", "t", "--skeleton", SKELETON, "--duration", "60", *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline, got = time.monotonic() + 20, 0
        while got < sum(map(len, pieces)) and time.monotonic() < deadline:
            time.sleep(0.05)
            journals = list(journal_dir(db).glob("*.raw")) if journal_dir(db).is_dir() else []
            if journals:
                got = sum(map(len, read_raw_capture(journals[0]).data_chunks()))
        assert got == sum(map(len, pieces)), "the recorder never received the stream"
    finally:
        recorder.send_signal(signal.SIGKILL)
        recorder.wait()
    return db, journals[0], sent


def test_a_killed_recording_of_an_avatar_that_came_is_recovered_as_its_recorder_would(
        tmp_path):
    from posedb.record import recover

    db, journal, sent = _killed_recording(tmp_path, "--avatar", "Avatar01")
    rows = recover(db, lock_timeout=5)
    assert [(r["status"], r["takes"], r["frames"]) for r in rows] == [("recovered", ["t"], 5)]
    lib = PoseLibrary(db)
    assert [t.name for t in lib.takes()] == ["t"]
    data = lib.take_data("t")
    np.testing.assert_array_equal(data.frame_indices, np.arange(100, 105))
    np.testing.assert_allclose(data.channels[:, :6], sent[1][:, :6], rtol=1e-6)
    assert "avatar Avatar01 (index 1)" in lib.take("t").notes
    assert not journal.exists()


def test_a_killed_recording_of_an_avatar_that_never_came_is_refused_and_kept_for_a_choice(
        tmp_path):
    """What its recorder would have said (the avatars that came, with their frames), nothing
    stored, the journal kept (no one saw the refusal when it was made) with the command that
    stores it; `db recover` once told to pass --avatar, which it did not take, and refused
    the journal at every run."""
    from posedb.record import recover

    db, journal, sent = _killed_recording(tmp_path, "--avatar", "Bob")
    for _ in range(2):  # refused again, never half-stored
        run = _cli("db", "recover", "--db", str(db), "--json")
        assert run.returncode == 1, run.stderr
        [row] = json.loads(run.stdout)
        assert row["status"].startswith("failed: No frame of avatar 'Bob' arrived; the stream "
                                        "carried Avatar00 (index 0, 5 frames), Avatar01 "
                                        "(index 1, 5 frames)"), row
        assert f"--journal {journal}` with --avatar NAME_OR_INDEX" in row["status"]
        assert "--every-avatar" in row["status"]
        assert [(a["name"], a["frames"]) for a in row["avatars"]] == [("Avatar00", 5),
                                                                      ("Avatar01", 5)]
        assert journal.exists() and PoseLibrary(db).takes() == []
    text = _cli("db", "recover", "--db", str(db))
    assert text.returncode == 1 and "Avatar00 (index 0, 5 frames)" in text.stdout
    # a choice of avatar applies to one journal
    run = _cli("db", "recover", "--db", str(db), "--avatar", "Avatar01")
    assert run.returncode == 2 and "--journal" in run.stderr, run.stderr
    assert journal.exists()
    # another avatar that never came is refused the same way
    [row] = recover(db, journal=journal, avatar="Carol", lock_timeout=5)
    assert row["status"].startswith("failed: No frame of avatar 'Carol'") and journal.exists()
    [row] = recover(db, journal=journal, avatar="1", lock_timeout=5)
    assert (row["status"], row["takes"], row["frames"]) == ("recovered", ["t"], 5), row
    lib = PoseLibrary(db)
    data = lib.take_data("t")
    np.testing.assert_array_equal(data.frame_indices, np.arange(100, 105))
    np.testing.assert_allclose(data.channels[:, :6], sent[1][:, :6], rtol=1e-6)
    assert "recorded with --avatar 'Bob', of which no frame came" in lib.take("t").notes
    assert not journal.exists() and recover(db, lock_timeout=5) == []


def test_recover_keeps_every_avatar_of_a_journal_when_told(tmp_path):
    import time

    from capture.rawcapture import DATA
    from posedb.record import TakeRecorder, recover

    pieces, _ = interleaved(n=4)
    db = tmp_path / "poses.h5"
    recorder = TakeRecorder(db, "pair", SKELETON, "tcp://test", lock_timeout=5, avatar="Bob")
    t0 = time.time()
    for k, piece in enumerate(pieces):
        recorder.writer.write(DATA, t0 + (k // 2) / 60, piece)
    recorder.abandon()  # as a killed recorder leaves it
    with pytest.raises(ValueError, match=r"Expected a journal of an interrupted recording"):
        recover(db, journal=tmp_path / "other.raw", avatar=None, lock_timeout=5)
    with pytest.raises(ValueError, match=r"Expected the journal whose avatar to choose"):
        recover(db, avatar=None, lock_timeout=5)
    assert recorder.journal.exists()
    run = _cli("db", "recover", "--db", str(db), "--journal", str(recorder.journal),
               "--every-avatar", "--json")
    assert run.returncode == 0, run.stderr
    [row] = json.loads(run.stdout)
    assert (row["takes"], row["frames"]) == (["pair-Avatar00", "pair-Avatar01"], 8), row
    assert not recorder.journal.exists()
