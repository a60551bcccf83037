"""The studio's live stream when several avatars share it: each avatar's frames go to a take of
its own, or only the avatar chosen; the readout names every avatar with its frame count."""

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
    sent = {a: payloads(n, 354, seed=30 + a) for a in (0, 1)}
    return [0.3] + [binary_frame(sent[a][k], k, avatar=a, name=NAMES[a])
                    for k in range(n) for a in (0, 1)] + [0.2], sent


def test_live_stream_records_each_avatar_apart(tmp_path):
    pieces, sent = _stream()
    stream = LiveStream(f"tcp://127.0.0.1:{serve_tcp(pieces)}", SKELETON)
    try:
        stream.start_take(str(tmp_path / "poses.h5"), "bench")
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
    pieces, sent = _stream()
    stream = LiveStream(f"tcp://127.0.0.1:{serve_tcp(pieces)}", SKELETON, avatar="Avatar01")
    try:
        stream.start_take(str(tmp_path / "poses.h5"), "alice")
        _wait(lambda: stream.frames_in_take >= 10 and stream.summary()["frames"] >= 10, 3)
        time.sleep(0.1)
        assert stream.frames_in_take == 10
        take = stream.stop_take()
    finally:
        stream.close()
    assert take.name == "alice" and take.frames == 10
    assert [t.name for t in PoseLibrary(tmp_path / "poses.h5").takes()] == ["alice"]
