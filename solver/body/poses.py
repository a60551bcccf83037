"""Where a captured pose comes from: the pose library or a frame of a BVH file.

    db:NAME                 a pose of the library (by name or id)
    bvh:PATH#frame=N        frame N (0-based) of a BVH file; `bvh:` may be left out for a path
                            ending in .bvh, and PATH may be bundled:NAME
    bvh:PATH#frame=N&unit=U the same for a file whose length unit no profile knows (U: m, cm,
                            mm, in, cmu or metres per unit)
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
from scipy.spatial.transform import Rotation

from capture import Skeleton, WorldPose, forward_kinematics, read_bvh, resolve_path, skeleton_fk
from capture.jointmap import JointMapError, check_joint_map

from solver.body.model import Body
from solver.body.retarget import RetargetError, place, retarget_pose
from solver.body.rig import RigMotion

# (a path holds no "#frame=": one frame a reference)
_FRAME = re.compile(r"^(?P<path>(?:(?!#frame=).)+)#frame=(?P<frame>-?\d+)"
                    r"(?:&unit=(?P<unit>[^&#]+))?$")


MAX_SPAN = 10.0  # metres: no captured body's joints lie farther apart


class PoseSourceError(ValueError):
    """A pose reference that cannot be resolved."""


@dataclass(frozen=True, eq=False)
class CapturedPose:
    """A captured skeleton in one posture: world frames (1, J) in metres; for a library pose
    stored by a relaxation, where it stands relative to the standard placement
    (`posedb.PosePlacement`, None otherwise: see `solver.scene.placement.place_person`)."""

    skeleton: Skeleton
    world: WorldPose
    label: str
    placement: object = None  # posedb.PosePlacement | None (posedb is loaded for db: poses only)


def load_pose(spec: str, db: str | os.PathLike | None = None, *,
              unit: str | float | None = None,
              joint_map: Mapping[str, str] | None = None) -> CapturedPose:
    """Resolves `db:NAME` or `[bvh:]PATH#frame=N` (see the module docstring).

    Parameters
    ----------
    spec : str
        ``db:NAME`` for a pose of the library (by name or id), or ``[bvh:]PATH#frame=N`` for
        frame N (0-based) of a BVH file; PATH may be ``bundled:NAME``.
    db : str or os.PathLike, optional
        The pose library file; needed for a ``db:`` pose.
    unit : str or float, optional
        The BVH file's length unit (a name of `capture.units.UNITS` or metres per unit), for a
        skeleton no profile knows; ``...#frame=N&unit=U`` in `spec` says the same.
    joint_map : mapping of str to str, optional
        Role -> joint name of the skeleton (see `capture.jointmap`), carried by the returned
        skeleton so retargeting uses it; a library skeleton's stored map is kept otherwise.

    Returns
    -------
    CapturedPose
        The captured skeleton, its world frames (1, J) (positions in metres), a label naming
        the pose and its frame and, for a library pose that carries one, its placement.

    Raises
    ------
    PoseSourceError
        If `spec` has neither form, a ``db:`` pose has no `db`, or the frame is out of range.
    """
    if spec.startswith("db:"):
        from posedb import PoseLibrary

        if db is None:
            raise PoseSourceError(f"Pose {spec!r} needs a pose library (--db)")
        lib = PoseLibrary(db)
        info, skeleton, quats, root = lib.pose_data(spec[3:])
        trans = skeleton.offsets_m.copy()
        if any(c.endswith("position") for ch in skeleton.channels[1:] for c in ch):
            # position channels on the joints (Axis exports): the frame's own bone vectors
            channels = lib.take_data(info.take, info.frame, info.frame + 1).channels
            trans = skeleton.local_translations(np.asarray(channels, dtype=np.float64))[0]
        trans[0] = root
        rot = Rotation.from_quat(quats).as_matrix()
        world = forward_kinematics(skeleton.parents, rot[None], trans[None], skeleton.levels)
        skeleton = _mapped(skeleton, joint_map, f"pose {spec[3:]!r}")
        _check_span(world, f"pose {spec[3:]!r}")
        return CapturedPose(skeleton, world, f"{info.name} (frame {info.frame})",
                            info.placement)
    text = spec[4:] if spec.startswith("bvh:") else spec
    m = _FRAME.match(text)
    if m is None or not m["path"].strip():  # (a blank file name too: "bvh: #frame=1")
        raise PoseSourceError(
            f"Expected a pose as db:NAME or [bvh:]FILE.bvh#frame=N[&unit=U], got {spec!r}"
        )
    path = resolve_path(m["path"])
    chosen = unit if unit is not None else m["unit"]
    bvh = read_bvh(path, unit="auto" if chosen is None else chosen)
    frame = int(m["frame"])
    if bvh.motion.num_frames == 0:
        raise PoseSourceError(f"{m['path']} has no frames (its MOTION section says Frames: 0)")
    if not 0 <= frame < bvh.motion.num_frames:
        raise PoseSourceError(f"Expected a frame in 0..{bvh.motion.num_frames - 1} of "
                              f"{m['path']}, got {frame}")  # (the file as named, not resolved)
    if bvh.skeleton.unit_m is None:
        # (said in the pose: the one form every command takes; `design`, `fit` and `relax`
        # have no --unit)
        raise PoseSourceError(f"{path}: the file's length unit is unknown (no known skeleton "
                              f"profile): give it in the pose, e.g. "
                              f"{m['path']}#frame={frame}&unit=cm (m, dm, cm, mm, in, cmu or "
                              f"metres per unit)")
    skeleton = _mapped(bvh.skeleton, joint_map, str(path))
    world = skeleton_fk(skeleton, bvh.motion.channels[frame:frame + 1])
    _check_span(world, f"{m['path']} frame {frame}")
    return CapturedPose(skeleton, world, f"{Path(path).name} frame {frame}")


def _check_span(world: WorldPose, where: str) -> None:
    """A PoseSourceError for a captured pose whose joints lie farther apart than any body's
    (MAX_SPAN metres), or not at finite places: a wrong length unit, most often."""
    with np.errstate(over="ignore", invalid="ignore"):
        span = float(np.ptp(world.positions[0], axis=0).max())
    if not span <= MAX_SPAN:  # (NaN fails it too)
        raise PoseSourceError(f"{where}: its joints span {span:.3g} m, more than any body's "
                              f"{MAX_SPAN:g} m: is the file's length unit right? (give it in the "
                              "pose, as FILE.bvh#frame=N&unit=U; a command's --unit, where it "
                              "has one, overrides that)")


def _mapped(skeleton: Skeleton, joint_map: Mapping[str, str] | None, where: str) -> Skeleton:
    if not joint_map:
        return skeleton
    try:
        # (the map is at fault, not the file or pose it is given for)
        return skeleton.with_joint_map(check_joint_map(skeleton, dict(joint_map),
                                                       f"The joint map for {where}"))
    except JointMapError as exc:
        raise PoseSourceError(str(exc)) from None


def retarget_captured(captured: CapturedPose, body: Body) -> RigMotion:
    """`retarget_pose` of a captured pose, its errors naming where the pose came from."""
    try:
        return retarget_pose(captured.skeleton, captured.world, body)
    except RetargetError as exc:
        raise RetargetError(f"{captured.label}: {exc}") from None


def pose_body(captured: CapturedPose, body: Body, *, lowest: float | None = 0.0,
              pelvis: float | None = None) -> RigMotion:
    """The body's rig in the captured posture, its lowest skin point (or pelvis) at a height;
    with both None, where the capture put it (scaled by leg length).

    Parameters
    ----------
    captured : CapturedPose
        The captured skeleton in one posture (see `load_pose`).
    body : Body
        The body whose rig is posed.
    lowest : float or None, default 0.0
        Height (y, metres) of the lowest posed skin point.
    pelvis : float, optional
        Height (y, metres) of the pelvis (the rig's root joint) instead of the lowest point.

    Returns
    -------
    RigMotion
        The rig in the posture: local rotations (1, J, 3, 3), root positions (1, 3) in metres
        and world frames (1, J).

    Raises
    ------
    RetargetError
        If the captured skeleton cannot be retargeted.
    """
    motion = retarget_captured(captured, body)
    if pelvis is not None:
        return place(motion, pelvis=pelvis)
    if lowest is None:
        return motion
    return place(motion, lowest=lowest)
