"""The Perception Neuron BVH broadcast: a codec for its binary and string frames.

Axis Neuron and Axis Studio broadcast one frame per sample, as a 64-byte binary header followed by
`DataCount` little-endian float32 values, or as a text line `<avatar index> <avatar name> <v0> ...
<vN-1> ||`. Two binary headers exist: the current one (data version 1.1.0.0, carrying the
sender's frame index) and the old one (1.0.x, without it). See
`shared/reference/perception-neuron-stream.md` for the byte layout.

The decoder reads a byte stream in pieces of any size. It resynchronises on the next plausible
header after garbage, rejects impossible headers (a DataCount over `MAX_DATA_COUNT` is never
allocated), and, because the format has no checksum, accepts a binary frame only when its
framing is confirmed: the bytes after it start another frame (its token and, once they have
arrived, version bytes of major version 1), the datagram ends exactly there,
or its DataCount is the one the paired skeleton expects for its flags, and no other header
begins inside it (which would mean it was cut short): neither a valid one nor the token and
version of its own header, the start of a fragment. A bit flipped inside a value, or a frame
cut short and followed by exactly as many stray bytes as it lost, cannot be detected by any
reader of this format; a value made NaN or infinite is rejected.
"""

from __future__ import annotations

import re
import struct
from collections import deque
from dataclasses import dataclass, field
from typing import Iterable, NamedTuple

import numpy as np

TOKEN = b"\xff\xdd"
FOOTER = b"\xff\xee"
HEADER_SIZE = 64
MAX_DATA_COUNT = 4096
MAX_AVATARS = 64  # avatars one stream may carry (Axis sends one per suit); frames of more are
# corrupt, so the per-avatar counters stay bounded whatever a stream sends
VERSION_NEW = (0, 0, 1, 1)  # build, revision, minor, major: data version 1.1.0.0
VERSION_OLD = (0, 0, 0, 1)  # 1.0.0.0
NAME_SIZE = 32

from .constants import FORMATS  # noqa: E402 (capture.neuron.FORMATS, as before)

# Current header: token, version[4], count u16, displacement u8, reference u8, avatar u32,
# name[32], frame index u32, reserved u32 x3, footer.
_NEW = struct.Struct("<2s4BHBBI32sI12s2s")
# Old header: token, version[4], count u32, displacement u32, reference u32, avatar u32, name[32],
# reserved u32 x2, footer.
_OLD = struct.Struct("<2s4BIIII32s8s2s")
assert _NEW.size == _OLD.size == HEADER_SIZE

_STRING_END = b"||"


class NeuronStreamError(ValueError):
    """Bad input to the Perception Neuron codec (the only error type it raises)."""


class NeuronFrame(NamedTuple):
    """One decoded frame.

    values : (N,) float32 payload as sent (degrees and centimetres, in BVH channel order).
    frame_index : the sender's frame index (current binary header), else None.
    avatar_index, avatar_name : which avatar the frame belongs to.
    with_displacement, with_reference : the header's flags; for string frames, what their size
        means for the paired skeleton (None without one).
    kind : "binary", "binary-old" or "string".
    received_at : receive time (seconds, `time.time()` clock) set by the source, else None.
    """

    values: np.ndarray
    frame_index: int | None
    avatar_index: int
    avatar_name: str
    with_displacement: bool | None
    with_reference: bool | None
    kind: str
    received_at: float | None = None


def _avatars_sum(name: str) -> property:
    """A read-only stream total: the sum of counter `name` over the avatars' counters."""
    return property(lambda stats: sum(getattr(a, name) for a in stats.avatars.values()),
                    doc=f"{name} over every avatar (the sum of their own counters)")


@dataclass
class DecoderStats:
    """Counters of what a decoder met.

    frames : frames returned.
    dropped : frames missing according to the sender's frame index (index gaps).
    corrupt : candidate frames rejected (impossible header, unconfirmed framing, non-finite
        values, unparsable string line, a frame cut short by a disconnect or end of input).
    resynced : times bytes were skipped to find the next frame.
    skipped_bytes : bytes skipped in total.
    restarts : times the frame index went backwards or jumped implausibly far (a restarted
        sender).
    damaged_index : frames whose index broke the sequence only for themselves (a flipped bit):
        counted here, not as drops and a restart.
    first_index, last_index : the sender's first and last frame index (of any avatar).
    gaps : (index before, index after) of the latest gaps, at most 1,024 kept.
    avatars : the counters of each avatar, keyed by (avatar index, avatar name), in the order
        the avatars first appeared. Axis sends one frame per avatar per sample when several
        people wear suits, each avatar counting its own frame index: gaps and restarts are
        judged within an avatar's own frames.

    `frames`, `dropped`, `restarts` and `damaged_index` are the sums of the avatars' own
    counters (read-only: a frame is counted once, in its avatar); the other counters belong to
    the stream, since what they count (a rejected frame, skipped bytes) has no avatar, and the
    first and last index are of the stream's order across avatars.
    """

    corrupt: int = 0
    resynced: int = 0
    skipped_bytes: int = 0
    first_index: int | None = None
    last_index: int | None = None
    gaps: list[tuple[int, int]] = field(default_factory=list)
    avatars: dict[tuple[int, str], "AvatarStats"] = field(default_factory=dict)

    frames = _avatars_sum("frames")
    dropped = _avatars_sum("dropped")
    restarts = _avatars_sum("restarts")
    damaged_index = _avatars_sum("damaged_index")

    def avatar(self, index: int, name: str) -> "AvatarStats | None":
        """The counters of avatar (index, name), made at its first frame; None for a new one
        past MAX_AVATARS (its frame counts as corrupt: the tables stay bounded whatever a
        stream sends)."""
        key = (index, name)
        st = self.avatars.get(key)
        if st is None:
            if len(self.avatars) >= MAX_AVATARS:
                return None
            st = self.avatars[key] = AvatarStats(index, name)
        return st

    def avatar_dicts(self) -> list[dict]:
        """Each avatar's counters as plain data, in the order the avatars first appeared."""
        return [a.as_dict() for a in self.avatars.values()]

    def as_dict(self) -> dict:
        return {
            "frames": self.frames, "dropped": self.dropped, "corrupt": self.corrupt,
            "resynced": self.resynced, "skipped_bytes": self.skipped_bytes,
            "restarts": self.restarts, "damaged_index": self.damaged_index,
            "first_index": self.first_index,
            "last_index": self.last_index,
        }


@dataclass
class AvatarStats:
    """One avatar's counters (see `DecoderStats`): frames, dropped, restarts, damaged_index,
    first_index and last_index of its own frames."""

    index: int
    name: str
    frames: int = 0
    dropped: int = 0
    restarts: int = 0
    damaged_index: int = 0
    first_index: int | None = None
    last_index: int | None = None

    def as_dict(self) -> dict:
        return {"index": self.index, "name": self.name, "frames": self.frames,
                "dropped": self.dropped, "restarts": self.restarts,
                "damaged_index": self.damaged_index, "first_index": self.first_index,
                "last_index": self.last_index}


# -- encoding --------------------------------------------------------------------------------


def _name_bytes(name: str) -> bytes:
    raw = name.encode("utf-8")
    if len(raw) > NAME_SIZE:
        raise NeuronStreamError(f"Expected an avatar name of at most {NAME_SIZE} bytes, got "
                                f"{len(raw)} ({name!r})")
    return raw.ljust(NAME_SIZE, b"\0")


def _check_values(values: np.ndarray) -> np.ndarray:
    values = np.ascontiguousarray(values, dtype="<f4")
    if values.ndim != 1 or not 0 < values.size <= MAX_DATA_COUNT:
        raise NeuronStreamError(
            f"Expected 1 to {MAX_DATA_COUNT} values per frame, got shape {values.shape}"
        )
    return values


def encode_binary(values: np.ndarray, *, frame_index: int = 0, avatar_index: int = 0,
                  avatar_name: str = "Avatar00", with_displacement: bool = True,
                  with_reference: bool = False, old_header: bool = False) -> bytes:
    """One binary frame: header (current or old) and the float32 payload.

    values : (N,) payload, N <= MAX_DATA_COUNT.
    """
    values = _check_values(values)
    name = _name_bytes(avatar_name)
    if old_header:
        head = _OLD.pack(TOKEN, *VERSION_OLD, values.size, int(with_displacement),
                         int(with_reference), avatar_index, name, b"\0" * 8, FOOTER)
    else:
        head = _NEW.pack(TOKEN, *VERSION_NEW, values.size, int(with_displacement),
                         int(with_reference), avatar_index, name, frame_index & 0xFFFFFFFF,
                         b"\0" * 12, FOOTER)
    return head + values.tobytes()


def encode_string(values: np.ndarray, *, avatar_index: int = 0,
                  avatar_name: str = "Avatar00") -> bytes:
    """One string frame: `<avatar index> <avatar name> <v0> ... <vN-1> ||` and CRLF.

    Values are written with 9 significant digits, which float32 reads back exactly.
    """
    values = _check_values(values)
    if not avatar_name or any(c.isspace() for c in avatar_name) or "||" in avatar_name:
        raise NeuronStreamError(f"Expected an avatar name without spaces, got {avatar_name!r}")
    body = " ".join(f"{v:.9g}" for v in values.tolist())
    return f"{avatar_index} {avatar_name} {body} ||\r\n".encode("ascii")


def encode_frame(values: np.ndarray, fmt: str, **kw) -> bytes:
    """Encodes in one of `FORMATS`; keyword arguments as for the format's encoder."""
    if fmt == "binary":
        return encode_binary(values, **kw)
    if fmt == "binary-old":
        kw.pop("frame_index", None)
        return encode_binary(values, old_header=True, **kw)
    if fmt == "string":
        for key in ("frame_index", "with_displacement", "with_reference"):
            kw.pop(key, None)
        return encode_string(values, **kw)
    raise NeuronStreamError(f"Expected a format from {FORMATS}, got {fmt!r}")


# -- decoding --------------------------------------------------------------------------------


class _Header(NamedTuple):
    count: int
    displacement: bool
    reference: bool
    avatar_index: int
    name: bytes
    frame_index: int | None
    kind: str


def _parse_header(buf, pos: int) -> _Header | None:
    """The header at `pos` (64 bytes available), or None when it cannot be a real header."""
    if buf[pos + 62:pos + 64] != FOOTER:
        return None
    major, minor = buf[pos + 5], buf[pos + 4]
    if major == 1 and minor >= 1:
        (_, _, _, _, _, count, disp, ref, avatar, name, index, _, _) = _NEW.unpack_from(buf, pos)
        kind = "binary"
    elif major == 1 and minor == 0:
        (_, _, _, _, _, count, disp, ref, avatar, name, _, _) = _OLD.unpack_from(buf, pos)
        index = None
        kind = "binary-old"
    else:
        return None
    if not (0 < count <= MAX_DATA_COUNT) or disp > 1 or ref > 1:
        return None
    return _Header(count, bool(disp), bool(ref), avatar, name, index, kind)


_NAME_CACHE: dict[bytes, str] = {}


def _avatar_name(raw: bytes) -> str:
    name = _NAME_CACHE.get(raw)
    if name is None:
        name = raw.split(b"\0", 1)[0].decode("utf-8", "replace")
        if len(_NAME_CACHE) < 1024:
            _NAME_CACHE[raw] = name
    return name


_BLANK = b"\r\n\0 \t"
_NOISE = re.compile(rb"[|\r\n\0 \t]+")  # no frame starts with these: blanks, and "||" noise
_NOISE_START = frozenset(b"|\r\n\0 \t")
_MAX_LINE = 65536  # a string frame of 4096 floats fits many times over
_U32 = 0xFFFFFFFF
# A jump of the frame index beyond this many frames (about 2.4 hours at 120 Hz) is no gap
# of dropped frames: it counts as a restart, never as a billion drops.
MAX_INDEX_GAP = 1 << 20
_MAX_GAPS_KEPT = 1024
_OPEN, _SOFT, _FINAL = 0, 1, 2  # what may follow the bytes held: more bytes, a pause, nothing


def _flags_by_count(counts: dict[tuple[bool, bool], int]) -> dict[int, tuple[bool, bool]]:
    """The flags a string frame of each size was sent with. Where two layouts share a size
    (a 3-bone skeleton: 18 floats either way) the one without the reference block wins."""
    out: dict[int, tuple[bool, bool]] = {}
    for flags in ((True, False), (False, False), (True, True), (False, True)):
        if flags in counts:
            out.setdefault(counts[flags], flags)
    return out


class StreamDecoder:
    """Incremental decoder of Perception Neuron frames from bytes of any chunking.

    counts : the DataCount the paired skeleton expects for each (with_displacement,
        with_reference), e.g. `StreamLayout.counts()`. With it, a frame of any other size is
        rejected (and remembered in `mismatch` so the caller can name the mismatch), and a
        string frame gets the flags its size means for that skeleton.
    datagram : each `feed` is one datagram (UDP). A frame may span several datagrams in
        order (Axis splits one larger than the path's MTU); bytes held longer than
        `reassembly_timeout` seconds, or when a datagram starts a new frame, count corrupt.
    fmt : "auto" (the first valid frame fixes the format of the stream), "binary" or "string".

    With or without a skeleton, a binary frame is accepted only once what follows it is
    another frame's token, or it ends exactly where a datagram, a pause (`settle`) or the
    input ends. `feed` returns the frames completed by the new bytes; `settle` those a pause
    confirms; `flush` settles what is left at the end of input or on a disconnect. Counters
    are in `stats`; each cost is linear in the bytes received.
    """

    def __init__(self, counts: dict[tuple[bool, bool], int] | None = None,
                 datagram: bool = False, fmt: str = "auto", reassembly_timeout: float = 0.5):
        if fmt not in ("auto", "binary", "string"):
            raise NeuronStreamError(f"Expected fmt 'auto', 'binary' or 'string', got {fmt!r}")
        self.strict = counts is not None
        self.counts: dict[tuple[bool, bool], int] = dict(counts or {})
        self._string_flags = _flags_by_count(self.counts)
        self.datagram = datagram
        self.reassembly_timeout = reassembly_timeout
        self.mode = None if fmt == "auto" else fmt
        self.stats = DecoderStats()
        self.mismatch: tuple[int, bool | None, bool | None] | None = None
        self._buf = bytearray()
        self._pos = 0  # first byte not settled
        self._base = 0  # stream offset of _buf[0]
        self._quiet = 0  # no token and no "||" starts in _buf[_pos:_quiet]
        self._quiet_eol = 0  # no CR or LF in _buf[_pos:_quiet_eol]
        # whether string frames have been seen ending with "||": until then a CR or LF ends a
        # frame too (the reference accepts CR, LF or "||"); after, a line without it was cut
        self._bars_seen = False
        self._feeds: deque[tuple[int, float | None]] = deque()  # (stream offset of a read's end, time)
        self._held_since: float | None = None
        self._lost = False
        # per avatar (index, name): the last index accepted, and an index that broke the
        # sequence, not judged yet
        self._last_index: dict[tuple[int, str], int] = {}
        self._suspect: dict[tuple[int, str], int] = {}
        self._pending: tuple[int, _Header, int] | None = None  # (start, header, end) offsets

    # -- bookkeeping --------------------------------------------------------------------------

    def _count_index(self, avatar: "AvatarStats", index: int | None) -> None:
        """Counts gaps and restarts within one avatar's frames. An index that breaks the
        sequence is judged by the next one: if that continues from before it, it was damaged
        (a flipped bit), not a jump."""
        if index is None:
            return
        st = self.stats
        if st.first_index is None:
            st.first_index = index
        if avatar.first_index is None:
            avatar.first_index = index
        key = (avatar.index, avatar.name)
        last, suspect = self._last_index.get(key), self._suspect.get(key)
        if last is None:
            self._accept_index(avatar, index)
            return
        if suspect is None:
            if (index - last) & _U32 == 1:
                self._accept_index(avatar, index)
            else:
                self._suspect[key] = index
            return
        del self._suspect[key]
        if (index - suspect) & _U32 != 1 and 1 <= (index - last) & _U32 <= MAX_INDEX_GAP:
            avatar.damaged_index += 1
            self._step(avatar, last, (index - 1) & _U32)  # the damaged frame took one place
            self._accept_index(avatar, index)
            return
        self._step(avatar, last, suspect)
        self._accept_index(avatar, suspect)
        self._count_index(avatar, index)

    def _settle_index(self) -> None:
        for key, suspect in list(self._suspect.items()):
            avatar = self.stats.avatars[key]
            self._step(avatar, self._last_index[key], suspect)
            self._accept_index(avatar, suspect)
        self._suspect.clear()

    def _step(self, avatar: "AvatarStats", last: int, index: int) -> None:
        st = self.stats
        step = (index - last) & _U32
        if step == 0 or step > MAX_INDEX_GAP:  # backwards, repeated or implausibly far
            avatar.restarts += 1
        elif step > 1:
            avatar.dropped += step - 1
            st.gaps.append((last, index))
            if len(st.gaps) > _MAX_GAPS_KEPT:
                del st.gaps[:_MAX_GAPS_KEPT // 2]

    def _accept_index(self, avatar: "AvatarStats", index: int) -> None:
        self._last_index[(avatar.index, avatar.name)] = index
        avatar.last_index = index
        self.stats.last_index = index

    def _skip(self, n: int) -> None:
        if n > 0:
            self._lost = True
            self.stats.skipped_bytes += n

    def _found(self) -> None:
        """A frame was accepted: if bytes were skipped before it, that was a resynchronisation."""
        if self._lost:
            self.stats.resynced += 1
            self._lost = False

    def _time_at(self, end: int) -> float | None:
        """Receive time of the read that brought the byte before buffer index `end`."""
        offset = self._base + end
        for feed_end, t in self._feeds:
            if feed_end >= offset:
                return t
        return self._feeds[-1][1] if self._feeds else None

    def _drop_held(self) -> None:
        """Forgets the bytes held (a partial frame), counting them corrupt unless blank."""
        if self._buf[self._pos:].strip(_BLANK):
            self.stats.corrupt += 1
        self._base += len(self._buf)
        self._buf = bytearray()
        self._pos = self._quiet = self._quiet_eol = 0
        self._feeds.clear()
        self._held_since = None

    # -- public -------------------------------------------------------------------------------

    def feed(self, data: bytes, received_at: float | None = None) -> list[NeuronFrame]:
        """Adds received bytes (one read, or one datagram) and returns the frames they
        complete, in order."""
        out: list[NeuronFrame] = []
        if self.datagram and self._pos < len(self._buf) and self._new_frame_or_stale(
                data, received_at):
            self._drop_held()
        buf = self._buf
        if self._pos and self._pos * 2 > len(buf):
            del buf[:self._pos]
            self._base += self._pos
            self._quiet = max(0, self._quiet - self._pos)
            self._quiet_eol = max(0, self._quiet_eol - self._pos)
            self._pos = 0
        buf += data
        self._feeds.append((self._base + len(buf), received_at))
        self._pos = self._scan(buf, self._pos, out, _SOFT if self.datagram else _OPEN)
        self._after_scan(received_at)
        return out

    def settle(self) -> list[NeuronFrame]:
        """Accepts a complete frame that ends exactly where the bytes received so far end.

        Call it when the stream pauses (a poll that brought nothing): like a datagram's end,
        a pause right after a frame confirms it without waiting for the next one.
        """
        out: list[NeuronFrame] = []
        if self._pos < len(self._buf):
            self._pos = self._scan(self._buf, self._pos, out, _SOFT)
            self._after_scan(None)
        return out

    def flush(self, received_at: float | None = None) -> list[NeuronFrame]:
        """Settles the bytes still held at end of input or on a disconnect.

        A complete frame still waiting for confirmation is accepted when it ends exactly where
        the input ends; a frame cut short counts as corrupt.
        """
        out: list[NeuronFrame] = []
        self._pos = self._scan(self._buf, self._pos, out, _FINAL)
        self._drop_held()
        self._settle_index()
        self._lost = False  # what follows starts clean: nothing was skipped to reach it
        return out

    def _after_scan(self, received_at: float | None) -> None:
        settled = self._base + self._pos
        feeds = self._feeds
        while len(feeds) > 1 and feeds[0][0] <= settled:
            feeds.popleft()
        if self._pos >= len(self._buf):
            self._held_since = None
        elif self._held_since is None:
            self._held_since = received_at

    def _new_frame_or_stale(self, data: bytes, received_at: float | None) -> bool:
        """Whether a datagram ends the partial frame held: it starts a valid binary header,
        or the partial has waited past the reassembly timeout."""
        if (received_at is not None and self._held_since is not None
                and received_at - self._held_since > self.reassembly_timeout):
            return True
        return (self.mode != "string" and data[:2] == TOKEN and len(data) >= HEADER_SIZE
                and _parse_header(data, 0) is not None)

    # -- binary -------------------------------------------------------------------------------

    def _size_fits(self, head: _Header) -> bool:
        """Whether the frame's size fits the paired skeleton (always true without one)."""
        if not self.strict:
            return True
        if self.counts.get((head.displacement, head.reference)) == head.count:
            return True
        self.mismatch = (head.count, head.displacement, head.reference)
        return False

    def _emit_binary(self, buf, pos: int, head: _Header, end: int, out: list) -> bool:
        values = np.frombuffer(bytes(buf[pos + HEADER_SIZE:end]), dtype="<f4")
        if not np.isfinite(values).all():
            self.stats.corrupt += 1
            return False
        name = _avatar_name(head.name)
        avatar = self.stats.avatar(head.avatar_index, name)
        if avatar is None:
            self.stats.corrupt += 1
            return False
        self.mode = "binary"
        self._found()
        self._count_index(avatar, head.frame_index)
        avatar.frames += 1
        out.append(NeuronFrame(values, head.frame_index, head.avatar_index, name,
                               head.displacement, head.reference, head.kind,
                               self._time_at(end)))
        return True

    def _scan(self, buf: bytearray, pos: int, out: list, edge: int) -> int:
        """Decodes frames from buf[pos:]; returns the position of the first unsettled byte."""
        if self.mode is None:
            pos = self._scan_unknown(buf, pos, out, edge)
            if self.mode is None:
                return pos
        if self.mode == "string":
            return self._scan_strings(buf, pos, out, edge)
        n = len(buf)
        while pos < n:
            if buf[pos:pos + 2] != TOKEN:
                tok = buf.find(TOKEN, pos + 1)
                if tok < 0:
                    # keep a trailing 0xFF: it may be the first half of a token
                    keep = 1 if (buf[n - 1] == 0xFF and edge != _FINAL) else 0
                    self._skip(n - keep - pos)
                    return n - keep
                self._skip(tok - pos)
                pos = tok
            pos, status = self._binary_at(buf, pos, out, edge)
            if status == _WAIT:
                return pos
        return pos

    def _scan_unknown(self, buf: bytearray, pos: int, out: list, edge: int) -> int:
        """Until a first frame fixes the format, tries whichever marker comes first: a binary
        token, the "||" that ends a string frame, or a line end (which ends a string frame
        sent without "||"). Each marker is searched for once."""
        n = len(buf)
        tok = bar = eol = -2  # -2: not searched yet; -1: none up to the end
        while self.mode is None and pos < n:
            if buf[pos] in _NOISE_START:
                end = _NOISE.match(buf, pos).end()
                self._skip(end - pos)
                pos = end
                continue
            if -1 != tok < pos:
                tok = buf.find(TOKEN, max(pos, self._quiet))
            if -1 != bar < pos:
                bar = buf.find(_STRING_END, max(pos, self._quiet))
            if -1 != eol < pos:
                eol = _line_end(buf, max(pos, self._quiet_eol), n)
            if 0 <= eol < min(m for m in (tok, bar, n) if m >= 0):
                # a line ended by CR or LF before any other marker: a string frame without
                # "||", or garbage (skipped, as before a first frame)
                self._emit_string(bytes(buf[pos:eol]), eol, out, quiet=True)
                if self.mode is None:
                    self._skip(eol - pos)
                pos = eol
                continue
            if tok < 0 and bar < 0:
                if edge == _FINAL or n - pos > _MAX_LINE:
                    self._skip(n - pos)  # no frame in it: garbage
                    return n
                self._quiet = max(pos, n - 1)
                self._quiet_eol = n
                return pos  # wait for a marker
            if tok >= 0 and (bar < 0 or tok < bar):
                self._skip(tok - pos)
                pos, status = self._binary_at(buf, tok, out, edge)
                if status == _WAIT:
                    return pos
                continue
            start = max(pos, buf.rfind(b"\n", pos, bar) + 1, buf.rfind(b"\r", pos, bar) + 1)
            self._skip(start - pos)
            pos = self._scan_strings(buf, start, out, _FINAL, stop=bar + 2)
        return pos

    def _binary_at(self, buf: bytearray, pos: int, out: list, edge: int) -> tuple[int, int]:
        """Tries the binary frame whose token is at `pos`: returns the position to go on from
        and _FRAME (one was emitted), _REJECT (bytes were skipped) or _WAIT (need more)."""
        n = len(buf)
        final = edge == _FINAL
        pending = self._pending
        if pending is not None and pending[0] == self._base + pos:
            # a whole frame that only waited for what follows it: judged already
            self._pending = None
            return self._confirm(buf, pos, pending[1], pending[2] - self._base, out, edge)
        if n - pos < HEADER_SIZE:
            if final:
                self.stats.corrupt += 1  # cut short by the end of input
                self._skip(n - pos)
                return n, _REJECT
            return pos, _WAIT
        head = _parse_header(buf, pos)
        if head is None or not self._size_fits(head):
            self.stats.corrupt += 1
            self._skip(1)
            return pos + 1, _REJECT
        end = pos + HEADER_SIZE + 4 * head.count
        inner = _embedded_header(buf, pos, min(end, n))
        if inner == _UNDECIDED and not final:
            return pos, _WAIT
        if inner >= 0:
            # this frame was cut short and another one began inside it
            self.stats.corrupt += 1
            self._skip(inner - pos)
            return inner, _REJECT
        if end > n:
            if final:
                self.stats.corrupt += 1
                self._skip(n - pos)
                return n, _REJECT
            return pos, _WAIT
        return self._confirm(buf, pos, head, end, out, edge)

    def _confirm(self, buf: bytearray, pos: int, head: _Header, end: int, out: list,
                 edge: int) -> tuple[int, int]:
        """Accepts the whole, plausible frame at buf[pos:end] if what follows confirms it."""
        n = len(buf)
        final = edge == _FINAL
        # The format has no checksum: only what follows a frame confirms where it ends, the
        # token and (once they have arrived) the version bytes of a next header (major 1): a
        # value whose bytes hold the token alone is no header
        if end + 2 <= n and buf[end:end + 2] != TOKEN:
            confirmed = False
        elif end + _OWN_START <= n:
            confirmed = buf[end + 5] == 1
        elif end + 2 <= n and final:
            confirmed = True  # (the token, and no more bytes to judge it by)
        elif end == n and edge != _OPEN:
            confirmed = True
        elif final:
            confirmed = False
        else:
            self._pending = (self._base + pos, head, self._base + end)
            return pos, _WAIT
        if confirmed and self._emit_binary(buf, pos, head, end, out):
            return end, _FRAME
        if not confirmed:
            self.stats.corrupt += 1
        self._skip(1)
        return pos + 1, _REJECT

    # -- string -------------------------------------------------------------------------------

    def _scan_strings(self, buf: bytearray, pos: int, out: list, edge: int,
                      stop: int | None = None) -> int:
        """Decodes string frames from buf[pos:stop]; returns the first unsettled position."""
        n = len(buf) if stop is None else stop
        while pos < n:
            if buf[pos] in _NOISE_START:
                end = _NOISE.match(buf, pos, n).end()
                if buf.find(b"|", pos, end) >= 0:
                    self._skip(end - pos)  # "||" with no frame before it: noise
                pos = end
                continue
            bar = buf.find(_STRING_END, max(pos, self._quiet), n)
            eol = _line_end(buf, max(pos, self._quiet_eol), bar if bar >= 0 else n)
            if eol >= 0:
                if self._bars_seen:
                    self.stats.corrupt += 1  # a line without its "||": cut short
                    self._skip(eol - pos)
                else:
                    self._emit_string(bytes(buf[pos:eol]), eol, out)  # a line end ends it
                pos = eol
                continue
            if bar < 0:
                if edge == _FINAL or n - pos > _MAX_LINE:
                    self.stats.corrupt += 1
                    self._skip(n - pos)
                    return n
                self._quiet, self._quiet_eol = max(pos, n - 1), n
                return pos
            if self._emit_string(bytes(buf[pos:bar]), bar + 2, out):
                self._bars_seen = True
            pos = bar + 2
        return pos

    def _emit_string(self, text: bytes, end: int, out: list, quiet: bool = False) -> bool:
        """Emits the string frame in `text` (without its terminator); returns whether it was
        one. quiet: text that is no frame at all is not counted corrupt (a line before the
        first frame); one that is a frame of the wrong size for the skeleton still is."""
        words = text.split()
        try:
            if len(words) < 3:
                raise ValueError("too few fields")
            avatar = int(words[0])
            name = words[1].decode("ascii")
            with np.errstate(over="ignore"):  # (a value beyond float32 is refused below)
                values = np.array([float(w) for w in words[2:]], dtype=np.float32)
        except (ValueError, UnicodeDecodeError):
            self.stats.corrupt += not quiet
            return False
        if avatar < 0 or values.size > MAX_DATA_COUNT or not np.isfinite(values).all():
            self.stats.corrupt += not quiet
            return False
        flags = (None, None)
        if self.strict:
            if values.size not in self._string_flags:
                self.mismatch = (int(values.size), None, None)
                self.stats.corrupt += 1
                return False
            flags = self._string_flags[values.size]
        counts = self.stats.avatar(avatar, name)
        if counts is None:
            self.stats.corrupt += 1
            return False
        self.mode = "string"
        self._found()
        counts.frames += 1
        out.append(NeuronFrame(values, None, avatar, name, *flags, "string", self._time_at(end)))
        return True


_UNDECIDED = -2
_FRAME, _REJECT, _WAIT = 0, 1, 2
_OWN_START = 6  # token and version: how a header of the same stream begins


def _embedded_header(buf: bytearray, pos: int, stop: int) -> int:
    """Where another header begins inside the frame whose header is at `pos` and whose bytes
    received so far end at `stop`: -1 if nowhere, or _UNDECIDED if a token there cannot be
    judged yet because its header has not fully arrived.

    Another header begins where a valid one does, or where the frame's own token and version
    bytes come again within it, even if what follows them is no valid header: a fragment of a
    frame that was itself cut short. Wherever they fall among a frame's float32 values, those
    six bytes make one of them a magnitude no sender of this format produces: about 2e18, or
    nonzero and below 1e-37.
    """
    own = buf[pos:pos + _OWN_START]
    hi = stop + 1 if stop < len(buf) else stop
    k = buf.find(TOKEN, pos + 2, hi)
    while 0 <= k < stop:
        if k + _OWN_START <= stop and buf[k:k + _OWN_START] == own:
            return k
        if k + HEADER_SIZE > len(buf):
            return _UNDECIDED
        if _parse_header(buf, k) is not None:
            return k
        k = buf.find(TOKEN, k + 1, hi)
    return -1


def _line_end(buf: bytearray, pos: int, stop: int) -> int:
    """Index of the first CR or LF in buf[pos:stop], or -1."""
    cr = buf.find(b"\r", pos, stop)
    lf = buf.find(b"\n", pos, stop)
    if cr < 0:
        return lf
    if lf < 0:
        return cr
    return min(cr, lf)


def decode_all(data: bytes | Iterable[bytes], **kw) -> tuple[list[NeuronFrame], DecoderStats]:
    """Decodes a whole input (bytes, or chunks as received) and settles its end."""
    dec = StreamDecoder(**kw)
    frames: list[NeuronFrame] = []
    chunks = [data] if isinstance(data, (bytes, bytearray, memoryview)) else data
    for chunk in chunks:
        frames.extend(dec.feed(chunk))
    frames.extend(dec.flush())
    return frames, dec.stats
