"""The studio's live stream when several avatars share it: each avatar's frames go to a take of
its own, or only the avatar chosen; the readout names every avatar with its frame count."""

import threading
import time

import numpy as np

from posedb import PoseLibrary
from studio.record import LiveStream, readout_text

from tests.capture.test_stream_independent_sender import (SKELETON, binary_frame, payloads,
                                                          serve_tcp)

NAMES = ("Avatar00", "Avatar01")


def _wait(predicate, seconds):
    end = time.monotonic() + seconds
    while not predicate() and time.monotonic() < end:
        time.sleep(0.02)


def _stream(n=10):
    """The frames of two avatars, sent once the take has started (`ready.set()`)."""
    sent = {a: payloads(n, 354, seed=30 + a) for a in (0, 1)}
    ready = threading.Event()
    return [ready] + [binary_frame(sent[a][k], k, avatar=a, name=NAMES[a])
                      for k in range(n) for a in (0, 1)] + [0.2], sent, ready


def test_live_stream_records_each_avatar_apart(tmp_path):
    pieces, sent, ready = _stream()
    stream = LiveStream(f"tcp://127.0.0.1:{serve_tcp(pieces)}", SKELETON)
    try:
        stream.start_take(str(tmp_path / "poses.h5"), "bench")
        ready.set()
        _wait(lambda: stream.frames_in_take >= 20, 3)
        text = readout_text(stream.summary(), stream)
        assert "Avatar00 (index 0): 10 frames" in text and "Avatar01 (index 1): 10" in text
        take = stream.stop_take()
    finally:
        stream.close()
    assert take.name == "bench-Avatar00"
    lib = PoseLibrary(tmp_path / "poses.h5")
    assert sorted(t.name for t in lib.takes()) == ["bench-Avatar00", "bench-Avatar01"]
    np.testing.assert_array_equal(lib.take_data("bench-Avatar01").frame_indices, np.arange(10))


def test_live_stream_keeps_the_chosen_avatar(tmp_path):
    pieces, sent, ready = _stream()
    stream = LiveStream(f"tcp://127.0.0.1:{serve_tcp(pieces)}", SKELETON, avatar="Avatar01")
    try:
        stream.start_take(str(tmp_path / "poses.h5"), "alice")
        ready.set()
        _wait(lambda: stream.frames_in_take >= 10 and stream.summary()["frames"] >= 10, 3)
        time.sleep(0.1)
        assert stream.frames_in_take == 10
        take = stream.stop_take()
    finally:
        stream.close()
    assert take.name == "alice" and take.frames == 10
    assert [t.name for t in PoseLibrary(tmp_path / "poses.h5").takes()] == ["alice"]


class _HeldBack:
    """A stream that goes on (never exhausted), one record per read: the last binary frame
    read waits in the decoder for what follows it, while its bytes are in the take's journal
    (its receive times lie ahead of the clock, so no pause confirms it meanwhile)."""

    datagram = False
    exhausted = False
    name = "tcp://test"

    def __init__(self, pieces):
        from capture.rawcapture import DATA

        self._records = [(DATA, time.time() + 600 + k / 120, piece) for k, piece in enumerate(pieces)]
        self.started = False

    def poll(self, timeout):
        if not self.started or not self._records:
            time.sleep(min(timeout, 0.01))
            return []
        return [self._records.pop(0)]

    def close(self):
        pass


def test_a_take_stopped_holds_the_frames_the_readout_showed(tmp_path, monkeypatch):
    """Stopped with the last frame received still held by the decoder: the take holds the
    frames the readout counted, not the one more whole frame its journal holds."""
    import studio.record

    sent = payloads(5, 354, seed=7)
    transport = _HeldBack([binary_frame(sent[k], k, avatar=0, name=NAMES[0]) for k in range(5)])
    monkeypatch.setattr(studio.record, "open_transport", lambda url: transport)
    stream = LiveStream("tcp://test", SKELETON)
    try:
        stream.start_take(str(tmp_path / "poses.h5"), "held")
        transport.started = True
        _wait(lambda: not transport._records and stream.frames_in_take >= 4, 3)
        time.sleep(0.1)
        shown = stream.frames_in_take
        take = stream.stop_take()
    finally:
        stream.close()
    assert shown == 4  # the fifth waits in the decoder
    assert take.frames == shown
