"""Motion capture input: BVH files, skeletons, forward kinematics, known skeleton profiles.

Conventions (shared by the whole project): metres and seconds, Y up, gravity along -Y, a body in
rest pose faces +Z; rotations via `scipy.spatial.transform.Rotation`, quaternions (x, y, z, w).
"""

from .bvh import Bvh, BvhParseError, Motion, format_bvh, parse_bvh, read_bvh, write_bvh
from .profiles import PROFILES, Profile, identify_profile
from .recordings import bundled_recordings, resolve_path
from .skeleton import (
    CHANNEL_NAMES,
    Skeleton,
    SkeletonError,
    UnitUnknownError,
    WorldPose,
    forward_kinematics,
    joint_levels,
    skeleton_fk,
)
from .units import UNITS, UnitError, resolve_unit

__all__ = [
    "Bvh",
    "BvhParseError",
    "CHANNEL_NAMES",
    "Motion",
    "PROFILES",
    "Profile",
    "Skeleton",
    "SkeletonError",
    "UNITS",
    "UnitError",
    "UnitUnknownError",
    "WorldPose",
    "bundled_recordings",
    "format_bvh",
    "forward_kinematics",
    "identify_profile",
    "joint_levels",
    "parse_bvh",
    "read_bvh",
    "resolve_path",
    "resolve_unit",
    "skeleton_fk",
    "write_bvh",
]
