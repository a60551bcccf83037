"""Benchmark entries of the pose library."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np

from capture.bench import BenchCase
from capture.recordings import resolve_path

POSES = 100_000
VOCABULARY = ("sit", "lean", "lounge", "lie", "floor", "high", "low", "office", "outdoor",
              "relaxed", "upright", "reading")
QUERY = "sit and not floor"


def _library_setup():
    """A library of one take and 100,000 poses, each with three tags of twelve."""
    from .library import PoseLibrary

    folder = Path(tempfile.mkdtemp(prefix="sitrelax-bench-"))
    lib = PoseLibrary(folder / "bench.h5", create=True)
    rng = np.random.default_rng(0)
    with lib.edit() as ed:
        tid = ed.import_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"))
        for k in range(POSES):
            tags = rng.choice(len(VOCABULARY), 3, replace=False)
            ed.add_pose(tid, k % 77, f"pose{k:06d}", tags=[VOCABULARY[t] for t in tags])
    lib.search_poses(QUERY)  # build the tag index once, as an open library keeps it
    return lib


def _query(lib):
    return lib.search_poses(QUERY)


def _cold_setup():
    return _library_setup().path


def _cold_query(path):
    from .library import PoseLibrary

    return PoseLibrary(path).search_poses(QUERY)


def cases() -> list[BenchCase]:
    return [
        BenchCase("posedb_query", f"tag search '{QUERY}' over {POSES:,} poses (open library)",
                  _library_setup, _query),
        BenchCase("posedb_open_query",
                  f"open a {POSES:,}-pose library and run the same search", _cold_setup,
                  _cold_query, repeats=5),
    ]
