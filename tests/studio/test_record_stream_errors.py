"""The Record view's stream says a problem in the reader's words: a stream whose frames fit no
layout of the paired header is named by its sizes, without a Python class name."""

import socket
import threading
import time

from capture.neuron import encode_binary
from studio.record import LiveStream

AXIS = "bundled:axis_neuron_standing_yxz.bvh"


def test_wrong_frame_size_is_said_plainly():
    server = socket.create_server(("127.0.0.1", 0))
    server.settimeout(10)
    port = server.getsockname()[1]

    def serve():
        with server:
            conn, _ = server.accept()
            with conn:
                try:
                    for k in range(6):
                        conn.sendall(encode_binary([0.0] * 300, frame_index=k))
                        time.sleep(0.005)
                    time.sleep(1.0)
                except OSError:
                    pass  # (the reader hung up on the stream it refused)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    said = []
    stream = LiveStream(f"tcp://127.0.0.1:{port}", AXIS, on_error=said.append)
    try:
        end = time.monotonic() + 10
        while not said and time.monotonic() < end:
            time.sleep(0.05)
    finally:
        stream.close()
        thread.join(5)
    assert said and said[0].startswith("Expected a frame size that fits the 59-joint skeleton")
    assert "got 300 floats" in said[0]
    assert "Error" not in said[0]
