"""The receiver checked against a sender written here from the wire-format reference
(`shared/reference/perception-neuron-stream.md`), not from `capture.neuron`: string lines that
end at a line break without "||", string values beyond float32, and a byte stream whose frames a
pause confirmed, decoded again from its raw capture (the journal `capture record` stores)."""

import json
import socket
import struct
import subprocess
import sys
import threading
import time
import warnings

import numpy as np
import pytest

from capture import read_bvh
from capture.cli import listen
from capture.neuron import decode_all
from capture.stream_layout import StreamLayout

from ..conftest import recording

AXIS = "axis_neuron_standing_yxz.bvh"
SKELETON = f"bundled:{AXIS}"
COUNTS = StreamLayout(read_bvh(recording(AXIS), unit=None).skeleton).counts()


# -- an independent sender (from the reference's tables) -----------------------------------


def binary_frame(values, index, *, displacement=1, reference=0, avatar=0, name="Avatar00"):
    """Current header: FF DD, version 00 00 01 01, u16 count, u8 flags, u32 avatar, 32-byte
    name, u32 frame index, 12 reserved bytes, FF EE; then float32 values."""
    head = (b"\xff\xdd" + bytes([0, 0, 1, 1]) + struct.pack("<H", len(values))
            + bytes([displacement, reference]) + struct.pack("<I", avatar)
            + name.encode().ljust(32, b"\0") + struct.pack("<I", index) + bytes(12)
            + b"\xff\xee")
    assert len(head) == 64
    return head + struct.pack(f"<{len(values)}f", *values)


def string_frame(values, *, avatar=0, name="Avatar00", end=b" ||\r\n"):
    """`<avatar index> <avatar name> <v0> ... <vN-1>` and the end marker."""
    return (f"{avatar} {name} " + " ".join(repr(float(v)) for v in values)).encode() + end


def payloads(n, count, seed=0):
    """(n, count) float32 values a sender would send (degrees, centimetres)."""
    return np.random.default_rng(seed).uniform(-180, 180, (n, count)).astype(np.float32)


def serve_tcp(pieces):
    """A one-client TCP server (as Axis is) sending `pieces` (bytes, a float: a pause in
    seconds, or a threading.Event: a wait until it is set), then closing. Returns the port."""
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def run():
        server.settimeout(10)
        try:
            conn, _ = server.accept()
        except OSError:
            server.close()
            return
        with conn:
            try:
                for piece in pieces:
                    if isinstance(piece, float):
                        time.sleep(piece)
                    elif isinstance(piece, threading.Event):
                        piece.wait(10)  # (until the receiver is ready)
                    else:
                        conn.sendall(piece)
                time.sleep(0.05)
            except OSError:
                pass  # (the receiver gave up: the test's assertions say why)
        server.close()

    threading.Thread(target=run, daemon=True).start()
    return port


# -- string frames ended by a line break alone ----------------------------------------------


@pytest.mark.parametrize("end", [b"\r\n", b"\n", b"\r", b" ||\r\n", b"||"])
def test_string_frames_end_at_cr_lf_or_bars(end):
    sent = payloads(12, 180, seed=1)
    stream = b"".join(string_frame(v, avatar=2, name="Bob", end=end) for v in sent)
    for chunks in ([stream], [stream[i:i + 700] for i in range(0, len(stream), 700)]):
        frames, stats = decode_all(chunks, counts=COUNTS)
        assert len(frames) == 12 and stats.corrupt == 0
        np.testing.assert_array_equal(np.array([f.values for f in frames]), sent)
        assert {(f.avatar_index, f.avatar_name, f.kind) for f in frames} == {(2, "Bob", "string")}


def test_cli_listens_to_string_lines_without_bars():
    sent = payloads(40, 180, seed=2)
    pieces = []
    for v in sent:
        pieces += [string_frame(v, end=b"\r\n"), 0.01]
    port = serve_tcp(pieces)
    run = subprocess.run(
        [sys.executable, "-m", "studio.cli", "capture", "listen", f"tcp://127.0.0.1:{port}",
         "--skeleton", SKELETON, "--frames", "40", "--duration", "8", "--json"],
        capture_output=True, text=True, timeout=30)
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["frames"] == 40 and summary["corrupt"] == 0, summary


def test_a_line_cut_short_in_a_stream_with_bars_still_counts_corrupt():
    sent = payloads(3, 180, seed=3)
    cut = string_frame(sent[1])[:200] + b"\r\n"
    stream = string_frame(sent[0]) + cut + string_frame(sent[2])
    frames, stats = decode_all(stream, counts=COUNTS)
    np.testing.assert_array_equal(np.array([f.values for f in frames]), sent[[0, 2]])
    assert stats.corrupt == 1


def test_a_string_value_beyond_float32_is_corrupt_without_a_warning():
    values = payloads(1, 180, seed=4)[0].astype(object)
    values[7] = 1e39
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        frames, stats = decode_all(string_frame(values), counts=COUNTS)
    assert frames == [] and stats.corrupt == 1


# -- a pause confirms a frame: the same in a raw capture ------------------------------------


def test_frames_a_pause_confirmed_are_decoded_again_from_the_raw_capture(tmp_path):
    sent = payloads(12, 354, seed=5)
    pieces = []
    for k, v in enumerate(sent):
        pieces.append(binary_frame(v, 500 + k))
        if k % 4 == 3:  # a pause, then a few stray bytes (a noisy bridge)
            pieces += [0.3, b"\x00stray\x01"]
    port = serve_tcp(pieces)
    raw = tmp_path / "live.raw"
    live = listen(f"tcp://127.0.0.1:{port}", SKELETON, frames=12, duration=8,
                  save_raw=str(raw))
    assert live["frames"] == 12 and live["dropped"] == 0 and live["corrupt"] == 0, live
    again = listen(f"file:{raw}", SKELETON)
    assert {k: again[k] for k in ("frames", "dropped", "first_index", "last_index")} == {
        "frames": 12, "dropped": 0, "first_index": 500, "last_index": 511}


def test_record_stores_every_frame_it_counted(tmp_path):
    from posedb.record import record

    sent = payloads(9, 354, seed=6)
    pieces = []
    for k, v in enumerate(sent):
        pieces.append(binary_frame(v, k))
        if k % 3 == 2:
            pieces += [0.3, b"\x00stray\x01"]
    port = serve_tcp(pieces)
    summary = record(f"tcp://127.0.0.1:{port}", tmp_path / "poses.h5", "take", SKELETON,
                     frames=9, duration=8, lock_timeout=5)
    assert summary["frames"] == 9 and summary["corrupt"] == 0, summary
    assert summary["take"]["frames"] == 9, summary["take"]
    assert "9 frames, 0 dropped, 0 corrupt" in summary["take"]["notes"]
