"""The library under stress: killed commits, long writers, a finishing recorder racing
`recover`, read-only and symlinked files edited by other users, bit flips, and compaction."""

import json
import os
import random
import shutil
import stat
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from posedb import files
from posedb.library import PoseLibrary
from posedb.locking import exclusive, lock_path, try_exclusive
from posedb.record import journal_dir, record, recover
from posedb.schema import LibraryError

from ..conftest import ROOT, recording

CMU = "cmu_75_18_high_sit.bvh"
NOBODY = 65534
posix_only = pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")


@pytest.fixture
def db(tmp_path):
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    lib.import_bvh(recording(CMU), tags=["sit"], subject="75")
    lib.add_pose(CMU[:-4], 39, "seated")
    return tmp_path / "poses.h5"


def _temporaries(path: Path) -> list[str]:
    return [p.name for p in path.parent.iterdir() if p.name.endswith(".tmp")]


# -- killed commits -------------------------------------------------------------------------


def _kill_commits(db: Path, kills: int, seed: int = 0) -> dict:
    """Forks a child that commits tags in a loop, kills it with SIGKILL at a random moment,
    then runs the next command (an open); `kills` times."""
    rng = random.Random(seed)
    left, notes = 0, 0
    for k in range(kills):
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # the writer
            os.close(read)
            lib = PoseLibrary(db)
            os.write(write, b"x")
            n = 0
            while True:
                with lib.edit() as ed:
                    ed.tag("seated", add=[f"t{k}-{n % 3}"])
                n += 1
        os.close(write)
        os.read(read, 1)
        os.close(read)
        time.sleep(rng.uniform(0.0, 0.12))
        os.kill(pid, 9)
        os.waitpid(pid, 0)
        left += bool(_temporaries(db))
        lib = PoseLibrary(db)  # the next command
        notes += len(lib.notes)
        assert _temporaries(db) == [], f"kill {k}"
    assert PoseLibrary(db).check() == []
    return {"kills": kills, "left_a_copy": left, "notes": notes}


@posix_only
def test_20_killed_commits_leave_no_temporary_after_the_next_command(db):
    # where a kill lands is chance (a busy machine shifts it): rounds of 20 until one lands
    # inside a commit, five at most; every round must leave nothing behind
    for seed in range(5):
        result = _kill_commits(db, 20, seed=seed)
        assert result["notes"] == result["left_a_copy"]
        if result["left_a_copy"]:
            break
    assert result["left_a_copy"] > 0, result  # the kills did land inside commits


@posix_only
@pytest.mark.slow
def test_200_killed_commits(db):
    print(_kill_commits(db, 200, seed=1))


# -- long writers ---------------------------------------------------------------------------


def _hold_lock(path: Path, seconds: float) -> subprocess.Popen:
    """Another process holding the library's write lock for `seconds` (a long import)."""
    code = ("import sys, time\nfrom posedb.locking import exclusive\n"
            "with exclusive(sys.argv[1], timeout=None):\n"
            "    print('held', flush=True)\n    time.sleep(float(sys.argv[2]))\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(path), str(seconds)],
                            stdout=subprocess.PIPE, text=True, cwd=ROOT,
                            env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.stdout.readline() == "held\n"
    return proc


def _record_from_file(db, take, **kw):
    from tests.capture.test_stream_fixtures import STREAMS

    return record(f"file:{STREAMS / 'skipped_indices.raw'}", db, take, str(recording(CMU)), **kw)


def _tag_and_record_behind_a_long_writer(db: Path, seconds: float) -> None:
    holder = _hold_lock(db, seconds)
    waits, events, errors = [], [], []

    def tag():
        try:
            with PoseLibrary(db, on_wait=waits.append).edit() as ed:
                ed.tag("seated", add=["waited"])
        except Exception as exc:  # collected for the assertion below
            errors.append(exc)

    thread = threading.Thread(target=tag)
    thread.start()
    summary = _record_from_file(db, "behind", on_event=events.append)
    thread.join()
    holder.wait()
    assert not errors and summary["take"]["name"] == "behind"
    lib = PoseLibrary(db)
    assert "waited" in lib.pose("seated").tags and lib.take("behind").frames == 60
    assert waits and waits[-1] >= seconds - 1.5  # progress was reported while waiting
    assert any("waiting" in e for e in events)
    assert not list(journal_dir(db).glob("*.raw"))


@pytest.mark.slow  # (3.5-7.5 s: the default run stays within its time)
def test_a_long_writer_makes_a_tag_and_a_recording_commit_wait(db):
    _tag_and_record_behind_a_long_writer(db, 3.0)


@pytest.mark.slow
def test_a_20_s_writer_makes_a_tag_and_a_recording_commit_wait(db):
    _tag_and_record_behind_a_long_writer(db, 20.0)


def test_import_parses_outside_the_lock(db, monkeypatch, capsys):
    import capture
    from capture import read_bvh
    from studio.cli import main

    seen = []

    def parse(path, **kw):
        lock = try_exclusive(db)  # free while the file is parsed
        seen.append(lock is not None)
        if lock is not None:
            lock.release()
        return read_bvh(path, **kw)

    monkeypatch.setattr(capture, "read_bvh", parse)  # the command imports it when it runs
    assert main(["db", "import", str(recording(CMU)), "--name", "again", "--db", str(db)]) == 0
    assert seen == [True]


@pytest.mark.slow  # (3.5-7.5 s: the default run stays within its time)
def test_a_recording_that_cannot_commit_keeps_its_journal_and_says_what_to_run(db):
    holder = _hold_lock(db, 3.0)
    with pytest.raises(LibraryError) as err:
        _record_from_file(db, "later", lock_timeout=0.5)
    holder.wait()
    (journal,) = journal_dir(db).glob("*.raw")
    assert str(journal) in str(err.value)
    assert f"run `sitrelax db recover --db {db}` to store it" in str(err.value)
    assert [r["status"] for r in recover(db)] == ["recovered"]
    assert PoseLibrary(db).take("later").frames == 60


@pytest.mark.parametrize("races", [pytest.param(2), pytest.param(6, marks=pytest.mark.slow)])
def test_recover_and_a_finishing_recorder_store_the_take_once(db, races):
    for k in range(races):
        holder = _hold_lock(db, 0.6)  # the recorder's final commit waits: the old race window
        outcome = {}
        thread = threading.Thread(
            target=lambda: outcome.update(_record_from_file(db, f"race{k}")))
        thread.start()
        deadline = time.monotonic() + 30
        while not list(journal_dir(db).glob("*.raw")):
            assert thread.is_alive() and time.monotonic() < deadline, "the recorder never began"
            time.sleep(0.01)
        time.sleep(0.2)
        statuses = [r["status"] for r in recover(db)]
        thread.join()
        holder.wait()
        assert all(not s.startswith("failed") for s in statuses), statuses
        assert outcome["take"]["name"] == f"race{k}"
        assert [t.name for t in PoseLibrary(db).takes()].count(f"race{k}") == 1
    assert not list(journal_dir(db).glob("*.raw"))


@pytest.mark.slow  # (3.5-7.5 s: the default run stays within its time)
def test_a_recording_whose_name_was_taken_meanwhile_is_stored_under_another(db, capsys):
    """A take of the recording's name stored while it ran (another recorder, an import) does
    not strand the journal: it is stored as NAME-2, and its notes say why."""
    from studio.cli import main

    holder = _hold_lock(db, 3.0)
    with pytest.raises(LibraryError):
        _record_from_file(db, "twin", lock_timeout=0.5)  # (its journal is kept)
    holder.wait()
    assert main(["db", "import", str(recording(CMU)), "--name", "twin", "--db", str(db)]) == 0
    capsys.readouterr()
    assert main(["db", "recover", "--db", str(db), "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)
    assert row["status"] == "recovered as 'twin-2' (a take named 'twin' was there first)"
    stored = PoseLibrary(db).take("twin-2")
    assert stored.frames == 60 and "a take named 'twin' was there first" in stored.notes
    assert not list(journal_dir(db).glob("*.raw"))
    assert not list(journal_dir(db).glob("*.lock"))  # (nor the stored journal's lock)
