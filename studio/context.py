"""What every studio view of one browser tab is given (`StudioContext`), and what a view is
(`View`): the studio builds one set of views per connected tab, each in its own GUI tab, each
drawing its 3D nodes under its own scene prefix (`/record`, `/library`, `/design`)."""

from __future__ import annotations

import os
import threading
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol


@dataclass
class StudioContext:
    """Shared by the views of every tab: the pose library's path (None: none opened), the folder
    exports and saved scenarios go to, the upload limit in bytes, one lock that serialises
    the library writes of all tabs (each write is one commit of the library's own editing), and
    the named design sessions that tabs joining by name share (name -> the Design view's
    session)."""

    db: str | None
    out: Path
    limit: int
    library_lock: threading.RLock = field(default_factory=threading.RLock)
    designs: dict = field(default_factory=dict)


class View(Protocol):
    """One view of one tab. Built as ``ViewClass(client, tab, context)`` where `client` is the
    tab's `viser.ClientHandle` (its own GUI and scene), `tab` the GUI container the view fills
    (``with tab:`` places GUI elements in it) and `context` the `StudioContext`."""

    prefix: str  # the scene path under which the view draws, e.g. "/record"

    def close(self) -> None:
        """Stops what the view runs (streams, fits) when its tab goes away."""


PROBLEM, INTERNAL = "**Problem:**", "**Internal error:**"
NOTICE_S = 10.0  # seconds a problem's notice stays up (its text stays in the status line)


def guarded(lock, action, status, client=None, shown: str = "") -> None:
    """Runs a view's `action` holding `lock`; a problem becomes `status(text)`: bad input names
    itself, anything else shows its trace, and the studio stays up. With the tab's `client`, a
    problem also pops up as a notice (the status line may be scrolled out of view in a long
    panel); `shown`, the status line's text now: a problem shown there from an earlier action
    is cleared before this one runs."""
    with lock:
        if shown.startswith((PROBLEM, INTERNAL)):
            status("")
        try:
            action()
        except (ValueError, OSError, KeyError) as exc:
            status(f"{PROBLEM} {exc}")
            notice(client, "Problem", str(exc))
        except Exception as exc:  # noqa: BLE001 (the studio stays up; the trace is shown)
            status(f"{INTERNAL} {type(exc).__name__}: {exc}\n\n```\n"
                   f"{traceback.format_exc(limit=3)}\n```")
            notice(client, "Internal error", f"{type(exc).__name__}: {exc}")


def notice(client, title: str, text: str) -> None:
    """A red notice in the tab, closed after NOTICE_S (nothing without a client)."""
    if client is None:
        return
    try:
        client.add_notification(title, text[:300], auto_close_seconds=NOTICE_S, color="red")
    except Exception:  # noqa: BLE001 (a tab that went away: its status line is all there is)
        pass


POLL_EVERY = 2.0  # s between looks at the library file: a change elsewhere is listed


def library_stamp(db: str | None) -> tuple | None:
    """The library file's identity and version (None: no file): a change replaces the file."""
    try:
        st = os.stat(db)
    except (OSError, TypeError):
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


class LibraryWatch:
    """Calls `changed()` on a thread of its own when the library file `db` changes (another
    tab, a recording, another process): the file is looked at every POLL_EVERY seconds, not
    read. A `changed` that raises (a file mid-change) is called again at the next look."""

    def __init__(self, db: str, changed, name: str):
        self.db = db
        self._changed = changed
        self._seen = library_stamp(db)
        self._closing = threading.Event()
        threading.Thread(target=self._run, daemon=True, name=name).start()

    def read(self) -> None:
        """The library was just read as it is now: no call for what is there already."""
        self._seen = library_stamp(self.db)

    def close(self) -> None:
        self._closing.set()

    def _run(self) -> None:
        while not self._closing.wait(POLL_EVERY):
            stamp = library_stamp(self.db)
            if stamp is None or stamp == self._seen:
                continue
            try:
                self._changed()
            except Exception:  # noqa: BLE001 (a file mid-change: the next look sees it)
                continue
            self._seen = stamp
