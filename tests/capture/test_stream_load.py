"""Ten simultaneous 120 Hz streams for 30 s lose no frame (slow: `pytest -m slow`)."""

import socket
import subprocess
import sys
import threading
import time

import pytest

from capture import read_bvh
from capture.sources import open_source
from capture.stream_layout import StreamLayout

from tests.conftest import recording

STREAMS = 10
SECONDS = 30
HZ = 120


def _free_ports(n):
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


@pytest.mark.slow
def test_ten_streams_at_120_hz_lose_nothing():
    name = "axis_neuron_standing_yxz.bvh"  # 125 fps, 59 bones, 1,480-byte frames
    bvh = read_bvh(recording(name), unit=None)
    layout = StreamLayout(bvh.skeleton)
    rate = HZ * bvh.motion.frame_time
    total = HZ * SECONDS
    ports = _free_ports(STREAMS)
    servers = [subprocess.Popen(
        [sys.executable, "-m", "solver.cli", "capture", "replay", f"bundled:{name}",
         "--tcp", f"127.0.0.1:{p}", "--rate", str(rate), "--loop", "--wait-client",
         "--frames", str(total)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        for p in ports]
    results = {}

    def receive(port):
        src = open_source(f"tcp://127.0.0.1:{port}", layout)
        frames = []
        end = time.monotonic() + SECONDS + 30
        while len(frames) < total and time.monotonic() < end:
            frames.extend(src.read(0.2))
        src.close()
        results[port] = (frames, src.stats())

    threads = [threading.Thread(target=receive, args=(p,)) for p in ports]
    start = time.monotonic()
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    elapsed = time.monotonic() - start
    for s in servers:
        s.wait(10)
    for port in ports:
        frames, stats = results[port]
        assert len(frames) == total, (port, stats)
        assert [f.frame_index for f in frames] == list(range(total))
        assert stats["dropped"] == 0 and stats["corrupt"] == 0
    assert elapsed >= SECONDS * 0.95  # really at 120 Hz, not faster
