"""`sitrelax demo` stopped midway (Ctrl-C, or a stage that fails) leaves its folder as it was,
and an --out it cannot use is refused by name before any work."""

import time

import pytest

from solver.scene import demo
from solver.scene.demo import DemoError, run_demo


def test_an_interrupted_capture_leaves_the_empty_folder_empty(tmp_path, monkeypatch):
    """Ctrl-C while both recordings stream: the recorders are stopped and what they wrote
    (library, journals, locks) goes; the empty folder given stays, empty."""
    monkeypatch.setattr(demo, "STANDING_SECONDS", 0.5)
    out = tmp_path / "demo"
    out.mkdir()

    def progress(message):
        if message.startswith("streaming"):
            time.sleep(0.2)  # (frames arrive and are journalled)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_demo(out, progress=progress)
    time.sleep(0.5)  # nothing is written after the demo has returned
    assert out.is_dir() and list(out.iterdir()) == []


def test_an_interrupted_fit_leaves_no_folder_behind(tmp_path, monkeypatch):
    """Ctrl-C once the library and the scenario are written: the folder the demo made (and
    its parent) go, so that the same --out can be given again."""
    from solver.scene import run

    monkeypatch.setattr(demo, "STANDING_SECONDS", 0.5)

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(run, "run_fit", interrupted)
    out = tmp_path / "new" / "demo"
    with pytest.raises(KeyboardInterrupt):
        run_demo(out)
    assert not (tmp_path / "new").exists()


def test_a_file_or_an_empty_name_is_refused_as_the_folder(tmp_path):
    path = tmp_path / "demo"
    path.write_text("a designer's")
    with pytest.raises(DemoError, match="Expected a folder for the demo .--out., got a file"):
        run_demo(path)
    assert path.read_text() == "a designer's"
    with pytest.raises(DemoError, match="got an empty name"):
        run_demo("")
