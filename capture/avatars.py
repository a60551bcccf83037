"""Several avatars on one stream: telling them apart, choosing one, and naming their takes.

When several people wear suits, Axis Neuron and Axis Studio broadcast one frame per avatar per
sample on the same stream: a binary frame carries the avatar's index and name in its header, a
string frame starts with them (`<avatar index> <avatar name> ...`). Each avatar counts its own
frame index. An avatar is identified by the pair (index, name), as the frames carry it.

A recording never mixes avatars: with a chosen avatar (`avatar_selector`, a name or an index)
it keeps that avatar's frames alone; without one, each avatar seen becomes a take of its own
(`avatar_take_names`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Mapping

from .neuron import NeuronFrame


@dataclass(frozen=True)
class AvatarKey:
    """An avatar as its frames name it: the avatar index and the avatar name."""

    index: int
    name: str

    @property
    def label(self) -> str:
        """`Avatar01 (index 1)`: how messages name the avatar."""
        return f"{self.name or '(no name)'} (index {self.index})"

    def as_dict(self) -> dict:
        return {"index": self.index, "name": self.name}


def avatar_key(frame: NeuronFrame) -> AvatarKey:
    """The avatar a frame belongs to."""
    return AvatarKey(int(frame.avatar_index), frame.avatar_name)


class AvatarNotSeenError(ValueError):
    """The chosen avatar never appeared in the stream: `what` says so, naming the avatars that
    came, and the message adds what to do; `avatars` lists those that came, as plain data
    ({"index", "name", "frames"}), in the order they first appeared."""

    def __init__(self, what: str, advice: str, avatars: list[dict]):
        super().__init__(f"{what} {advice}")
        self.what = what
        self.avatars = avatars


@dataclass(frozen=True)
class AvatarSelector:
    """A chosen avatar: `text` is its index in decimal digits, or else its name.

    A frame matches when `text` is a whole number equal to the frame's avatar index, or, for
    any other text, when its avatar name equals `text`: one avatar, never two (an avatar named
    "1" beside the avatar of index 1 is chosen by its own index).
    """

    text: str

    def matches(self, frame: NeuronFrame | AvatarKey) -> bool:
        if isinstance(frame, AvatarKey):
            index, name = frame.index, frame.name
        else:
            index, name = frame.avatar_index, frame.avatar_name
        if self.text.isdecimal():
            return int(self.text) == index
        return name == self.text

    def not_seen(self, counts: Mapping[AvatarKey, int], *, takes: bool = False
                 ) -> AvatarNotSeenError:
        """The error for a stream in which this avatar never appeared, naming those that did
        (`counts`: frames of each avatar seen); `takes`: the stream was being recorded, and
        without --avatar each avatar would become a take of its own."""
        seen = describe_avatars(counts) if counts else "no frame of any avatar"
        every = " (each as a take of its own)" if takes else ""
        return AvatarNotSeenError(
            f"No frame of avatar {self.text!r} arrived; the stream carried {seen}.",
            "Pass --avatar with one of those names or indices, or leave --avatar out to keep "
            f"every avatar{every}",
            [k.as_dict() | {"frames": int(n)} for k, n in counts.items()])


def avatar_selector(text: str | int | None) -> AvatarSelector | None:
    """The avatar chosen by `text` (a name or an index; surrounding blanks ignored), or None
    for no choice (None). Raises ValueError for an empty text."""
    if text is None:
        return None
    if isinstance(text, int) and not isinstance(text, bool):
        if text < 0:
            raise ValueError(f"Expected an avatar index >= 0, got {text}")
        return AvatarSelector(str(text))
    chosen = str(text).strip()
    if not chosen:
        raise ValueError(f"Expected an avatar name or index, got {text!r}")
    return AvatarSelector(chosen)


def split_by_avatar(frames: Iterable[NeuronFrame]) -> dict[AvatarKey, list[NeuronFrame]]:
    """Each avatar's frames, in arrival order; the avatars in the order they first appeared."""
    out: dict[AvatarKey, list[NeuronFrame]] = {}
    for f in frames:
        out.setdefault(avatar_key(f), []).append(f)
    return out


def count_by_avatar(frames: Iterable[NeuronFrame],
                    counts: dict[AvatarKey, int] | None = None) -> dict[AvatarKey, int]:
    """Adds each avatar's number of frames in `frames` to `counts` (a new dict if None)."""
    counts = {} if counts is None else counts
    for f in frames:
        key = avatar_key(f)
        counts[key] = counts.get(key, 0) + 1
    return counts


def describe_avatars(counts: Mapping[AvatarKey, int]) -> str:
    """`Avatar00 (index 0, 12 frames), Avatar01 (index 1, 11 frames)`."""
    return ", ".join(f"{k.name or '(no name)'} (index {k.index}, {n} frame"
                     f"{'' if n == 1 else 's'})" for k, n in counts.items())


def _name_part(name: str) -> str:
    """An avatar name as a part of a take name: no '/', control characters or blanks."""
    cleaned = "".join("_" if c == "/" or not c.isprintable() or c.isspace() else c
                      for c in name).strip("_")
    return cleaned


def avatar_take_names(take: str, avatars: Iterable[AvatarKey]) -> dict[AvatarKey, str]:
    """The take name of each avatar of a recording named `take`: `take` itself when one
    avatar was seen, else `<take>-<avatar name>` (`<take>-<name>-<index>` where two avatars
    share a name, `<take>-avatar<index>` for an avatar without a usable name)."""
    keys = list(dict.fromkeys(avatars))
    if len(keys) <= 1:
        return {k: take for k in keys}
    parts = {k: _name_part(k.name) for k in keys}
    shared = {p for p in parts.values() if list(parts.values()).count(p) > 1}
    out = {}
    for k in keys:
        part = parts[k]
        if not part:
            part = f"avatar{k.index}"
        elif part in shared:
            part = f"{part}-{k.index}"
        out[k] = f"{take}-{part}"
    return out
