"""Motion capture input: BVH files, skeletons, forward kinematics, known skeleton profiles,
and live Perception Neuron streams (codec, sources, raw captures, replay server).

Conventions (shared by the whole project): metres and seconds, Y up, gravity along -Y, a body in
rest pose faces +Z; rotations via `scipy.spatial.transform.Rotation`, quaternions (x, y, z, w).
"""

from .bvh import Bvh, BvhParseError, Motion, format_bvh, parse_bvh, read_bvh, write_bvh
from .neuron import NeuronFrame, NeuronStreamError, StreamDecoder, decode_all, encode_frame
from .profiles import PROFILES, Profile, identify_profile
from .rawcapture import RawCaptureError, RawCaptureWriter, read_raw_capture
from .recordings import bundled_recordings, resolve_path
from .replay import Replay, ReplayError, ReplayThread
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
from .sources import Source, StreamSourceError, open_source
from .stream_layout import LayoutMismatchError, StreamLayout
from .units import UNITS, UnitError, resolve_unit

__all__ = [
    "Bvh",
    "BvhParseError",
    "CHANNEL_NAMES",
    "LayoutMismatchError",
    "Motion",
    "NeuronFrame",
    "NeuronStreamError",
    "PROFILES",
    "Profile",
    "RawCaptureError",
    "RawCaptureWriter",
    "Replay",
    "ReplayError",
    "ReplayThread",
    "Skeleton",
    "SkeletonError",
    "Source",
    "StreamDecoder",
    "StreamLayout",
    "StreamSourceError",
    "UNITS",
    "UnitError",
    "UnitUnknownError",
    "WorldPose",
    "bundled_recordings",
    "decode_all",
    "encode_frame",
    "format_bvh",
    "forward_kinematics",
    "identify_profile",
    "joint_levels",
    "open_source",
    "parse_bvh",
    "read_bvh",
    "read_raw_capture",
    "resolve_path",
    "resolve_unit",
    "skeleton_fk",
    "write_bvh",
]
