"""Results folders written whole or not at all (`capture.files`): a folder written again holds
one result, an interrupted or failed run leaves the earlier one as it was, and errors name the
user's folder and files, never a hidden one."""

from __future__ import annotations

import errno
import os
import subprocess
import sys

import pytest

import capture.files as files
from capture.files import STAGE_PREFIX, replace_results, results_folder, write_atomic


def _contents(folder):
    return {p.name: p.read_text() for p in folder.iterdir()}


def _earlier(folder):
    """An earlier result (report.json listing a.obj and old.png) and the user's own file."""
    folder.mkdir()
    for name, text in (("a.obj", "old"), ("old.png", "old"), ("report.json", "old"),
                       ("notes.txt", "the user's")):
        (folder / name).write_text(text)
    return lambda f: {"a.obj", "old.png", "report.json"}


def test_a_folder_written_again_holds_the_new_result_alone(tmp_path):
    out = tmp_path / "out"
    previous = _earlier(out)
    with results_folder(out, previous, "report.json") as stage:
        assert stage.parent == out and stage.name.startswith(STAGE_PREFIX)
        assert (out / "old.png").exists()  # (nothing changes before the block ends well)
        for name in ("a.obj", "b.obj", "report.json"):
            (stage / name).write_text("new")
    assert _contents(out) == {"a.obj": "new", "b.obj": "new", "report.json": "new",
                              "notes.txt": "the user's"}


@pytest.mark.parametrize("stop", [ValueError("no fit"), KeyboardInterrupt()])
def test_a_failed_or_interrupted_run_leaves_the_earlier_result(tmp_path, stop):
    out = tmp_path / "out"
    previous = _earlier(out)
    with pytest.raises(type(stop)):
        with results_folder(out, previous, "report.json") as stage:
            (stage / "a.obj").write_text("new")
            raise stop
    assert _contents(out) == {"a.obj": "old", "old.png": "old", "report.json": "old",
                              "notes.txt": "the user's"}


def test_a_folder_made_for_a_failed_run_goes_again(tmp_path):
    with pytest.raises(ValueError):
        with results_folder(tmp_path / "new" / "out") as stage:
            (stage / "a.obj").write_text("new")
            raise ValueError("no fit")
    assert list(tmp_path.iterdir()) == []


def test_an_error_about_a_staged_file_names_it_in_the_user_s_folder(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(OSError) as caught:
        with results_folder(out) as stage:
            raise OSError(errno.ENOSPC, "No space left on device", str(stage / "solid.stl"))
    assert caught.value.filename == str(out / "solid.stl")
    assert caught.value.errno == errno.ENOSPC


def test_an_unwritable_folder_is_refused_before_the_work(tmp_path, monkeypatch):
    def refused(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied", "/somewhere/.hidden")

    monkeypatch.setattr(files.tempfile, "mkdtemp", refused)
    ran = []
    with pytest.raises(OSError, match="Cannot write the results into this folder") as caught:
        with results_folder(tmp_path):
            ran.append(1)
    assert caught.value.filename == str(tmp_path) and not ran


def test_an_empty_folder_name_is_refused(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ValueError, match="empty name"):
        with results_folder(""):
            pass
    assert list(tmp_path.iterdir()) == []


def test_a_killed_run_s_hidden_folder_goes_with_the_next_run(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    orphan = tmp_path / f"{STAGE_PREFIX}{dead}-abc"
    alive = tmp_path / f"{STAGE_PREFIX}{os.getppid()}-abc"  # (a process that still runs)
    for stage in (orphan, alive):
        stage.mkdir()
        (stage / "surface.obj").write_text("half")
    with results_folder(tmp_path) as stage:
        (stage / "report.json").write_text("new")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([alive.name, "report.json"])


def _new_over_old(tmp_path):
    """A stage holding a new a.obj, b.obj and report.json, and a folder holding an old a.obj."""
    stage, out = tmp_path / "stage", tmp_path / "out"
    stage.mkdir()
    out.mkdir()
    for name in ("report.json", "a.obj", "b.obj"):
        (stage / name).write_text("new")
    (out / "a.obj").write_text("old")
    return stage, out


def test_replacing_is_undone_when_a_move_fails(tmp_path, monkeypatch):
    """`replace_results` with its fourth move failing: the folder is as it was (the earlier
    result's stale file and the user's own file untouched), the new files are back in the
    stage, and a second go moves them all, report.json last, and drops the stale file."""
    stage, out = _new_over_old(tmp_path)
    (out / "old.png").write_text("old")
    (out / "report.json").write_text("old")  # (an earlier result's report: written last)
    os.utime(out / "report.json", (1e9 + 10, 1e9 + 10))
    os.utime(out / "old.png", (1e9, 1e9))
    (out / "notes.txt").write_text("the user's")
    real, moves = os.replace, []

    def failing(src, dst):
        moves.append(os.path.basename(dst))
        if len(moves) == 4:  # a.obj out and in, b.obj in, then report.json's first move
            raise OSError("disk full")
        real(src, dst)

    stale = {"a.obj", "old.png", "report.json", "../elsewhere.txt", ".hidden",
             "x/../../elsewhere.txt"}
    monkeypatch.setattr(files.os, "replace", failing)
    with pytest.raises(OSError, match="disk full"):
        replace_results(stage, out, stale, "report.json")
    monkeypatch.setattr(files.os, "replace", real)
    assert _contents(out) == {"a.obj": "old", "report.json": "old", "old.png": "old",
                              "notes.txt": "the user's"}
    assert sorted(p.name for p in stage.iterdir()) == ["a.obj", "b.obj", "report.json"]
    (tmp_path / "elsewhere.txt").write_text("the user's")
    moves.clear()
    monkeypatch.setattr(files.os, "replace", lambda src, dst: (moves.append(
        os.path.basename(dst)), real(src, dst)))
    replace_results(stage, out, stale, "report.json")
    assert moves[-1] == "report.json"
    assert _contents(out) == {"a.obj": "new", "b.obj": "new", "report.json": "new",
                              "notes.txt": "the user's"}
    assert (tmp_path / "elsewhere.txt").exists()


def test_write_atomic_names_the_file_asked_for_when_the_disk_is_full(tmp_path, monkeypatch):
    def full(fd):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(files.os, "fsync", full)
    with pytest.raises(OSError) as caught:
        write_atomic(tmp_path / "surface.obj", b"v 0 0 0\n")
    assert caught.value.filename == str(tmp_path / "surface.obj")
    assert caught.value.errno == errno.ENOSPC and list(tmp_path.iterdir()) == []


def test_write_atomic_names_the_file_asked_for_in_a_folder_it_may_not_write(tmp_path,
                                                                         monkeypatch):
    def refused(*args, **kwargs):
        raise PermissionError(errno.EACCES, "Permission denied",
                              str(tmp_path / ".surface.obj.x.tmp"))

    monkeypatch.setattr(files.tempfile, "mkstemp", refused)
    with pytest.raises(PermissionError) as caught:
        write_atomic(tmp_path / "surface.obj", b"")
    assert caught.value.filename == str(tmp_path / "surface.obj")


def test_a_folder_of_the_user_s_named_as_a_result_file_is_refused_and_kept(tmp_path):
    out = tmp_path / "out"
    previous = _earlier(out)
    (out / "sections.png").mkdir()
    (out / "sections.png" / "my_drawing.svg").write_text("the user's")
    with pytest.raises(IsADirectoryError) as caught:
        with results_folder(out, previous, "report.json") as stage:
            for name in ("a.obj", "sections.png", "report.json"):
                (stage / name).write_text("new")
    assert caught.value.filename == str(out / "sections.png")
    assert (out / "sections.png" / "my_drawing.svg").read_text() == "the user's"
    assert (out / "a.obj").read_text() == "old" and (out / "report.json").read_text() == "old"
    assert not [p for p in out.iterdir() if p.name.startswith(STAGE_PREFIX)]


def test_an_interrupt_while_the_files_move_in_waits_until_they_have(tmp_path, monkeypatch):
    """Ctrl-C arriving while the results move in (here: raised by the first move's signal)
    ends the command only once every file is in place: never half the new result."""
    import signal

    stage, out = _new_over_old(tmp_path)
    real, moves = os.replace, []

    def interrupted(src, dst):
        moves.append(dst)
        if len(moves) == 1:
            os.kill(os.getpid(), signal.SIGINT)
        real(src, dst)

    monkeypatch.setattr(files.os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        replace_results(stage, out, (), "report.json")
    assert _contents(out) == {"a.obj": "new", "b.obj": "new", "report.json": "new"}


def test_a_file_of_the_earlier_result_the_user_changed_since_stays(tmp_path):
    """The earlier result's old.png, edited after its report.json was written (a designer's
    own version of it), is not the result's any more: a new result that does not write it
    leaves it; its a.obj, untouched since, goes."""
    out = tmp_path / "out"
    previous = _earlier(out)
    os.utime(out / "report.json", (1e9 + 10, 1e9 + 10))
    os.utime(out / "a.obj", (1e9, 1e9))
    (out / "old.png").write_text("the user's version")
    os.utime(out / "old.png", (1e9 + 20, 1e9 + 20))
    with results_folder(out, previous, "report.json") as stage:
        (stage / "report.json").write_text("new")
    assert _contents(out) == {"old.png": "the user's version", "report.json": "new",
                              "notes.txt": "the user's"}
