"""`sitrelax bvh ...`: command-line access to BVH recordings."""

from __future__ import annotations

import argparse
import json

import numpy as np

from .bvh import read_bvh
from .recordings import bundled_recordings, resolve_path


def bvh_info(spec: str, unit: str = "auto") -> dict:
    """A summary of a BVH file (`spec` is a path or `bundled:NAME`) as plain data."""
    path = resolve_path(spec)
    bvh = read_bvh(path, unit=unit)
    sk, mo = bvh.skeleton, bvh.motion
    info = {
        "file": str(path),
        "joints": sk.num_joints,
        "frames": mo.num_frames,
        "frame_time": mo.frame_time,
        "fps": mo.fps,
        "channels": sk.num_channels,
        "duration": mo.duration,
        "joint_names": list(sk.names),
        "profile": bvh.profile,
        "unit_m": sk.unit_m,
        "root_height_min_m": None,
        "root_height_max_m": None,
    }
    if sk.unit_m is not None and mo.num_frames:
        heights = sk.root_positions(mo.channels)[:, 1]
        info["root_height_min_m"] = float(np.min(heights))
        info["root_height_max_m"] = float(np.max(heights))
    return info


def _cmd_info(args: argparse.Namespace) -> int:
    info = bvh_info(args.file, args.unit)
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    print(f"file        {info['file']}")
    print(f"profile     {info['profile'] or 'unknown'}")
    print(f"joints      {info['joints']}")
    print(f"channels    {info['channels']}")
    print(f"frames      {info['frames']} at {info['frame_time']:g} s ({info['fps']:.1f} fps)")
    print(f"duration    {info['duration']:.3f} s")
    if info["unit_m"] is None:
        print("unit        unknown (pass --unit, e.g. --unit cm, for metric heights)")
    else:
        print(f"unit        {info['unit_m']:g} m per file unit")
        if info["root_height_min_m"] is not None:
            print(f"root height {info['root_height_min_m']:.3f} .. "
                  f"{info['root_height_max_m']:.3f} m")
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    names = bundled_recordings()
    if args.json:
        print(json.dumps(names))
    else:
        for name in names:
            print(f"bundled:{name}")
    return 0


def register(subparsers) -> None:
    """Adds the `bvh` command group to the top-level parser."""
    bvh = subparsers.add_parser("bvh", help="inspect BVH motion files")
    sub = bvh.add_subparsers(dest="bvh_command", required=True)
    info = sub.add_parser("info", help="summarise a BVH file")
    info.add_argument("file", help="a .bvh path or bundled:NAME (see `sitrelax bvh list`)")
    info.add_argument("--unit", default="auto",
                      help="length unit of the file: auto (from the skeleton profile), m, cm, mm, "
                           "in, cmu, or metres per unit (default: auto)")
    info.add_argument("--json", action="store_true", help="machine-readable output")
    info.set_defaults(func=_cmd_info)
    lst = sub.add_parser("list", help="list the bundled recordings")
    lst.add_argument("--json", action="store_true", help="machine-readable output")
    lst.set_defaults(func=_cmd_list)
