"""A browser tab without a browser (`HeadlessTab`): a websocket client speaking viser's protocol
to the studio's viser server, so the studio builds that tab's views as for a page. It reports a
camera (when viser counts a client as connected), sends what a page sends (clicks, gizmo drags)
and reads whatever the server sends, noting when a scene node's messages and the texts of
markdown panels arrived. The tests and the `studio_refit` benchmark drive the studio with it."""

from __future__ import annotations

import threading
import time
from collections import deque

import msgspec
import numpy as np
import viser
import zstandard
from viser import _messages
from websockets.sync.client import connect


def looking(position, target) -> tuple[float, float, float, float]:
    """viser's camera (w, x, y, z) at `position` looking at `target`, Y up (OpenCV axes: x
    right, y down the image, z ahead)."""
    from scipy.spatial.transform import Rotation

    ahead = np.asarray(target, dtype=float) - position
    ahead /= np.linalg.norm(ahead)
    right = np.cross(ahead, [0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    x, y, z, w = Rotation.from_matrix(np.stack([right, np.cross(ahead, right), ahead],
                                               axis=1)).as_quat()
    return (w, x, y, z)


CAMERA = dict(wxyz=looking((0.0, 1.8, 1.2), (0.0, 0.45, 0.0)), position=(0.0, 1.8, 1.2),
              fov=1.0, near=0.01, far=100.0, image_height=900, image_width=1400,
              look_at=(0.0, 0.45, 0.0), up_direction=(0.0, 1.0, 0.0))


def _messages_of(frame: bytes) -> list[dict]:
    """The messages in one of viser's frames (a zstd-compressed msgpack window of messages after
    two little-endian uint64 sizes, then the raw arrays)."""
    size, packed = int.from_bytes(frame[:8], "little"), int.from_bytes(frame[8:16], "little")
    inner = zstandard.ZstdDecompressor().decompress(frame[16:16 + packed],
                                                     max_output_size=size)
    return msgspec.msgpack.decode(inner)["messages"]


class HeadlessTab:
    """One connected tab of `studio` (a `studio.web.Studio`); `view` its Design view.
    `watch` names scene nodes (e.g. "/design/surface") whose messages' arrival times are kept:
    the last in `arrived` (name -> time.perf_counter()), the last few thousand in `arrivals`
    (name -> times, oldest first). With `texts`, the contents sent to markdown panels are kept
    with their arrival times in `contents` ((time, text), the last few thousand); with
    `notices`, the notices the tab was shown in `notices` ((title, body), the last few
    hundred). Frames are decoded only for these (not for a tab that only looks on)."""

    def __init__(self, studio, camera: dict | None = None, timeout: float = 20.0,
                 watch: tuple[str, ...] = (), texts: bool = False, notices: bool = False):
        self.studio = studio
        before = set(studio.views)
        self.socket = connect(f"ws://127.0.0.1:{studio.server.get_port()}",
                              subprotocols=[f"viser-v{viser.__version__}"], max_size=None)
        self.received = 0
        self.arrived: dict[str, float] = {}
        self.arrivals: dict[str, deque] = {name: deque(maxlen=4096) for name in watch}
        self._watch = set(watch)
        self._texts = texts
        self._notices = notices
        self.contents: deque = deque(maxlen=4096)
        self.notices: deque = deque(maxlen=256)
        self._closed = threading.Event()
        threading.Thread(target=self._drain, daemon=True).start()
        self.send(_messages.ViewerCameraMessage(**{**CAMERA, **(camera or {})}))
        deadline = time.monotonic() + timeout
        while not set(studio.views) - before:
            if time.monotonic() > deadline:
                self.close()
                raise TimeoutError(f"the studio built no views for the tab in {timeout} s")
            time.sleep(0.02)
        (self.client_id,) = set(studio.views) - before
        self.view = studio.view(self.client_id)

    def send(self, message) -> None:
        self.socket.send(msgspec.msgpack.encode(message.as_serializable_dict()))

    def _drain(self) -> None:
        while not self._closed.is_set():
            try:
                frame = self.socket.recv(timeout=0.5)
            except TimeoutError:
                continue
            except Exception:  # noqa: BLE001 (the socket closed)
                return
            self.received += len(frame)
            if (self._watch or self._texts or self._notices) and isinstance(frame, bytes):
                now = time.perf_counter()
                messages = _messages_of(frame)
                self.notices.extend(
                    (m["props"].get("title"), m["props"].get("body")) for m in messages
                    if m.get("type") == "NotificationShowMessage" and
                    isinstance(m.get("props"), dict))
                names = {m["name"] for m in messages if isinstance(m.get("name"), str)}
                for name in self._watch & names:
                    self.arrived[name] = now
                    self.arrivals[name].append(now)
                if self._texts:  # a markdown panel's text goes as its parsed "_markdown"
                    self.contents.extend(
                        (now, m["updates"]["_markdown"]) for m in messages
                        if isinstance(m.get("updates"), dict) and
                        isinstance(m["updates"].get("_markdown"), str))

    def text_arrived(self, part: str, since: float) -> float | None:
        """When a markdown text containing `part` first arrived at or after `since` (a
        time.perf_counter()), or None (the tab must have been made with `texts`)."""
        return next((t for t, text in list(self.contents) if t >= since and part in text),
                    None)

    def close(self, timeout: float = 10.0) -> None:
        """Closes the connection and waits (up to `timeout` s) for the studio to close the
        tab's views."""
        self._closed.set()
        self.socket.close()
        deadline = time.monotonic() + timeout
        while getattr(self, "client_id", None) in self.studio.views and \
                time.monotonic() < deadline:
            time.sleep(0.02)
