"""A serial bridge that goes away (a USB-serial adapter unplugged, a serial-over-network peer
closing) ends its source as the end of a file does: the frames that came are kept, and a take
recording from it is stored, rather than all of it thrown away with an error."""

import socket
import threading
import time

from capture import read_bvh
from capture.cli import listen
from capture.neuron import encode_binary
from capture.stream_layout import StreamLayout

from ..conftest import recording

AXIS = "bundled:axis_neuron_standing_yxz.bvh"


def _bridge(frames: int) -> tuple[int, threading.Thread]:
    """A serial-over-network peer on a free loopback port: sends `frames` binary frames to the
    first client, then hangs up. Returns its port and thread."""
    bvh = read_bvh(recording("axis_neuron_standing_yxz.bvh"), unit=None)
    payload = StreamLayout(bvh.skeleton).to_payload(bvh.motion.channels[:frames])
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)

    def serve():
        with server:
            conn, _ = server.accept()
            with conn:
                time.sleep(0.3)  # (pyserial empties its input once the port is open)
                for k, values in enumerate(payload):
                    conn.sendall(encode_binary(values, frame_index=k))
                    time.sleep(0.002)
                time.sleep(0.2)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    return server.getsockname()[1], thread


def test_listen_keeps_the_frames_of_a_bridge_that_went_away():
    port, thread = _bridge(12)
    events = []
    start = time.monotonic()
    summary = listen(f"socket://127.0.0.1:{port}", AXIS, duration=20.0, on_event=events.append)
    thread.join(5)
    assert time.monotonic() - start < 10  # the source ended: no waiting out the duration
    assert summary["frames"] == 12 and summary["corrupt"] == 0
    assert summary["last_index"] == 11
    assert any("went away" in e and "the source has ended" in e for e in events)


def test_record_stores_the_take_of_a_bridge_that_went_away(tmp_path):
    from posedb import PoseLibrary
    from posedb.record import record, recordings

    port, thread = _bridge(12)
    db = tmp_path / "poses.h5"
    summary = record(f"socket://127.0.0.1:{port}", db, "bridge", AXIS, duration=20.0)
    thread.join(5)
    assert summary["take"]["name"] == "bridge", summary
    assert summary["take"]["frames"] == 12, summary
    assert PoseLibrary(db).take("bridge").frames == 12
    assert recordings(db) == []  # no journal left behind
