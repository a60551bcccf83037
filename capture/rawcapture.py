"""Raw stream captures: the exact bytes a source received, with receive times.

File format (`.raw`, little-endian), made to be appended to while a stream runs and read back
even after the writer was killed:

    magic        8 bytes   b"SITRAW\\x00\\x01"  (format version 1)
    header_len   u32       length of the header that follows
    header       JSON      UTF-8 object: "source" (URL), "transport" ("stream" or "datagram"),
                           "time_origin" (Unix seconds of t = 0), "started_at" (ISO 8601 UTC),
                           optional "skeleton_bvh" (the paired BVH header: its hierarchy
                           and frame time, without motion), "note" and
                           fields of the program that wrote it (a recording's take)
    records      repeated  kind u8, t f64 (seconds since time_origin), length u32, bytes

Record kinds: 0 data (one read from a stream, or one datagram), 1 connected, 2 disconnected
(the bytes of an event record hold a UTF-8 note), 3 mark (a moment the recording program marked,
its bytes a UTF-8 JSON object of that program's; its time is the receive time of the frame
marked). A record cut short at the end of the file (a writer killed mid-write) is ignored and
reported as `truncated`.

Times are checked as they are read, since a damaged time would stall a replay or reach a take:
the time origin must be a finite Unix time (up to the year 9999, as `started_at` can state), and
a record's time finite, a time between two such Unix times, and, after the first record, at
most `MAX_BACKWARDS_S` before the latest time before it (a clock corrected while a capture ran)
and at most `MAX_GAP_S` after it (a machine suspended while a capture ran). The first record
may lie far from the time origin: a capture of a replayed capture keeps the replayed receive
times. `check_raw_capture` checks a whole file before anything of it is used.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import re
import struct
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

MAGIC = b"SITRAW\x00\x01"
DATA, CONNECTED, DISCONNECTED, MARK = 0, 1, 2, 3
KIND_NAMES = {DATA: "data", CONNECTED: "connected", DISCONNECTED: "disconnected", MARK: "mark"}
_RECORD = struct.Struct("<BdI")
_MAX_RECORD = 64 * 1024 * 1024
MAX_BACKWARDS_S = 86_400.0  # a record's time at most 1 day before the latest before it
MAX_GAP_S = 30 * 86_400.0  # and at most 30 days after it
_MAX_ORIGIN = 253_402_300_799.0  # 9999-12-31T23:59:59Z: the last time `started_at` can state
_MAX_TIME = 2 * _MAX_ORIGIN  # a record's time: between two such Unix times


# As the BVH reader finds them: the keyword in any capitalisation, after closing braces on its
# line ("}}MOTION"), and "Frame Time" with or without its space.
_MOTION = re.compile(r"^[ \t}]*(MOTION)\b", re.MULTILINE | re.IGNORECASE)
_FRAME_TIME = re.compile(r"Frame\s*Time\s*:\s*(\S+)", re.IGNORECASE)


def skeleton_header_text(bvh_text: str) -> str:
    """The header of a BVH file's text: its hierarchy, and a MOTION section with no frames
    that keeps the frame time. Raw captures store this, not the file's motion."""
    m = _MOTION.search(bvh_text)
    if m is None:
        return bvh_text
    ft = _FRAME_TIME.search(bvh_text, m.end())
    frame_time = ft.group(1) if ft else "0.008333333"
    hierarchy = bvh_text[:m.start(1)]
    if hierarchy and not hierarchy.endswith(("\n", "\r")):
        hierarchy += "\n"  # (braces before the keyword on its line stay with the hierarchy)
    return f"{hierarchy}MOTION\nFrames: 0\nFrame Time: {frame_time}\n"


class RawCaptureError(ValueError):
    """A file that is not a raw capture, or a damaged one."""


@dataclass(frozen=True)
class RawRecord:
    kind: int
    t: float
    data: bytes


@dataclass
class RawCapture:
    """A whole raw capture in memory."""

    header: dict
    records: list[RawRecord] = field(default_factory=list)
    truncated: bool = False

    @property
    def transport(self) -> str:
        return self.header.get("transport", "stream")

    def data_chunks(self) -> list[bytes]:
        return [r.data for r in self.records if r.kind == DATA]


class RawCaptureWriter:
    """Appends records to a new raw capture file (an existing file is never overwritten).

    Records are written straight through to the operating system, so a killed process loses
    at most the record being written. Several threads may write (a stream's reader and a mark).
    """

    def __init__(self, path: str | os.PathLike, *, source: str, transport: str = "stream",
                 time_origin: float, skeleton_bvh: str | None = None, note: str | None = None,
                 extra: dict | None = None):
        if transport not in ("stream", "datagram"):
            raise RawCaptureError(f"Expected transport 'stream' or 'datagram', got {transport!r}")
        self.path = Path(path)
        self.time_origin = float(time_origin)
        if not -_MAX_ORIGIN <= self.time_origin <= _MAX_ORIGIN:  # (NaN fails too)
            raise RawCaptureError(f"{self.path}: expected a finite Unix time as the time "
                                  f"origin, got {time_origin!r}")
        header = {
            "source": source,
            "transport": transport,
            "time_origin": self.time_origin,
            "started_at": _dt.datetime.fromtimestamp(self.time_origin, _dt.timezone.utc)
            .isoformat(),
        }
        if skeleton_bvh is not None:
            header["skeleton_bvh"] = skeleton_bvh
        if note is not None:
            header["note"] = note
        for key, value in (extra or {}).items():
            header.setdefault(key, value)
        blob = json.dumps(header).encode("utf-8")
        try:
            self._fh = open(self.path, "xb", buffering=0)
        except FileExistsError:
            raise RawCaptureError(f"Refusing to overwrite existing capture {self.path}") from None
        self._fh.write(MAGIC + struct.pack("<I", len(blob)) + blob)
        self._lock = threading.Lock()

    def write(self, kind: int, t_abs: float, data: bytes = b"") -> None:
        """Appends one record; `t_abs` is a Unix time, stored relative to the time origin."""
        if kind not in KIND_NAMES:
            raise RawCaptureError(f"Expected a record kind in {sorted(KIND_NAMES)}, got {kind}")
        t = t_abs - self.time_origin
        if not -_MAX_TIME <= t <= _MAX_TIME:  # (NaN fails too; a reader refuses it)
            raise RawCaptureError(f"{self.path}: expected a finite record time (Unix s, up to "
                                  f"the year 9999), got {t_abs!r}")
        record = _RECORD.pack(kind, t, len(data)) + bytes(data)
        with self._lock:  # one record's bytes never interleave with another's
            self._fh.write(record)

    def fileno(self) -> int:
        return self._fh.fileno()

    def sync(self) -> None:
        """Forces what was written onto the disk (a killed process loses nothing written
        anyway; this guards against a machine going down)."""
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        if not self._fh.closed:
            os.fsync(self._fh.fileno())
            self._fh.close()

    def __enter__(self) -> "RawCaptureWriter":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _read_header(fh, path) -> dict:
    magic = fh.read(len(MAGIC))
    if magic != MAGIC:
        raise RawCaptureError(
            f"{path}: expected a raw capture (magic {MAGIC!r}), got {magic[:8]!r}"
        )
    size = fh.read(4)
    if len(size) < 4:
        raise RawCaptureError(f"{path}: expected a header length, got end of file")
    (n,) = struct.unpack("<I", size)
    blob = fh.read(n)
    if len(blob) < n:
        raise RawCaptureError(f"{path}: expected a {n}-byte header, got {len(blob)} bytes")
    try:
        header = json.loads(blob.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise RawCaptureError(f"{path}: expected a JSON header, got {exc}") from None
    if not isinstance(header, dict) or header.get("transport", "stream") not in (
            "stream", "datagram"):
        raise RawCaptureError(f"{path}: expected a header object with a valid transport")
    origin = header.get("time_origin", 0.0)
    if isinstance(origin, bool) or not isinstance(origin, (int, float)) or not (
            -_MAX_ORIGIN <= origin <= _MAX_ORIGIN):  # (NaN fails the comparison too)
        raise RawCaptureError(f"{path}: expected a finite Unix time as the header's "
                              f"time_origin, got {origin!r}")
    return header


class _RecordTimes:
    """Checks the times of a capture's records in file order (see the module docstring)."""

    def __init__(self, path: Path):
        self.path = path
        self.index = 0  # of the next record, counting from 0
        self.latest = math.nan  # the latest time so far

    def check(self, t: float, offset: int) -> None:
        """Refuses the time `t` of the next record, which starts at byte `offset`."""
        if not -_MAX_TIME <= t <= _MAX_TIME:  # (NaN fails too)
            raise RawCaptureError(self._problem(t, offset))
        if self.index == 0:
            self.latest = t
        elif t > self.latest:
            if t > self.latest + MAX_GAP_S:
                raise RawCaptureError(self._problem(t, offset))
            self.latest = t
        elif t < self.latest - MAX_BACKWARDS_S:
            raise RawCaptureError(self._problem(t, offset))
        self.index += 1

    def _problem(self, t: float, offset: int) -> str:
        where = f"{self.path}: record {self.index} (counting from 0, at byte {offset})"
        if not math.isfinite(t):
            return f"{where}: expected a finite time (s since the time origin), got {t!r}"
        if not -_MAX_TIME <= t <= _MAX_TIME:
            return (f"{where}: expected a time within {_MAX_TIME:.6g} s of the time origin, "
                    f"got {t:.6g} s")
        latest = f"the latest time before it ({self.latest:.6g} s)"
        if t < self.latest:
            return (f"{where}: expected a time at most {MAX_BACKWARDS_S / 86400:g} day before "
                    f"{latest}, got {t:.6g} s")
        return (f"{where}: expected a time at most {MAX_GAP_S / 86400:g} days after {latest}, "
                f"got {t:.6g} s")


class RawRecords:
    """Lazy iterator over the records of a raw capture; `truncated` is set when it meets a
    record cut short at the end of the file."""

    def __init__(self, fh, path: Path):
        self._fh = fh
        self._path = path
        self.truncated = False

    def close(self) -> None:
        """Closes the file (records not yet read are not read)."""
        self._fh.close()

    def __iter__(self) -> Iterator[RawRecord]:
        fh = self._fh
        times = _RecordTimes(self._path)
        with fh:
            while True:
                offset = fh.tell()
                head = fh.read(_RECORD.size)
                if len(head) < _RECORD.size:
                    self.truncated = len(head) > 0
                    return
                kind, t, n = _check_head(head, offset, self._path)
                data = fh.read(n)
                if len(data) < n:
                    self.truncated = True  # (its time is not checked: it is not used)
                    return
                times.check(t, offset)
                yield RawRecord(kind, t, data)


def _check_head(head: bytes, offset: int, path: Path) -> tuple[int, float, int]:
    kind, t, n = _RECORD.unpack(head)
    if kind not in KIND_NAMES or n > _MAX_RECORD:
        raise RawCaptureError(f"{path}: damaged record at byte {offset} (kind {kind}, length {n})")
    return kind, t, n


def iter_raw_capture(path: str | os.PathLike) -> tuple[dict, RawRecords]:
    """The header and a lazy iterator over the records of a raw capture."""
    path = Path(path)
    try:
        fh = open(path, "rb")
    except IsADirectoryError:
        raise RawCaptureError(f"{path}: expected a raw capture file, got a directory") from None
    try:
        header = _read_header(fh, path)
    except BaseException:
        fh.close()
        raise
    return header, RawRecords(fh, path)


def check_raw_capture(path: str | os.PathLike) -> tuple[dict, int, bool]:
    """Checks a whole raw capture before it is used: its header, and every record's kind,
    length and time (the records' bytes are skipped, not read).

    Returns (header, number of whole records, whether a record is cut short at the end).
    Raises `RawCaptureError` naming the file and the first bad record.
    """
    header, records = iter_raw_capture(path)
    path = Path(path)
    times = _RecordTimes(path)
    with records._fh as fh:
        size = os.fstat(fh.fileno()).st_size  # (a file still written to: checked this far)
        offset = fh.tell()
        while True:
            head = fh.read(_RECORD.size)
            if len(head) < _RECORD.size:
                return header, times.index, len(head) > 0
            kind, t, n = _check_head(head, offset, path)
            end = offset + _RECORD.size + n
            if end > size:
                return header, times.index, True
            times.check(t, offset)
            offset = fh.seek(end)


def raw_header(path: str | os.PathLike) -> dict:
    """The header of a raw capture alone (the file closed again)."""
    header, records = iter_raw_capture(path)
    records.close()
    return header


def raw_marks(path: str | os.PathLike) -> list[tuple[float, dict]]:
    """The mark records of a raw capture: (Unix time, the mark's JSON object), in file order.
    A mark whose bytes are not a JSON object is a damaged capture."""
    header, records = iter_raw_capture(path)
    origin = float(header.get("time_origin", 0.0))
    out = []
    for r in records:
        if r.kind != MARK:
            continue
        try:
            mark = json.loads(r.data.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            mark = None
        if not isinstance(mark, dict):
            raise RawCaptureError(f"{path}: expected a mark record holding a JSON object, got "
                                  f"{r.data[:40]!r}")
        out.append((origin + r.t, mark))
    return out


def read_raw_capture(path: str | os.PathLike) -> RawCapture:
    """Reads a whole raw capture; `truncated` tells whether its last record was cut short."""
    header, records = iter_raw_capture(path)
    return RawCapture(header, list(records), records.truncated)


def write_raw_capture(path: str | os.PathLike, capture: RawCapture) -> None:
    """Writes a whole capture (used to make fixtures); refuses to overwrite."""
    h = dict(capture.header)
    origin = float(h.pop("time_origin", 0.0))
    writer = RawCaptureWriter(path, source=h.pop("source", "unknown"),
                              transport=h.pop("transport", "stream"), time_origin=origin,
                              skeleton_bvh=h.pop("skeleton_bvh", None), note=h.pop("note", None))
    with writer:
        for r in capture.records:
            writer.write(r.kind, origin + r.t, r.data)
