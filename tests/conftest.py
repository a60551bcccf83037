"""Shared test fixtures: where the real recordings and the fixture corpus live."""

import os
from pathlib import Path

import pytest

from capture.recordings import bundled_dir

# Test workers run side by side (pytest -n), as batch jobs do: one thread each, so that a fit's
# second thread (solver.threads.overlapped) does not starve the other worker, a browser test's
# page least of all. The tests of that thread ask for it themselves (test_overlap.py).
if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("SITRELAX_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
FIXTURES = ROOT / "fixtures"
# The shared recordings beside the repository, when present; the bundled copies otherwise.
SHARED_BVH = ROOT.parent / "shared" / "data" / "bvh"


def recording(name: str) -> Path:
    shared = SHARED_BVH / name
    return shared if shared.exists() else bundled_dir() / name


def high_sit_library(path: Path, poses=((39, "perch", ("sit",)),), take_tags=()) -> Path:
    """A new pose library at `path` with the bundled high-sit recording as a take `high_sit`
    (tagged `take_tags`) and `poses` (frame, name, tags) of it; its path."""
    from capture.recordings import resolve_path
    from posedb import PoseLibrary

    lib = PoseLibrary(path, create=True)
    take = lib.import_bvh(resolve_path("bundled:cmu_75_18_high_sit.bvh"), name="high_sit",
                          tags=list(take_tags))
    for frame, name, tags in poses:
        lib.add_pose(take.id, frame, name, tags=list(tags))
    return Path(path)


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


def listening_addresses(port: int) -> set[str]:
    """The local addresses on which some process of this machine listens on TCP `port`, read
    from /proc/net (no traffic is sent anywhere)."""
    import ipaddress

    found = set()
    for table, size in (("/proc/net/tcp", 4), ("/proc/net/tcp6", 16)):
        try:
            lines = Path(table).read_text().splitlines()[1:]
        except OSError:
            continue
        for line in lines:
            fields = line.split()
            address, hex_port = fields[1].split(":")
            if int(hex_port, 16) != port or fields[3] != "0A":  # 0A: LISTEN
                continue
            raw = bytes.fromhex(address)
            # the kernel writes each 32-bit word in host (little-endian) order
            raw = b"".join(raw[i:i + 4][::-1] for i in range(0, size, 4))
            found.add(str(ipaddress.ip_address(raw)))
    return found
