"""The studio's Library view: the takes and poses of the pose library with thumbnails, tag search
with the library's expressions, a timeline to scrub a take with its skeleton shown, the held
postures that `sitrelax db suggest` proposes marked on it, and the library's edits (accept a
hold or a frame as a pose, rename, tag, untag, delete).

Every edit is one commit of the library's own editing (`PoseLibrary.edit`), made under the
studio's library lock: it happens whole or not at all, as the same command would make it.
Thumbnails are rendered on the server (`studio.skeleton_draw`) and cached by pose or take
frame (poses never change their rotations, and a library never reuses an id; a library made
anew at the same path does, so its items' creation times are part of the key). The skeleton
is drawn under `/library` in the scene (Y up, metres).
"""

from __future__ import annotations

import contextlib
import html
import threading

import numpy as np

from capture import skeleton_fk
from posedb import PoseLibrary
from posedb.library import TakeData, checked_name
from posedb.regions import DEFAULT_SUPPORT
from posedb.suggest import HeldPosture, take_holds

from .context import LibraryWatch, StudioContext, guarded
from .record import split_words
from .skeleton_draw import SceneFigure, png_base64, pose_world, posed_body, skeleton_thumbnail

MAX_THUMBNAILS = 24  # pictures of poses (and of takes) shown at once: a search's first
# (library file, "pose"/"take", id, frame, and what tells apart the pose or take of that id in
# a library made anew at that path: ids start again there) -> base64 PNG
_THUMBS: dict[tuple, str] = {}
_MAX_CACHED = 4096
NONE = "(none)"


def _cached(key: tuple, make) -> str:
    """The base64 PNG of a thumbnail, rendered by `make()` once."""
    if key not in _THUMBS:
        if len(_THUMBS) >= _MAX_CACHED:
            _THUMBS.clear()
        _THUMBS[key] = png_base64(make())
    return _THUMBS[key]


def gallery_html(items: list[tuple[str, str, str]], more: int = 0) -> str:
    """Thumbnails three to a row, each with its title and a line under it. items : (base64
    PNG, title, line); the texts are escaped (names are the library's users' words)."""
    cells = "".join(
        '<figure style="margin:0;width:31%;text-align:center">'
        f'<img src="data:image/png;base64,{png}" alt="{html.escape(title)}" '
        'style="width:100%;border:1px solid #ddd;border-radius:4px">'
        '<figcaption style="font-size:0.72em;line-height:1.25;overflow-wrap:anywhere">'
        f'<b>{html.escape(title)}</b><br>{html.escape(line)}</figcaption></figure>'
        for png, title, line in items)
    tail = (f'<p style="font-size:0.75em">... and {more} more (narrow the search)</p>'
            if more else "")
    return f'<div style="display:flex;flex-wrap:wrap;gap:4px">{cells}</div>{tail}'



def hold_label(h: HeldPosture, frame_time: float) -> str:
    """How a hold is listed: its frames, length and proposed frame."""
    seconds = (h.end - h.start + 1) * frame_time
    return f"frames {h.start}-{h.end} ({seconds:.2f} s, {h.kind}): frame {h.frame}"


class LibraryView:
    """The Library tab of one browser tab (the `studio.context.View` contract)."""

    prefix = "/library"

    def __init__(self, client, tab, context: StudioContext):
        self.client, self.context = client, context
        self.lib: PoseLibrary | None = None
        self.data: TakeData | None = None  # the take on the timeline
        self.holds: list[HeldPosture] = []
        self.expr = ""
        self._closed = False  # the tab went away
        self._lock = threading.RLock()
        self._centre = np.zeros(3)  # subtracted from the take's positions: it plays at the origin
        # the view's nodes hang under one frame, which the studio can hide with its tab
        self.root = client.scene.add_frame(self.prefix, show_axes=False)
        self.figure = SceneFigure(client.scene, self.prefix)
        gui = self.gui = client.gui
        with tab:
            gui.add_markdown("**Library**: takes and poses of the pose library")
            self.status = gui.add_markdown("")
            self.with_body = gui.add_checkbox("Show the body", initial_value=True,
                                              hint="the average body posed by the skeleton")
            with gui.add_folder("Search"):
                self.search_text = gui.add_text("Tags", initial_value="",
                                                hint="a tag expression: sit and not floor")
                self.search = gui.add_button("Search")
                self.refresh = gui.add_button("Refresh")
                self.found = gui.add_markdown("")
                self.pose_gallery = gui.add_html("")
                self.take_gallery = gui.add_html("")
            with gui.add_folder("Take") as self.take_folder:
                self.take = gui.add_dropdown("Take", [NONE], order=1.0)
                self.take_info = gui.add_markdown("", order=2.0)
                self.frame = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0,
                                            order=3.0)
                self.hold = gui.add_dropdown("Suggested hold", [NONE], order=4.0)
                self.go_hold = gui.add_button("Go to hold", order=5.0)
                self.new_pose = gui.add_text("Pose name", initial_value="", order=6.0,
                                             hint="empty: TAKE-fNNNNN")
                self.new_tags = gui.add_text("Pose tags", initial_value="", order=7.0)
                self.new_support = gui.add_text("Supported", initial_value=DEFAULT_SUPPORT,
                                                order=8.0, hint="regions or a use: chair, "
                                                "pelvis thighs, ...")
                self.accept = gui.add_button("Accept hold as pose", order=9.0)
                self.save_frame = gui.add_button("Save this frame as pose", order=10.0)
            with gui.add_folder("Pose"):
                self.pose = gui.add_dropdown("Pose", [NONE])
                self.pose_info = gui.add_markdown("")
                self.rename_to = gui.add_text("New name", initial_value="")
                self.rename = gui.add_button("Rename")
                self.edit_tags = gui.add_text("Tags to change", initial_value="")
                self.add_tags = gui.add_button("Add tags")
                self.remove_tags = gui.add_button("Remove tags")
                self.delete = gui.add_button("Delete pose")
        actions = ((self.search, self.do_search), (self.refresh, self.do_refresh),
                   (self.go_hold, self.do_go_hold), (self.accept, self.do_accept_hold),
                   (self.save_frame, self.do_save_frame), (self.rename, self.do_rename),
                   (self.add_tags, lambda: self.do_tag(remove=False)),
                   (self.remove_tags, lambda: self.do_tag(remove=True)),
                   (self.delete, self.do_delete))
        for button, action in actions:
            button.on_click(lambda _e, action=action: self._guarded(action))
        self.take.on_update(lambda _e: self._guarded(self._take_chosen))
        self.pose.on_update(lambda _e: self._guarded(self._pose_chosen))
        self.with_body.on_update(lambda _e: self._guarded(self._show_frame))
        self._wire_frame()
        # what a recording, another tab or another process changes is listed again
        self._watch = LibraryWatch(context.db, self._reread, "library-poll") \
            if context.db is not None else None
        self._guarded(self.do_refresh)

    # plumbing ------------------------------------------------------------------------------
    def _guarded(self, action) -> None:
        guarded(self._lock, action, self._status, self.client, self.status.content)

    def _status(self, text: str) -> None:
        self.status.content = text

    def _wire_frame(self) -> None:
        self.frame.on_update(lambda _e: self._guarded(self._show_frame))

    def _library(self) -> PoseLibrary:
        if self.context.db is None:
            raise ValueError("No pose library: start the studio with --db")
        if self.lib is None:
            self.lib = PoseLibrary(self.context.db)
        return self.lib

    @contextlib.contextmanager
    def _edit(self):
        """One commit of the library's editing, serialised with the other tabs' writes."""
        lib = self._library()
        with self.context.library_lock, lib.edit() as ed:
            yield ed

    # search and lists ----------------------------------------------------------------------
    def do_refresh(self) -> None:
        """Reads the library again (others may have changed it) and lists what matches."""
        if self.context.db is None:
            self._status("No pose library: start the studio with --db to see one.")
            return
        self._watch.read()
        self.lib = PoseLibrary(self.context.db)
        self._list()

    def _reread(self) -> None:
        """Lists again what changed in the library, keeping what is chosen."""
        with self._lock:
            if self._closed:  # (the tab went away while the file was looked at)
                return
            self.lib = PoseLibrary(self.context.db)
            self._list(keep=True)

    def do_search(self) -> None:
        expr = self.search_text.value.strip()
        # a bad expression is refused here and the last one kept: the lists every edit makes
        # again would fail on it, an edit made then saying so as if it had failed
        self._library().find_poses(expr or None)
        self.expr = expr
        self._list()

    def _list(self, keep: bool = False) -> None:
        """Lists the matches; `keep`: the pose chosen stays chosen if it still matches."""
        lib = self._library()
        expr = self.expr or None
        poses = lib.find_poses(expr)
        takes = lib.find_takes(expr)
        take_names = {t.id: t.name for t in lib.takes()}
        self.found.content = (f"{len(takes)} take(s), {len(poses)} pose(s)"
                              + (f" match `{self.expr}`" if self.expr else ""))
        self._set_options(self.pose, [p.name for p in poses], keep=keep)
        # every take stays on the timeline's list; the search picks the pictures
        self._set_options(self.take, [t.name for t in lib.takes()], keep=True)
        key = str(lib.target)
        self.pose_gallery.content = gallery_html(
            [(_cached((key, "pose", p.id, p.frame, p.created_at),
                      lambda p=p: self._pose_picture(p)), p.name,
              f"{take_names[p.take]} #{p.frame}: {' '.join(p.tags) or 'no tags'}")
             for p in poses[:MAX_THUMBNAILS]], max(0, len(poses) - MAX_THUMBNAILS))
        self.take_gallery.content = gallery_html(
            [(_cached((key, "take", t.id, t.frames // 2, t.recorded_at, t.skeleton, t.source),
                      lambda t=t: self._take_picture(t.id, t.frames // 2)), t.name,
              f"take, {t.duration:.1f} s: {' '.join(t.tags) or 'no tags'}")
             for t in takes[:MAX_THUMBNAILS]], max(0, len(takes) - MAX_THUMBNAILS))

    def _set_options(self, dropdown, names: list[str], keep: bool = False) -> None:
        options = names or [NONE]
        current = dropdown.value
        dropdown.options = options
        if keep and current in options:
            dropdown.value = current
        else:
            dropdown.value = options[0]

    def _pose_picture(self, p) -> np.ndarray:
        _, skeleton, rot, root = self._library().pose_data(p.id)
        return skeleton_thumbnail(pose_world(skeleton, rot, root).positions, skeleton.parents)

    def _take_picture(self, take_id: str, frame: int) -> np.ndarray:
        data = self._library().take_data(take_id, frame, frame + 1)
        positions = skeleton_fk(data.skeleton, data.motion().channels[0]).positions
        return skeleton_thumbnail(positions, data.skeleton.parents)

    # the timeline --------------------------------------------------------------------------
    def _take_chosen(self) -> None:
        if self.take.value == NONE:
            return
        self.load_take(self.take.value)

    def load_take(self, name: str) -> None:
        """Puts a take on the timeline, with its suggested holds marked."""
        lib = self._library()
        info = lib.take(name)
        self.data = lib.take_data(info.id)
        self.holds = take_holds(self.data)
        mean = np.asarray(self.data.root_positions, dtype=np.float64).mean(axis=0)
        self._centre = np.array([mean[0], 0.0, mean[2]])  # about the origin, on the floor
        if self.take.value != info.name:
            self.take.value = info.name  # (its update calls here again: nothing changes)
        marks = tuple((h.frame, f"{h.frame}") for h in self.holds)
        last = max(1, info.frames - 1)  # (a one-frame take, as a relaxed pose's: held still)
        self.frame.remove()
        with self.take_folder:
            self.frame = self.gui.add_slider("Frame", min=0, max=last, step=1,
                                             initial_value=self.holds[0].frame
                                             if self.holds else 0, marks=marks or None,
                                             order=3.0, disabled=info.frames < 2)
        self._wire_frame()
        labels = [hold_label(h, info.frame_time) for h in self.holds]
        self._set_options(self.hold, labels)
        self.take_info.content = (
            f"**{info.name}**: {info.frames} frames at {1 / info.frame_time:.0f} fps "
            f"({info.duration:.1f} s), tags {' '.join(info.tags) or '-'}; "
            f"{len(self.holds)} suggested hold(s)"
            + "".join(f"\n- {label}" for label in labels))
        self._show_frame()

    def _show_frame(self) -> None:
        if self.data is None:
            return
        channels = self.data.motion().channels
        k = min(int(self.frame.value), len(channels) - 1)
        world = skeleton_fk(self.data.skeleton, channels[k])
        self._draw(self.data.skeleton, world, self._centre)

    def _draw(self, skeleton, world, centre: np.ndarray) -> None:
        """The skeleton (and, when asked, the body) in `world`, moved by -`centre` (3,) m."""
        self.figure.show(world.positions - centre, skeleton.parents)
        if self.with_body.value:
            vertices, triangles = posed_body(skeleton, world)
            self.figure.show_body(vertices - centre.astype(np.float32), triangles)
        else:
            self.figure.show_body(None)

    def _selected_hold(self) -> HeldPosture:
        labels = [hold_label(h, self.data.take.frame_time) for h in self.holds] \
            if self.data is not None else []
        if self.hold.value not in labels:
            raise ValueError("Choose a take with a suggested hold first")
        return self.holds[labels.index(self.hold.value)]

    def do_go_hold(self) -> None:
        self.frame.value = self._selected_hold().frame
        self._show_frame()

    def do_accept_hold(self) -> None:
        """The hold as a pose, unless its frame is a pose of the take already (accepted before,
        renamed or not, as `db suggest --accept` skips it): that pose is chosen instead."""
        frame = self._selected_hold().frame
        take = self.data.take
        known = [p for p in self._library().find_poses(take=take.id) if p.frame == frame]
        if known:
            self.pose.value = known[0].name
            self._status(f"Frame {frame} of {take.name} is pose **{known[0].name}** already.")
            return
        self._add_pose(frame)

    def do_save_frame(self) -> None:
        if self.data is None:
            raise ValueError("Choose a take first")
        self._add_pose(min(int(self.frame.value), self.data.take.frames - 1))

    def _add_pose(self, frame: int) -> None:
        """A pose at `frame` of the take on the timeline, named as `db suggest --accept` names
        it unless named, with the take's tags and those typed."""
        take = self.data.take
        name = self.new_pose.value.strip() or f"{take.name}-f{frame:05d}"
        support = split_words(self.new_support.value) or DEFAULT_SUPPORT
        with self._edit() as ed:
            ed.add_pose(take.id, frame, name, tags=tuple(take.tags)
                        + tuple(split_words(self.new_tags.value)), supports=support)
        name = checked_name(name)  # as stored (composed, NFC): as the list has it
        self.new_pose.value = ""
        self._list()
        self.pose.value = name
        self._status(f"Added pose **{name}** at frame {frame} of {take.name}.")

    # poses ---------------------------------------------------------------------------------
    def _pose_name(self) -> str:
        if self.pose.value == NONE:
            raise ValueError("Choose a pose first")
        return self.pose.value

    def _pose_chosen(self) -> None:
        if self.pose.value == NONE:  # (none left, say after a delete: the timeline's frame)
            self.pose_info.content = ""
            if self.data is not None:
                self._show_frame()
            else:
                self.figure.hide()
            return
        info, skeleton, rot, root = self._library().pose_data(self.pose.value)
        take = self._library().take(info.take)
        self.pose_info.content = (f"**{info.name}**: frame {info.frame} of {take.name}; tags "
                                  f"{' '.join(info.tags) or '-'}; supported "
                                  f"{', '.join(info.supports)}")
        self._draw(skeleton, pose_world(skeleton, rot, root), root * [1.0, 0.0, 1.0])

    def do_rename(self) -> None:
        old, new = self._pose_name(), self.rename_to.value.strip()
        with self._edit() as ed:
            ed.rename(old, new)
        new = checked_name(new)  # as stored (composed, NFC): as the list has it
        self.rename_to.value = ""
        self._list()
        self.pose.value = new
        self._status(f"Renamed {old} to **{new}**.")

    def do_tag(self, remove: bool) -> None:
        name, words = self._pose_name(), split_words(self.edit_tags.value)
        if not words:
            raise ValueError("Type the tags to add or remove")
        with self._edit() as ed:
            tags = ed.tag(name, add=() if remove else words, remove=words if remove else ())
        self._list()
        if name in self.pose.options:
            self.pose.value = name
        self._status(f"{name}: tags {' '.join(tags) or '-'}.")

    def do_delete(self) -> None:
        name = self._pose_name()
        with self._edit() as ed:
            ed.delete_pose(name)
        self._list()
        self._status(f"Deleted pose {name}.")

    def close(self) -> None:
        """Stops looking at the library file (a list under way is finished first)."""
        if self._watch is not None:
            self._watch.close()
        with self._lock:
            self._closed = True
