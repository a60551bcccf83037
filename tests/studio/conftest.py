"""A pose library with one named seated pose, shared by the studio's tests."""

from pathlib import Path

import pytest

from tests.conftest import high_sit_library


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    """poses.h5 with the bundled high sit imported and frame 39 named "perch" (sit, high)."""
    return high_sit_library(tmp_path_factory.mktemp("studio") / "poses.h5",
                            [(39, "perch", ["sit", "high"])])
