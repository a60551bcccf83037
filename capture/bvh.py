"""Reading and writing BVH motion files.

A BVH file is a HIERARCHY block (joints with OFFSET, CHANNELS and End Site entries) followed by a
MOTION block (`Frames:`, `Frame Time:`, then one line of channel values per frame). The hierarchy
is tokenised line by line (it is small); the motion block, which holds nearly all of the bytes, is
parsed in one vectorised call and only re-read line by line when it is malformed, to name the line.

Accepted variations: any of the six rotation orders per joint (and subsets of axes), position
channels on any joint, keywords in any capitalisation (`End Site`, `END SITE`, `EndSite`), tabs,
CRLF or LF line ends, braces on the keyword's line or their own, joint names containing spaces,
`:` or `.`. See `capture.skeleton` for the frame and channel conventions.
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
_NUMBER = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_MAX_SHOWN = 40


def _show(token: str) -> str:
    return repr(token if len(token) <= _MAX_SHOWN else token[:_MAX_SHOWN] + "...")


class _Lines:
    """Cursor over the header's tokens, each tagged with its 1-based line number.

    lines : the file's raw lines (bytes); a line is decoded only when the cursor reaches it.
    """

    def __init__(self, lines: list[bytes], path: str | None):
        self.lines = lines
        self.path = path
        self.i = 0
        self.tokens: list[str] = []
        self.line_no = 0

    def text(self, k: int) -> str:
        try:
            return self.lines[k].decode("utf-8")
        except UnicodeDecodeError:
            raise BvhParseError(self.path, k + 1, "expected UTF-8 text, got undecodable bytes "
                                "(is this a binary file?)") from None

    def error(self, message: str, line: int | None = None) -> BvhParseError:
        return BvhParseError(self.path, line if line is not None else max(self.line_no, 1), message)

    def _fill(self) -> bool:
        while not self.tokens:
            if self.i >= len(self.lines):
                return False
            raw = self.text(self.i)
            self.i += 1
            self.line_no = self.i
            self.tokens = _tokenise_line(raw)
        return True

    def peek(self) -> str | None:
        return self.tokens[0] if self._fill() else None

    @property
    def last_line(self) -> int:
        """1-based number of the last line that holds anything: where end of file is met."""
        k = len(self.lines)
        while k > 1 and not self.lines[k - 1].strip():
            k -= 1
        return k

    def take(self, what: str) -> str:
        if not self._fill():
            raise self.error(f"expected {what}, got end of file", line=self.last_line)
        return self.tokens.pop(0)

    def rest_of_line(self) -> list[str]:
        rest, self.tokens = self.tokens, []
        return rest


def _tokenise_line(raw: str) -> list[str]:
    # Braces are tokens of their own even when glued to a word ("Hips{").
    text = raw.replace("{", " { ").replace("}", " } ")
    words = text.split()
    if not words:
        return []
    head = words[0].lower()
    if head in ("root", "joint"):
        # A joint name is the rest of the line (3ds Max names such as "Bip01 L Thigh" have spaces).
        body = words[1:]
        tail = []
        while body and body[-1] in ("{", "}"):
            tail.insert(0, body.pop())
        return [words[0].upper(), " ".join(body)] + tail if body else [words[0].upper()] + tail
    if head == "endsite" or (head == "end" and len(words) > 1 and words[1].lower() == "site"):
        return ["END SITE"] + words[(1 if head == "endsite" else 2):]
    return words


@dataclass
class _Tree:
    """The hierarchy's tables as they are read, in file (depth-first) order."""

    names: list[str] = field(default_factory=list)
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


def _parse_hierarchy(cur: _Lines) -> Skeleton:
    tree = _Tree()
    _hierarchy_keyword(cur)
    while _next_root(cur, tree):
        _parse_joint(cur, tree, -1, "ROOT")
    return tree.skeleton()


def _hierarchy_keyword(cur: _Lines) -> None:
    """The file's first line: `HIERARCHY` alone."""
    first = cur.peek()
    if first is None:
        raise cur.error("expected 'HIERARCHY', got an empty file", line=1)
    if first.upper() != "HIERARCHY":
        raise cur.error(f"expected 'HIERARCHY' to start a BVH file, got {_show(first)}")
    cur.take("HIERARCHY")
    extra = cur.rest_of_line()
    if extra:
        raise cur.error(f"expected nothing after 'HIERARCHY', got {_show(extra[0])}")


def _next_root(cur: _Lines, tree: _Tree) -> bool:
    """Takes a ROOT keyword (True) or the `MOTION` line that ends the hierarchy (False)."""
    tok = cur.peek()
    if tok is None:
        raise cur.error("expected 'MOTION' after the hierarchy, got end of file",
                        line=cur.last_line)
    key = tok.upper()
    if key == "ROOT":
        cur.take("ROOT")
        return True
    if key == "MOTION":
        if not tree.names:
            raise cur.error("expected a ROOT joint before 'MOTION', got none")
        cur.take("MOTION")
        extra = cur.rest_of_line()
        if extra:
            raise cur.error(f"expected nothing after 'MOTION', got {_show(extra[0])}")
        return False
    if tok == "}":
        raise cur.error("expected ROOT or MOTION, got an unmatched '}'")
    raise cur.error(f"expected ROOT or MOTION, got {_show(tok)}")


def _open_brace(cur: _Lines, owner: str) -> None:
    tok = cur.take(f"'{{' after {owner}")
    if tok != "{":
        raise cur.error(f"expected '{{' after {owner}, got {_show(tok)}")


def _offset_triplet(cur: _Lines) -> tuple[float, float, float]:
    """The three numbers after OFFSET, the rest of its line."""
    values = cur.rest_of_line()
    if len(values) != 3:
        raise cur.error(f"expected 3 numbers after OFFSET, got {len(values)}")
    out = []
    for v in values:
        if not _NUMBER.fullmatch(v):
            raise cur.error(f"expected a number in OFFSET, got {_show(v)}")
        x = float(v)
        if not math.isfinite(x):
            raise cur.error(f"expected a finite number in OFFSET, got {_show(v)}")
        out.append(x)
    return tuple(out)  # type: ignore[return-value]


def _channel_list(cur: _Lines) -> tuple[str, ...]:
    """The count and names after CHANNELS, the rest of its line, in canonical spelling."""
    count_tok = cur.take("channel count")
    if not count_tok.isdigit():
        raise cur.error(f"expected a channel count after CHANNELS, got {_show(count_tok)}")
    count = int(count_tok)
    listed = cur.rest_of_line()
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


def _parse_end_site(cur: _Lines, tree: _Tree, parent: int) -> None:
    """An `End Site { OFFSET x y z }` block of joint `parent` (its keyword already taken)."""
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


def _joint_header(cur: _Lines, tree: _Tree, parent: int, keyword: str) -> tuple[int, str]:
    """The name after ROOT/JOINT and the opening brace; adds the joint and returns its index."""
    if not cur.tokens or cur.tokens[0] == "{":
        raise cur.error(f"expected a joint name after {keyword}, got none")
    name = cur.take("joint name")
    if name in tree.names:
        raise cur.error(f"expected a unique joint name, got {name!r} a second time")
    tree.names.append(name)
    tree.parents.append(parent)
    tree.offsets.append((math.nan, math.nan, math.nan))
    tree.channels.append(())
    _open_brace(cur, f"{keyword} {name}")
    return len(tree.names) - 1, name


def _parse_joint(cur: _Lines, tree: _Tree, parent: int, keyword: str) -> None:
    """A ROOT or JOINT block (its keyword already taken), with its children, to its '}'."""
    decl_line = cur.line_no
    j, name = _joint_header(cur, tree, parent, keyword)
    have_offset = have_channels = False
    while True:
        tok = cur.take(f"'}}' closing joint {name!r} (opened at line {decl_line})")
        if tok == "}":
            break
        key = tok.upper()
        if key == "OFFSET":
            if have_offset:
                raise cur.error(f"expected one OFFSET for joint {name!r}, got a second one")
            tree.offsets[j] = _offset_triplet(cur)
            have_offset = True
        elif key == "CHANNELS":
            if have_channels:
                raise cur.error(f"expected one CHANNELS line for joint {name!r}, got a second")
            tree.channels[j] = _channel_list(cur)
            have_channels = True
        elif key == "JOINT":
            _parse_joint(cur, tree, j, "JOINT")
        elif key == "END SITE":
            _parse_end_site(cur, tree, j)
        else:
            raise _unexpected_in_joint(cur, tok, name, decl_line)
    if not have_offset:
        raise cur.error(f"expected an OFFSET for joint {name!r}, got none", line=decl_line)
    if not have_channels:
        raise cur.error(f"expected a CHANNELS line for joint {name!r}, got none",
                        line=decl_line)


def _unexpected_in_joint(cur: _Lines, tok: str, name: str, decl_line: int) -> BvhParseError:
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


_FRAMES = re.compile(r"frames\s*:\s*(\S*)\s*(.*)", re.IGNORECASE)
_FRAME_TIME = re.compile(r"frame\s*time\s*:\s*(\S*)\s*(.*)", re.IGNORECASE)


def _motion_header(cur: _Lines) -> tuple[int, float, int]:
    """Parses `Frames:` and `Frame Time:`; returns frames, frame time and the Frames line."""

    def next_line(what: str) -> tuple[str, int]:
        while cur.i < len(cur.lines):
            text = cur.text(cur.i).strip()
            cur.i += 1
            if text:
                return text, cur.i
        raise cur.error(f"expected {what}, got end of file", line=cur.last_line)

    text, frames_line = next_line("'Frames: N'")
    m = _FRAMES.fullmatch(text)
    if not m:
        raise cur.error(f"expected 'Frames: N', got {_show(text)}", line=frames_line)
    if not m.group(1).isdigit() or m.group(2):
        raise cur.error(f"expected a whole number of frames, got {_show(text)}", line=frames_line)
    frames = int(m.group(1))
    text, line = next_line("'Frame Time: SECONDS'")
    m = _FRAME_TIME.fullmatch(text)
    if not m:
        raise cur.error(f"expected 'Frame Time: SECONDS', got {_show(text)}", line=line)
    token = m.group(1)
    if not _NUMBER.fullmatch(token) or m.group(2):
        raise cur.error(f"expected a number of seconds per frame, got {_show(text)}", line=line)
    frame_time = float(token)
    if not (math.isfinite(frame_time) and frame_time > 0):
        raise cur.error(f"expected a positive frame time, got {_show(token)}", line=line)
    return frames, frame_time, frames_line


def _diagnose_motion(
    lines: list[bytes], first: int, n_channels: int, frames: int, frames_line: int, path
) -> None:
    """Finds the first malformed motion line and raises; used only when the fast parse failed."""
    data_rows = 0
    for k in range(first, len(lines)):
        line_no = k + 1
        try:
            text = lines[k].decode("ascii")
        except UnicodeDecodeError:
            raise BvhParseError(path, line_no, "expected ASCII numbers in the motion data, got "
                                "non-ASCII bytes") from None
        tokens = text.split()
        if not tokens:
            continue
        data_rows += 1
        if len(tokens) != n_channels:
            raise BvhParseError(
                path, line_no,
                f"expected {n_channels} values per frame (the channels of the hierarchy), "
                f"got {len(tokens)}",
            )
        for col, token in enumerate(tokens, start=1):
            if not _NUMBER.fullmatch(token):
                low = token.lower().lstrip("+-")
                if low in ("nan", "inf", "infinity"):
                    raise BvhParseError(path, line_no,
                                        f"expected a finite number in column {col}, got {_show(token)}")
                raise BvhParseError(path, line_no,
                                    f"expected a number in column {col}, got {_show(token)}")
            if not math.isfinite(float(token)):
                raise BvhParseError(path, line_no,
                                    f"expected a finite number in column {col}, got {_show(token)}")
    if data_rows != frames:
        raise BvhParseError(
            path, frames_line,
            f"expected {frames} frames as declared by 'Frames:', got {data_rows} lines of data",
        )


def parse_bvh(data: bytes | str, *, unit: str | float | None = "auto",
              path: str | os.PathLike | None = None) -> Bvh:
    """Parses BVH content.

    data : the file's bytes (or text).
    unit : metres per file unit, a unit name ("cm", "cmu", ... see `capture.units`), "auto" to
        take the unit of the recognised profile (None when no profile matches), or None.
    path : used in error messages only.
    """
    if isinstance(data, str):
        data = data.encode("utf-8")
    path = None if path is None else str(path)
    if b"\x00" in data:
        line = data.count(b"\n", 0, data.index(b"\x00")) + 1
        raise BvhParseError(path, line, "expected a text BVH file, got binary data (NUL byte)")
    if not data.strip():
        raise BvhParseError(path, 1, "expected 'HIERARCHY', got an empty file")
    raw_lines = data.split(b"\n")
    # The hierarchy and motion header are decoded as text; the motion data stays as bytes.
    cur = _Lines(raw_lines, path)
    skeleton = _parse_hierarchy(cur)
    frames, frame_time, frames_line = _motion_header(cur)
    first_data = cur.i
    n_channels = skeleton.num_channels

    offset = sum(len(raw_lines[k]) + 1 for k in range(first_data))
    block = data[offset:]
    channels = None
    if frames == 0 or n_channels == 0:
        if block.strip():
            _diagnose_motion(raw_lines, first_data, n_channels, frames, frames_line, path)
            raise BvhParseError(path, frames_line, "expected no motion data, got some")
        channels = np.zeros((0 if frames == 0 else frames, n_channels))
        if frames and n_channels == 0:
            raise BvhParseError(path, frames_line, "expected channels for the declared frames")
    else:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                channels = np.loadtxt(io.BytesIO(block), dtype=np.float64, comments=None, ndmin=2)
        except ValueError:
            channels = None
        if (channels is None or channels.shape != (frames, n_channels)
                or not np.isfinite(channels).all()):
            _diagnose_motion(raw_lines, first_data, n_channels, frames, frames_line, path)
            raise BvhParseError(path, first_data + 1, "expected numeric motion data")

    profile = identify_profile(skeleton.names)
    unit_m = _choose_unit(unit, profile)
    skeleton = skeleton.with_unit(unit_m)
    return Bvh(skeleton, Motion(channels, frame_time), profile, path)


def _choose_unit(unit: str | float | None, profile: str | None) -> float | None:
    from .profiles import PROFILES

    if unit is None:
        return None
    if isinstance(unit, str) and unit.strip().lower() == "auto":
        return PROFILES[profile].unit_m if profile is not None else None
    return resolve_unit(unit)


def read_bvh(path: str | os.PathLike, *, unit: str | float | None = "auto") -> Bvh:
    """Reads a BVH file.

    path : a file path.
    unit : metres per file unit or a unit name; "auto" (default) takes the unit of the
        recognised skeleton profile (Perception Neuron: cm; CMU: 0.056444 m) and leaves it
        unknown (None) otherwise, so metric quantities then raise instead of guessing.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except IsADirectoryError:
        raise BvhParseError(path, None, "expected a BVH file, got a directory") from None
    return parse_bvh(data, unit=unit, path=path)


# -- writing -------------------------------------------------------------------------------


def format_bvh(skeleton: Skeleton, motion: Motion | None = None) -> str:
    """BVH text for a skeleton and its motion (a header with `Frames: 0` when motion is None)."""
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
    out = ["HIERARCHY"]

    def emit(j: int, depth: int) -> None:
        pad = "\t" * depth
        kw = "ROOT" if skeleton.parents[j] < 0 else "JOINT"
        out.append(f"{pad}{kw} {skeleton.names[j]}")
        out.append(f"{pad}{{")
        out.append(f"{pad}\tOFFSET " + " ".join(f"{v:.6f}" for v in skeleton.offsets[j]))
        chans = skeleton.channels[j]
        out.append(f"{pad}\tCHANNELS {len(chans)}" + "".join(" " + c for c in chans))
        for c in children[j]:
            emit(c, depth + 1)
        for e in ends[j]:
            out.append(f"{pad}\tEnd Site")
            out.append(f"{pad}\t{{")
            out.append(f"{pad}\t\tOFFSET " + " ".join(f"{v:.6f}" for v in skeleton.end_sites[e]))
            out.append(f"{pad}\t}}")
        out.append(f"{pad}}}")

    for j in np.flatnonzero(skeleton.parents < 0):
        emit(int(j), 0)
    channels = np.zeros((0, skeleton.num_channels)) if motion is None else motion.channels
    frame_time = 1.0 / 120.0 if motion is None else motion.frame_time
    if channels.shape[1:] != (skeleton.num_channels,):
        raise ValueError(
            f"Expected motion channels (T, {skeleton.num_channels}), got {channels.shape}"
        )
    if not np.isfinite(channels).all():
        raise ValueError("Expected finite motion channels, got NaN or inf")
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
