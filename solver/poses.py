"""Where a captured pose comes from: the pose library or a frame of a BVH file.

    db:NAME                 a pose of the library (by name or id)
    bvh:PATH#frame=N        frame N (0-based) of a BVH file; `bvh:` may be left out for a path
                            ending in .bvh, and PATH may be bundled:NAME
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from capture import Skeleton, WorldPose, forward_kinematics, read_bvh, resolve_path, skeleton_fk

from .body import Body
from .retarget import RigMotion, place, retarget_pose

_FRAME = re.compile(r"^(?P<path>.+?)#frame=(?P<frame>-?\d+)$")


class PoseSourceError(ValueError):
    """A pose reference that cannot be resolved."""


@dataclass(frozen=True, eq=False)
class CapturedPose:
    """A captured skeleton in one posture: world frames (1, J) in metres."""

    skeleton: Skeleton
    world: WorldPose
    label: str


def load_pose(spec: str, db: str | os.PathLike | None = None) -> CapturedPose:
    """Resolves `db:NAME` or `[bvh:]PATH#frame=N` (see the module docstring)."""
    if spec.startswith("db:"):
        from posedb import PoseLibrary

        if db is None:
            raise PoseSourceError(f"Pose {spec!r} needs a pose library (--db)")
        info, skeleton, quats, root = PoseLibrary(db).pose_data(spec[3:])
        trans = skeleton.offsets_m.copy()
        trans[0] = root
        rot = Rotation.from_quat(quats).as_matrix()
        world = forward_kinematics(skeleton.parents, rot[None], trans[None], skeleton.levels)
        return CapturedPose(skeleton, world, f"{info.name} (frame {info.frame})")
    text = spec[4:] if spec.startswith("bvh:") else spec
    m = _FRAME.match(text)
    if m is None:
        raise PoseSourceError(
            f"Expected a pose as db:NAME or [bvh:]FILE.bvh#frame=N, got {spec!r}"
        )
    path = resolve_path(m["path"])
    bvh = read_bvh(path)
    frame = int(m["frame"])
    if not 0 <= frame < bvh.motion.num_frames:
        raise PoseSourceError(f"Expected a frame in 0..{bvh.motion.num_frames - 1} of {path}, "
                              f"got {frame}")
    world = skeleton_fk(bvh.skeleton, bvh.motion.channels[frame:frame + 1])
    return CapturedPose(bvh.skeleton, world, f"{Path(path).name} frame {frame}")


def pose_body(captured: CapturedPose, body: Body, *, lowest: float | None = 0.0,
              pelvis: float | None = None) -> RigMotion:
    """The body's rig in the captured posture, its lowest skin point (or pelvis) at a height;
    with both None, where the capture put it (scaled by leg length)."""
    motion = retarget_pose(captured.skeleton, captured.world, body)
    if lowest is None and pelvis is None:
        return motion
    return place(motion, lowest=lowest, pelvis=pelvis)




def t_pose(body: Body, root_rotation: np.ndarray | None = None,
           root_position: np.ndarray | None = None):
    """The body's rig with its upper arms straight out sideways (a T-pose), optionally turned
    by a root rotation (3, 3) and moved; returns the world frames (J)."""
    from .retarget import _swing
    from .skinning import rig_pose

    n = len(body.joint_names)
    local = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    for side, sign in (("Left", 1.0), ("Right", -1.0)):
        arm, elbow = body.joint_index(f"{side}Arm"), body.joint_index(f"{side}ForeArm")
        local[arm] = _swing(body.joints[elbow] - body.joints[arm], np.array([sign, 0.0, 0.0]))
    if root_rotation is not None:
        local[0] = root_rotation
    root = body.joints[0] if root_position is None else root_position
    return rig_pose(body, local, root)
