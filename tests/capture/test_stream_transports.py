"""Replay -> receive over loopback TCP, UDP, pyserial loop:// and a pty pair, at 10x real time:
every frame of every shared recording arrives, in order, equal to the file in float32."""

import os
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
import serial

from capture import read_bvh
from capture.replay import Replay, ReplayThread, TcpServerSink, UdpSink, WriterSink
from capture.sources import SerialTransport, Source, open_source
from capture.stream_layout import StreamLayout

from tests.conftest import recording

FILES = ["cmu_75_18_high_sit.bvh", "cmu_75_17_medium_sit.bvh", "cmu_82_05_floor_sit_excerpt.bvh",
         "axis_neuron_standing_yxz.bvh"]
FORMATS = ["binary", "binary-old", "string"]


class _FdWriter:
    def __init__(self, fd):
        self.fd = fd

    def write(self, data):
        return os.write(self.fd, data)


def _receive(source, count, timeout):
    frames = []
    end = time.monotonic() + timeout
    while len(frames) < count and time.monotonic() < end:
        frames.extend(source.read(0.1))
    return frames


def _check(bvh, source, frames, fmt):
    assert len(frames) == bvh.motion.num_frames
    got = np.array([source.channels(f) for f in frames], dtype=np.float32)
    np.testing.assert_array_equal(got, bvh.motion.channels.astype(np.float32))
    stats = source.stats()
    assert stats["dropped"] == 0 and stats["corrupt"] == 0
    if fmt == "binary":
        assert [f.frame_index for f in frames] == list(range(len(frames)))


LOOP_BYTES_PER_S = 120_000  # pyserial's loop:// moves 0.2-0.4 MB/s (one queue operation per
                            # byte; at 200 kB/s the Axis file did not all arrive in time on a
                            # machine 1.8x slower than usual)


def _run(name, fmt, transport, disp=True, ref=False):
    path = recording(name)
    bvh = read_bvh(path, unit=None)
    layout = StreamLayout(bvh.skeleton)
    replay = Replay.from_bvh(path, fmt=fmt, with_displacement=disp, with_reference=ref)
    rate = 10.0
    if transport == "loop":
        frame_bytes = len(replay.item(0)[1])
        rate = min(rate, LOOP_BYTES_PER_S / (frame_bytes / bvh.motion.frame_time))
    timeout = replay.duration / rate + 10
    cleanup = []
    if transport == "tcp":
        sink = TcpServerSink("127.0.0.1", 0)
        thread = ReplayThread(replay, sink, wait_for_client=True, rate=10.0).start()
        source = open_source(f"tcp://127.0.0.1:{sink.port}", layout)
    elif transport == "udp":
        source = open_source("udp://127.0.0.1:0", layout)
        thread = ReplayThread(replay, UdpSink("127.0.0.1", source.transport.port),
                              rate=10.0).start()
    elif transport == "loop":
        port = serial.serial_for_url("loop://", timeout=0.1)
        source = Source(SerialTransport(port, "loop://"), layout)
        thread = ReplayThread(replay, WriterSink(port, close=False), rate=rate).start()
    else:  # a pty pair: the replay writes the master, pyserial reads the slave device
        master, slave = os.openpty()
        cleanup += [lambda: os.close(master), lambda: os.close(slave)]
        source = open_source(f"serial://{os.ttyname(slave)}?baudrate=115200", layout)
        thread = ReplayThread(replay, WriterSink(_FdWriter(master), close=False),
                              rate=10.0).start()
    try:
        frames = _receive(source, bvh.motion.num_frames, timeout)
        thread.join(timeout)
        assert thread.error is None
        _check(bvh, source, frames, fmt)
        # paced at 10x real time (loop:// as fast as it carries), measured at the sender
        assert thread.stats.elapsed_s >= 0.9 * replay.duration / rate
    finally:
        thread.stop()
        source.close()
        for fn in cleanup:
            fn()


def _cases():
    for transport in ("tcp", "udp", "loop", "pty"):
        for name in FILES:
            for fmt in FORMATS:
                # the default run: every format of every file over TCP (the 17 s, 59-bone
                # recording in binary), the small high sit in every format over every transport
                # and the Axis recording in binary over UDP; `-m slow` runs every combination
                axis = name.startswith("axis")
                fast = (transport == "tcp" and (not axis or fmt == "binary")
                        or name == "cmu_75_18_high_sit.bvh"
                        or (transport == "udp" and axis and fmt == "binary"))
                slow = not fast
                yield pytest.param(transport, name, fmt,
                                   marks=[pytest.mark.slow] if slow else [])


@pytest.mark.parametrize("transport, name, fmt", list(_cases()))
def test_replay_receive_every_file_and_format(transport, name, fmt):
    _run(name, fmt, transport)


@pytest.mark.parametrize("disp, ref", [(False, False), (True, True), (False, True)])
def test_tcp_displacement_and_reference_layouts(disp, ref):
    _run("cmu_75_18_high_sit.bvh", "binary", "tcp", disp, ref)


def test_several_tcp_clients_get_every_frame():
    path = recording("cmu_75_18_high_sit.bvh")
    bvh = read_bvh(path, unit=None)
    layout = StreamLayout(bvh.skeleton)
    sink = TcpServerSink("127.0.0.1", 0)
    sources = [open_source(f"tcp://127.0.0.1:{sink.port}", layout) for _ in range(3)]
    for s in sources:
        s.read(0.05)  # connect
    deadline = time.monotonic() + 5
    while len(sink.clients) < 3 and time.monotonic() < deadline:
        sink.wait(0.05)
    thread = ReplayThread(Replay.from_bvh(path), sink, rate=10.0).start()
    try:
        for s in sources:
            _check(bvh, s, _receive(s, 77, 10), "binary")
    finally:
        thread.stop()
        for s in sources:
            s.close()


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _replay_process(port, start_index):
    return subprocess.Popen(
        [sys.executable, "-m", "solver.cli", "capture", "replay",
         "bundled:cmu_75_17_medium_sit.bvh", "--tcp", f"127.0.0.1:{port}", "--rate", "1",
         "--loop", "--start-index", str(start_index)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


@pytest.mark.slow
def test_peer_killed_and_restarted_is_reconnected_and_the_gap_reported():
    port = _free_port()
    bvh = read_bvh(recording("cmu_75_17_medium_sit.bvh"), unit=None)
    events = []
    server = _replay_process(port, 0)
    source = open_source(f"tcp://127.0.0.1:{port}", StreamLayout(bvh.skeleton),
                         on_event=events.append)
    try:
        before = _receive(source, 30, 10)
        assert len(before) == 30
        server.kill()  # SIGKILL mid-stream
        server.wait()
        down = _receive(source, 10**6, 0.8)  # whatever was in flight, then nothing
        server = _replay_process(port, 1000)  # Axis comes back, its index counting on
        after = _receive(source, 20, 15)
        assert len(after) == 20
    finally:
        server.kill()
        server.wait()
        source.close()
    last = (before + down)[-1].frame_index
    first = after[0].frame_index
    # like Axis, the server broadcasts from its start whether or not anyone listens, so the
    # frames it sent before the client's back-off ran out are part of the gap
    assert 1000 <= first < 1000 + 60 * 3
    assert [f.frame_index for f in after] == list(range(first, first + 20))
    stats = source.stats()
    assert stats["reconnects"] == 1
    assert stats["dropped"] == first - last - 1
    text = "\n".join(events)
    assert "reconnected after" in text
    assert f"frames flow again at index {first}: {first - last - 1} frames missed after index " \
           f"{last}" in text


def test_unreachable_server_is_retried_with_back_off():
    port = _free_port()
    events = []
    source = open_source(f"tcp://127.0.0.1:{port}", on_event=events.append)
    start = time.monotonic()
    while time.monotonic() - start < 1.6:
        source.read(0.1)
    source.close()
    retries = [e for e in events if "cannot connect" in e]
    # 0.1, 0.2, 0.4, 0.8 s: about five attempts in 1.6 s, not sixteen
    assert 3 <= len(retries) <= 6, events
    assert "retrying in 0.2 s" in retries[1]


def test_bad_urls_are_named():
    from capture.sources import StreamSourceError

    for url, message in [("http://x", "Expected a source URL"),
                         ("tcp://localhost", "HOST:PORT"),
                         ("serial:///dev/nonexistent-tty", "Cannot open serial source"),
                         ("serial://x?parity=Q", "Unknown serial options")]:
        with pytest.raises(StreamSourceError, match=message):
            open_source(url)
