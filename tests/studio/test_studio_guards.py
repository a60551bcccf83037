"""The studio refuses foreign pages (Host, Origin, its websocket too), takes names as names,
makes --out, and drops an upload over the limit as it arrives."""

from __future__ import annotations

import base64
import os
import socket

import pytest

from studio.web import Studio

from studio.headless import HeadlessTab as Tab


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    out = tmp_path_factory.mktemp("studio") / "not" / "yet"
    server = Studio(port=0, out=str(out))
    yield server
    server.stop()


@pytest.fixture(scope="module")
def tab(studio):
    tab = Tab(studio)
    tab.view.add_person("bvh:bundled:cmu_75_18_high_sit.bvh#frame=39")
    yield tab
    tab.close()


def _upgrade(port: int, origin: str | None, host: str = "127.0.0.1") -> str:
    """The status line viser's websocket (or our front) answers an upgrade with."""
    key = base64.b64encode(os.urandom(16)).decode()
    head = (f"GET / HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            "Sec-WebSocket-Protocol: viser-v1\r\n"
            + (f"Origin: {origin}\r\n" if origin else "") + "\r\n")
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(head.encode())
        return sock.recv(4096).split(b"\r\n", 1)[0].decode()


def test_the_websocket_refuses_foreign_origins_and_hosts(studio):
    port = studio.port
    assert " 101 " in _upgrade(port, f"http://127.0.0.1:{port}")
    assert " 101 " in _upgrade(port, f"http://localhost:{port}", host="localhost")
    assert " 403 " in _upgrade(port, "http://evil.example")
    assert " 403 " in _upgrade(port, None, host="rebound.example")
    # viser's own port, found by a page that scans loopback, refuses a foreign Origin too
    assert " 403 " in _upgrade(studio.server.get_port(), "http://evil.example")


@pytest.mark.parametrize("name", ["../../escaped", "/etc/cron.d/x", "a/b", "..", ".hidden",
                                  "x" * 200])
def test_a_name_is_never_a_path(studio, tab, name):
    view = tab.view
    view.name.value = name
    for action in (view._save_toml, view._export):
        view._guarded(action)
        assert "Expected a name" in view.status_text
    assert not studio.out.exists() or all(
        p.resolve().is_relative_to(studio.out.resolve()) for p in studio.out.rglob("*"))
    assert not (studio.out.parent.parent / "escaped.toml").exists()


def test_save_toml_makes_the_out_folder(studio, tab):
    tab.view.name.value = "first design"
    tab.view._guarded(tab.view._save_toml)
    assert (studio.out / "first design.toml").is_file(), tab.view.status_text


def test_an_upload_over_the_limit_is_dropped_as_it_arrives(studio, tab):
    from viser import _messages

    client = studio.server.get_clients()[tab.client_id]  # the tab's own GUI takes its uploads
    handlers = client._websock_connection._incoming_handlers
    uuid = tab.view.upload._impl.uuid
    states = client.gui._current_file_upload_states

    def send(message) -> None:
        for handler in list(handlers[type(message)]):
            handler(tab.client_id, message)

    # declared over the limit: refused before a byte is kept
    send(_messages.FileTransferStartUpload(uuid, "t1", "big.obj", "", 256, 128 * 2 ** 20))
    assert "t1" not in states and "big.obj" in studio.problem_text
    # declared small, sent large: dropped once the bytes pass the limit
    send(_messages.FileTransferStartUpload(uuid, "t2", "liar.obj", "", 64, 4 * 2 ** 20))
    part = b"v 0 0 0\n" * (2 ** 16)  # 512 KiB
    for k in range(12):
        send(_messages.FileTransferPart(uuid, "t2", k, part))
        if "t2" not in states:
            break
    assert "t2" not in states and k * len(part) <= studio.limit
    assert "dropped" in studio.problem_text
