"""The library's file: owner, mode and symbolic link kept across changes (edited as another
user where the machine allows), locking without fcntl, bit flips named, and compaction."""

import json
import os
import random
import shutil
import stat
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from capture import read_bvh
from posedb.library import PoseLibrary
from posedb.schema import LibraryError
from posedb.verify import verify

from ..conftest import ROOT, recording

CMU = "cmu_75_18_high_sit.bvh"
NOBODY = 65534
as_root = pytest.mark.skipif(
    not hasattr(os, "fork") or not hasattr(os, "geteuid") or os.geteuid() != 0,
    reason="editing as another user needs root (to setuid to nobody in a forked child)")


@pytest.fixture
def shared_dir():
    """A folder every user may write (pytest's tmp_path is private to root)."""
    path = Path(tempfile.mkdtemp(prefix="sitrelax-shared-", dir="/tmp"))
    path.chmod(0o777)
    yield path
    shutil.rmtree(path, ignore_errors=True)


def _library(path: Path) -> Path:
    lib = PoseLibrary(path, create=True)
    lib.import_bvh(recording(CMU), tags=["sit"])
    lib.add_pose(CMU[:-4], 39, "seated")
    return path


def _tag_as(uid: int | None, path: Path) -> str:
    """`tag seated mine` on the library, in a forked child running as `uid` (None: as we
    are); returns "ok" or the error's message."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:
        os.close(read)
        try:
            if uid is not None:
                os.setgroups([])
                os.setgid(uid)
                os.setuid(uid)
            with PoseLibrary(path).edit() as ed:
                ed.tag("seated", add=["mine"])
            message = "ok"
        except Exception as exc:  # reported to the parent
            message = f"{type(exc).__name__}: {exc}"
        os.write(write, message.encode())
        os._exit(0)
    os.close(write)
    with os.fdopen(read) as f:
        message = f.read()
    os.waitpid(pid, 0)
    return message


def _owner_mode(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)


@as_root
def test_a_read_only_root_library_is_refused_to_another_user_and_to_root(shared_dir):
    path = _library(shared_dir / "poses.h5")
    path.chmod(0o444)
    before = path.read_bytes()
    message = _tag_as(NOBODY, path)
    assert message.startswith("ReadOnlyError") and "mode 0444, owner root" in message, message
    assert _tag_as(None, path).startswith("ReadOnlyError")  # read-only on purpose, even for root
    assert _owner_mode(path) == (0, 0, 0o444) and path.read_bytes() == before
    assert not [p for p in shared_dir.iterdir() if p.name.endswith(".tmp")]


@as_root
def test_owner_and_mode_are_kept_whoever_edits(shared_dir):
    path = _library(shared_dir / "poses.h5")
    os.chown(path, NOBODY, NOBODY)
    path.chmod(0o640)  # not what a new file would get from the umask
    assert _tag_as(NOBODY, path) == "ok"
    assert _owner_mode(path) == (NOBODY, NOBODY, 0o640)
    with PoseLibrary(path).edit() as ed:  # root edits nobody's file: it stays nobody's
        ed.tag("seated", add=["root"])
    assert _owner_mode(path) == (NOBODY, NOBODY, 0o640)
    assert PoseLibrary(path).pose("seated").tags == ("mine", "root")


@pytest.mark.skipif(not hasattr(os, "symlink"), reason="needs symbolic links")
def test_a_symlinked_library_stays_a_link_and_its_target_is_edited(tmp_path):
    (tmp_path / "store").mkdir()
    target = _library(tmp_path / "store" / "real.h5")
    target.chmod(0o600)
    link = tmp_path / "poses.h5"
    link.symlink_to(target)
    with PoseLibrary(link).edit() as ed:
        ed.tag("seated", add=["linked"])
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert stat.S_IMODE(target.stat().st_mode) == 0o600
    assert "linked" in PoseLibrary(target).pose("seated").tags
    assert not list(tmp_path.glob(".*.tmp")) and not list(target.parent.glob(".*.tmp"))


@as_root
def test_a_symlinked_library_edited_by_another_user(shared_dir):
    (shared_dir / "store").mkdir(mode=0o777)
    (shared_dir / "store").chmod(0o777)
    target = _library(shared_dir / "store" / "real.h5")
    os.chown(target, NOBODY, NOBODY)
    target.chmod(0o600)
    link = shared_dir / "poses.h5"
    link.symlink_to(target)
    assert _tag_as(NOBODY, link) == "ok"
    assert link.is_symlink() and os.readlink(link) == str(target)
    assert _owner_mode(target) == (NOBODY, NOBODY, 0o600)


def test_locking_without_fcntl(tmp_path):
    """In a Python where `import fcntl` fails: `db list` imports, writers queue, and a killed
    writer leaves no stale lock."""
    path = _library(tmp_path / "poses.h5")
    code = f"""
import os, signal, sys, time
sys.modules["fcntl"] = None
import warnings; warnings.simplefilter("ignore")
from studio.cli import main
import posedb.locking as locking
assert not locking.has_os_lock()
db = {str(path)!r}
assert main(["db", "list", "--db", db]) == 0
import threading
from posedb.library import PoseLibrary
errors = []
def add(k):
    try:
        PoseLibrary(db).add_pose("cmu_75_18_high_sit", k, f"p{{k}}")
    except Exception as exc:
        errors.append(exc)
threads = [threading.Thread(target=add, args=(k,)) for k in range(4)]
[t.start() for t in threads]; [t.join() for t in threads]
assert not errors, errors
pid = os.fork()
if pid == 0:
    with locking.exclusive(db, timeout=None):
        os.kill(os.getpid(), signal.SIGKILL)
os.waitpid(pid, 0)
assert locking.lock_path(db).name.endswith(".softlock")
t = time.monotonic()
PoseLibrary(db, lock_timeout=5).add_pose("cmu_75_18_high_sit", 9, "after_kill")
print("ok", round(time.monotonic() - t, 2))
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=120)
    assert run.returncode == 0, run.stderr
    assert run.stdout.splitlines()[-1].startswith("ok")
    assert {f"p{k}" for k in range(4)} | {"after_kill"} <= {p.name for p in
                                                           PoseLibrary(path).poses()}


def _reads(path: Path) -> None:
    """Everything a user reads of a library."""
    lib = PoseLibrary(path)
    for take in lib.takes():
        lib.take_data(take.id)
    for pose in lib.poses():
        lib.pose_data(pose.id)
    lib.stats()


def test_bit_flips_are_named_and_a_damaged_library_is_not_edited(tmp_path):
    good = _library(tmp_path / "good.h5")
    size = good.stat().st_size
    rng = random.Random(7)
    outcomes = {"read error": 0, "edit refused": 0, "harmless": 0}
    for trial in range(40):
        path = tmp_path / f"flip{trial}.h5"
        data = bytearray(good.read_bytes())
        offset = rng.randrange(size)
        data[offset] ^= 1 << rng.randrange(8)
        path.write_bytes(bytes(data))
        try:
            _reads(path)
        except LibraryError as exc:
            assert str(path) in str(exc), (offset, exc)
            outcomes["read error"] += 1
        problems = verify(path)
        before = path.read_bytes()
        try:
            with PoseLibrary(path).edit() as ed:
                ed.tag("seated", add=["mine"])
        except LibraryError as exc:
            assert str(path) in str(exc), (offset, exc)
            assert path.read_bytes() == before
            outcomes["edit refused"] += 1
            continue
        assert problems == [], (offset, problems)  # a change only to a library found sound
        outcomes["harmless"] += 1
    print(outcomes)
    assert outcomes["read error"] and outcomes["edit refused"], outcomes


def test_compact_leaves_no_byte_of_a_deleted_take(tmp_path):
    path = tmp_path / "poses.h5"
    lib = PoseLibrary(path, create=True)
    secret_notes, secret_subject = "NOTES-of-the-deleted-take-7f3a", "SUBJECT-deleted-9c1e"
    bvh = read_bvh(recording(CMU))
    sk = bvh.skeleton.with_joint_map({"pelvis": "Hips"})
    with lib.edit() as ed:
        ed.add_take(sk, bvh.motion.channels, bvh.motion.frame_time, name="kept", tags=["a"])
        ed.import_bvh(bvh, name="gone", subject=secret_subject, notes=secret_notes)
        ed.add_pose("kept", 10, "kept_pose", notes="kept notes")
        ed.add_pose("gone", 39, "gone_pose", notes="POSE-NOTES-deleted-41b2")
    with lib.edit() as ed:
        ed.delete_take("gone")
    raw = path.read_bytes()
    print({s: s.encode() in raw for s in (secret_notes, secret_subject)})  # before compaction
    kept = lib.take_data("kept")
    sizes = lib.compact()
    raw = path.read_bytes()
    for text in (secret_notes, secret_subject, "POSE-NOTES-deleted-41b2", "gone_pose"):
        assert text.encode() not in raw, text
    assert b'"gone"' not in raw
    lib = PoseLibrary(path)
    assert lib.check() == [] and sizes["size_after"] <= sizes["size_before"]
    assert [t.name for t in lib.takes()] == ["kept"] and lib.take("kept").tags == ("a",)
    again = lib.take_data("kept")
    assert dict(again.skeleton.joint_map) == {"pelvis": "Hips"}
    np.testing.assert_array_equal(again.channels, kept.channels)
    info, _, rot, _ = lib.pose_data("kept_pose")
    np.testing.assert_allclose(rot, kept.local_rotations[10], atol=1e-7)
    assert info.notes == "kept notes"
    with lib.edit() as ed:  # and it stays editable
        ed.add_pose("kept", 20, "after")
    assert lib.pose_data("after")[2].shape == rot.shape


def test_check_and_compact_commands(tmp_path, capsys):
    from studio.cli import main

    path = _library(tmp_path / "poses.h5")
    assert main(["db", "check", "--db", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["ok"] is True
    assert main(["db", "compact", "--db", str(path)]) == 0
    assert "compacted" in capsys.readouterr().out
    import h5py

    with h5py.File(path, "r") as f:  # where the first chunk of the take's channels lies
        chunk = f["takes/take-00001/channels"].id.get_chunk_info(0)
    data = bytearray(path.read_bytes())
    data[chunk.byte_offset + chunk.size // 2] ^= 0xFF
    path.write_bytes(bytes(data))
    assert main(["db", "check", "--db", str(path)]) == 1
    assert "/takes/take-00001/channels" in capsys.readouterr().out
    assert main(["db", "tag", "seated", "mine", "--db", str(path)]) == 2
    err = capsys.readouterr().err
    assert str(path) in err and "was not changed" in err and "db check" in err


def test_a_lock_timeout_negative_waits_on_and_nan_is_refused(tmp_path, monkeypatch, capsys):
    """$SITRELAX_LOCK_TIMEOUT and --lock-timeout agree: negative (or infinite) waits as long as
    the other writer runs; NaN, which would poll without waiting and never time out, is
    refused by name."""
    import threading

    from posedb.library import default_lock_timeout
    from posedb.locking import exclusive, lock_wait
    from studio.cli import main

    for text, seconds in (("-1", None), ("inf", None), ("none", None), ("2.5", 2.5)):
        monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", text)
        assert default_lock_timeout() == seconds
    monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", "nan")
    with pytest.raises(LibraryError, match=r"SITRELAX_LOCK_TIMEOUT.*got nan"):
        default_lock_timeout()
    assert lock_wait(-3.0) is None and lock_wait(0.0) == 0.0
    monkeypatch.delenv("SITRELAX_LOCK_TIMEOUT")
    path = _library(tmp_path / "poses.h5")
    assert main(["db", "tag", "--db", str(path), "--lock-timeout", "nan",
                 "cmu_75_18_high_sit", "x"]) == 2
    assert "--lock-timeout in seconds" in capsys.readouterr().err
    # a negative timeout waits for the writer holding the lock, however long
    held, done = threading.Event(), []

    def hold() -> None:
        with exclusive(path, timeout=0):
            held.set()
            time.sleep(1.5)

    holder = threading.Thread(target=hold)
    holder.start()
    held.wait(10)
    monkeypatch.setenv("SITRELAX_LOCK_TIMEOUT", "-1")
    start = time.monotonic()
    done.append(main(["db", "tag", "--db", str(path), "cmu_75_18_high_sit", "x"]))
    holder.join()
    assert done == [0] and time.monotonic() - start > 1.0


def test_check_finds_a_skeleton_offset_that_is_no_number(tmp_path, capsys):
    """An offset that is not a number would be exported as `OFFSET nan ...`, which no BVH
    reader (ours included) takes: the check names it."""
    import h5py

    from studio.cli import main

    path = _library(tmp_path / "poses.h5")
    with h5py.File(path, "r+") as f:
        (key,) = list(f["skeletons"])[:1]
        offsets = f["skeletons"][key]["offsets"]
        row = offsets[3]
        row[1] = np.nan
        offsets[3] = row
    assert main(["db", "check", "--db", str(path), "--quick"]) == 1
    assert f"/skeletons/{key}/offsets: 1 value(s) that are not numbers" in capsys.readouterr().out


def test_a_library_in_a_folder_that_does_not_exist_is_refused_not_made(tmp_path, capsys):
    from studio.cli import main

    path = tmp_path / "typo" / "dir" / "poses.h5"
    assert main(["db", "import", "--db", str(path), "bundled:cmu_82_05_floor_sit_excerpt.bvh"]) == 2
    assert f"its folder {path.parent} does not exist" in capsys.readouterr().err
    assert not (tmp_path / "typo").exists()
    good = _library(tmp_path / "poses.h5")
    with pytest.raises(LibraryError, match="No pose or take 'nobody'"):
        with PoseLibrary(good).edit() as ed:
            ed.rename("nobody", "x")


def test_export_range_is_checked_as_the_flags_say_both_ends_included(tmp_path, capsys):
    from studio.cli import main

    path = _library(tmp_path / "poses.h5")
    out = tmp_path / "part.bvh"
    for start, end in (("0", "77"), ("50", "10"), ("-1", "3")):
        assert main(["db", "export", "cmu_75_18_high_sit", "--db", str(path), "--out", str(out),
                     "--start", start, "--end", end]) == 2
        assert f"within 0..76 of take 'cmu_75_18_high_sit', start <= end, got {start}..{end}" \
            in capsys.readouterr().err
    assert main(["db", "export", "cmu_75_18_high_sit", "--db", str(path), "--out", str(out),
                 "--start", "76", "--end", "76"]) == 0
    assert "wrote 1 frame of" in capsys.readouterr().out
    assert main(["db", "export", "cmu_75_18_high_sit", "--db", str(path), "--out",
                 str(tmp_path)]) == 2
    assert f"got a folder: {tmp_path}" in capsys.readouterr().err


def test_db_take_rename_and_delete(tmp_path, capsys):
    from studio.cli import main

    path = _library(tmp_path / "poses.h5")
    lib = PoseLibrary(path)
    lib.add_pose("cmu_75_18_high_sit", 39, "perch")
    lib.add_pose("cmu_75_18_high_sit", 40, "perch2")
    assert main(["db", "take", "rename", "cmu_75_18_high_sit", "high", "--db", str(path)]) == 0
    assert PoseLibrary(path).take("high").frames == 77
    assert main(["db", "take", "delete", "high", "--db", str(path)]) == 0
    assert "deleted take high and its 3 pose(s)" in capsys.readouterr().out  # (and "seated")
    lib = PoseLibrary(path)
    assert "high" not in [t.name for t in lib.takes()] and lib.find_poses() == []
    assert main(["db", "take", "delete", "perch", "--db", str(path)]) == 2
    assert "No take 'perch'" in capsys.readouterr().err


def test_a_failed_import_into_a_new_library_leaves_no_library(tmp_path, capsys):
    """A header-only file (`Frames: 0`) holds nothing to store: the error names the take, and
    the library the import would have made is not left behind empty."""
    from studio.cli import main

    empty = tmp_path / "empty.bvh"
    empty.write_text("HIERARCHY\nROOT Hips\n{\n OFFSET 0 0 0\n CHANNELS 6 Xposition Yposition "
                     "Zposition Zrotation Xrotation Yrotation\n End Site\n {\n  OFFSET 0 1 0\n }"
                     "\n}\nMOTION\nFrames: 0\nFrame Time: 0.01\n")
    path = tmp_path / "new.h5"
    assert main(["db", "import", "--db", str(path), str(empty), "--unit", "cm"]) == 2
    assert "Expected at least one frame for take 'empty'" in capsys.readouterr().err
    assert not path.exists()  # (its lock file stays: another writer may be waiting on it)
    kept = _library(tmp_path / "kept.h5")  # an existing library stays, as it was
    before = kept.read_bytes()
    assert main(["db", "import", "--db", str(kept), str(empty), "--unit", "cm"]) == 2
    assert kept.read_bytes() == before
