"""How a Perception Neuron frame's floats map onto the channels of a BVH skeleton header.

The broadcast lists bones in the header's depth-first order. Rotation triplets come in the order
of the joint's rotation channels in the header (Y, X, Z for Axis's default YXZ). With
displacement, bone b carries position x, y, z at `r + 6b + 0..2` and its rotation at
`r + 6b + 3..5`; without, the hips position is at `r + 0..2` and bone b's rotation at
`r + 3 + 3b + 0..2`. With the reference block, r = 6 and the frame starts with 6 reference
values; else r = 0.

A header with position channels on every joint (Axis's 6-channel layout) takes the bone positions
from a frame with displacement, or its offsets from a frame without; a header with positions on
the root only ignores the (constant) bone positions of a frame with displacement.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .skeleton import POSITION_CHANNELS, ROTATION_CHANNELS, Skeleton

REFERENCE_SIZE = 6


class LayoutMismatchError(ValueError):
    """A frame whose size or flags do not fit the paired skeleton header."""


def _flags_text(disp: bool | None, ref: bool | None) -> str:
    if disp is None:
        return "a string frame"
    return (f"{'with' if disp else 'without'} displacement, "
            f"{'with' if ref else 'without'} reference")


@dataclass(frozen=True, eq=False)
class StreamLayout:
    """The channel mapping between stream frames and a skeleton header.

    skeleton : the BVH header paired with the stream; every joint needs three rotation
        channels.
    """

    skeleton: Skeleton

    def __post_init__(self) -> None:
        for j, chans in enumerate(self.skeleton.channels):
            rot = [c for c in chans if c in ROTATION_CHANNELS]
            if len(rot) != 3:
                raise LayoutMismatchError(
                    f"Expected three rotation channels on every joint of a stream skeleton, got "
                    f"{len(rot)} on {self.skeleton.names[j]!r}"
                )

    @property
    def num_bones(self) -> int:
        return self.skeleton.num_joints

    def count(self, with_displacement: bool, with_reference: bool) -> int:
        """Floats per frame for the given flags."""
        n = self.num_bones
        body = 6 * n if with_displacement else 3 + 3 * n
        return body + (REFERENCE_SIZE if with_reference else 0)

    def counts(self) -> dict[tuple[bool, bool], int]:
        """Floats per frame for each (with_displacement, with_reference)."""
        return {(d, r): self.count(d, r) for d in (False, True) for r in (False, True)}

    def flags_for_count(self, count: int) -> tuple[bool, bool]:
        """The flags a frame of `count` floats was sent with (string frames carry none)."""
        for flags, c in self.counts().items():
            if c == count:
                return flags
        raise self.mismatch(count, None, None)

    def mismatch(self, count: int, disp: bool | None, ref: bool | None) -> LayoutMismatchError:
        sizes = ", ".join(f"{c} {_flags_text(d, r)}" for (d, r), c in self.counts().items())
        return LayoutMismatchError(
            f"Expected a frame size that fits the {self.num_bones}-joint skeleton header "
            f"({sizes}), got {count} floats ({_flags_text(disp, ref)})"
        )

    @cached_property
    def _tables(self) -> dict:
        """Per flags: (source index or -1, constant) for every header channel, and inverses."""
        sk = self.skeleton
        tables = {}
        for (disp, ref) in self.counts():
            r = REFERENCE_SIZE if ref else 0
            src = np.full(sk.num_channels, -1, dtype=np.int64)
            const = np.zeros(sk.num_channels)
            col = 0
            for j, chans in enumerate(sk.channels):
                k_rot = 0
                for c in chans:
                    if c in ROTATION_CHANNELS:
                        src[col] = (r + 6 * j + 3 + k_rot) if disp else (r + 3 + 3 * j + k_rot)
                        k_rot += 1
                    else:
                        axis = POSITION_CHANNELS.index(c)
                        if disp:
                            src[col] = r + 6 * j + axis
                        elif sk.parents[j] < 0 and j == 0:
                            src[col] = r + axis
                        else:
                            const[col] = sk.offsets[j, axis]
                    col += 1
            tables[(disp, ref)] = (src, const)
        return tables

    def to_channels(self, values: np.ndarray, with_displacement: bool | None = None,
                    with_reference: bool | None = None) -> np.ndarray:
        """Header channels from frame floats.

        values : (..., N) floats of frames sent with the given flags (None: inferred from N).
        Returns (..., C) float64 channels in the header's order (degrees, file units).
        """
        values = np.asarray(values)
        n = values.shape[-1]
        if with_displacement is None or with_reference is None:
            with_displacement, with_reference = self.flags_for_count(n)
        if n != self.count(with_displacement, with_reference):
            raise self.mismatch(n, with_displacement, with_reference)
        src, const = self._tables[(bool(with_displacement), bool(with_reference))]
        out = values[..., np.maximum(src, 0)].astype(np.float64)
        fill = src < 0
        if fill.any():
            out[..., fill] = const[fill]
        return out

    def to_payload(self, channels: np.ndarray, with_displacement: bool = True,
                   with_reference: bool = False) -> np.ndarray:
        """Frame floats from header channels: the inverse of `to_channels`.

        channels : (..., C) header channels. Bone positions missing from the header are sent as
        the bone offsets (as Axis does); the reference block is sent as zeros.
        Returns (..., N) float32.
        """
        sk = self.skeleton
        channels = np.asarray(channels, dtype=np.float64)
        if channels.shape[-1] != sk.num_channels:
            raise LayoutMismatchError(
                f"Expected channels (..., {sk.num_channels}), got {channels.shape}"
            )
        n = self.count(with_displacement, with_reference)
        out = np.zeros(channels.shape[:-1] + (n,), dtype=np.float32)
        r = REFERENCE_SIZE if with_reference else 0
        if with_displacement:
            pos_cols = r + 6 * np.arange(sk.num_joints)[:, None] + np.arange(3)
            out[..., pos_cols] = sk.offsets.astype(np.float32)
        else:
            out[..., r:r + 3] = sk.offsets[0].astype(np.float32)
        src, _ = self._tables[(bool(with_displacement), bool(with_reference))]
        have = src >= 0
        out[..., src[have]] = channels[..., have]
        return out
