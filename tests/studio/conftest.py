"""Shared by the studio's tests: a pose library with one named seated pose, a studio server
without a library and a Design view on it, and waiting for what a tab does."""

import time
from pathlib import Path

import pytest

from tests.conftest import high_sit_library


@pytest.fixture(scope="module")
def library(tmp_path_factory) -> Path:
    """poses.h5 with the bundled high sit imported and frame 39 named "perch" (sit, high)."""
    return high_sit_library(tmp_path_factory.mktemp("studio") / "poses.h5",
                            [(39, "perch", ["sit", "high"])])


@pytest.fixture(scope="module")
def studio(tmp_path_factory):
    """A studio server without a pose library on a free port (a module's tests share it)."""
    from studio.web import Studio

    server = Studio(port=0, out=str(tmp_path_factory.mktemp("out")))
    yield server
    server.stop()


@pytest.fixture
def design_view(studio):
    """A headless tab's Design view on `studio`, not refitting while edited."""
    from studio.headless import HeadlessTab

    tab = HeadlessTab(studio)
    tab.view.live.value = False
    yield tab.view
    tab.close()


def wait_until(predicate, timeout: float, what: str) -> None:
    """Polls `predicate` every 20 ms until it holds; an AssertionError naming `what` after
    `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.02)
    raise AssertionError(f"timed out after {timeout} s waiting for {what}")
