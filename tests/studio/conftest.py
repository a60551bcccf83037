"""A pose library with one named seated pose, shared by the studio's tests."""

from pathlib import Path

import pytest

from capture.recordings import resolve_path
from posedb import PoseLibrary


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    """poses.h5 with the bundled high sit imported and frame 39 named "perch" (sit, high)."""
    path = tmp_path_factory.mktemp("studio") / "poses.h5"
    lib = PoseLibrary(path, create=True)
    take = lib.import_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"), name="high_sit")
    lib.add_pose(take.id, 39, "perch", tags=["sit", "high"])
    return path
