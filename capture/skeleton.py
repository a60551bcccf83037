"""Skeletons, channel layouts and forward kinematics.

Frame conventions: right-handed, Y up, a body in rest pose faces +Z. Quaternions are (x, y, z, w).
A joint's channel list `Zrotation Xrotation Yrotation` is the intrinsic Euler sequence "ZXY":
R = Rz @ Rx @ Ry, rotating vectors from the joint's frame into its parent's frame. Angles in the
raw channels are degrees; lengths in the raw channels and offsets are in file units, and
`Skeleton.unit_m` (metres per file unit) turns them into metres.

A position channel replaces the matching component of the joint's offset (Axis Neuron writes
position channels equal to the offsets on every joint, so adding them would double every bone).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")
CHANNEL_NAMES = POSITION_CHANNELS + ROTATION_CHANNELS


class SkeletonError(ValueError):
    """A skeleton whose arrays disagree with each other."""


class UnitUnknownError(ValueError):
    """A metric quantity was asked of a skeleton whose file unit is not known."""


@dataclass(frozen=True, eq=False)
class Skeleton:
    """A joint hierarchy as stored in a motion file.

    names : (J,) joint names, unique.
    parents : (J,) int, -1 for a root, every parent listed before its children.
    offsets : (J, 3) float, joint origin in its parent's frame, in file units.
    channels : (J,) tuples of channel names from `CHANNEL_NAMES`, in file order.
    end_sites : (E, 3) float offsets of `End Site` entries, in file units.
    end_site_parents : (E,) int joint index owning each end site.
    unit_m : metres per file unit, or None when the unit is not known.
    joint_map : ((role, joint name), ...) the anatomical roles of the joints when no known
        profile says them (see `solver.body.retarget.joint_map_for`); empty by default.
    """

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    end_sites: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    end_site_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    unit_m: float | None = None
    joint_map: tuple[tuple[str, str], ...] = ()

    def __post_init__(self) -> None:
        names = tuple(str(n) for n in self.names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        channels = tuple(tuple(c) for c in self.channels)
        end_sites = np.asarray(self.end_sites, dtype=np.float64).reshape(-1, 3)
        end_parents = np.asarray(self.end_site_parents, dtype=np.int64).reshape(-1)
        n = len(names)
        if n == 0:
            raise SkeletonError("Expected at least one joint, got none")
        if parents.shape != (n,):
            raise SkeletonError(f"Expected `parents` of shape ({n},), got {parents.shape}")
        if offsets.shape != (n, 3):
            raise SkeletonError(f"Expected `offsets` of shape ({n}, 3), got {offsets.shape}")
        if len(channels) != n:
            raise SkeletonError(f"Expected {n} channel lists, got {len(channels)}")
        if len(set(names)) != n:
            dup = sorted({x for x in names if names.count(x) > 1})
            raise SkeletonError(f"Expected unique joint names, got duplicates {dup}")
        idx = np.arange(n)
        bad = np.flatnonzero((parents >= idx) | (parents < -1))
        if bad.size:
            j = int(bad[0])
            raise SkeletonError(
                f"Expected each parent to precede its child (-1 for a root), got parent "
                f"{parents[j]} for joint {j} ({names[j]!r})"
            )
        for j, chans in enumerate(channels):
            unknown = [c for c in chans if c not in CHANNEL_NAMES]
            if unknown or len(set(chans)) != len(chans):
                raise SkeletonError(
                    f"Expected distinct channels from {CHANNEL_NAMES} for joint {names[j]!r}, "
                    f"got {chans}"
                )
        if end_parents.shape != (end_sites.shape[0],) or np.any(
            (end_parents < 0) | (end_parents >= n)
        ):
            raise SkeletonError("Expected one valid joint index per end site")
        if self.unit_m is not None and not (np.isfinite(self.unit_m) and self.unit_m > 0):
            raise SkeletonError(f"Expected a positive unit_m, got {self.unit_m!r}")
        parents.setflags(write=False)
        offsets.setflags(write=False)
        end_sites.setflags(write=False)
        end_parents.setflags(write=False)
        object.__setattr__(self, "names", names)
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "end_sites", end_sites)
        object.__setattr__(self, "end_site_parents", end_parents)
        mapping = tuple(sorted((str(r), str(j)) for r, j in dict(self.joint_map).items()))
        for role, joint in mapping:
            if joint.removeprefix("end:") not in names:
                raise SkeletonError(f"Expected the joint map's joints in the skeleton, got "
                                    f"{joint!r} for role {role!r}")
        object.__setattr__(self, "joint_map", mapping)

    # -- layout -------------------------------------------------------------------------------

    @property
    def num_joints(self) -> int:
        return len(self.names)

    @cached_property
    def channel_starts(self) -> np.ndarray:
        """(J,) int index of each joint's first channel in a motion row."""
        counts = np.array([len(c) for c in self.channels], dtype=np.int64)
        starts = np.zeros(len(counts), dtype=np.int64)
        np.cumsum(counts[:-1], out=starts[1:])
        return starts

    @cached_property
    def num_channels(self) -> int:
        return int(sum(len(c) for c in self.channels))

    @cached_property
    def levels(self) -> tuple[np.ndarray, ...]:
        """Joint indices grouped by depth, roots first: the schedule of forward kinematics."""
        return joint_levels(self.parents)

    def index(self, name: str) -> int:
        """Index of the joint called `name`."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"No joint named {name!r}; joints are {list(self.names)}") from None

    def with_unit(self, unit_m: float | None) -> "Skeleton":
        """The same skeleton with another file unit (metres per file unit)."""
        return replace(self, unit_m=unit_m)

    def with_joint_map(self, joint_map) -> "Skeleton":
        """The same skeleton carrying a joint map (a mapping or pairs of role -> joint name)."""
        return replace(self, joint_map=tuple(dict(joint_map).items()))

    def require_unit(self) -> float:
        if self.unit_m is None:
            raise UnitUnknownError(
                "The skeleton's length unit is unknown: read the file with an explicit unit "
                "(for example unit='cm' or unit=0.056444) before asking for metres"
            )
        return float(self.unit_m)

    @property
    def offsets_m(self) -> np.ndarray:
        """(J, 3) joint offsets in metres."""
        return self.offsets * self.require_unit()

    @cached_property
    def _rotation_groups(self) -> tuple[tuple[str, np.ndarray, np.ndarray], ...]:
        # Joints sharing one Euler sequence are converted in a single scipy call.
        groups: dict[str, tuple[list[int], list[list[int]]]] = {}
        starts = self.channel_starts
        for j, chans in enumerate(self.channels):
            cols = [int(starts[j]) + k for k, c in enumerate(chans) if c in ROTATION_CHANNELS]
            if not cols:
                continue
            seq = "".join(c[0] for c in chans if c in ROTATION_CHANNELS)
            joints, columns = groups.setdefault(seq, ([], []))
            joints.append(j)
            columns.append(cols)
        return tuple(
            (seq, np.array(j, dtype=np.int64), np.array(c, dtype=np.int64))
            for seq, (j, c) in groups.items()
        )

    @cached_property
    def _position_columns(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        joints, axes, cols = [], [], []
        starts = self.channel_starts
        for j, chans in enumerate(self.channels):
            for k, c in enumerate(chans):
                if c in POSITION_CHANNELS:
                    joints.append(j)
                    axes.append(POSITION_CHANNELS.index(c))
                    cols.append(int(starts[j]) + k)
        return (np.array(joints, dtype=np.int64), np.array(axes, dtype=np.int64),
                np.array(cols, dtype=np.int64))

    # -- channels -> local transforms -------------------------------------------------------

    def _check_channels(self, channels: np.ndarray) -> np.ndarray:
        channels = np.asarray(channels, dtype=np.float64)
        if channels.ndim < 1 or channels.shape[-1] != self.num_channels:
            raise SkeletonError(
                f"Expected channels of shape (..., {self.num_channels}), got {channels.shape}"
            )
        return channels

    def _euler_groups(self, channels: np.ndarray):
        channels = self._check_channels(channels)
        batch = channels.shape[:-1]
        for seq, joints, cols in self._rotation_groups:
            angles = channels[..., cols]  # (..., Jg, k)
            rot = Rotation.from_euler(seq, angles.reshape(-1, len(seq)), degrees=True)
            yield batch, joints, angles.shape[:-1], rot

    def local_rotations(self, channels: np.ndarray) -> np.ndarray:
        """Local joint rotations from raw channels as quaternions.

        channels : (..., C) float, rotations in degrees.
        Returns (..., J, 4) float unit quaternions (x, y, z, w); identity for joints without
        rotation channels.
        """
        batch = np.shape(channels)[:-1]
        quats = np.zeros(tuple(batch) + (self.num_joints, 4))
        quats[..., 3] = 1.0
        for _, joints, shape, rot in self._euler_groups(channels):
            quats[..., joints, :] = rot.as_quat().reshape(shape + (4,))
        return quats

    def local_rotmats(self, channels: np.ndarray) -> np.ndarray:
        """Local joint rotations from raw channels as matrices.

        channels : (..., C) float, rotations in degrees.
        Returns (..., J, 3, 3) float rotation matrices (joint frame -> parent frame).
        """
        batch = np.shape(channels)[:-1]
        mats = np.broadcast_to(np.eye(3), tuple(batch) + (self.num_joints, 3, 3)).copy()
        for _, joints, shape, rot in self._euler_groups(channels):
            mats[..., joints, :, :] = rot.as_matrix().reshape(shape + (3, 3))
        return mats

    def local_translations(self, channels: np.ndarray) -> np.ndarray:
        """Local joint translations in metres: offsets, with position channels substituted.

        channels : (..., C) float raw channels (lengths in file units).
        Returns (..., J, 3) float metres.
        """
        channels = self._check_channels(channels)
        batch = channels.shape[:-1]
        local = np.broadcast_to(self.offsets, batch + self.offsets.shape).copy()
        joints, axes, cols = self._position_columns
        if joints.size:
            local[..., joints, axes] = channels[..., cols]
        return local * self.require_unit()

    def root_positions(self, channels: np.ndarray) -> np.ndarray:
        """(..., 3) float position of the first root in metres, in its parent (world) frame."""
        return self.local_translations(channels)[..., 0, :]

    def channels_from_pose(
        self, local_rotations: np.ndarray, local_translations: np.ndarray
    ) -> np.ndarray:
        """Raw channels (..., C) that reproduce the given local rotations and translations.

        local_rotations : (..., J, 4) xyzw; local_translations : (..., J, 3) metres.
        The inverse of `local_rotations` / `local_translations` for the joint's own Euler
        sequences (angles come back in scipy's canonical range).
        """
        q = np.asarray(local_rotations, dtype=np.float64)
        t = np.asarray(local_translations, dtype=np.float64)
        if q.shape[-2:] != (self.num_joints, 4) or t.shape[-2:] != (self.num_joints, 3):
            raise SkeletonError(
                f"Expected rotations (..., {self.num_joints}, 4) and translations "
                f"(..., {self.num_joints}, 3), got {q.shape} and {t.shape}"
            )
        batch = np.broadcast_shapes(q.shape[:-2], t.shape[:-2])
        out = np.zeros(batch + (self.num_channels,))
        for seq, joints, cols in self._rotation_groups:
            qq = np.broadcast_to(q[..., joints, :], batch + (len(joints), 4)).reshape(-1, 4)
            angles = Rotation.from_quat(qq).as_euler(seq, degrees=True)
            out[..., cols] = angles.reshape(batch + (len(joints), len(seq)))
        joints, axes, cols = self._position_columns
        if joints.size:
            out[..., cols] = np.broadcast_to(t, batch + t.shape[-2:])[..., joints, axes] / (
                self.require_unit()
            )
        return out


class WorldPose(NamedTuple):
    """Joint frames in the world: positions (..., J, 3) in metres, rotmats (..., J, 3, 3)."""

    positions: np.ndarray
    rotmats: np.ndarray

    def quaternions(self) -> np.ndarray:
        """(..., J, 4) world rotations as quaternions (x, y, z, w)."""
        shape = self.rotmats.shape[:-2]
        return Rotation.from_matrix(self.rotmats.reshape(-1, 3, 3)).as_quat().reshape(shape + (4,))


def depth_first_order(parents: np.ndarray) -> list[int]:
    """Joint indices in depth-first order, children in index order (the order a BVH file lists
    its joints), for any parent array (-1 for a root)."""
    parents = np.asarray(parents, dtype=np.int64)
    children: list[list[int]] = [[] for _ in range(len(parents))]
    for j, p in enumerate(parents):
        if p >= 0:
            children[int(p)].append(j)
    order: list[int] = []
    stack = [int(j) for j in np.flatnonzero(parents < 0)][::-1]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(children[j][::-1])
    return order


def joint_levels(parents: np.ndarray) -> tuple[np.ndarray, ...]:
    """Joint indices grouped by depth, roots first, for topologically sorted `parents` (J,)."""
    parents = np.asarray(parents, dtype=np.int64)
    depth = np.zeros(parents.shape[0], dtype=np.int64)
    for j, p in enumerate(parents):
        if p >= j or p < -1:
            raise SkeletonError(
                f"Expected each parent to precede its child (-1 for a root), got parent {p} "
                f"for joint {j}"
            )
        if p >= 0:
            depth[j] = depth[p] + 1
    return tuple(np.flatnonzero(depth == k) for k in range(int(depth.max(initial=0)) + 1))


def forward_kinematics(
    parents: np.ndarray,
    local_rotmats: np.ndarray,
    local_translations: np.ndarray,
    levels: tuple[np.ndarray, ...] | None = None,
) -> WorldPose:
    """World joint frames, vectorised over frames and over the joints of each depth level.

    parents : (J,) int, topologically sorted, -1 for roots.
    local_rotmats : (..., J, 3, 3) float, joint frame -> parent frame.
    local_translations : (..., J, 3) float joint origins in the parent frame (metres).
    levels : optional joint indices grouped by depth (`Skeleton.levels`), computed if omitted.
    Returns a `WorldPose` of positions (..., J, 3) and rotmats (..., J, 3, 3).
    """
    parents = np.asarray(parents, dtype=np.int64)
    rot = np.asarray(local_rotmats, dtype=np.float64)
    t = np.asarray(local_translations, dtype=np.float64)
    n = parents.shape[0]
    if rot.shape[-3:] != (n, 3, 3) or t.shape[-2:] != (n, 3):
        raise SkeletonError(
            f"Expected local rotmats (..., {n}, 3, 3) and translations (..., {n}, 3), "
            f"got {rot.shape} and {t.shape}"
        )
    batch = np.broadcast_shapes(rot.shape[:-3], t.shape[:-2])
    rot = np.broadcast_to(rot, batch + (n, 3, 3))
    t = np.broadcast_to(t, batch + (n, 3))
    if levels is None:
        levels = joint_levels(parents)
    world_r = np.empty(batch + (n, 3, 3))
    world_p = np.empty(batch + (n, 3))
    for idx in levels:
        par = parents[idx]
        if par[0] < 0:  # the first level holds the roots, and only them
            world_r[..., idx, :, :] = rot[..., idx, :, :]
            world_p[..., idx, :] = t[..., idx, :]
            continue
        pr = world_r[..., par, :, :]
        world_r[..., idx, :, :] = pr @ rot[..., idx, :, :]
        world_p[..., idx, :] = world_p[..., par, :] + (pr @ t[..., idx, :, None])[..., 0]
    return WorldPose(world_p, world_r)


def skeleton_fk(skeleton: Skeleton, channels: np.ndarray) -> WorldPose:
    """Forward kinematics straight from raw channels.

    channels : (..., C) raw channels of `skeleton`.
    Returns world positions (..., J, 3) in metres and rotmats (..., J, 3, 3).
    """
    return forward_kinematics(
        skeleton.parents,
        skeleton.local_rotmats(channels),
        skeleton.local_translations(channels),
        skeleton.levels,
    )


def rest_fk(skeleton: Skeleton) -> WorldPose:
    """The skeleton's rest frames: no joint turned, each at its OFFSET from its parent (the
    file's rest pose, whatever its position channels hold), positions (J, 3) in metres."""
    n = skeleton.num_joints
    return forward_kinematics(skeleton.parents, np.broadcast_to(np.eye(3), (n, 3, 3)),
                              skeleton.offsets_m, skeleton.levels)
