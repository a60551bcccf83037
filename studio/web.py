"""`sitrelax studio`: the studio in the browser, drawn with viser (whose web client ships inside
its Python package, so the studio works offline).

Every browser tab that connects gets its own GUI: a tab group with one tab per entry of `VIEWS`,
each view built as ``ViewClass(client, tab, context)`` (`studio.context.View`), drawing in the
tab's own scene under its prefix, and closed when the tab goes away. The Design view
(`studio.design_view`) holds a design session per tab. The scene is Y up, in metres.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from pathlib import Path

from .context import INTERNAL, StudioContext
from .design_view import DesignView
from .library_view import LibraryView
from .net import LOOPBACK, Front, allowed_names
from .record import RecordView

MAX_UPLOAD = 5 * 1024 * 1024  # bytes: the largest control mesh file the studio takes
MAX_MESSAGE = 1024 * 1024 + 64 * 1024  # bytes of one websocket message (uploads: 512 KiB parts)

# The tabs every browser tab gets, in order: (label, view class).
VIEWS = (
    ("Record", RecordView),
    ("Library", LibraryView),
    ("Design", DesignView),
)
SHOWN = "Design"  # the view whose 3D nodes a new tab shows (viser tells no tab switch)
# where the camera first looks when a view is shown (then the designer's own orbit is kept):
# a seat and its sitter, or a whole standing performer
FRAMING = {"Record": ((1.7, 1.5, 2.6), (0.0, 0.9, 0.0)),
           "Library": ((0.95, 0.8, 1.2), (0.0, 0.38, 0.0)),
           "Design": ((0.95, 0.8, 1.2), (0.0, 0.38, 0.0))}


@contextlib.contextmanager
def _guarded_websocket():
    """viser's websocket server, made while this is entered, takes only connections without an
    Origin (the front checks the browser's and removes it) and messages up to MAX_MESSAGE."""
    import websockets.asyncio.server as ws_server

    original = ws_server.serve

    def serve(*args, **kwargs):
        return original(*args, **{**kwargs, "origins": [None], "max_size": MAX_MESSAGE})

    ws_server.serve = serve
    try:
        yield
    finally:
        ws_server.serve = original


class Studio:
    """The studio server; `port` is the one bound (ask for 0 to get a free one). `views`
    holds the views of each connected tab (client id -> [view, ...])."""

    def __init__(self, db: str | None = None, host: str = "127.0.0.1", port: int = 8080,
                 out: str = "sitrelax-studio", limit: int = MAX_UPLOAD,
                 allow_hosts: tuple[str, ...] = ()):
        import viser

        self.context = StudioContext(db, Path(out), int(limit))
        self.out, self.limit = self.context.out, self.context.limit
        self.views: dict[int, list] = {}
        self.shown: dict[int, object] = {}  # per tab, its "3D view shows" dropdown
        self.problem_text = ""  # the last upload refused, as its tab was told
        self._lock = threading.Lock()
        with contextlib.redirect_stdout(io.StringIO()), _guarded_websocket():  # its banner
            self.server = viser.ViserServer(host=LOOPBACK, port=0, verbose=False)
        # the address the designer asked for is ours: it passes the page and the websocket to
        # viser (Host and Origin ours only), and refuses request bodies (413 past the limit)
        try:
            self.front = Front(host, port, self.server.get_port(), limit,
                               names=allowed_names(host, allow_hosts))
        except OSError:
            self.stop()
            raise
        self.host, self.port = host, self.front.port
        # the studio stays on this machine: no share link through an outside relay
        self.server.request_share_url = lambda verbose=True: None
        self.server.gui.configure_theme(show_share_button=False, control_width="large")
        scene = self.server.scene
        scene.set_up_direction("+y")
        # no shadows: viser's key light casts three cascades of them, which draws the scene four
        # times a frame; in a software-rendered browser that took a frame with two
        # pressure-coloured bodies from about 0.5 to 0.7-0.8 s (the lighting stays)
        scene.configure_default_lights(True, cast_shadow=False)
        self.server.initial_camera.position, self.server.initial_camera.look_at = \
            FRAMING[SHOWN]
        scene.add_grid("/floor", width=4.0, height=4.0, plane="xz", position=(0.0, 0.0, 0.0))
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)

    def _connect(self, client) -> None:
        """A new browser tab: its tab group, one tab per `VIEWS` entry, its views."""
        self._bound_uploads(client)
        views = []
        client.gui.add_markdown("**sitrelax studio**: supporting surfaces for captured poses")
        # viser does not tell the server which tab is open: the 3D view shows one view's
        # nodes at a time, chosen here
        shown = client.gui.add_dropdown("3D view shows", [label for label, _ in VIEWS],
                                        initial_value=SHOWN)
        group = client.gui.add_tab_group()
        roots = {}
        for label, view_class in VIEWS:
            tab = group.add_tab(label)
            frame = client.scene.add_frame(view_class.prefix, show_axes=False)
            try:
                view = view_class(client, tab, self.context)
            except Exception as exc:  # noqa: BLE001 (the tab says so; its other views work)
                with tab:
                    client.gui.add_markdown(f"{INTERNAL} the {label} view could not be built: "
                                            f"{type(exc).__name__}: {exc}")
                roots[label] = frame
                frame.visible = label == SHOWN
                continue
            roots[label] = getattr(view, "root", None) or frame
            roots[label].visible = label == SHOWN
            views.append(view)

        framed = {SHOWN}  # the views the camera has been framed for (the first showing)

        def show(_event) -> None:
            for label, root in roots.items():
                root.visible = label == shown.value
            if shown.value not in framed:
                framed.add(shown.value)
                position, target = FRAMING[shown.value]
                with client.atomic():
                    client.camera.position = position
                    client.camera.look_at = target
        shown.on_update(show)
        with self._lock:
            self.views[client.client_id] = views
            self.shown[client.client_id] = shown

    def _disconnect(self, client) -> None:
        with self._lock:
            views = self.views.pop(client.client_id, [])
            self.shown.pop(client.client_id, None)
        for view in views:
            view.close()

    def view(self, client_id: int | None = None, kind: type = DesignView):
        """The view of class `kind` of a connected tab (None: the only tab connected)."""
        with self._lock:
            if client_id is None:
                if len(self.views) != 1:
                    raise LookupError(f"Expected one connected tab, got {len(self.views)}")
                client_id = next(iter(self.views))
            return next(v for v in self.views[client_id] if isinstance(v, kind))

    def _bound_uploads(self, client) -> None:
        """A tab's uploads over the limit are dropped as they arrive: refused on their declared
        size, and their parts discarded once the bytes received pass it; the tab is told."""
        from viser import _messages

        gui = client.gui
        handlers = client._websock_connection._incoming_handlers
        start, part = gui._handle_file_transfer_start, gui._handle_file_transfer_part

        def on_start(client_id, message) -> None:
            if message.size_bytes > self.limit:
                self._refused(client, f"{message.filename[:100]} is {message.size_bytes} bytes; "
                                      f"the studio takes files up to {self.limit} bytes")
                return
            start(client_id, message)

        def on_part(client_id, message) -> None:
            state = gui._current_file_upload_states.get(message.transfer_uuid)
            if state is not None and (state["transferred_bytes"] + len(message.content)
                                      > self.limit):
                gui._current_file_upload_states.pop(message.transfer_uuid, None)
                self._refused(client, f"the upload passed {self.limit} bytes; dropped")
                return
            part(client_id, message)

        for cls, old, new in ((_messages.FileTransferStartUpload, start, on_start),
                              (_messages.FileTransferPart, part, on_part)):
            handlers[cls] = [new if h == old else h for h in handlers.get(cls, [])]

    def _refused(self, client, text: str) -> None:
        self.problem_text = text
        client.add_notification("Upload refused", text, color="red", auto_close_seconds=15.0)

    # life ---------------------------------------------------------------------------------
    def wait(self) -> None:
        while True:
            time.sleep(1.0)

    def stop(self) -> None:
        with self._lock:
            views = [v for vs in self.views.values() for v in vs]
            self.views.clear()
        for view in views:
            view.close()
        if getattr(self, "front", None) is not None:
            self.front.stop()
        with contextlib.redirect_stdout(io.StringIO()):
            self.server.stop()
