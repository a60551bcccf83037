"""Live recording: a recorder killed with SIGKILL loses at most a second, and the library stays
readable by other processes throughout."""

import json
import re
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from capture import read_bvh
from capture.replay import Replay, ReplayThread, TcpServerSink
from posedb.library import PoseLibrary
from posedb.record import journal_dir, record, recordings, recover

from tests.conftest import recording

AXIS = "axis_neuron_standing_yxz.bvh"


class _ClockedSink(TcpServerSink):
    """Remembers when each frame went out to a connected client."""

    def __init__(self):
        super().__init__("127.0.0.1", 0)
        self.sent = []  # (monotonic time, frame index)

    def send(self, data):
        super().send(data)
        if self.clients:
            self.sent.append((time.monotonic(), int.from_bytes(data[46:50], "little")))


def _cli(*args, **kw):
    return subprocess.run([sys.executable, "-m", "solver.cli", *args], capture_output=True,
                          text=True, timeout=60, **kw)


@pytest.mark.slow
def test_killed_recorder_loses_at_most_a_second_and_readers_carry_on(tmp_path):
    db = tmp_path / "poses.h5"
    lib = PoseLibrary(db, create=True)
    lib.import_bvh(recording("cmu_75_18_high_sit.bvh"))
    sink = _ClockedSink()
    replay = ReplayThread(Replay.from_bvh(recording(AXIS)), sink, rate=1.0, loop=True,
                          wait_for_client=True).start()
    recorder = subprocess.Popen(
        [sys.executable, "-m", "solver.cli", "capture", "record", f"tcp://127.0.0.1:{sink.port}",
         "--db", str(db), "--take", "live", "--skeleton", str(recording(AXIS)),
         "--duration", "120"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 15
        while len(sink.sent) < 300 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert len(sink.sent) >= 300, "the recorder never connected"
        # another process lists and reads the library while the recording runs
        listed = _cli("db", "list", "--db", str(db), "--json")
        assert listed.returncode == 0, listed.stderr
        rows = json.loads(listed.stdout)
        assert {"cmu_75_18_high_sit", "live"} <= {r["name"] for r in rows}
        assert [r["state"] for r in rows if r["kind"] == "recording"] == ["recording"]
        out = tmp_path / "read_while_recording.bvh"
        exported = _cli("db", "export", "cmu_75_18_high_sit", "--db", str(db), "--out", str(out))
        assert exported.returncode == 0, exported.stderr
        assert read_bvh(out).motion.num_frames == 77
        time.sleep(1.5)
        t_kill = time.monotonic()
        recorder.send_signal(signal.SIGKILL)
        recorder.wait()
    finally:
        replay.stop()
    before_kill = [idx for t, idx in sink.sent if t < t_kill]
    must_have = {idx for t, idx in sink.sent if t < t_kill - 1.0}
    # the library is readable at once, with the interrupted recording waiting
    lib = PoseLibrary(db)
    assert [t.name for t in lib.takes()] == ["cmu_75_18_high_sit"]
    assert [r.running for r in recordings(db)] == [False]
    result = recover(db)
    assert [r["status"] for r in result] == ["recovered"]
    lib = PoseLibrary(db)
    take = lib.take("live")
    data = lib.take_data(take.id)
    got = set(data.frame_indices.tolist())
    assert must_have <= got, len(must_have - got)
    assert got <= set(before_kill) | {idx for _, idx in sink.sent}
    assert len(got) >= len(before_kill) - 125  # at most one second (125 fps) lost
    assert take.frame_time == 1 / 125
    # the frames are the recording's, in order
    axis = read_bvh(recording(AXIS), unit=None)
    n = axis.motion.num_frames
    want = axis.motion.channels[data.frame_indices % n].astype(np.float32)
    np.testing.assert_array_equal(data.channels, want)
    assert not list(journal_dir(db).glob("*.raw"))


def test_record_in_process_from_a_raw_capture(tmp_path):
    from tests.capture.test_stream_fixtures import STREAMS

    db = tmp_path / "poses.h5"
    events = []
    summary = record(f"file:{STREAMS / 'skipped_indices.raw'}", db, "gappy",
                     str(recording("cmu_75_18_high_sit.bvh")), tags=["test"],
                     on_event=events.append)
    assert summary["frames"] == 60 and summary["dropped"] == 8
    lib = PoseLibrary(db)
    take = lib.take("gappy")
    assert take.frames == 60 and take.tags == ("test",) and take.kind == "stream"
    assert "8 dropped" in take.notes
    indices = lib.take_data("gappy").frame_indices
    assert indices[19] == 19 and indices[20] == 21  # the gap is kept, not filled
    # its start as an imported take's is written (the capture's header has microseconds)
    imported = lib.import_bvh(recording("cmu_75_18_high_sit.bvh"), name="imported")
    for t in (take, imported):
        assert re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\dZ", t.recorded_at), t.recorded_at


def test_a_take_recorded_for_n_frames_holds_the_n_frames_it_says(tmp_path):
    """The journal holds every byte received, frames past the last one read among them: the
    take holds the frames the recording counted and says it recorded, no more."""
    from tests.capture.test_stream_fixtures import STREAMS

    db = tmp_path / "poses.h5"
    summary = record(f"file:{STREAMS / 'skipped_indices.raw'}", db, "ten",
                     str(recording("cmu_75_18_high_sit.bvh")), frames=10)
    assert summary["frames"] == 10 and summary["take"]["frames"] == 10
    assert PoseLibrary(db).take("ten").frames == 10


def test_record_refuses_a_taken_name_before_listening(tmp_path):
    import pytest

    from posedb.library import DuplicateNameError

    db = tmp_path / "poses.h5"
    PoseLibrary(db, create=True).import_bvh(recording("cmu_75_18_high_sit.bvh"), name="busy")
    with pytest.raises(DuplicateNameError, match="take named 'busy' already exists"):
        record("tcp://127.0.0.1:9", db, "busy", str(recording("cmu_75_18_high_sit.bvh")))
    assert not journal_dir(db).exists() or not list(journal_dir(db).iterdir())
