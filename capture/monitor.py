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
"""

from __future__ import annotations

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

    indices : (n,) int sender frame indices; times : (n,) float receive times (s).
    Returns (period in s or None when no segment spans two frames, (n,) delays in s).
    """
    idx = np.asarray(indices, dtype=np.int64)
    t = np.asarray(times, dtype=np.float64)
    if len(idx) < 2:
        return None, np.zeros(len(idx))
    seg = index_segments(idx)
    steps = np.diff(idx) & 0xFFFFFFFF
    steps[np.diff(seg) > 0] = 0
    clock = np.concatenate([[0], np.cumsum(steps)]).astype(np.float64)  # unwrapped, per segment
    first = np.searchsorted(seg, seg)  # each frame's segment start
    k = clock - clock[first]
    u = t - t[first]
    # least squares through each segment's start: one slope (the period) for all of them
    denom = float(np.dot(k, k))
    if denom <= 0:
        return None, np.zeros(len(idx))
    period = float(np.dot(k, u)) / denom
    offsets = t - k * period
    lowest = np.full(seg[-1] + 1, np.inf)
    np.minimum.at(lowest, seg, offsets)
    return (period if period > 0 else None), offsets - lowest[seg]


class StreamMonitor:
    """Accumulates what a listener reports; `add` frames as they come, `summary` at any time."""

    def __init__(self) -> None:
        self.count = 0
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._indexed_t: list[float] = []
        self._indices: list[int] = []

    def add(self, frames: list[NeuronFrame]) -> None:
        for f in frames:
            t = f.received_at
            self.count += 1
            if t is not None:
                if self.first_t is None:
                    self.first_t = t
                self.last_t = t
            if f.frame_index is not None and t is not None:
                self._indices.append(f.frame_index)
                self._indexed_t.append(t)

    def fps(self) -> float | None:
        if self.count < 2 or self.first_t is None or self.last_t == self.first_t:
            return None
        return (self.count - 1) / (self.last_t - self.first_t)

    def period(self) -> float | None:
        """The sender's frame period (s) from its indices, across restarts; None if unknown."""
        return sender_timing(self._indices, self._indexed_t)[0]

    def latency_ms(self) -> tuple[float | None, float | None]:
        """Mean and largest arrival delay beyond the least-delayed frame, in milliseconds."""
        period, delay = sender_timing(self._indices, self._indexed_t)
        if period is None:
            return None, None
        return float(delay.mean()) * 1e3, float(delay.max()) * 1e3

    def summary(self, stats: dict) -> dict:
        """The listener's summary: decoder counters merged with rates and latency."""
        mean, worst = self.latency_ms()
        fps = self.fps()
        out = dict(stats)
        out.update(
            fps=fps,
            duration_s=(self.last_t - self.first_t) if self.count > 1 else 0.0,
            latency_ms=mean,
            latency_max_ms=worst,
        )
        return out
