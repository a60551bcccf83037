"""Live statistics of a received stream: frame rate, counters and arrival latency.

Latency is measured against the sender's clock as far as the stream reveals it: from frames that
carry the sender's frame index, the sender's period is estimated, and each frame's arrival delay
is taken beyond the least-delayed frame. It shows queueing and jitter on the way (network,
buffers, this process), not the constant part of the delay, which no receiver can see without a
shared clock.

The index is a clock only while it counts on: where it goes backwards, repeats or jumps
implausibly far (a sender that restarted or loops its file, a reconnection to a restarted Axis,
a damaged index), the run is split into segments, and the period is fitted over all segments
at once with a clock offset of its own for each.

Every figure is a finite number or None (a figure that cannot be computed: a rate over no time,
a latency without a sender's clock); receive times that are not finite are left out.
"""

from __future__ import annotations

import math

import numpy as np

from .avatars import AvatarKey, avatar_key
from .neuron import MAX_INDEX_GAP, NeuronFrame


def index_segments(indices: np.ndarray) -> np.ndarray:
    """Segment number of each frame: a new segment starts wherever the u32 index does not
    count on by 1 to `MAX_INDEX_GAP` frames.

    indices : (n,) int, the sender's frame indices in arrival order. Returns (n,) int.
    """
    idx = np.asarray(indices, dtype=np.int64)
    step = np.diff(idx) & 0xFFFFFFFF
    breaks = (step == 0) | (step > MAX_INDEX_GAP)
    return np.concatenate([[0], np.cumsum(breaks)]).astype(np.int64)


def sender_timing(indices: np.ndarray, times: np.ndarray) -> tuple[float | None, np.ndarray]:
    """The sender's frame period and each frame's arrival delay beyond the least-delayed frame
    of its segment.

    indices : (n,) int sender frame indices; times : (n,) finite float receive times (s).
    Returns (period in s or None when no segment spans two frames or the times give no
    finite positive period, (n,) finite delays in s: zeros when the period is None).
    Raises ValueError for a time that is not finite.
    """
    idx = np.asarray(indices, dtype=np.int64)
    t = np.asarray(times, dtype=np.float64)
    if len(idx) != len(t):
        raise ValueError(f"Expected as many receive times as indices ({len(idx)}), got {len(t)}")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise ValueError(f"Expected finite receive times, got {t[bad[0]]} at frame {bad[0]}")
    if len(idx) < 2:
        return None, np.zeros(len(idx))
    with np.errstate(all="ignore"):  # (times far apart overflow: no period then)
        period, delays = _fit_period(idx, t)
    if period is None or not math.isfinite(period) or period <= 0 or not np.all(
            np.isfinite(delays)):
        return None, np.zeros(len(idx))
    return period, delays


def _fit_period(idx: np.ndarray, t: np.ndarray) -> tuple[float | None, np.ndarray]:
    """`sender_timing` without its checks: the period may come out non-finite or <= 0."""
    seg = index_segments(idx)
    steps = np.diff(idx) & 0xFFFFFFFF
    steps[np.diff(seg) > 0] = 0
    clock = np.concatenate([[0], np.cumsum(steps)]).astype(np.float64)  # unwrapped, per segment
    first = np.searchsorted(seg, seg)  # each frame's segment start
    k = clock - clock[first]
    u = t - t[first]
    # least squares through each segment's start: one slope (the period) for all of them
    denom = float(np.dot(k, k))
    if not denom > 0:
        return None, np.zeros(len(idx))
    period = float(np.dot(k, u)) / denom
    offsets = t - k * period
    lowest = np.full(seg[-1] + 1, np.inf)
    np.minimum.at(lowest, seg, offsets)
    return period, offsets - lowest[seg]


def _finite(value: float | None) -> float | None:
    """`value`, or None where it is not a finite number."""
    return value if value is not None and math.isfinite(value) else None


class _AvatarClock:
    """What the monitor keeps of one avatar's frames: count, receive-time span and the
    sender's indices with their receive times."""

    def __init__(self) -> None:
        self.count = 0
        self.timed = 0
        self.first_t: float | None = None
        self.last_t: float | None = None
        self.indices: list[int] = []
        self.times: list[float] = []

    def add(self, f: NeuronFrame) -> None:
        self.count += 1
        t = f.received_at
        if t is None or not math.isfinite(t):
            return
        self.timed += 1
        self.first_t = t if self.first_t is None else min(self.first_t, t)
        self.last_t = t if self.last_t is None else max(self.last_t, t)
        if f.frame_index is not None:
            self.indices.append(f.frame_index)
            self.times.append(t)

    def fps(self) -> float | None:
        if self.first_t is None or self.timed < 2:
            return None
        span = _finite(self.last_t - self.first_t)
        if span is None or span <= 0:
            return None
        return _finite((self.timed - 1) / span)


class StreamMonitor:
    """Accumulates what a listener reports; `add` frames as they come, `summary` at any time.

    Frames are kept apart by avatar (Axis sends one frame per avatar per sample when several
    people wear suits, each avatar with its own frame index): `avatars` counts each avatar's
    frames, and the rate and latency are those of one avatar's frames (the kept avatar with
    the most frames), never of the mixture. `selector` (a `capture.avatars.AvatarSelector`)
    keeps one avatar: the others are counted in `avatars` and nowhere else.

    `count` is the number of kept frames; `first_t` and `last_t` are the earliest and the
    latest receive time (Unix s) of the kept frames so far (a clock set back while frames came
    never makes the span negative); frames without a finite receive time count as frames but
    not in the rate or the latency.
    """

    def __init__(self, selector=None) -> None:
        self.selector = selector
        self.count = 0
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._clocks: dict[AvatarKey, _AvatarClock] = {}

    def kept(self, key: AvatarKey) -> bool:
        """Whether frames of avatar `key` are kept (every avatar without a selector)."""
        return self.selector is None or self.selector.matches(key)

    def add(self, frames: list[NeuronFrame]) -> None:
        for f in frames:
            key = avatar_key(f)
            clock = self._clocks.get(key)
            if clock is None:
                clock = self._clocks[key] = _AvatarClock()
            clock.add(f)
            if not self.kept(key):
                continue
            self.count += 1
            t = f.received_at
            if t is None or not math.isfinite(t):
                continue
            self.first_t = t if self.first_t is None else min(self.first_t, t)
            self.last_t = t if self.last_t is None else max(self.last_t, t)

    @property
    def avatars(self) -> dict[AvatarKey, int]:
        """Frames of each avatar seen (kept or not), in the order they first appeared."""
        return {k: c.count for k, c in self._clocks.items()}

    def add_up_to(self, frames: list[NeuronFrame], limit: int | None) -> bool:
        """Adds `frames` (as `add`), with a `limit` only up to the one that brings a kept
        avatar's frames to it; whether that count is reached (False without a limit)."""
        if limit is None:
            self.add(frames)
            return False
        for frame in frames:
            self.add([frame])
            key = avatar_key(frame)  # (only its avatar's count moved)
            if self.kept(key) and self._clocks[key].count >= limit:
                return True
        return self.most_kept() >= limit

    def most_kept(self) -> int:
        """The frames of the kept avatar with the most of them (0 before any)."""
        return max((c.count for k, c in self._clocks.items() if self.kept(k)), default=0)

    def _main(self) -> _AvatarClock | None:
        """The kept avatar with the most frames: its frames give the rate and latency."""
        kept = [c for k, c in self._clocks.items() if self.kept(k)]
        return max(kept, key=lambda c: c.count) if kept else None

    def duration_s(self) -> float | None:
        """Seconds from the earliest to the latest receive time; None before any."""
        if self.first_t is None:
            return None
        return _finite(self.last_t - self.first_t)

    def fps(self) -> float | None:
        """Frames per second of one avatar received; None over no time (fewer than two
        frames)."""
        main = self._main()
        return None if main is None else main.fps()

    def period(self) -> float | None:
        """The sender's frame period (s) from its indices, across restarts; None if unknown."""
        main = self._main()
        return None if main is None else sender_timing(main.indices, main.times)[0]

    def latency_ms(self) -> tuple[float | None, float | None]:
        """Mean and largest arrival delay beyond the least-delayed frame, in milliseconds."""
        main = self._main()
        if main is None:
            return None, None
        period, delay = sender_timing(main.indices, main.times)
        if period is None:
            return None, None
        with np.errstate(all="ignore"):
            mean, worst = _finite(float(delay.mean()) * 1e3), _finite(float(delay.max()) * 1e3)
        if mean is None or worst is None:
            return None, None
        return mean, worst

    def avatar_rows(self, decoder_rows: list[dict] | None = None) -> list[dict]:
        """Each avatar seen, in the order they first appeared: index, name, frames (given to
        the monitor), fps, kept, and the decoder's dropped, restarts, first_index and
        last_index of its frames where `decoder_rows` (`DecoderStats.avatar_dicts()`) has
        them."""
        by_key = {(r["index"], r["name"]): r for r in decoder_rows or ()}
        rows = []
        for key, clock in self._clocks.items():
            row = {"index": key.index, "name": key.name, "frames": clock.count,
                   "fps": clock.fps(), "kept": self.kept(key)}
            decoded = by_key.get((key.index, key.name), {})
            for field in ("dropped", "restarts", "damaged_index", "first_index", "last_index"):
                row[field] = decoded.get(field)
            rows.append(row)
        return rows

    def summary(self, stats: dict) -> dict:
        """The listener's summary: decoder counters merged with rates and latency, and
        `avatars` (see `avatar_rows`). With a selector, `frames`, `dropped`, `restarts`,
        `damaged_index`, `first_index` and `last_index` are those of the kept avatar."""
        mean, worst = self.latency_ms()
        fps = self.fps()
        out = dict(stats)
        rows = self.avatar_rows(out.pop("avatars", None))
        out.update(
            fps=fps,
            duration_s=self.duration_s(),
            latency_ms=mean,
            latency_max_ms=worst,
            avatars=rows,
        )
        if self.selector is not None:
            kept = [r for r in rows if r["kept"]]
            out["avatar"] = self.selector.text
            out["frames"] = sum(r["frames"] for r in kept)
            for field in ("dropped", "restarts", "damaged_index"):
                out[field] = sum(r[field] or 0 for r in kept)
            out["first_index"] = kept[0]["first_index"] if kept else None
            out["last_index"] = kept[0]["last_index"] if kept else None
        return out
