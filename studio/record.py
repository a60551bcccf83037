"""The studio's Record view: connect to a stream (or practise on a replayed recording), watch the
skeleton live with the stream's frame rate, drops and latency, record takes into the pose library
and mark poses while the subject holds them.

A take is recorded by `posedb.record.TakeRecorder`, the sink of `sitrelax capture record`: the
stream goes to a journal beside the library as it arrives, forced to disk every half second,
and becomes a take in one commit when the take is stopped; a studio killed meanwhile leaves the
journal for `sitrelax db recover`, marks included. A mark (the button, or the key M) names the
frame on screen; it is written to the journal at once and becomes a pose of the take, with its
tags and supported regions, when the take is stored.

Several people in suits (one frame per avatar on the stream): the Avatar field chooses the one
shown and recorded; left empty, the first avatar seen is shown, each avatar becomes a take of its
own, and a mark goes to the take of the avatar on screen. The readout names every avatar with its
frame count.

The skeleton is drawn under `/record` in the scene (Y up, metres), at most `DRAW_HZ` times a
second whatever the stream's rate; every frame still reaches the journal.
"""

from __future__ import annotations

import threading
import time

from capture import read_bvh, resolve_path, skeleton_fk
from capture.recordings import bundled_recordings
from capture.replay import Replay, ReplayThread, TcpServerSink
from capture.avatars import AvatarKey, avatar_key, avatar_selector
from capture.monitor import StreamMonitor
from capture.sources import Source, UnknownProtocolError, open_transport
from capture.stream_layout import StreamLayout
from posedb import PoseLibrary
from posedb.record import TakeRecorder
from posedb.regions import BODY_REGIONS, DEFAULT_SUPPORT, support_regions

from .context import StudioContext, guarded
from .skeleton_draw import SceneFigure, posed_body

DRAW_HZ = 30.0  # skeleton updates sent to the browser per second, at most
BODY_HZ = 5.0  # body updates per second, at most (posing and skinning take about 30 ms)
READOUT_EVERY = 0.5  # s between updates of the frame rate, drops and latency line
READ_TIMEOUT = 0.02  # s a read of the stream waits for bytes
URL_CHOICE = "stream URL"
REPLAY_PREFIX = "practice: replay "
MARK_KEY = "M"


def split_words(text: str) -> list[str]:
    """Tags typed in a field: words separated by spaces or commas."""
    return [w for w in text.replace(",", " ").split() if w]


class LiveStream:
    """One connection to a stream, read in a background thread: the latest frame's joint
    positions, the listener's counters, and the take being recorded, if any.

    source_url : a stream URL (see `capture.sources`); skeleton : the paired BVH header (path
    or ``bundled:NAME``). `on_frame(world, received_at)` (the frame's `WorldPose`, (J,)) is
    called from the reading thread at most `draw_hz` times a second; `on_error(message)` when the stream
    stops on a problem (the connection is closed then).
    avatar : the avatar to show and record (its name or index), or None for every avatar: the
        first avatar seen is shown, and a take keeps each avatar as a take of its own when
        several come (see `posedb.record.import_journal_takes`).
    """

    def __init__(self, source_url: str, skeleton: str, *, on_frame=None, on_error=None,
                 draw_hz: float = DRAW_HZ, avatar: str | int | None = None):
        self.selector = avatar_selector(avatar)
        header = read_bvh(resolve_path(skeleton), unit="auto")
        if header.skeleton.unit_m is None:
            raise ValueError(f"{skeleton}: the skeleton's length unit is unknown")
        self.url, self.skeleton_spec = source_url, skeleton
        self.skeleton = header.skeleton
        self.source = Source(open_transport(source_url), StreamLayout(header.skeleton))
        self.monitor = StreamMonitor(self.selector)
        self.shown_avatar: AvatarKey | None = None  # the avatar drawn (and marked)
        self.stored: list = []  # (avatar, take) of the take last stored, one per avatar
        self.last_take_name: str | None = None  # the name asked for the take last stored
        self.recorder: TakeRecorder | None = None
        self.shown_at: float | None = None  # receive time of the frame last drawn
        self.frames_in_take = 0
        self.take_counts: dict[AvatarKey, int] = {}  # the frames of each kept avatar in the take
        self.error: str | None = None
        self._on_frame, self._on_error = on_frame, on_error
        self._period = 1.0 / draw_hz
        self._io = threading.Lock()  # the reader's reads against attaching/detaching a journal
        self._figures = threading.Lock()  # the monitor, fed by the reader, read by the view
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="record-stream", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        next_draw = 0.0
        try:
            while not self._stop.is_set() and not self.source.exhausted:
                with self._io:
                    frames = self.source.read(READ_TIMEOUT)
                    kept = [f for f in frames if self.monitor.kept(avatar_key(f))]
                    if self.recorder is not None:
                        self.frames_in_take += len(kept)
                        for f in kept:
                            key = avatar_key(f)
                            self.take_counts[key] = self.take_counts.get(key, 0) + 1
                        self.recorder.tick()
                with self._figures:
                    self.monitor.add(frames)
                if kept and self.shown_avatar is None:
                    self.shown_avatar = avatar_key(kept[0])
                shown = [f for f in kept if avatar_key(f) == self.shown_avatar]
                now = time.monotonic()
                if shown and now >= next_draw:
                    next_draw = now + self._period
                    last = shown[-1]
                    channels = self.source.channels(last)
                    world = skeleton_fk(self.skeleton, channels)
                    self.shown_at = last.received_at
                    if self._on_frame is not None:
                        self._on_frame(world, last.received_at)
        except UnknownProtocolError as exc:
            self._fail(str(exc), discard=True)
        except ValueError as exc:  # a stream the header does not fit, bad input: its own words
            self._fail(str(exc), discard=False)
        except Exception as exc:  # noqa: BLE001 (the view shows it; the studio stays up)
            self._fail(f"{type(exc).__name__}: {exc}", discard=False)

    def _fail(self, message: str, discard: bool) -> None:
        self.error = message
        with self._io:
            recorder, self.recorder = self.recorder, None
            self.source.raw = None
            self.source.close()
        if recorder is not None and discard:
            recorder.discard()
        elif recorder is not None:
            recorder.abandon()  # left for `sitrelax db recover`, which the message says
            message += f"; the take's journal {recorder.journal} waits for `sitrelax db recover`"
        if self._on_error is not None:
            self._on_error(message)

    def summary(self) -> dict:
        """The listener's figures so far: frames, fps, dropped, corrupt, latency (ms)..."""
        with self._figures:
            return self.monitor.summary(self.source.stats())

    def start_take(self, library: str, take: str, *, subject: str = "", tags=(),
                   notes: str = "") -> TakeRecorder:
        """Starts recording into a new take: from the next bytes received, into a journal."""
        if self.recorder is not None:
            raise ValueError(f"Take {self.recorder.take!r} is recording: stop it first")
        recorder = TakeRecorder(library, take, self.skeleton_spec, self.url,
                                datagram=self.source.transport.datagram, subject=subject,
                                tags=tags, notes=f"recorded in the studio{': ' if notes else ''}"
                                f"{notes}",
                                avatar=None if self.selector is None else self.selector.text)
        with self._io:
            self.source.raw = recorder.writer
            self.recorder = recorder
            self.frames_in_take = 0
            self.take_counts = {}
        return recorder

    def mark(self, **fields) -> dict:
        """Marks the frame on screen as a pose of the take recording (see `TakeRecorder.mark`)."""
        recorder = self.recorder
        if recorder is None:
            raise ValueError("Start a take first: a pose is marked in the take recording")
        if self.shown_at is None or self.frames_in_take == 0:
            raise ValueError("No frame of this take has arrived yet")
        return recorder.mark(self.shown_at, avatar=self.shown_avatar, **fields)

    def stop_take(self):
        """Stops recording and stores the take with its marked poses in one commit; returns
        the take (None when no frame came), the first one when several avatars each became a
        take (all of them are in `stored`, as (avatar, take)). A chosen avatar that never
        came raises `capture.avatars.AvatarNotSeenError` naming those that did; nothing is
        stored then."""
        with self._io:
            recorder, self.recorder = self.recorder, None
            self.source.raw = None
            counted = dict(self.take_counts)
        if recorder is None:
            raise ValueError("No take is recording")
        self.last_take_name = recorder.take
        try:
            # the frames counted, as the readout shows them: the journal may hold one more
            # whole frame, whose bytes came before the decoder let it out
            return recorder.finish(counted)
        finally:
            self.stored = recorder.stored

    def close(self) -> None:
        """Stops reading (a take recording is stored first) and closes the connection."""
        try:
            if self.recorder is not None:
                self.stop_take()
        finally:
            self._stop.set()
            self._thread.join(5.0)
            with self._io:
                self.source.close()


class RecordView:
    """The Record tab of one browser tab (the `studio.context.View` contract)."""

    prefix = "/record"

    def __init__(self, client, tab, context: StudioContext):
        self.client, self.context = client, context
        self.stream: LiveStream | None = None
        self.replay: ReplayThread | None = None
        self.last_take = None
        self.marked: list[dict] = []
        self._lock = threading.RLock()
        self._readout_stop = threading.Event()
        self._body_wanted = threading.Event()  # a frame waits for the body's thread
        self._latest = None  # (skeleton, world) of the frame last drawn
        self._closing = False  # the tab went away: its panel is not updated
        # the view's nodes hang under one frame, which the studio can hide with its tab
        self.root = client.scene.add_frame(self.prefix, show_axes=False)
        self.figure = SceneFigure(client.scene, self.prefix)
        gui = client.gui
        with tab:
            gui.add_markdown("**Record**: a live stream into the pose library")
            self.status = gui.add_markdown("")
            with gui.add_folder("Source"):
                choices = [URL_CHOICE] + [REPLAY_PREFIX + r for r in bundled_recordings()]
                self.choice = gui.add_dropdown("Source", choices, initial_value=choices[1]
                                               if len(choices) > 1 else choices[0])
                self.url = gui.add_text("URL", initial_value="tcp://127.0.0.1:7001",
                                        hint="tcp://HOST:PORT, udp://[HOST]:PORT, "
                                             "serial://DEVICE?baudrate=N")
                self.header = gui.add_text("Skeleton", initial_value="bundled:"
                                           "axis_neuron_standing_yxz.bvh",
                                           hint="the BVH header paired with the stream")
                self.avatar = gui.add_text(
                    "Avatar", initial_value="",
                    hint="several people in suits: the avatar to show and record (name, e.g. "
                         "Avatar01, or index); empty: each avatar becomes a take of its own")
                self.with_body = gui.add_checkbox(
                    "Show the body", initial_value=False,
                    hint=f"the average body posed by the skeleton, {BODY_HZ:.0f} times a second")
                self.connect = gui.add_button("Connect")
                self.disconnect = gui.add_button("Disconnect")
                self.readout = gui.add_markdown("Not connected.")
            with gui.add_folder("Take"):
                self.take_name = gui.add_text("Take name", initial_value="take-1")
                self.take_tags = gui.add_text("Take tags", initial_value="",
                                              hint="words, e.g. session:2 lounge")
                self.subject = gui.add_text("Subject", initial_value="")
                self.start = gui.add_button("Start take")
                self.stop = gui.add_button("Stop take")
            with gui.add_folder("Mark pose"):
                self.pose_name = gui.add_text("Pose name", initial_value="",
                                              hint="empty: TAKE-fNNNNN")
                self.pose_tags = gui.add_text("Pose tags", initial_value="")
                support = support_regions(DEFAULT_SUPPORT)
                self.parts = {r: gui.add_checkbox(f"Support {r.replace('_', ' ')}",
                                                  initial_value=r in support)
                              for r in BODY_REGIONS}
                self.mark_button = gui.add_button(f"Mark pose ({MARK_KEY})")
        # the key works anywhere on the page (viser's command palette hotkeys)
        self.mark_key = gui.add_command("Mark pose", description="mark the pose on screen in "
                                        "the take recording", hotkey=MARK_KEY)
        for button, action in ((self.connect, self.do_connect),
                               (self.disconnect, self.do_disconnect),
                               (self.start, self.do_start), (self.stop, self.do_stop),
                               (self.mark_button, self.do_mark)):
            button.on_click(lambda _e, action=action: self._guarded(action))
        self.mark_key.on_trigger(lambda _e: self._guarded(self.do_mark))
        self._readout_thread = threading.Thread(target=self._readout_loop, daemon=True,
                                                name="record-readout")
        self._readout_thread.start()
        self._body_thread = threading.Thread(target=self._body_loop, daemon=True,
                                             name="record-body")
        self._body_thread.start()

    # actions -------------------------------------------------------------------------------
    def _guarded(self, action) -> None:
        guarded(self._lock, action, self._status, self.client, self.status.content)

    def _status(self, text: str) -> None:
        if not self._closing:
            self.status.content = text

    def do_connect(self) -> None:
        """Connects to the chosen source (a practice replay starts its server first); a take
        recording from the source before is stored first, and the status says so."""
        recording = self.stream is not None and self.stream.recorder is not None
        self.do_disconnect(quiet=True)
        stored = f"{self.status.content} " if recording else ""
        choice = self.choice.value
        if choice.startswith(REPLAY_PREFIX):
            name = choice[len(REPLAY_PREFIX):]
            sink = TcpServerSink("127.0.0.1", 0)
            self.replay = ReplayThread(Replay.from_bvh(resolve_path(f"bundled:{name}")), sink,
                                       rate=1.0, loop=True).start()
            url, skeleton = f"tcp://127.0.0.1:{sink.port}", f"bundled:{name}"
            self.url.value, self.header.value = url, skeleton
        else:
            url, skeleton = self.url.value.strip(), self.header.value.strip()
        try:
            self.stream = LiveStream(url, skeleton, on_frame=self._draw, on_error=self._lost,
                                     avatar=self.avatar.value.strip() or None)
        except BaseException:
            self._stop_replay()
            raise
        self._status(f"{stored}Connected to {url}.")

    def do_disconnect(self, quiet: bool = False) -> None:
        """Disconnects; a take recording is stored first, as Stop take stores it."""
        stream, self.stream = self.stream, None
        try:
            if stream is not None:
                try:
                    if stream.recorder is not None:
                        self._store(stream, "Disconnected. ")
                    elif not quiet:
                        self._status("Disconnected.")
                finally:
                    stream.close()
                    self._latest = None
                    if not self._closing:  # (a tab gone: nobody to show it to)
                        # no figures of a stream that is gone, nor its frozen skeleton
                        self.readout.content = "Not connected."
                        self.figure.hide()
        finally:
            self._stop_replay()

    def _stop_replay(self) -> None:
        replay, self.replay = self.replay, None
        if replay is not None:
            replay.stop()

    def _need_stream(self) -> LiveStream:
        if self.stream is None:
            raise ValueError("Connect to a source first")
        return self.stream

    def do_start(self) -> None:
        if self.context.db is None:
            raise ValueError("Recording needs a pose library: start the studio with --db")
        stream = self._need_stream()
        with self.context.library_lock:
            recorder = stream.start_take(self.context.db, self.take_name.value,
                                         subject=self.subject.value.strip(),
                                         tags=split_words(self.take_tags.value))
        self.marked = []
        self._status(f"Recording take **{recorder.take}** into {self.context.db}.")

    def do_mark(self) -> None:
        stream = self._need_stream()
        supports = [r for r, box in self.parts.items() if box.value]
        if not supports:
            raise ValueError("Tick at least one region the pose needs supported")
        mark = stream.mark(name=self.pose_name.value, tags=split_words(self.pose_tags.value),
                           supports=supports)
        self.marked.append(mark)
        self.pose_name.value = ""
        shown = mark["name"] or "(named by its frame)"
        self._status(f"Marked pose {len(self.marked)}: {shown}, tags "
                     f"{' '.join(mark['tags']) or '-'}; stored with the take when it stops.")

    def do_stop(self) -> None:
        self._store(self._need_stream())

    def _store(self, stream: LiveStream, before: str = "") -> None:
        """Stores the take `stream` records and says what was stored (`before` it)."""
        self._status("Storing the take (waiting for the library if another writer holds it)...")
        with self.context.library_lock:
            take = stream.stop_take()
        self.last_take = take
        if take is None:
            self._status(f"{before}No frame arrived: no take stored.")
            return
        # the poses as stored (a name another pose took meanwhile got a suffix)
        takes = [t for _, t in stream.stored] or [take]
        lib = PoseLibrary(self.context.db)
        names = [p.name for t in takes for p in lib.find_poses(take=t.name)]
        stored = ", ".join(f"**{t.name}**: {t.frames} frames, {t.duration:.1f} s"
                           for t in takes)
        self._status(f"{before}Stored take{'s' if len(takes) > 1 else ''} {stored}"
                     + (" (one per avatar)" if len(takes) > 1 else "")
                     + f", {len(names)} marked pose(s)"
                     + (f": {', '.join(names)}." if names else "."))
        self.take_name.value = _next_name(take.name if len(takes) == 1
                                          else stream.last_take_name or take.name)

    # drawing -------------------------------------------------------------------------------
    def _draw(self, world, received_at: float) -> None:
        """Called from the stream's thread, throttled to DRAW_HZ; the body is posed in a
        thread of its own, so that its 30 ms never delay the stream's reads."""
        stream = self.stream
        if stream is None:
            return
        self.figure.show(world.positions, stream.skeleton.parents)
        self._latest = (stream.skeleton, world)
        self._body_wanted.set()

    def _body_loop(self) -> None:
        while not self._readout_stop.is_set():
            if not self._body_wanted.wait(0.5):
                continue
            self._body_wanted.clear()
            try:
                if self.with_body.value and self._latest is not None:
                    self.figure.show_body(*posed_body(*self._latest))
                else:
                    self.figure.show_body(None)
            except Exception as exc:  # noqa: BLE001 (a skeleton no body fits: said, not fatal)
                self.with_body.value = False
                self._status(f"**Problem:** the body cannot follow this skeleton: {exc}")
            self._readout_stop.wait(1.0 / BODY_HZ)

    def _lost(self, message: str) -> None:
        self._status(f"**Problem:** the stream stopped: {message}")
        self.readout.content = "Not connected: the stream stopped."

    def _readout_loop(self) -> None:
        while not self._readout_stop.wait(READOUT_EVERY):
            stream = self.stream
            if stream is None or stream.error is not None:
                continue
            try:
                text = readout_text(stream.summary(), stream)
                if self.stream is stream:  # (not one disconnected meanwhile)
                    self.readout.content = text
            except Exception:  # noqa: BLE001 (a closing stream: the next tick shows it)
                continue

    def close(self) -> None:
        self._readout_stop.set()
        self._body_wanted.set()
        with self._lock:
            self._closing = True
            self.do_disconnect(quiet=True)


def readout_text(s: dict, stream: LiveStream) -> str:
    """The line under the source: rate, counters and latency, and the take recording."""
    fps = f"{s['fps']:.1f}" if s.get("fps") else "-"
    latency = (f"{s['latency_ms']:.1f} ms (max {s['latency_max_ms']:.1f})"
               if s.get("latency_ms") is not None else "-")
    text = (f"{s['frames']} frames, **{fps} fps**, dropped {s['dropped']}, corrupt "
            f"{s['corrupt']}, latency {latency}")
    avatars = s.get("avatars") or []
    if len(avatars) > 1 or stream.selector is not None:
        text += "  \n" + ", ".join(
            f"{a['name'] or '(no name)'} (index {a['index']}): {a['frames']} frames"
            + ("" if a["kept"] else " (not recorded)") for a in avatars)
    recorder = stream.recorder
    if recorder is not None:
        text += (f"  \n**recording {recorder.take}**: {stream.frames_in_take} frames, "
                 f"{len(recorder.marks)} marked")
    events = stream.source.events
    if events and (stream.shown_at is None or events[-1][0] > stream.shown_at):
        # no frame since the source's last word: why (cannot connect, the peer went away)
        text += f"  \n*{events[-1][1]}*"
    return text


def _next_name(name: str) -> str:
    """take-1 -> take-2; other names get "-2"."""
    stem, sep, number = name.rpartition("-")
    if sep and number.isdigit():
        return f"{stem}-{int(number) + 1}"
    return f"{name}-2"
