"""Motion capture input: BVH files, skeletons, forward kinematics, known skeleton profiles,
and live Perception Neuron streams (codec, sources, raw captures, replay server).

Conventions (shared by the whole project): metres and seconds, Y up, gravity along -Y, a body in
rest pose faces +Z; rotations via `scipy.spatial.transform.Rotation`, quaternions (x, y, z, w).

This module is the facade: the names a user calls, each loaded when first used (so that the
`sitrelax` command starts without numpy and scipy).
"""

from __future__ import annotations

from capture.lazy import lazy_exports

_EXPORTS = {
    "capture.bvh": ("Bvh", "BvhParseError", "Motion", "format_bvh", "parse_bvh", "read_bvh",
                    "write_bvh"),
    "capture.neuron": ("NeuronFrame", "NeuronStreamError", "StreamDecoder", "decode_all",
                       "encode_frame"),
    "capture.profiles": ("PROFILES", "Profile", "identify_profile"),
    "capture.rawcapture": ("RawCaptureError", "RawCaptureWriter", "read_raw_capture"),
    "capture.recordings": ("bundled_recordings", "resolve_path"),
    "capture.replay": ("Replay", "ReplayError", "ReplayThread"),
    "capture.skeleton": ("CHANNEL_NAMES", "Skeleton", "SkeletonError", "UnitUnknownError",
                         "WorldPose", "forward_kinematics", "joint_levels", "skeleton_fk"),
    "capture.sources": ("Source", "StreamSourceError", "open_source"),
    "capture.stream_layout": ("LayoutMismatchError", "StreamLayout"),
    "capture.units": ("UNITS", "UnitError", "resolve_unit"),
}
__all__, _HOME, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
