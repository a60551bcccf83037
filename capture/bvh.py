"""Reading and writing BVH motion files.

A BVH file is a HIERARCHY block (joints with OFFSET, CHANNELS and End Site entries) followed by a
MOTION block (`Frames:`, `Frame Time:`, then one line of channel values per frame). The hierarchy
is read as a lazy stream of tokens that remember their line, by an iterative parser (an explicit
stack, no recursion), so its time is linear in the input and its memory and depth are bounded by
the limits below; the motion block, which holds nearly all of the bytes, is parsed in one
vectorised call and only re-read line by line when it is malformed, to name the line. Every
failure is a `BvhParseError` naming the file and the line.

Accepted variations: any of the six rotation orders per joint (and subsets of axes, in any
order), position channels on any joint and before or after the rotations, keywords in any
capitalisation (`End Site`, `END SITE`, `EndSite`, `End <name>`, `End Site <name>`), tabs, blank
lines, LF, CRLF or CR-only line ends, braces on the keyword's line, glued to it (`JOINT X{`) or
on their own (`}}`), joint names containing spaces, `:` or `.`, several roots, `Frame Time`
with a decimal comma (`0,008333`). See `capture.skeleton` for the frame and channel conventions.
"""

from __future__ import annotations

import io
import math
import os
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .files import write_atomic
from .recordings import resolve_path
from .profiles import identify_profile
from .skeleton import CHANNEL_NAMES, Skeleton, WorldPose, depth_first_order, skeleton_fk
from .units import resolve_unit


class BvhParseError(ValueError):
    """A BVH file that cannot be read; names the file, the 1-based line and what was expected."""

    def __init__(self, path: str | os.PathLike | None, line: int | None, message: str):
        self.path = None if path is None else str(path)
        self.line = line
        self.message = message
        where = self.path or "<bvh>"
        if line is not None:
            where = f"{where}:{line}"
        super().__init__(f"{where}: {message}")


@dataclass(frozen=True, eq=False)
class Motion:
    """Raw motion of a skeleton.

    channels : (T, C) float64 values as in the file (degrees; lengths in file units).
    frame_time : seconds between frames.
    """

    channels: np.ndarray
    frame_time: float

    @property
    def num_frames(self) -> int:
        return int(self.channels.shape[0])

    @property
    def duration(self) -> float:
        """Seconds covered by the frames (frames x frame time)."""
        return self.num_frames * self.frame_time

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time


@dataclass(frozen=True, eq=False)
class Bvh:
    """A BVH file's content: the skeleton, its motion, and the recognised joint-name profile."""

    skeleton: Skeleton
    motion: Motion
    profile: str | None = None
    path: str | None = None

    def world_positions(self) -> np.ndarray:
        """(T, J, 3) world joint positions in metres (needs a known unit)."""
        return self.fk().positions

    def fk(self) -> WorldPose:
        """World positions (T, J, 3) in metres and rotmats (T, J, 3, 3) of every frame."""
        return skeleton_fk(self.skeleton, self.motion.channels)


_CHANNEL_LOOKUP = {c.lower(): c for c in CHANNEL_NAMES}
# ASCII digits only: str.isdigit() and a Unicode \d accept "²" or "٣", which int() then refuses.
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?", re.ASCII)
_DIGITS = re.compile(r"[0-9]+", re.ASCII)
_DECIMAL_COMMA = re.compile(r"[+-]?[0-9]*,[0-9]+", re.ASCII)
_TOKEN = re.compile(rb"[{}]|[^\s{}]+")
_NON_SPACE = re.compile(rb"\S")
_LONE_CR = re.compile(rb"\r(?!\n)")
_MAX_SHOWN = 40
_LONG_DIGITS = re.compile(rb"\d{10}")

# Limits of the reader (README, "BVH support"): far beyond any real skeleton, they keep hostile
# input to a line-numbered error in bounded time and memory.
#: joints nested inside one another (real skeletons: under 30).
MAX_DEPTH = 1_000
#: joints in a file (real skeletons: under 300, with face rigs).
MAX_JOINTS = 10_000
#: characters of a joint name.
MAX_NAME_CHARS = 256
#: words after a keyword on its line (OFFSET takes 3, CHANNELS at most 7).
MAX_LINE_WORDS = 16
#: characters of a `Frames:` or `Frame Time:` line.
MAX_HEADER_LINE = 4_096
#: digits of a `Frames:` count.
MAX_FRAME_DIGITS = 15
#: seconds per frame: at most 1 MHz, at least one frame an hour, so fps and duration are finite.
MIN_FRAME_TIME = 1e-6
MAX_FRAME_TIME = 3_600.0
#: magnitude of an offset or a channel value (a position of 1,000 km in millimetres, a turn of
#: a billion degrees): what lies beyond overflows as a stream's float32 or in forward kinematics.
MAX_VALUE = 1e9


def _show(token: str) -> str:
    return repr(token if len(token) <= _MAX_SHOWN else token[:_MAX_SHOWN] + "...")


class _Tokens:
    """Cursor over the hierarchy's tokens, each tagged with its 1-based line.

    Braces are tokens of their own even when glued to a word ("Hips{", "}}"). Tokens are found
    one at a time by a regex scan of the bytes, so a pathological line costs time linear in what
    is read and no memory beyond one token; a token is decoded when it is reached.
    data : the file's bytes with LF or CRLF line ends.
    """

    def __init__(self, data: bytes, path: str | None):
        self.data = data
        self.path = path
        self._scan = _TOKEN.finditer(data)
        self._counted = 0  # byte offset up to which line ends have been counted
        self._line = 1  # the line of byte `_counted`
        self._ahead: tuple[bytes, int, int] | None = None  # next token, its line, its end
        self.line_no = 1  # line of the last token taken
        self.end = 0  # byte offset just after the last token taken

    def _next(self) -> tuple[bytes, int, int] | None:
        if self._ahead is None:
            m = next(self._scan, None)
            if m is None:
                return None
            start = m.start()
            self._line += self.data.count(b"\n", self._counted, start)
            self._counted = start
            self._ahead = (m.group(), self._line, m.end())
        return self._ahead

    def _decode(self, raw: bytes, line: int) -> str:
        try:
            return raw.decode("utf-8")
        except UnicodeDecodeError:
            raise BvhParseError(self.path, line, "expected UTF-8 text, got undecodable bytes "
                                "(is this a binary file?)") from None

    def error(self, message: str, line: int | None = None) -> BvhParseError:
        return BvhParseError(self.path, line if line is not None else self.line_no, message)

    @property
    def last_line(self) -> int:
        """1-based number of the last line that holds anything: where end of file is met."""
        end = len(self.data)
        while end > 0:  # back over trailing whitespace, a slice at a time (no whole copy)
            piece = self.data[max(0, end - 65_536):end]
            kept = len(piece.rstrip())
            end -= len(piece) - kept
            if kept:
                break
        return self.data.count(b"\n", 0, end) + 1

    def peek(self) -> str | None:
        ahead = self._next()
        return None if ahead is None else self._decode(ahead[0], ahead[1])

    def on_line(self, braces: bool = True) -> bool:
        """Whether another token follows on the line of the last one taken (a brace counts
        only if `braces`)."""
        ahead = self._next()
        return (ahead is not None and ahead[1] == self.line_no
                and (braces or ahead[0] not in (b"{", b"}")))

    def take(self, what: str) -> str:
        ahead = self._next()
        if ahead is None:
            raise self.error(f"expected {what}, got end of file", line=self.last_line)
        self._ahead = None
        raw, self.line_no, self.end = ahead
        return self._decode(raw, self.line_no)

    def line_words(self, keyword: str) -> list[str]:
        """The words after `keyword` on its line, up to a brace or the end of the line."""
        words: list[str] = []
        while self.on_line(braces=False):
            if len(words) == MAX_LINE_WORDS:
                raise self.error(f"expected at most {MAX_LINE_WORDS} words after {keyword}, "
                                 "got more")
            words.append(self.take(keyword))
        return words


@dataclass
class _Tree:
    """The hierarchy's tables as they are read, in file (depth-first) order."""

    names: list[str] = field(default_factory=list)
    known: set[str] = field(default_factory=set)
    parents: list[int] = field(default_factory=list)
    offsets: list[tuple[float, float, float]] = field(default_factory=list)
    channels: list[tuple[str, ...]] = field(default_factory=list)
    end_sites: list[tuple[float, float, float]] = field(default_factory=list)
    end_parents: list[int] = field(default_factory=list)

    def skeleton(self) -> Skeleton:
        return Skeleton(
            names=tuple(self.names),
            parents=np.array(self.parents, dtype=np.int64),
            offsets=np.array(self.offsets, dtype=np.float64),
            channels=tuple(self.channels),
            end_sites=np.array(self.end_sites, dtype=np.float64).reshape(-1, 3),
            end_site_parents=np.array(self.end_parents, dtype=np.int64),
        )


@dataclass
class _OpenJoint:
    """A joint whose closing brace is still to come."""

    index: int
    name: str
    line: int
    have_offset: bool = False
    have_channels: bool = False


def _parse_hierarchy(cur: _Tokens) -> Skeleton:
    tree = _Tree()
    _hierarchy_keyword(cur)
    while _next_root(cur, tree):
        _parse_joint(cur, tree)
    return tree.skeleton()


def _hierarchy_keyword(cur: _Tokens) -> None:
    """The file's first line: `HIERARCHY` alone."""
    first = cur.peek()
    if first is None:
        raise cur.error("expected 'HIERARCHY', got an empty file", line=1)
    cur.take("HIERARCHY")
    if first.upper() != "HIERARCHY":
        raise cur.error(f"expected 'HIERARCHY' to start a BVH file, got {_show(first)}")
    if cur.on_line():
        raise cur.error(f"expected nothing after 'HIERARCHY', got {_show(cur.peek())}")


def _next_root(cur: _Tokens, tree: _Tree) -> bool:
    """Takes a ROOT keyword (True) or the `MOTION` line that ends the hierarchy (False)."""
    if cur.peek() is None:
        raise cur.error("expected 'MOTION' after the hierarchy, got end of file",
                        line=cur.last_line)
    tok = cur.take("ROOT or MOTION")
    key = tok.upper()
    if key == "ROOT":
        return True
    if key == "MOTION":
        if not tree.names:
            raise cur.error("expected a ROOT joint before 'MOTION', got none")
        if cur.on_line():
            raise cur.error(f"expected nothing after 'MOTION', got {_show(cur.peek())}")
        return False
    if tok == "}":
        raise cur.error("expected ROOT or MOTION, got an unmatched '}'")
    raise cur.error(f"expected ROOT or MOTION, got {_show(tok)}")


def _open_brace(cur: _Tokens, owner: str) -> None:
    tok = cur.take(f"'{{' after {owner}")
    if tok != "{":
        raise cur.error(f"expected '{{' after {owner}, got {_show(tok)}")


def _offset_triplet(cur: _Tokens) -> tuple[float, float, float]:
    """The three numbers after OFFSET on its line."""
    values = cur.line_words("OFFSET")
    if len(values) != 3:
        raise cur.error(f"expected 3 numbers after OFFSET, got {len(values)}")
    out = []
    for v in values:
        if not _NUMBER.fullmatch(v):
            raise cur.error(f"expected a number in OFFSET, got {_show(v)}")
        x = float(v)
        if not math.isfinite(x):
            raise cur.error(f"expected a finite number in OFFSET, got {_show(v)}")
        if abs(x) > MAX_VALUE:
            raise cur.error(f"expected a number within +-{MAX_VALUE:g} in OFFSET, got "
                            f"{_show(v)}")
        out.append(x)
    return tuple(out)  # type: ignore[return-value]


def _channel_list(cur: _Tokens) -> tuple[str, ...]:
    """The count and names after CHANNELS on its line, in canonical spelling."""
    words = cur.line_words("CHANNELS")
    if not words or not _DIGITS.fullmatch(words[0]):
        got = _show(words[0]) if words else "none"
        raise cur.error(f"expected a channel count after CHANNELS, got {got}")
    if len(words[0]) > 2 or int(words[0]) > len(CHANNEL_NAMES):
        raise cur.error(f"expected at most {len(CHANNEL_NAMES)} channels (each one once), "
                        f"got a count of {_show(words[0])}")
    count, listed = int(words[0]), words[1:]
    if len(listed) != count:
        raise cur.error(
            f"expected {count} channel names after 'CHANNELS {count}', got {len(listed)}"
        )
    chans: list[str] = []
    for c in listed:
        canon = _CHANNEL_LOOKUP.get(c.lower())
        if canon is None:
            raise cur.error(
                f"expected a channel name ({', '.join(CHANNEL_NAMES)}), got {_show(c)}"
            )
        if canon in chans:
            raise cur.error(f"expected distinct channels, got {canon} twice")
        chans.append(canon)
    return tuple(chans)


def _parse_end_site(cur: _Tokens, tree: _Tree, parent: int) -> None:
    """An `End Site { OFFSET x y z }` block of joint `parent` (its keyword already taken).

    Whatever follows `End` on its line (`Site`, a name as in `End LeftToe_End`) is ignored.
    """
    cur.line_words("End Site")
    _open_brace(cur, "End Site")
    off = None
    while True:
        tok = cur.take(f"'}}' closing the End Site of {tree.names[parent]!r}")
        if tok == "}":
            break
        if tok.upper() != "OFFSET":
            raise cur.error(f"expected OFFSET or '}}' in an End Site, got {_show(tok)}")
        if off is not None:
            raise cur.error("expected one OFFSET in an End Site, got a second one")
        off = _offset_triplet(cur)
    if off is None:
        raise cur.error("expected an OFFSET in the End Site, got none")
    tree.end_sites.append(off)
    tree.end_parents.append(parent)


def _joint_name(cur: _Tokens, keyword: str) -> str:
    """The words after ROOT/JOINT on its line, up to a brace: names may hold spaces (3ds Max's
    "Bip01 L Thigh")."""
    words: list[str] = []
    size = -1
    while cur.on_line(braces=False):
        words.append(cur.take("joint name"))
        size += len(words[-1]) + 1
        if size > MAX_NAME_CHARS:
            raise cur.error(f"expected a joint name of at most {MAX_NAME_CHARS} characters "
                            f"after {keyword}, got {_show(' '.join(words))}")
    if not words:
        raise cur.error(f"expected a joint name after {keyword}, got none")
    return " ".join(words)


def _open_joint(cur: _Tokens, tree: _Tree, parent: int, keyword: str) -> _OpenJoint:
    """The name after ROOT/JOINT (its keyword already taken) and the opening brace; adds the
    joint to the tables."""
    line = cur.line_no
    if len(tree.names) >= MAX_JOINTS:
        raise cur.error(f"expected at most {MAX_JOINTS} joints in a file, got more")
    name = _joint_name(cur, keyword)
    if name in tree.known:
        raise cur.error(f"expected a unique joint name, got {name!r} a second time")
    tree.known.add(name)
    tree.names.append(name)
    tree.parents.append(parent)
    tree.offsets.append((math.nan, math.nan, math.nan))
    tree.channels.append(())
    _open_brace(cur, f"{keyword} {name}")
    return _OpenJoint(len(tree.names) - 1, name, line)


def _close_joint(cur: _Tokens, joint: _OpenJoint) -> None:
    if not joint.have_offset:
        raise cur.error(f"expected an OFFSET for joint {joint.name!r}, got none", line=joint.line)
    if not joint.have_channels:
        raise cur.error(f"expected a CHANNELS line for joint {joint.name!r}, got none",
                        line=joint.line)


def _parse_joint(cur: _Tokens, tree: _Tree) -> None:
    """A ROOT block (its keyword already taken) with all its descendants, to its '}'.

    Iterative, with an explicit stack of open joints, so depth costs no Python recursion.
    """
    stack = [_open_joint(cur, tree, -1, "ROOT")]
    while stack:
        top = stack[-1]
        tok = cur.take(f"'}}' closing joint {top.name!r} (opened at line {top.line})")
        key = tok.upper()
        if tok == "}":
            _close_joint(cur, stack.pop())
        elif key == "OFFSET":
            if top.have_offset:
                raise cur.error(f"expected one OFFSET for joint {top.name!r}, got a second one")
            tree.offsets[top.index] = _offset_triplet(cur)
            top.have_offset = True
        elif key == "CHANNELS":
            if top.have_channels:
                raise cur.error(f"expected one CHANNELS line for joint {top.name!r}, "
                                "got a second")
            tree.channels[top.index] = _channel_list(cur)
            top.have_channels = True
        elif key == "JOINT":
            if len(stack) >= MAX_DEPTH:
                raise cur.error(f"expected joints nested at most {MAX_DEPTH} deep, got deeper")
            stack.append(_open_joint(cur, tree, top.index, "JOINT"))
        elif key in ("END", "ENDSITE"):
            _parse_end_site(cur, tree, top.index)
        else:
            raise _unexpected_in_joint(cur, tok, top.name, top.line)


def _unexpected_in_joint(cur: _Tokens, tok: str, name: str, decl_line: int) -> BvhParseError:
    """The error for a token that has no place inside a joint's braces."""
    key = tok.upper()
    if key == "ROOT":
        return cur.error(f"expected JOINT or '}}' inside joint {name!r}, got ROOT")
    if key == "MOTION":
        return cur.error(
            f"expected '}}' closing joint {name!r} (opened at line {decl_line}) before "
            "'MOTION', got 'MOTION'"
        )
    return cur.error(
        f"expected OFFSET, CHANNELS, JOINT, End Site or '}}' in joint {name!r}, "
        f"got {_show(tok)}"
    )


_FRAMES = re.compile(r"frames\s*:\s*(\S*)\s*(.*)", re.IGNORECASE | re.ASCII)
_FRAME_TIME = re.compile(r"frame\s*time\s*:\s*(\S*)\s*(.*)", re.IGNORECASE | re.ASCII)


def _next_text_line(cur: _Tokens, pos: int, line: int, what: str) -> tuple[str, int, int]:
    """The next non-blank line from byte `pos` (line `line`): its stripped text, its line
    number and the offset after it."""
    data = cur.data
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        raw = data[pos:end].strip()
        pos = end + 1
        if raw:
            if len(raw) > MAX_HEADER_LINE:
                raise cur.error(f"expected {what}, got a line of {len(raw)} characters",
                                line=line)
            return cur._decode(raw, line), line, pos
        line += 1
    raise cur.error(f"expected {what}, got end of file", line=cur.last_line)


def _frame_count(cur: _Tokens, text: str, line: int) -> int:
    m = _FRAMES.fullmatch(text)
    if not m:
        raise cur.error(f"expected 'Frames: N', got {_show(text)}", line=line)
    count = m.group(1)
    if not _DIGITS.fullmatch(count) or m.group(2):
        raise cur.error(f"expected a whole number of frames, got {_show(text)}", line=line)
    if len(count.lstrip("0")) > MAX_FRAME_DIGITS:
        raise cur.error(f"expected a frame count of at most {MAX_FRAME_DIGITS} digits, got "
                        f"{len(count.lstrip('0'))} digits", line=line)
    return int(count)


def _frame_time(cur: _Tokens, text: str, line: int) -> float:
    m = _FRAME_TIME.fullmatch(text)
    if not m:
        raise cur.error(f"expected 'Frame Time: SECONDS', got {_show(text)}", line=line)
    token = m.group(1)
    if _DECIMAL_COMMA.fullmatch(token):  # "0,008333" from a decimal-comma locale
        token = token.replace(",", ".")
    if not _NUMBER.fullmatch(token) or m.group(2):
        raise cur.error(f"expected a number of seconds per frame, got {_show(text)}", line=line)
    frame_time = float(token)
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise cur.error(f"expected a positive frame time, got {_show(token)}", line=line)
    if not MIN_FRAME_TIME <= frame_time <= MAX_FRAME_TIME:
        raise cur.error(f"expected a frame time from {MIN_FRAME_TIME:g} to "
                        f"{MAX_FRAME_TIME:g} s, got {_show(token)}", line=line)
    return frame_time


def _count_words(raw: bytes) -> int:
    """Whitespace-separated words in `raw`, counted in slices so memory stays bounded."""
    count, in_word, step = 0, False, 1 << 16
    for k in range(0, len(raw), step):
        piece = raw[k:k + step]
        count += len(piece.split())
        if in_word and not piece[:1].isspace():
            count -= 1  # a word cut by the slice boundary was counted twice
        in_word = not piece[-1:].isspace()
    return count


def _check_motion_line(raw: bytes, line: int, n_channels: int, path) -> bool:
    """Raises for a malformed motion line; returns whether it holds data (is not blank)."""
    if not raw.isascii():
        raise BvhParseError(path, line, "expected ASCII numbers in the motion data, got "
                            "non-ASCII bytes")
    words = raw.split(None, n_channels)  # at most n_channels + 1 pieces: bounded memory
    if not words:
        return False
    got = len(words) if len(words) <= n_channels else n_channels + _count_words(words[-1])
    if got != n_channels:
        raise BvhParseError(path, line, f"expected {n_channels} values per frame (the "
                            f"channels of the hierarchy), got {got}")
    for col, word in enumerate(words, start=1):
        token = word.decode("ascii")
        if not _NUMBER.fullmatch(token):
            low = token.lower().lstrip("+-")
            kind = "a finite number" if low in ("nan", "inf", "infinity") else "a number"
            raise BvhParseError(path, line, f"expected {kind} in column {col}, got "
                                f"{_show(token)}")
        if not math.isfinite(float(token)):
            raise BvhParseError(path, line,
                                f"expected a finite number in column {col}, got {_show(token)}")
        if abs(float(token)) > MAX_VALUE:
            raise BvhParseError(path, line, f"expected a number within +-{MAX_VALUE:g} in "
                                f"column {col}, got {_show(token)}")
    return True


def _diagnose_motion(data: bytes, pos: int, line: int, n_channels: int, frames: int,
                     frames_line: int, path) -> None:
    """Finds the first malformed motion line from byte `pos` (line `line`) and raises; used
    only when the fast parse failed."""
    # A well-formed line is passed by one regex match (in C); only the others, and lines with an
    # exponent (which may overflow), are taken apart in Python.
    number = _NUMBER.pattern.encode()
    well_formed = re.compile(rb"\s*%s(?:\s+%s){%d}\s*"
                             % (number, number, max(n_channels - 1, 0)))
    data_rows = 0
    while pos < len(data):
        end = data.find(b"\n", pos)
        end = len(data) if end < 0 else end
        raw = data[pos:end]
        if n_channels and well_formed.fullmatch(raw) and b"e" not in raw and b"E" not in raw \
                and not _LONG_DIGITS.search(raw):  # (a run of digits may pass MAX_VALUE)
            data_rows += 1
        else:
            data_rows += _check_motion_line(raw, line, n_channels, path)
        pos, line = end + 1, line + 1
    if data_rows != frames:
        raise BvhParseError(
            path, frames_line,
            f"expected {frames} frames as declared by 'Frames:', got {data_rows} lines of data",
        )


def _parse_motion(cur: _Tokens, n_channels: int) -> Motion:
    """The MOTION block after the hierarchy (the cursor stands on the `MOTION` keyword)."""
    data, path = cur.data, cur.path
    end = data.find(b"\n", cur.end)
    pos, line = (len(data) if end < 0 else end + 1), cur.line_no + 1
    text, frames_line, pos = _next_text_line(cur, pos, line, "'Frames: N'")
    frames = _frame_count(cur, text, frames_line)
    text, line, pos = _next_text_line(cur, pos, frames_line + 1, "'Frame Time: SECONDS'")
    frame_time = _frame_time(cur, text, line)
    line += 1
    block = data[pos:]
    if frames == 0 or n_channels == 0:
        if block and not block.isspace():
            _diagnose_motion(data, pos, line, n_channels, frames, frames_line, path)
            raise BvhParseError(path, frames_line, "expected no motion data, got some")
        if frames:
            raise BvhParseError(path, frames_line, "expected channels for the declared frames")
        return Motion(np.zeros((0, n_channels)), frame_time)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            channels = np.loadtxt(io.BytesIO(block), dtype=np.float64, comments=None, ndmin=2)
    except ValueError:
        channels = None
    if (channels is None or channels.shape != (frames, n_channels)
            or not (np.abs(channels) <= MAX_VALUE).all()):  # (NaN fails it too)
        _diagnose_motion(data, pos, line, n_channels, frames, frames_line, path)
        raise BvhParseError(path, line, "expected numeric motion data")
    return Motion(channels, frame_time)


def _prepared(data: bytes | str, path: str | None) -> bytes:
    """The file's bytes with LF or CRLF line ends (CR-only files rewritten), without a UTF-8
    byte order mark (Windows editors write one), checked for text."""
    if isinstance(data, str):
        data = data.encode("utf-8")
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    # CRLF needs no rewriting (CR is whitespace, lines are counted at LF); a lone CR, as in
    # CR-only files, ends a line too, so those files are rewritten to LF.
    if _LONE_CR.search(data):
        data = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
    if b"\x00" in data:
        line = data.count(b"\n", 0, data.index(b"\x00")) + 1
        raise BvhParseError(path, line, "expected a text BVH file, got binary data (NUL byte)")
    if _NON_SPACE.search(data) is None:  # stops at the first word; strip would copy the file
        raise BvhParseError(path, 1, "expected 'HIERARCHY', got an empty file")
    return data


def parse_bvh(data: bytes | str, *, unit: str | float | None = "auto",
              path: str | os.PathLike | None = None) -> Bvh:
    """Parses BVH content.

    data : the file's bytes (or text).
    unit : metres per file unit, a unit name ("cm", "cmu", ... see `capture.units`), "auto" to
        take the unit of the recognised profile (None when no profile matches), or None.
    path : used in error messages only.
    Raises `BvhParseError` (a ValueError naming the file and line) for a malformed file.
    """
    path = None if path is None else str(path)
    cur = _Tokens(_prepared(data, path), path)
    skeleton = _parse_hierarchy(cur)
    motion = _parse_motion(cur, skeleton.num_channels)
    profile = identify_profile(skeleton.names)
    skeleton = skeleton.with_unit(_choose_unit(unit, profile))
    return Bvh(skeleton, motion, profile, path)


def _choose_unit(unit: str | float | None, profile: str | None) -> float | None:
    from .profiles import PROFILES

    if unit is None:
        return None
    if isinstance(unit, str) and unit.strip().lower() == "auto":
        return PROFILES[profile].unit_m if profile is not None else None
    return resolve_unit(unit)


def read_bvh(path: str | os.PathLike, *, unit: str | float | None = "auto") -> Bvh:
    """Reads a BVH file.

    path : a file path, or `bundled:NAME` for a recording bundled with the package
        (`capture.recordings`).
    unit : metres per file unit or a unit name; "auto" (default) takes the unit of the
        recognised skeleton profile (Perception Neuron: cm; CMU: 0.056444 m) and leaves it
        unknown (None) otherwise, so metric quantities then raise instead of guessing.
    """
    path = resolve_path(path) if isinstance(path, str) else Path(path)
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise BvhParseError(path, None, "expected a BVH file, got a directory") from None
    return parse_bvh(data, unit=unit, path=path)


# -- writing -------------------------------------------------------------------------------


# What the reader splits words at: ASCII whitespace only (it reads bytes).
_ASCII_SPACE = re.compile(r"[ \t\n\r\x0b\x0c]+")


def _check_writable(skeleton: Skeleton, channels: np.ndarray, frame_time: float) -> None:
    """Raises ValueError for what `read_bvh` would refuse, or read back otherwise, once written:
    a joint name it reads differently, a non-finite offset, a frame time outside its bounds."""
    for name in skeleton.names:
        if (not name or "{" in name or "}" in name or "\x00" in name
                or len(name) > MAX_NAME_CHARS
                or " ".join(_ASCII_SPACE.split(name)) != name or name != name.strip(" ")):
            raise ValueError(
                f"Expected joint names a BVH file keeps (1 to {MAX_NAME_CHARS} characters, no "
                "braces, words separated by single spaces, none at either end), got "
                f"{_show(name)}"
            )
    if skeleton.num_joints > MAX_JOINTS or len(skeleton.levels) > MAX_DEPTH:
        raise ValueError(f"Expected at most {MAX_JOINTS} joints nested at most {MAX_DEPTH} deep "
                         f"(what a BVH file may hold), got {skeleton.num_joints} joints "
                         f"{len(skeleton.levels)} deep")
    for what, values, owners in (
            ("an OFFSET", skeleton.offsets, np.arange(skeleton.num_joints)),
            ("an End Site OFFSET", skeleton.end_sites, skeleton.end_site_parents)):
        bad = np.flatnonzero(~(np.abs(values) <= MAX_VALUE).all(axis=1))  # (NaN too)
        if bad.size:
            name = skeleton.names[int(owners[bad[0]])]
            raise ValueError(f"Expected finite numbers within +-{MAX_VALUE:g} in {what} of "
                             f"joint {name!r}, got {values[bad[0]].tolist()}")
    if channels.shape[1:] != (skeleton.num_channels,):
        raise ValueError(
            f"Expected motion channels (T, {skeleton.num_channels}), got {channels.shape}"
        )
    beyond = channels[~(np.abs(channels) <= MAX_VALUE)]  # (NaN too)
    if beyond.size:
        raise ValueError(f"Expected finite motion channels within +-{MAX_VALUE:g}, got "
                         f"{float(beyond[0]):g}")
    try:
        written = float(f"{float(frame_time):.7g}")  # the value the file will hold
    except (TypeError, ValueError):
        written = math.nan
    if not MIN_FRAME_TIME <= written <= MAX_FRAME_TIME:  # (NaN fails the comparison too)
        raise ValueError(f"Expected a frame time from {MIN_FRAME_TIME:g} to "
                         f"{MAX_FRAME_TIME:g} s, got {frame_time!r}")


def format_bvh(skeleton: Skeleton, motion: Motion | None = None) -> str:
    """BVH text for a skeleton and its motion (a header with `Frames: 0` when motion is None).

    Raises ValueError for what the text could not carry so that `parse_bvh` reads it back the
    same: joints not in depth-first order, a joint name the reader would read otherwise, a NaN
    or infinite value, a frame time outside the reader's bounds.
    """
    children: dict[int, list[int]] = {j: [] for j in range(skeleton.num_joints)}
    for j, p in enumerate(skeleton.parents):
        if p >= 0:
            children[int(p)].append(j)
    ends: dict[int, list[int]] = {j: [] for j in range(skeleton.num_joints)}
    for e, p in enumerate(skeleton.end_site_parents):
        ends[int(p)].append(e)
    order = depth_first_order(skeleton.parents)
    if order != list(range(skeleton.num_joints)):
        raise ValueError(
            "Expected joints in depth-first order (the order a BVH file lists them, which fixes "
            f"the channel layout), got the order {order}"
        )
    channels = np.zeros((0, skeleton.num_channels)) if motion is None else motion.channels
    frame_time = 1.0 / 120.0 if motion is None else motion.frame_time
    _check_writable(skeleton, channels, frame_time)
    out = ["HIERARCHY"]

    def numbers(values) -> str:
        return " ".join(f"{v:.6f}" for v in values)

    # An explicit stack (a joint, or the closing lines of one), not recursion: the reader takes
    # joints nested MAX_DEPTH deep, deeper than Python's recursion limit.
    stack: list[int | list[str]] = [int(j) for j in np.flatnonzero(skeleton.parents < 0)][::-1]
    depth = np.zeros(skeleton.num_joints, dtype=np.int64)
    while stack:
        item = stack.pop()
        if isinstance(item, list):
            out.extend(item)
            continue
        j = item
        if skeleton.parents[j] >= 0:
            depth[j] = depth[skeleton.parents[j]] + 1
        pad = "\t" * int(depth[j])
        kw = "ROOT" if skeleton.parents[j] < 0 else "JOINT"
        out.append(f"{pad}{kw} {skeleton.names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET {numbers(skeleton.offsets[j])}")
        chans = skeleton.channels[j]
        out.append(f"{pad}\tCHANNELS {len(chans)}" + "".join(" " + c for c in chans))
        closing = []
        for e in ends[j]:
            closing += [f"{pad}\tEnd Site", f"{pad}\t{{",
                        f"{pad}\t\tOFFSET {numbers(skeleton.end_sites[e])}", f"{pad}\t}}"]
        closing.append(f"{pad}}}")
        stack.append(closing)  # after the children, which are pushed above it
        stack.extend(children[j][::-1])
    out.append("MOTION")
    out.append(f"Frames: {channels.shape[0]}")
    out.append(f"Frame Time: {frame_time:.7g}")
    text = "\n".join(out) + "\n"
    if channels.shape[0]:
        buf = io.StringIO()
        np.savetxt(buf, channels, fmt="%.6f", delimiter=" ")
        text += buf.getvalue()
    return text


def write_bvh(path: str | os.PathLike, skeleton: Skeleton, motion: Motion | None = None) -> None:
    """Writes a BVH file atomically: the file appears whole or not at all."""
    text = format_bvh(skeleton, motion)
    write_atomic(path, text.encode("utf-8"))
