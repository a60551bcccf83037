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


class StreamMonitor:
    """Accumulates what a listener reports; `add` frames as they come, `summary` at any time.

    `first_t` and `last_t` are the earliest and the latest receive time (Unix s) of the frames
    so far (a clock set back while frames came never makes the span negative); frames without
    a finite receive time count as frames but not in the rate or the latency.
    """

    def __init__(self) -> None:
        self.count = 0
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._timed = 0
        self._indexed_t: list[float] = []
        self._indices: list[int] = []

    def add(self, frames: list[NeuronFrame]) -> None:
        for f in frames:
            t = f.received_at
            self.count += 1
            if t is None or not math.isfinite(t):
                continue
            self._timed += 1
            self.first_t = t if self.first_t is None else min(self.first_t, t)
            self.last_t = t if self.last_t is None else max(self.last_t, t)
            if f.frame_index is not None:
                self._indices.append(f.frame_index)
                self._indexed_t.append(t)

    def duration_s(self) -> float | None:
        """Seconds from the earliest to the latest receive time; None before any."""
        if self.first_t is None:
            return None
        return _finite(self.last_t - self.first_t)

    def fps(self) -> float | None:
        """Frames per second received; None over no time (fewer than two frames)."""
        span = self.duration_s()
        if self._timed < 2 or span is None or span <= 0:
            return None
        return _finite((self._timed - 1) / span)

    def period(self) -> float | None:
        """The sender's frame period (s) from its indices, across restarts; None if unknown."""
        return sender_timing(self._indices, self._indexed_t)[0]

    def latency_ms(self) -> tuple[float | None, float | None]:
        """Mean and largest arrival delay beyond the least-delayed frame, in milliseconds."""
        period, delay = sender_timing(self._indices, self._indexed_t)
        if period is None:
            return None, None
        with np.errstate(all="ignore"):
            mean, worst = _finite(float(delay.mean()) * 1e3), _finite(float(delay.max()) * 1e3)
        if mean is None or worst is None:
            return None, None
        return mean, worst

    def summary(self, stats: dict) -> dict:
        """The listener's summary: decoder counters merged with rates and latency."""
        mean, worst = self.latency_ms()
        fps = self.fps()
        out = dict(stats)
        out.update(
            fps=fps,
            duration_s=self.duration_s(),
            latency_ms=mean,
            latency_max_ms=worst,
        )
        return out
