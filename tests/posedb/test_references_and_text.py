"""References that name one pose, text the library can store, and copies of a sibling library:
each checked against the file itself (h5py) where the library's own reading could hide it."""

import json

import h5py
import pytest

from posedb import files
from posedb.library import PoseLibrary
from posedb.schema import LibraryError, NotFoundError

from tests.conftest import high_sit_library


def _stored_pose_names(path):
    """The pose names as the file holds them, read without posedb."""
    with h5py.File(path, "r") as f:
        if "names_utf8" not in f["poses"]:
            return []
        return f["poses/names_utf8"][:].tobytes().decode("utf-8").split("\n")


def test_a_pose_named_like_a_short_id_is_its_own_not_the_pose_of_that_id(tmp_path, capsys):
    from studio.cli import main

    # pose-000001 is named "pose-3"; pose-000003 (named "third") is made after it
    path = high_sit_library(tmp_path / "poses.h5",
                            poses=((10, "pose-3", ()), (20, "second", ()), (30, "third", ())))
    lib = PoseLibrary(path)
    assert lib.pose("pose-3").name == "pose-3" and lib.pose("pose-3").frame == 10
    assert lib.pose("pose-000003").name == "third"  # (the id's own form still names the id)
    assert main(["db", "show", "pose-3", "--db", str(path), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["frame"] == 10
    # deleting "pose-3" deletes that pose, not "third"
    assert main(["db", "pose", "delete", "pose-3", "--db", str(path)]) == 0
    assert _stored_pose_names(path) == ["second", "third"]
    # a name of non-ASCII digits is a name too: free although pose id 2 exists
    lib = PoseLibrary(path)
    lib.add_pose("high_sit", 40, "pose-\u0662")  # ARABIC-INDIC DIGIT TWO
    assert lib.pose("pose-\u0662").frame == 40 and lib.pose("pose-000002").name == "second"
    assert _stored_pose_names(path) == ["second", "third", "pose-\u0662"]


def test_opening_a_library_leaves_the_change_of_a_library_named_like_it_alone(tmp_path):
    """`poses.h5.old` beside `poses.h5`: the copy a change of the one makes is not a copy a
    killed writer of the other left."""
    main_lib = high_sit_library(tmp_path / "poses.h5")
    other = high_sit_library(tmp_path / "poses.h5.old")
    with PoseLibrary(other).edit() as ed:
        ed.add_pose("high_sit", 5, "kept")
        PoseLibrary(main_lib)  # a reader of poses.h5 meanwhile (`db list`)
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".poses.h5.old.")]
    assert _stored_pose_names(other) == ["perch", "kept"]
    # a copy that a killed writer of poses.h5 left is still removed
    left = files.temporary_path(main_lib.resolve())
    left.write_bytes(b"half a change")
    notes = PoseLibrary(main_lib).notes
    assert not left.exists() and len(notes) == 1 and left.name in notes[0]


@pytest.mark.parametrize("option", ["--name", "--notes"])
def test_text_that_is_not_utf8_is_refused_naming_it_not_called_damage(tmp_path, capsys, option):
    from studio.cli import main

    path = high_sit_library(tmp_path / "poses.h5")
    before = path.read_bytes()
    bad = "o\udcffk"  # how Python passes on a command line byte that is not UTF-8
    args = ["db", "pose", "add", "high_sit", "3", "--db", str(path), "--json", option, bad]
    if option == "--notes":
        args += ["--name", "fine"]
    assert main(args) == 2
    captured = capsys.readouterr()
    assert "UTF-8" in captured.err and "damaged" not in captured.err
    assert json.loads(captured.out)["exit_status"] == 2
    assert path.read_bytes() == before


def test_names_and_notes_that_hdf5_cannot_hold_are_refused_before_a_change(tmp_path):
    path = high_sit_library(tmp_path / "poses.h5")
    lib = PoseLibrary(path)
    for change, said in (
            (lambda ed: ed.add_pose("high_sit", 3, "a\x00b"), "control characters"),
            (lambda ed: ed.add_pose("high_sit", 3, "a\x1bb"), "control characters"),
            (lambda ed: ed.rename_take("high_sit", "s\udcffb"), "take name as UTF-8"),
            (lambda ed: ed.set_take("high_sit", notes="n\x00"), "without NUL"),
            (lambda ed: ed.set_pose("perch", notes="\udcff"), "notes of pose 'perch'")):
        with pytest.raises(LibraryError, match=said):
            with lib.edit() as ed:
                change(ed)
    assert _stored_pose_names(path) == ["perch"]
    with h5py.File(path, "r") as f:
        assert f["takes/take-00001"].attrs["name"] == "high_sit"


def test_a_recording_whose_take_could_never_be_stored_is_refused_before_it_starts(tmp_path):
    from posedb.record import journal_dir, record

    from tests.capture.test_stream_fixtures import STREAMS
    from tests.conftest import recording

    db = tmp_path / "poses.h5"
    with pytest.raises(LibraryError, match="notes of take 'live' as UTF-8"):
        record(f"file:{STREAMS / 'skipped_indices.raw'}", db, "live",
               str(recording("cmu_75_18_high_sit.bvh")), notes="n\udcffx")
    # no journal left that `db recover` would fail to store again and again
    assert not journal_dir(db).exists() or not list(journal_dir(db).glob("*.raw"))


def test_tagging_what_is_neither_a_pose_nor_a_take_says_both_were_looked_for(tmp_path):
    lib = PoseLibrary(high_sit_library(tmp_path / "poses.h5"))
    with pytest.raises(NotFoundError, match="No pose or take 'nosuch'"):
        with lib.edit() as ed:
            ed.tag("nosuch", add=["sit"])


def test_a_name_is_one_name_however_its_accents_are_encoded(tmp_path, capsys):
    """"Café" typed (composed, NFC) and "Café" from a file name on macOS (decomposed, NFD)
    look alike: they are one name, stored composed, found given either way."""
    from posedb.library import DuplicateNameError
    from studio.cli import main

    composed, decomposed = "Caf\u00e9", "Cafe\u0301"
    path = high_sit_library(tmp_path / "poses.h5")
    lib = PoseLibrary(path)
    lib.add_pose("high_sit", 3, decomposed)
    with pytest.raises(DuplicateNameError, match="already exists"):
        lib.add_pose("high_sit", 4, composed)
    assert _stored_pose_names(path) == ["perch", composed]
    assert lib.pose(composed).frame == 3 and lib.pose(decomposed).frame == 3
    with lib.edit() as ed:
        ed.rename_take("high_sit", "Sitze\u0301")
    with h5py.File(path, "r") as f:
        assert f["takes/take-00001"].attrs["name"] == "Sitz\u00e9"
    assert lib.take("Sitze\u0301").id == lib.take("Sitz\u00e9").id == "take-00001"
    assert main(["db", "list", "--take", "Sitze\u0301", "--db", str(path), "--json"]) == 0
    assert [r["name"] for r in json.loads(capsys.readouterr().out)] == ["Sitz\u00e9", "perch",
                                                                         composed]
