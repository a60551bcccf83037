"""Finding the held postures in a take.

A held posture is a stretch in which the body stays nearly still: the mean speed of its major
joints (the profile's anatomical joints, or all joints for an unknown skeleton), smoothed over
`smooth` seconds, stays under `max_speed` metres per second. It counts when it lasts at least
`min_duration` seconds (a "hold"), or at least `min_bottom_duration` seconds at the bottom of
a motion (a "bottom": the bottom of a squat or of a sit-down, held about 0.3 s), where the hips
are at least `bottom_drop` metres lower than at some moment within `BOTTOM_WINDOW` seconds both
before and after. Heights are the root joint's Y coordinate (BVH's up axis), in metres.
One pose is proposed per stretch: its stillest frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from capture import PROFILES, Skeleton, skeleton_fk
from capture.profiles import strip_namespace

from .constants import DEFAULT_MAX_SPEED, DEFAULT_MIN_DURATION, MAX_HOLD_DURATION
from .regions import DEFAULT_SUPPORT

DEFAULT_SMOOTH = 0.2  # s
DEFAULT_MIN_BOTTOM_DURATION = 0.2  # s: a squat's bottom holds ~0.3 s, of which the still part less
DEFAULT_BOTTOM_DROP = 0.1  # m: the hips go down and come up again by this much (squat ~0.4 m)
BOTTOM_WINDOW = 2.0  # s looked at before and after a short stillness for the descent and rise


@dataclass(frozen=True)
class HeldPosture:
    """Frames [start, end] (inclusive, 0-based in the take), the proposed `frame`, and `kind`:
    "hold" (long enough on its own) or "bottom" (short, at the bottom of a motion)."""

    start: int
    end: int
    frame: int
    mean_speed: float
    kind: str = "hold"

    def as_dict(self) -> dict:
        return {"start": self.start, "end": self.end, "frame": self.frame,
                "mean_speed_m_s": self.mean_speed, "kind": self.kind}


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
    # a window longer than the take is cut to it (and its frame count cannot overflow)
    width = max(1, min(int(round(min(smooth / frame_time, 2.0 ** 53))), t))
    if width > 1:
        kernel = np.ones(width) / width
        padded = np.pad(speed, (width // 2, width - 1 - width // 2), mode="edge")
        speed = np.convolve(padded, kernel, mode="valid")
    return speed


def _frames(seconds: float, frame_time: float) -> int:
    # BVH frame times are rounded (.0333333 for 1/30 s): allow that much slack; a count beyond
    # any take's (a day at a millionth of a second) is capped rather than overflowing
    return max(1, int(min(np.ceil(seconds / frame_time * (1 - 1e-4)), 2.0 ** 53)))


def _is_bottom(height: np.ndarray, start: int, end: int, window: int, drop: float) -> bool:
    """Whether the hips in frames [start, end] are `drop` m lower than at some frame of the
    `window` frames before and of the `window` frames after."""
    before = height[max(0, start - window):start]
    after = height[end + 1:end + 1 + window]
    if not len(before) or not len(after):
        return False
    low = height[start:end + 1].max()
    return before.max() - low >= drop and after.max() - low >= drop


def _check_options(**options) -> None:
    """Refuses an option of `held_postures` out of its range, naming it: the frame time and
    max_speed finite and > 0, the durations from 0 to MAX_HOLD_DURATION seconds, bottom_drop
    finite and >= 0 (min_bottom_duration may be None)."""
    from .schema import LibraryError

    for name, value in options.items():
        if value is None and name == "min_bottom_duration":
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = float("nan")
        if name in ("frame_time", "max_speed"):
            ok, wanted = np.isfinite(number) and number > 0, "a finite number > 0"
        elif name == "bottom_drop":
            ok, wanted = np.isfinite(number) and number >= 0, "a finite number >= 0"
        else:
            ok = 0 <= number <= MAX_HOLD_DURATION
            wanted = f"a finite number of seconds from 0 to {MAX_HOLD_DURATION:g}"
        if not ok:
            raise LibraryError(f"Expected {name} as {wanted}, got {value!r}")


def held_postures(skeleton: Skeleton, channels: np.ndarray, frame_time: float,
                  profile: str | None = None, *, max_speed: float = DEFAULT_MAX_SPEED,
                  min_duration: float = DEFAULT_MIN_DURATION,
                  smooth: float = DEFAULT_SMOOTH,
                  min_bottom_duration: float | None = DEFAULT_MIN_BOTTOM_DURATION,
                  bottom_drop: float = DEFAULT_BOTTOM_DROP) -> list[HeldPosture]:
    """The held postures of a take, in time order (see the module docstring).

    channels : (T, C) raw channels of `skeleton` (its unit must be known).
    frame_time : s between frames (> 0); max_speed : m/s (> 0); bottom_drop : m (>= 0).
    min_duration, smooth : s, from 0 to MAX_HOLD_DURATION (a day).
    min_bottom_duration : s, shortest still stretch at the bottom of a motion, from 0 to
        MAX_HOLD_DURATION; None: none.
    Raises a LibraryError naming an option out of its range.
    """
    _check_options(frame_time=frame_time, max_speed=max_speed, min_duration=min_duration,
                   smooth=smooth, min_bottom_duration=min_bottom_duration,
                   bottom_drop=bottom_drop)
    speed = joint_speed(skeleton, channels, frame_time, profile, smooth)
    height = skeleton.root_positions(channels)[:, 1]
    min_frames = _frames(min_duration, frame_time)
    min_bottom = min_frames if min_bottom_duration is None else min(
        min_frames, _frames(min_bottom_duration, frame_time))
    window = _frames(BOTTOM_WINDOW, frame_time)
    edges = np.diff(np.concatenate([[0], (speed < max_speed).astype(np.int8), [0]]))
    out = []
    for s, e in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1):
        length = e - s + 1
        if length >= min_frames:
            kind = "hold"
        elif length >= min_bottom and _is_bottom(height, s, e, window, bottom_drop):
            kind = "bottom"
        else:
            continue
        frame = int(s + np.argmin(speed[s:e + 1]))
        out.append(HeldPosture(int(s), int(e), frame, float(speed[s:e + 1].mean()), kind))
    return out


def take_holds(data, **options) -> list[HeldPosture]:
    """The held postures of a library take's arrays (`posedb.library.TakeData`), its skeleton's
    profile deciding the major joints; `options` as `held_postures` takes them."""
    from capture import identify_profile

    return held_postures(data.skeleton, data.motion().channels, data.take.frame_time,
                         identify_profile(data.skeleton.names), **options)


class _NothingToAdd(Exception):
    """Raised inside an edit to leave the library untouched: every hold is a pose already."""


def _poses_at(editor, take_id: str) -> dict[int, int]:
    """The frames of a take that are poses already, as the edit has them: frame -> table row
    (the first pose at that frame)."""
    from .library import _parse_id

    table = editor.table
    rows = np.flatnonzero(table.mask(None) & (table.cols["take"] == _parse_id(take_id, "take-")))
    out: dict[int, int] = {}
    for row in rows.tolist():
        out.setdefault(int(table.value("frame", row)), row)
    return out


def suggest_poses(library, take: str, *, accept: bool = False, tags=(),
                  supports=DEFAULT_SUPPORT, max_speed: float = DEFAULT_MAX_SPEED,
                  min_duration: float = DEFAULT_MIN_DURATION,
                  min_bottom_duration: float | None = DEFAULT_MIN_BOTTOM_DURATION) -> list[dict]:
    """The held postures of a library take (`posedb.PoseLibrary`), as dicts; with `accept`,
    each becomes a pose "<take>-fNNNNN" (the take's name shortened to keep it within the
    library's 200 characters: `posedb.library.derived_name`) carrying the take's tags and
    `tags`, all in one commit (its entry gains `name`, the name later commands take, `pose`,
    the id, `tags`, and `added`: True).

    Accepting again is safe: a hold whose frame is a pose of the take already (an earlier
    acceptance, whatever it is called now) is skipped, its entry naming that pose with
    `added` False, and only the other holds are added. A name held by another take or pose
    refuses the whole batch (a DuplicateNameError), leaving the library as it was.
    """
    from .library import _pose_id, derived_name

    info = library.take(take)
    held = take_holds(library.take_data(info.id), max_speed=max_speed,
                      min_duration=min_duration, min_bottom_duration=min_bottom_duration)
    rows = [h.as_dict() for h in held]
    if accept and rows:
        try:
            with library.edit() as ed:
                info = ed.takes.get(info.id, info)  # (as of the write lock: renamed meanwhile?)
                inherited = tuple(info.tags) + tuple(tags)
                existing = _poses_at(ed, info.id)
                for row in rows:
                    known = existing.get(row["frame"])
                    if known is None:
                        row["name"] = derived_name(info.name, f"-f{row['frame']:05d}")
                        row["pose"] = ed.add_pose(info.id, row["frame"], row["name"],
                                                  tags=inherited, supports=supports)
                        known = ed.table.row_of(row["pose"])
                        row["added"] = True
                    else:
                        row["name"] = ed.table.names[known]
                        row["pose"] = _pose_id(ed.table.value("id", known))
                        row["added"] = False
                    row["tags"] = list(ed.table.tags(known))
                if not any(row["added"] for row in rows):
                    raise _NothingToAdd  # (no commit: the file is not rewritten)
        except _NothingToAdd:
            pass
    return rows
