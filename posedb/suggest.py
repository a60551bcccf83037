"""Finding the held postures in a take.

A held posture is a stretch of at least `min_duration` seconds in which the body stays nearly
still: the mean speed of its major joints (the profile's anatomical joints, or all joints for an
unknown skeleton), smoothed over `smooth` seconds, stays under `max_speed` metres per second.
One pose is proposed per stretch: its stillest frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture import PROFILES, Skeleton, skeleton_fk
from capture.profiles import strip_namespace

DEFAULT_MAX_SPEED = 0.2  # m/s: settling and fidgeting while seated stay under it; walking ~1 m/s
DEFAULT_MIN_DURATION = 0.5  # s
DEFAULT_SMOOTH = 0.2  # s


@dataclass(frozen=True)
class HeldPosture:
    """Frames [start, end] (inclusive, 0-based in the take) and the proposed `frame`."""

    start: int
    end: int
    frame: int
    mean_speed: float

    def as_dict(self) -> dict:
        return {"start": self.start, "end": self.end, "frame": self.frame,
                "mean_speed_m_s": self.mean_speed}


def _major_joints(skeleton: Skeleton, profile: str | None) -> np.ndarray:
    if profile is None or profile not in PROFILES:
        return np.arange(skeleton.num_joints)
    names = [strip_namespace(n) for n in skeleton.names]
    wanted = set(PROFILES[profile].roles.values())
    return np.array([j for j, n in enumerate(names) if n in wanted])


def joint_speed(skeleton: Skeleton, channels: np.ndarray, frame_time: float,
                profile: str | None = None, smooth: float = DEFAULT_SMOOTH) -> np.ndarray:
    """(T,) mean speed in m/s of the major joints, smoothed over `smooth` seconds."""
    positions = skeleton_fk(skeleton, channels).positions[:, _major_joints(skeleton, profile)]
    t = positions.shape[0]
    if t < 2:
        return np.zeros(t)
    step = np.linalg.norm(np.diff(positions, axis=0), axis=-1).mean(axis=1) / frame_time
    speed = np.concatenate([[step[0]], step])  # speed at frame k: from k-1 to k
    width = max(1, int(round(smooth / frame_time)))
    if width > 1:
        kernel = np.ones(width) / width
        padded = np.pad(speed, (width // 2, width - 1 - width // 2), mode="edge")
        speed = np.convolve(padded, kernel, mode="valid")
    return speed


def held_postures(skeleton: Skeleton, channels: np.ndarray, frame_time: float,
                  profile: str | None = None, *, max_speed: float = DEFAULT_MAX_SPEED,
                  min_duration: float = DEFAULT_MIN_DURATION,
                  smooth: float = DEFAULT_SMOOTH) -> list[HeldPosture]:
    """The held postures of a take, in time order.

    channels : (T, C) raw channels of `skeleton` (its unit must be known).
    """
    speed = joint_speed(skeleton, channels, frame_time, profile, smooth)
    still = speed < max_speed
    # BVH frame times are rounded (.0333333 for 1/30 s): allow that much slack
    min_frames = max(1, int(np.ceil(min_duration / frame_time * (1 - 1e-4))))
    edges = np.diff(np.concatenate([[0], still.astype(np.int8), [0]]))
    starts = np.flatnonzero(edges == 1)
    ends = np.flatnonzero(edges == -1) - 1
    out = []
    for s, e in zip(starts, ends):
        if e - s + 1 < min_frames:
            continue
        frame = int(s + np.argmin(speed[s:e + 1]))
        out.append(HeldPosture(int(s), int(e), frame, float(speed[s:e + 1].mean())))
    return out


def suggest_poses(library, take: str, *, accept: bool = False, tags=(),
                  supports=("torso", "legs"), max_speed: float = DEFAULT_MAX_SPEED,
                  min_duration: float = DEFAULT_MIN_DURATION) -> list[dict]:
    """The held postures of a library take (`posedb.PoseLibrary`), as dicts; with `accept`,
    each becomes a pose "<take>-fNNNNN" (its `pose` entry holds the new id), all in one commit.
    """
    from capture import identify_profile

    info = library.take(take)
    data = library.take_data(info.id)
    held = held_postures(data.skeleton, data.motion().channels, info.frame_time,
                         identify_profile(data.skeleton.names), max_speed=max_speed,
                         min_duration=min_duration)
    rows = [h.as_dict() for h in held]
    if accept and rows:
        with library.edit() as ed:
            for row in rows:
                row["name"] = f"{info.name}-f{row['frame']:05d}"
                row["pose"] = ed.add_pose(info.id, row["frame"], row["name"], tags=tags,
                                          supports=supports)
    return rows
