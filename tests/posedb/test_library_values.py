"""Values a library must never hold: numbers that are not finite, that the type they are stored
as cannot hold, or that mean nothing (a frame time of 0, a support bit naming no region, a pose
of a missing take). A write refuses them before anything is written, `db check` names them in
a damaged file, and the readers refuse such a file as damaged rather than divide by them or
print them."""

import hashlib
import json
import re
import warnings

import h5py
import numpy as np
import pytest

from capture import read_bvh
from capture.sources import RawFileTransport, Source
from posedb.library import PoseLibrary
from posedb.record import TakeRecorder, journal_dir, recover
from posedb.schema import LibraryError
from posedb.verify import verify

from tests.capture.test_stream_fixtures import STREAMS
from tests.conftest import recording

CMU = "cmu_75_18_high_sit.bvh"
CAPTURE = STREAMS / "skipped_indices.raw"  # 60 CMU frames


def _digest(path) -> str:
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "poses.h5"
    lib = PoseLibrary(path, create=True)
    lib.import_bvh(recording(CMU), tags=["sit"])
    lib.add_pose(CMU[:-4], 39, "seated")
    return path


def _far_bvh(tmp_path, value: str, name: str = "far"):
    """The CMU take with the root's first X position of the first frame set to `value`."""
    lines = recording(CMU).read_text().split("\n")
    k = next(i for i, line in enumerate(lines) if line.startswith("Frame Time")) + 1
    values = lines[k].split()
    values[0] = value
    lines[k] = " ".join(values)
    path = tmp_path / f"{name}.bvh"
    path.write_text("\n".join(lines))
    return path


def _main(*args) -> int:
    from studio.cli import main

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # (a library never warns on stderr: it refuses)
        return main(list(args))


# -- 1. a write checks every array it stores ------------------------------------------------


@pytest.mark.parametrize("value, unit", [("1e40", "auto"), ("1e36", "1000")])
def test_an_import_beyond_float32_is_refused_and_the_library_is_unchanged(db, tmp_path, capsys,
                                                                           value, unit):
    """Root positions are stored as float32 metres: 1e40 of the CMU file's unit (5.6e38 m),
    or 1e36 km, would become infinity, after which the library could not even drop the take.
    The BVH reader refuses such values now (within +-1e9, `capture.bvh.MAX_VALUE`), naming the
    line; the library's own check of what it stores is `test_every_array_of_a_take_...`."""
    far = _far_bvh(tmp_path, value)
    before = _digest(db)
    assert _main("db", "import", str(far), "--unit", unit, "--db", str(db)) == 2
    err = capsys.readouterr().err
    assert f"{far}:" in err and f"expected a number within +-1e+09 in column 1, got " \
        f"'{value}'" in err
    assert _digest(db) == before and verify(db) == []
    assert _main("db", "take", "delete", CMU[:-4], "--db", str(db)) == 0  # still editable


def test_every_array_of_a_take_is_checked_before_anything_is_written(db):
    bvh = read_bvh(recording(CMU))
    t = bvh.motion.num_frames
    good = dict(channels=bvh.motion.channels, frame_time=bvh.motion.frame_time)
    times = 1.7e9 + np.arange(t) / 30
    bad = {
        "frame_time": (dict(frame_time=float("nan")), "frame_time is nan"),
        "frame_time 0": (dict(frame_time=0.0), "frame_time is 0.0"),
        "channels": (dict(channels=np.where(np.arange(t)[:, None] == 5, np.inf,
                                            bvh.motion.channels)),
                     "Expected finite channels for take 'x', got inf in frame 5"),
        "received_at": (dict(received_at=np.where(np.arange(t) == 3, np.nan, times)),
                        "Expected finite received_at for take 'x', got nan in frame 3"),
        "received_at shape": (dict(received_at=times[:-1]), f"received_at ({t},)"),
        "frame_indices": (dict(frame_indices=np.arange(t) + 0.5),
                          "Expected whole numbers as frame_indices of take 'x'"),
        "frame_indices range": (dict(frame_indices=np.full(t, 1e19)),
                                "stored as int64), got 1e+19 in frame 0"),
    }
    before = _digest(db)
    for case, (change, message) in bad.items():
        with pytest.raises(LibraryError, match=re.escape(message)):
            with PoseLibrary(db).edit() as ed:
                ed.add_take(bvh.skeleton, name="x", **(good | change))
        assert _digest(db) == before, case
    from posedb.schema import InvalidDataError

    with pytest.raises(InvalidDataError):  # (the class a recorder tells from a busy library)
        with PoseLibrary(db).edit() as ed:
            ed.add_take(bvh.skeleton, name="x", **(good | bad["frame_time"][0]))


# -- 2. a recording whose receive times are not numbers -------------------------------------


def _journal_with_times_that_are_not_numbers(db, monkeypatch) -> TakeRecorder:
    """A journal of the fixture capture left as a killed recorder leaves it, read back (as the
    capture side could, before its reader was hardened) with frame 7's receive time NaN."""
    import importlib

    module = importlib.import_module("posedb.record")  # (`posedb.record` is the function)
    rec = TakeRecorder(db, "nan_times", str(recording(CMU)), f"file:{CAPTURE}")
    source = Source(RawFileTransport(CAPTURE), rec.layout, raw=rec.writer)
    while not source.exhausted:
        source.read(0.0)
    source.raw = None
    source.close()

    class NotANumberAtFrame7(Source):
        def __iter__(self):
            for k, frame in enumerate(super().__iter__()):
                yield frame._replace(received_at=float("nan")) if k == 7 else frame

    monkeypatch.setattr(module, "Source", NotANumberAtFrame7)
    return rec


def test_recover_refuses_receive_times_that_are_not_numbers_and_keeps_the_journal(
        db, monkeypatch, capsys):
    rec = _journal_with_times_that_are_not_numbers(db, monkeypatch)
    rec.abandon()
    before = _digest(db)
    (row,) = recover(db)
    assert row["status"].startswith("failed: Expected finite received_at for take "
                                    "'nan_times'"), row
    assert "got nan in frame 7" in row["status"]
    assert rec.journal.exists() and _digest(db) == before and verify(db) == []
    assert _main("db", "recover", "--db", str(db)) == 1  # the command says which journal
    out = capsys.readouterr().out
    assert out.startswith("nan_times: failed: ") and f"its journal {rec.journal} is kept" in out
    assert _main("db", "list", "--json", "--db", str(db)) == 0
    rows = json.loads(capsys.readouterr().out, parse_constant=pytest.fail)
    assert [r["name"] for r in rows if r["kind"] == "take"] == [CMU[:-4]]


def test_a_recorder_whose_receive_times_are_not_numbers_stores_nothing(db, monkeypatch):
    rec = _journal_with_times_that_are_not_numbers(db, monkeypatch)
    before = _digest(db)
    with pytest.raises(LibraryError, match=r"The recording of take 'nan_times' was not stored "
                                           r".*received_at.*it is kept as received in"):
        rec.finish()
    assert _digest(db) == before and list(journal_dir(db).glob("*.raw")) == [rec.journal]


# -- 3. held-posture options ---------------------------------------------------------------


@pytest.mark.parametrize("option, value, message", [
    ("--min-duration", "1e308", "argument --min-duration: expected a number <= 86400"),
    ("--min-duration", "-1", "argument --min-duration: expected a number >= 0"),
    ("--max-speed", "0", "argument --max-speed: expected a number > 0"),
])
def test_suggest_options_out_of_range_are_refused_by_their_name(db, capsys, option, value,
                                                                message):
    with pytest.raises(SystemExit) as stopped:
        _main("db", "suggest", CMU[:-4], option, value, "--db", str(db))
    assert stopped.value.code == 2
    err = capsys.readouterr().err
    assert message in err and ("max_speed" not in err or option == "--max-speed")


def test_held_postures_names_the_option_out_of_range_and_never_overflows():
    from capture import identify_profile
    from posedb.suggest import held_postures

    bvh = read_bvh(recording(CMU))
    args = (bvh.skeleton, bvh.motion.channels, bvh.motion.frame_time,
            identify_profile(bvh.skeleton.names))
    for option, value in (("min_duration", 1e308), ("min_duration", -1.0),
                          ("min_bottom_duration", 1e308), ("smooth", float("inf"))):
        with pytest.raises(LibraryError, match=f"Expected {option} as a finite number of "
                                               "seconds from 0 to 86400"):
            held_postures(*args, **{option: value})
    with pytest.raises(LibraryError, match="Expected frame_time as a finite number > 0"):
        held_postures(*args[:2], 0.0, args[3])
    assert held_postures(*args, min_duration=86400, min_bottom_duration=None) == []
    assert held_postures(bvh.skeleton, bvh.motion.channels, 1e-300, args[3], smooth=86400,
                         min_duration=86400, min_bottom_duration=None) == []


# -- 4. damage `db check` names and readers refuse ------------------------------------------


def _set(path, where: str, key: str | None, value) -> None:
    """Sets attribute `key` of `where` (or, key None, element 0 of the dataset)."""
    with h5py.File(path, "r+") as f:
        if key is not None:
            f[where].attrs[key] = value
        else:
            data = f[where][:]
            data.flat[0] = value
            f[where][...] = data


def _delete(path, where: str) -> None:
    with h5py.File(path, "r+") as f:
        del f[where]


def _skeleton(path) -> str:
    with h5py.File(path, "r") as f:
        return "/skeletons/" + next(iter(f["skeletons"]))


DAMAGE = {
    "frame_time 0": (lambda p: _set(p, "/takes/take-00001", "frame_time", 0.0),
                     "/takes/take-00001: frame_time is 0.0, not a number of seconds"),
    "frame_time NaN": (lambda p: _set(p, "/takes/take-00001", "frame_time", np.nan),
                       "/takes/take-00001: frame_time is nan"),
    "root NaN": (lambda p: _set(p, "/poses/root_position", None, np.nan),
                 "pose 'seated': root_position [nan,"),
    "supports 0xFFFF": (lambda p: _set(p, "/poses/supports", None, 0xFFFF),
                        "pose 'seated': supports 0xffff has bits above the 13"),
    "created_at NaN": (lambda p: _set(p, "/poses/created_at", None, np.nan),
                       "pose 'seated': created_at is nan"),
    "placement half NaN": (lambda p: _set(p, "/poses/placement", None, 0.1),
                           "pose 'seated': placement [0.1, nan, nan, nan] is neither an offset"),
    "unit NaN": (lambda p: _set(p, _skeleton(p), "unit_m", np.nan),
                 "attribute 'unit_m' is unknown (nan)"),
    "offsets NaN": (lambda p: _set(p, _skeleton(p) + "/offsets", None, np.nan),
                    "/offsets: 1 value(s) that are not numbers"),
    "missing take": (lambda p: _delete(p, "/takes/take-00001"),
                     "pose 'seated' refers to take-00001, which does not exist"),
    "stray attribute NaN": (lambda p: _set(p, "/poses", "unit_m", np.nan),
                            "/poses: attribute 'unit_m' is nan, not a number"),
}


@pytest.mark.parametrize("damage", list(DAMAGE))
def test_check_names_damage_and_readers_refuse_it_rather_than_print_nan(db, tmp_path, capsys,
                                                                        damage):
    make, problem = DAMAGE[damage]
    make(db)
    assert _main("db", "check", "--db", str(db), "--quick") == 1
    assert problem in capsys.readouterr().out
    out = tmp_path / "out.bvh"
    commands = [("list", "--json"), ("show", "seated", "--json"), ("stats", "--json"),
                ("suggest", CMU[:-4], "--json"),
                ("export", CMU[:-4], "--out", str(out))]
    for command in commands:
        code = _main("db", *command, "--db", str(db))
        text = capsys.readouterr()
        if code == 0:  # (a reader that never meets the damaged value)
            json.loads(text.out, parse_constant=pytest.fail) if "--json" in command else None
            assert damage == "stray attribute NaN" or command[0] in ("list", "show", "stats")
            assert "nan" not in text.out.lower(), (command, text.out)
        else:
            assert code == 2, (command, text)
            assert f"{db} is damaged: " in text.err and "db check" in text.err, (command, text)
            assert "Traceback" not in text.err
    assert damage == "stray attribute NaN" or not out.exists()  # nothing exported
