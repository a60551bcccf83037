"""Shared test fixtures: where the real recordings and the fixture corpus live."""

from pathlib import Path

import pytest

from capture.recordings import bundled_dir

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
# The shared recordings beside the repository, when present; the bundled copies otherwise.
SHARED_BVH = ROOT.parent / "shared" / "data" / "bvh"


def recording(name: str) -> Path:
    shared = SHARED_BVH / name
    return shared if shared.exists() else bundled_dir() / name


@pytest.fixture
def cmu_high_sit() -> Path:
    return recording("cmu_75_18_high_sit.bvh")


@pytest.fixture
def axis_standing() -> Path:
    return recording("axis_neuron_standing_yxz.bvh")


# Property tests: 300 examples each by default; `pytest --hypothesis-profile=deep` for a search
# of 5,000.
from hypothesis import settings  # noqa: E402

settings.register_profile("default", max_examples=300)
settings.register_profile("deep", max_examples=5000)
settings.load_profile("default")
