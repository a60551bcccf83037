"""Live statistics of a received stream: frame rate, counters and arrival latency.

Latency is measured against the sender's clock as far as the stream reveals it: from frames that
carry the sender's frame index, the sender's period is estimated over the whole run, and each
frame's arrival delay is taken beyond the least-delayed frame. It shows queueing and jitter on
the way (network, buffers, this process), not the constant part of the delay, which no receiver
can see without a shared clock.
"""

from __future__ import annotations

import numpy as np

from .neuron import NeuronFrame


class StreamMonitor:
    """Accumulates what a listener reports; `add` frames as they come, `summary` at any time."""

    def __init__(self) -> None:
        self.count = 0
        self.first_t: float | None = None
        self.last_t: float | None = None
        self._indexed_t: list[float] = []
        self._indices: list[int] = []
        self._unwrap = 0
        self._prev_index: int | None = None

    def add(self, frames: list[NeuronFrame]) -> None:
        for f in frames:
            t = f.received_at
            self.count += 1
            if t is not None:
                if self.first_t is None:
                    self.first_t = t
                self.last_t = t
            if f.frame_index is not None and t is not None:
                idx = f.frame_index
                if self._prev_index is not None and idx < self._prev_index - (1 << 31):
                    self._unwrap += 1 << 32  # the u32 index wrapped around
                self._prev_index = idx
                self._indices.append(idx + self._unwrap)
                self._indexed_t.append(t)

    def fps(self) -> float | None:
        if self.count < 2 or self.first_t is None or self.last_t == self.first_t:
            return None
        return (self.count - 1) / (self.last_t - self.first_t)

    def latency_ms(self) -> tuple[float | None, float | None]:
        """Mean and largest arrival delay beyond the least-delayed frame, in milliseconds."""
        if len(self._indices) < 2:
            return None, None
        idx = np.asarray(self._indices, dtype=np.float64)
        t = np.asarray(self._indexed_t)
        span = idx[-1] - idx[0]
        if span <= 0:
            return None, None
        period = (t[-1] - t[0]) / span
        offsets = t - idx * period
        delay = (offsets - offsets.min()) * 1e3
        return float(delay.mean()), float(delay.max())

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
