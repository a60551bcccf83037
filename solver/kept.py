"""What is built from arrays and asked for again, kept by the arrays' content.

The evaluation, the guarantees and the placement ask about the same skins and surfaces many times
over (each support, each person, each figure); what they build from them (search trees, the
draped grid of a surface) is kept here, keyed by the arrays' shapes, types and bytes, so that an
equal array held by another object finds it too. A few entries are kept, the least recently
asked for going first; the studio evaluates from several threads, so the table is locked (what an
entry holds is built outside the lock: two threads may both build it, and the last kept wins).
"""

from __future__ import annotations

import threading

import numpy as np


class KeptByContent:
    """A table of `size` entries, each a dict of what was built from some arrays (`entry`)."""

    def __init__(self, size: int):
        self.size = size
        self._entries: dict[tuple, dict] = {}
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._entries)

    def entry(self, *arrays: np.ndarray | None) -> dict:
        """The dict kept for these arrays (None for an array not given), empty when new; the
        entry asked for least recently goes when the table is full."""
        key = tuple(None if a is None else (a.shape, a.dtype.str, hash(a.tobytes()))
                    for a in arrays)
        with self._lock:
            kept = self._entries.pop(key, None)
            if kept is None:
                kept = {}
                while len(self._entries) >= self.size:
                    del self._entries[next(iter(self._entries))]
            self._entries[key] = kept  # the last asked for last
        return kept
