"""The pose table: every pose of a library, column by column.

Kept as numpy columns plus a boolean tag-membership matrix, so opening a library of 100,000
poses and searching it by tags takes milliseconds. On disk (group `/poses`):

    id, take, frame, rotation_start, rotation_count  int64 (P,)
    supports uint16 (P,)  created_at float64 (P,)   root_position float64 (P, 3)
    placement float64 (P, 4)  where the pose stands relative to the standard placement, in its
                              own frame: offset x, y, z (metres) and heading (radians); a row
                              of NaN for a pose placed the standard way (`PosePlacement`;
                              schema 3: a version 2 file has no such column, read as all NaN)
    names_utf8 uint8      the pose names, UTF-8, joined by "\\n" (names hold no line break)
    notes_utf8 uint8 + notes_offsets int64 (P + 1,)   each pose's notes, UTF-8
    tag_vocabulary str (K,)   tag_matrix uint8 (P, K): 1 where pose p carries tag k
    rotations float32 (R, 4)  each pose's own copy of its local rotations (xyzw), rows
                              [rotation_start, rotation_start + rotation_count)
"""

from __future__ import annotations

import unicodedata
from typing import Iterable, Sequence

import h5py
import numpy as np

from .tags import compile_expression

_NUMERIC = {"id": np.int64, "take": np.int64, "frame": np.int64, "rotation_start": np.int64,
            "rotation_count": np.int64, "supports": np.uint16, "created_at": np.float64}
_STR = h5py.string_dtype()


class PoseTable:
    """Columns of the poses; rows are appended, edited and dropped in place."""

    def __init__(self) -> None:
        self.cols = {k: np.zeros(0, dtype=t) for k, t in _NUMERIC.items()}
        self.root = np.zeros((0, 3))
        self.placement = np.zeros((0, 4))
        self.names: list[str] = []
        self._notes_blob = b""
        self._notes_offsets = np.zeros(1, dtype=np.int64)
        self._notes: dict[int, str] = {}  # decoded or edited notes, by row
        self.vocab: list[str] = []
        self.matrix = np.zeros((0, 0), dtype=bool)
        self._pending: list[tuple] = []
        self._by_name: dict[str, int] | None = None
        self._by_id: dict[int, int] | None = None

    # -- io -----------------------------------------------------------------------------------

    @classmethod
    def read(cls, g: h5py.Group) -> "PoseTable":
        t = cls()
        if "id" not in g:
            return t
        for key, dtype in _NUMERIC.items():
            t.cols[key] = np.asarray(g[key][:], dtype=dtype)
        t.root = np.asarray(g["root_position"][:], dtype=np.float64).reshape(-1, 3)
        t.placement = (np.asarray(g["placement"][:], dtype=np.float64).reshape(-1, 4)
                       if "placement" in g else np.full((len(t.root), 4), np.nan))
        blob = g["names_utf8"][:].tobytes().decode("utf-8")
        t.names = blob.split("\n") if len(t.cols["id"]) else []
        t._notes_blob = g["notes_utf8"][:].tobytes()
        t._notes_offsets = g["notes_offsets"][:]
        t.vocab = [s.decode("utf-8") for s in g["tag_vocabulary"][:]]
        t.matrix = g["tag_matrix"][:].astype(bool).reshape(len(t.names), len(t.vocab))
        return t

    def write(self, g: h5py.Group) -> None:
        self._flush()
        notes = [self.notes(r).encode("utf-8") for r in range(len(self))]
        offsets = np.zeros(len(notes) + 1, dtype=np.int64)
        np.cumsum([len(n) for n in notes], out=offsets[1:])
        used = self.matrix.any(axis=0) if len(self) else np.zeros(len(self.vocab), dtype=bool)
        data = dict(
            {k: v for k, v in self.cols.items()},
            root_position=self.root,
            placement=self.placement,
            names_utf8=np.frombuffer("\n".join(self.names).encode("utf-8"), dtype=np.uint8),
            notes_utf8=np.frombuffer(b"".join(notes), dtype=np.uint8),
            notes_offsets=offsets,
            tag_matrix=self.matrix[:, used].astype(np.uint8),
        )
        for key, value in data.items():
            if key in g:
                del g[key]
            opts = dict(compression="gzip", compression_opts=4) if value.size > 4096 else {}
            g.create_dataset(key, data=value, **opts)
        if "tag_vocabulary" in g:
            del g["tag_vocabulary"]
        vocab = [v for v, u in zip(self.vocab, used) if u]
        g.create_dataset("tag_vocabulary", data=np.array(vocab, dtype=object), dtype=_STR,
                         shape=(len(vocab),))

    def copy(self) -> "PoseTable":
        self._flush()
        t = PoseTable()
        t.cols = {k: v.copy() for k, v in self.cols.items()}
        t.root = self.root.copy()
        t.placement = self.placement.copy()
        t.names = list(self.names)
        t._notes_blob = self._notes_blob
        t._notes_offsets = self._notes_offsets
        t._notes = dict(self._notes)
        t.vocab = list(self.vocab)
        t.matrix = self.matrix.copy()
        return t

    # -- rows ---------------------------------------------------------------------------------

    def __len__(self) -> int:
        return len(self.names)

    def _index(self) -> tuple[dict[str, int], dict[int, int]]:
        if self._by_name is None:
            self._flush()
            self._by_name = {n: r for r, n in enumerate(self.names)}
            self._by_id = {int(i): r for r, i in enumerate(self.cols["id"].tolist())}
        return self._by_name, self._by_id

    def row_of(self, ref: str, id_prefix: str = "pose-") -> int | None:
        """Row of a pose given by id (`pose-000042`) or name. Only an id's own form (the
        prefix and at least six ASCII digits, a form no name may take) is read as an id:
        `pose-5` or `pose-٥` is a name, which must not resolve to the pose of id 5."""
        by_name, by_id = self._index()
        digits = ref[len(id_prefix):] if ref.startswith(id_prefix) else ""
        if len(digits) >= 6 and digits.isascii() and digits.isdigit():
            row = by_id.get(int(digits))
            if row is not None:
                return row
        row = by_name.get(ref)
        if row is None:  # (names are stored composed, NFC: `posedb.library.checked_name`)
            row = by_name.get(unicodedata.normalize("NFC", ref))
        return row

    def value(self, key: str, row: int):
        self._flush()
        return self.cols[key][row].item()

    def placement_of(self, row: int) -> np.ndarray:
        """(4,) a pose's placement row: offset x, y, z (m) and heading (rad), NaN for none."""
        self._flush()
        return self.placement[row].copy()

    def tags(self, row: int) -> tuple[str, ...]:
        self._flush()
        return tuple(sorted(self.vocab[k] for k in np.flatnonzero(self.matrix[row])))

    def all_tags(self) -> list[str]:
        self._flush()
        used = self.matrix.any(axis=0) if len(self) else []
        return sorted(v for v, u in zip(self.vocab, used) if u)

    def notes(self, row: int) -> str:
        if row not in self._notes:
            if row >= len(self._notes_offsets) - 1:
                return ""
            a, b = self._notes_offsets[row], self._notes_offsets[row + 1]
            self._notes[row] = self._notes_blob[a:b].decode("utf-8")
        return self._notes[row]

    def mask(self, expr: str | None) -> np.ndarray:
        """(P,) bool: the rows whose tags satisfy a tag expression (all rows for None or an
        empty one, spaces alone included)."""
        self._flush()
        if expr is None or not expr.strip():
            return np.ones(len(self), dtype=bool)
        vocab = {v: k for k, v in enumerate(self.vocab)}
        return compile_expression(expr)(self.matrix, vocab)

    # -- edits --------------------------------------------------------------------------------

    def _tag_columns(self, tags: Iterable[str]) -> list[int]:
        cols = []
        for tag in tags:
            try:
                cols.append(self.vocab.index(tag))
            except ValueError:
                self.vocab.append(tag)
                cols.append(len(self.vocab) - 1)
        return cols

    def append(self, *, id: int, name: str, take: int, frame: int, tags: Sequence[str],
               supports: int, notes: str, created_at: float, rotation_start: int,
               rotation_count: int, root: Sequence[float],
               placement: Sequence[float] | None = None) -> int:
        """Adds a row (cheaply: rows are merged into the columns when next needed);
        `placement` (4,): offset x, y, z (m) and heading (rad), None for the standard one."""
        by_name, by_id = self._index()
        row = len(self.names)
        self.names.append(name)
        by_name[name] = row
        by_id[int(id)] = row
        self._notes[row] = notes
        self._pending.append((id, take, frame, rotation_start, rotation_count, supports,
                              created_at, tuple(root), self._tag_columns(tags),
                              (np.nan,) * 4 if placement is None else tuple(placement)))
        return row

    def _flush(self) -> None:
        if not self._pending:
            return
        rows = self._pending
        self._pending = []
        for k, key in enumerate(("id", "take", "frame", "rotation_start", "rotation_count",
                                 "supports", "created_at")):
            new = np.array([r[k] for r in rows], dtype=_NUMERIC[key])
            self.cols[key] = np.concatenate([self.cols[key], new])
        self.root = np.concatenate([self.root, np.array([r[7] for r in rows]).reshape(-1, 3)])
        self.placement = np.concatenate([self.placement,
                                         np.array([r[9] for r in rows]).reshape(-1, 4)])
        old = self.matrix
        matrix = np.zeros((old.shape[0] + len(rows), len(self.vocab)), dtype=bool)
        matrix[:old.shape[0], :old.shape[1]] = old
        for i, r in enumerate(rows):
            matrix[old.shape[0] + i, r[8]] = True
        self.matrix = matrix

    def rename(self, row: int, name: str) -> None:
        by_name, _ = self._index()
        del by_name[self.names[row]]
        self.names[row] = name
        by_name[name] = row

    def set_tags(self, row: int, tags: Iterable[str]) -> None:
        self._flush()
        cols = self._tag_columns(tags)
        if self.matrix.shape[1] < len(self.vocab):
            grown = np.zeros((len(self), len(self.vocab)), dtype=bool)
            grown[:, :self.matrix.shape[1]] = self.matrix
            self.matrix = grown
        self.matrix[row] = False
        self.matrix[row, cols] = True

    def set(self, row: int, key: str, value) -> None:
        self._flush()
        self.cols[key][row] = value

    def set_notes(self, row: int, notes: str) -> None:
        self._notes[row] = notes

    def drop(self, rows: Sequence[int]) -> None:
        self._flush()
        notes = [self.notes(r) for r in range(len(self))]
        keep = np.ones(len(self), dtype=bool)
        keep[list(rows)] = False
        self.cols = {k: v[keep] for k, v in self.cols.items()}
        self.root = self.root[keep]
        self.placement = self.placement[keep]
        self.matrix = self.matrix[keep]
        idx = np.flatnonzero(keep)
        self.names = [self.names[r] for r in idx]
        self._notes = {new: notes[old] for new, old in enumerate(idx)}
        self._notes_blob, self._notes_offsets = b"", np.zeros(1, dtype=np.int64)
        self._by_name = self._by_id = None
