"""The pose library: round trips, poses, tags, search, suggestions, and bad input."""

import hashlib
import json

import h5py
import numpy as np
import pytest

from capture import read_bvh
from posedb.library import DuplicateNameError, PoseLibrary
from posedb.schema import SCHEMA_VERSION, LibraryError, NotFoundError, SchemaError
from posedb.tags import TagError, compile_expression, membership

from tests.conftest import SHARED_BVH, recording

NAMES = ["cmu_75_18_high_sit.bvh", "cmu_75_17_medium_sit.bvh", "cmu_82_05_floor_sit_excerpt.bvh",
         "axis_neuron_standing_yxz.bvh"]


@pytest.fixture
def lib(tmp_path):
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    with lib.edit() as ed:
        ed.import_bvh(recording("cmu_75_18_high_sit.bvh"), subject="75", tags=["sit", "high"])
        ed.import_bvh(recording("cmu_82_05_floor_sit_excerpt.bvh"), subject="82",
                      tags=["sit", "floor"])
    return lib


def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_import_export_round_trip_of_every_recording(tmp_path):
    lib = PoseLibrary(tmp_path / "poses.h5", create=True)
    files = sorted(SHARED_BVH.glob("*.bvh")) or [recording(n) for n in NAMES]
    with lib.edit() as ed:
        for path in files:
            ed.import_bvh(path, subject="s", tags=["imported"])
    assert len(lib.takes()) == len(files)
    for path in files:
        original = read_bvh(path)
        take = lib.take(path.stem)
        assert take.frames == original.motion.num_frames
        from capture import write_bvh

        out = tmp_path / f"{path.stem}.out.bvh"
        exported = lib.take_bvh(take.id)
        write_bvh(out, exported.skeleton, exported.motion)
        again = read_bvh(out)
        assert again.skeleton.names == original.skeleton.names
        assert np.abs(again.motion.channels - original.motion.channels).max() <= 1e-4
        np.testing.assert_allclose(again.skeleton.offsets, original.skeleton.offsets, atol=1e-6)
        # derived arrays agree with the reader's own
        data = lib.take_data(take.id)
        np.testing.assert_allclose(data.root_positions,
                                   original.skeleton.root_positions(original.motion.channels),
                                   atol=1e-5)
        ours = original.skeleton.local_rotations(original.motion.channels)
        dots = np.abs(np.sum(data.local_rotations * ours, axis=-1))
        assert dots.min() > 1 - 1e-6


def test_frame_range_export(lib):
    data = lib.take_data("cmu_75_18_high_sit", 10, 21)
    original = read_bvh(recording("cmu_75_18_high_sit.bvh"))
    np.testing.assert_array_equal(data.channels, original.motion.channels[10:21])
    with pytest.raises(ValueError, match="frame range within 0..77"):
        lib.take_data("cmu_75_18_high_sit", 70, 80)
    with pytest.raises(ValueError, match=r"got 10\.\.10 \(empty"):
        lib.take_data("cmu_75_18_high_sit", 10, 10)


def test_skeletons_are_stored_once(tmp_path):
    lib = PoseLibrary(tmp_path / "p.h5", create=True)
    with lib.edit() as ed:
        ed.import_bvh(recording("cmu_75_18_high_sit.bvh"))
        ed.import_bvh(recording("cmu_75_18_high_sit.bvh"), name="again")
        ed.import_bvh(recording("axis_neuron_standing_yxz.bvh"))
    assert lib.stats()["skeletons"] == 2
    assert lib.take("again").skeleton == lib.take("cmu_75_18_high_sit").skeleton


def test_pose_lifecycle(lib):
    pose = lib.add_pose("cmu_75_18_high_sit", 39, "perch", tags=["Sit", "high"],
                        supports=["torso", "legs", "feet"], notes="knees at 90 degrees")
    assert pose.tags == ("high", "sit")
    assert pose.supports == ("upper_back", "lower_back", "pelvis", "thighs", "calves", "feet")
    info, sk, rot, root = lib.pose_data("perch")
    take = lib.take_data("cmu_75_18_high_sit", 39, 40)
    np.testing.assert_allclose(rot, take.local_rotations[0], atol=1e-7)
    np.testing.assert_allclose(root, take.root_positions[0], atol=1e-6)
    assert 0.45 < root[1] < 0.55  # seated hips height, metres
    with lib.edit() as ed:
        ed.rename("perch", "high_perch")
        ed.tag("high_perch", add=["favourite"], remove=["high"])
        ed.set_pose("high_perch", supports="seat", notes="")
    again = lib.pose("high_perch")
    assert again.id == pose.id and again.tags == ("favourite", "sit")
    assert again.supports == ("pelvis", "thighs") and again.notes == ""
    with lib.edit() as ed:
        ed.set_pose("high_perch", supports=["Forearms", "calves", "head", "calves"])
    # in BODY_REGIONS order, each once
    assert lib.pose("high_perch").supports == ("head", "calves", "forearms")
    with lib.edit() as ed:
        ed.delete_pose("high_perch")
    with pytest.raises(NotFoundError, match="No pose 'high_perch'"):
        lib.pose("high_perch")


def test_search(lib):
    lib.add_pose("cmu_75_18_high_sit", 39, "a", tags=["sit", "high"])
    lib.add_pose("cmu_75_18_high_sit", 35, "b", tags=["sit", "lean"])
    lib.add_pose("cmu_82_05_floor_sit_excerpt", 8, "c", tags=["sit", "floor", "lounge"])
    names = lambda poses: sorted(p.name for p in poses)  # noqa: E731
    assert names(lib.find_poses("sit and not floor")) == ["a", "b"]
    assert names(lib.find_poses("lean or lounge")) == ["b", "c"]
    assert names(lib.find_poses("not (high or lean)")) == ["c"]
    assert names(lib.find_poses("SIT AND NOT FLOOR")) == ["a", "b"]
    assert names(lib.find_poses("unknown_tag")) == []
    assert names(lib.find_poses(take="cmu_82_05_floor_sit_excerpt")) == ["c"]
    assert names(lib.find_poses("sit", subject="75")) == ["a", "b"]
    assert [t.name for t in lib.find_takes("floor")] == ["cmu_82_05_floor_sit_excerpt"]


@pytest.mark.parametrize("expr, message", [
    ("sit and", "expected a tag or '\\(', got the end"),
    ("(sit or lean", "expected '\\)'"),
    ("sit lean", "expected 'and', 'or' or the end, got 'lean'"),
    ("sit & lean", "expected 'and', 'or' or the end, got '&'"),
    ("", "empty"),
])
def test_bad_tag_expressions_are_named(expr, message):
    with pytest.raises(TagError, match=message):
        compile_expression(expr)


def test_tag_expression_by_hand():
    m, vocab = membership([("a", "b"), ("a",), ("b", "c"), ()])
    assert compile_expression("a and not b")(m, vocab).tolist() == [False, True, False, False]
    assert compile_expression("a or b and c")(m, vocab).tolist() == [True, True, True, False]
    assert compile_expression("not a and not b")(m, vocab).tolist() == [False, False, False, True]


def test_suggest_finds_the_seated_phase_only(lib):
    from posedb.suggest import held_postures

    data = lib.take_data("cmu_75_18_high_sit")
    held = held_postures(data.skeleton, data.motion().channels, data.take.frame_time, "cmu")
    assert held, "no held posture found"
    for h in held:
        assert 18 <= h.start <= h.frame <= h.end <= 51, h
        assert (h.end - h.start + 1) * data.take.frame_time >= 0.5 - 1e-3
    hips = data.root_positions[[h.frame for h in held], 1]
    assert np.all(hips < 0.55)


def test_suggest_cli_accepts(tmp_path, capsys):
    from solver.cli import main

    db = str(tmp_path / "p.h5")
    assert main(["db", "import", str(recording("cmu_75_18_high_sit.bvh")), "--db", db]) == 0
    capsys.readouterr()
    assert main(["db", "suggest", "cmu_75_18_high_sit", "--db", db, "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert rows and all({"start", "end", "frame"} <= set(r) for r in rows)
    assert main(["db", "suggest", "cmu_75_18_high_sit", "--db", db, "--accept", "--tag", "sit",
                 "--json"]) == 0
    capsys.readouterr()
    assert main(["db", "list", "--db", db, "--tag", "sit", "--kind", "pose", "--json"]) == 0
    poses = json.loads(capsys.readouterr().out)
    assert [p["frame"] for p in poses] == [r["frame"] for r in rows]
    assert all({"id", "kind", "name", "tags"} <= set(p) and p["kind"] == "pose" for p in poses)


# -- bad input leaves the library as it was -----------------------------------------------------


def test_not_hdf5(tmp_path):
    path = tmp_path / "notes.h5"
    path.write_text("these are my notes, not a database")
    with pytest.raises(SchemaError, match="not an HDF5 file"):
        PoseLibrary(path)
    assert path.read_text() == "these are my notes, not a database"


def test_truncated_file(lib, tmp_path):
    whole = lib.path.read_bytes()
    cut = tmp_path / "cut.h5"
    cut.write_bytes(whole[: len(whole) // 3])
    before = _digest(cut)
    with pytest.raises(SchemaError, match="damaged or truncated"):
        PoseLibrary(cut)
    assert _digest(cut) == before


def test_foreign_hdf5(tmp_path):
    path = tmp_path / "other.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("temperature", data=np.arange(5))
    before = _digest(path)
    with pytest.raises(SchemaError, match="HDF5 file but not a sitrelax pose library"):
        PoseLibrary(path)
    with pytest.raises(SchemaError):  # nor is it taken over by an import
        PoseLibrary(path, create=True)
    assert _digest(path) == before


@pytest.mark.parametrize("version, message", [
    (SCHEMA_VERSION + 1, "newer than this sitrelax reads"),
    (0, "cannot migrate"),
    ("one", "unreadable schema version"),
])
def test_wrong_schema_version(lib, version, message):
    with h5py.File(lib.path, "r+") as f:
        f.attrs["sitrelax_schema"] = version
    before = _digest(lib.path)
    with pytest.raises(SchemaError, match=message):
        PoseLibrary(lib.path)
    assert _digest(lib.path) == before


def test_bvh_that_fails_to_parse(lib, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n\tOFFSET 0 0\n")
    before = _digest(lib.path)
    with pytest.raises(ValueError, match="bad.bvh:4: expected 3 numbers after OFFSET"):
        with lib.edit() as ed:
            ed.import_bvh(recording("cmu_75_17_medium_sit.bvh"))  # fine, but the batch fails
            ed.import_bvh(bad)
    assert _digest(lib.path) == before
    assert [t.name for t in lib.takes()] == ["cmu_75_18_high_sit", "cmu_82_05_floor_sit_excerpt"]
    assert not list(tmp_path.glob(".poses.h5.*.tmp"))


def test_duplicate_names(lib):
    lib.add_pose("cmu_75_18_high_sit", 39, "perch")
    before = _digest(lib.path)
    with pytest.raises(DuplicateNameError, match="take named 'cmu_75_18_high_sit' already"):
        lib.import_bvh(recording("cmu_75_18_high_sit.bvh"))
    with pytest.raises(DuplicateNameError, match="pose named 'perch' already"):
        lib.add_pose("cmu_75_18_high_sit", 40, "perch")
    with pytest.raises(DuplicateNameError):
        with lib.edit() as ed:
            ed.add_pose("cmu_75_18_high_sit", 41, "fresh")
            ed.rename("fresh", "perch")
    # takes and poses share one namespace with their ids: a reference names one thing
    take = lib.take("cmu_75_18_high_sit")
    with pytest.raises(DuplicateNameError, match="take named"):
        lib.add_pose("cmu_75_18_high_sit", 42, "cmu_82_05_floor_sit_excerpt")
    for name in (take.id, "pose-000007", "take-123456"):
        with pytest.raises(LibraryError, match="not of an id's form"):
            lib.add_pose("cmu_75_18_high_sit", 42, name)
    with pytest.raises(DuplicateNameError, match="pose named 'perch'"):
        with lib.edit() as ed:
            ed.rename("cmu_82_05_floor_sit_excerpt", "perch")
    assert _digest(lib.path) == before
    # names like the studio's default take names are no ids (those are zero-padded)
    lib.add_pose("cmu_75_18_high_sit", 43, "take-1")
    with lib.edit() as ed:  # and a take is renamed as a take, whatever a pose is called
        ed.rename_take(take.id, "pose-7")
    assert lib.take(take.id).name == "pose-7" and lib.pose("take-1").frame == 43


@pytest.mark.parametrize("call, message", [
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 77, "x"), "frame in 0..76"),
    (lambda lib: lib.add_pose("nope", 1, "x"), "No take 'nope'"),
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 1, "x", supports=["tail"]),
     r"Expected body regions \(head, upper_back.*got 'tail'"),
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 1, "x", supports=[]),
     "at least one body region"),
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 1, "x", tags=["not"]), "Expected a tag"),
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 1, "a/b"), "without '/'"),
    (lambda lib: lib.add_pose("cmu_75_18_high_sit", 5.7, "x"), "whole frame number for frame"),
    (lambda lib: lib.take_data("cmu_75_18_high_sit", 1.5, 3),
     "whole frame number for start, got 1.5"),
])
def test_bad_pose_requests(lib, call, message):
    before = _digest(lib.path)
    with pytest.raises(LibraryError, match=message):
        call(lib)
    assert _digest(lib.path) == before


def test_missing_library_is_named(tmp_path):
    with pytest.raises(NotFoundError, match="No pose library at"):
        PoseLibrary(tmp_path / "none.h5")
    assert not (tmp_path / "none.h5").exists()


def test_concurrent_writers_queue(lib):
    import threading

    errors = []

    def add(k):
        try:
            PoseLibrary(lib.path).add_pose("cmu_75_18_high_sit", k, f"p{k}")
        except Exception as exc:  # collected for the assertion below
            errors.append(exc)

    threads = [threading.Thread(target=add, args=(k,)) for k in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert sorted(p.name for p in PoseLibrary(lib.path).poses()) == sorted(f"p{k}" for k in range(8))


def test_a_bad_name_is_refused_saying_what_is_wrong(lib):
    from posedb.library import checked_name

    assert checked_name("  perch  ") == "perch"
    for name, said in (("", "got an empty one"), ("   ", "got an empty one"),
                       ("x" * 201, "at most 200 characters, got 201"),
                       ("a/b", "without '/'"), ("a\tb", "without '/', tabs")):
        with pytest.raises(LibraryError, match=said):
            checked_name(name)


def test_a_new_tag_is_a_word_not_a_note(lib, monkeypatch):
    import posedb.tags
    from posedb.suggest import suggest_poses
    from posedb.tags import MAX_TAG

    long = "x" * MAX_TAG
    with lib.edit() as ed:
        ed.tag("cmu_75_18_high_sit", add=[long])
    with pytest.raises(TagError, match=f"at most {MAX_TAG} characters.*got one of 200"):
        with lib.edit() as ed:
            ed.tag("cmu_75_18_high_sit", add=["y" * 200])
    # a tag stored before (here: before the limit is lowered) is inherited, kept and removed
    monkeypatch.setattr(posedb.tags, "MAX_TAG", 10)
    (row,) = suggest_poses(lib, "cmu_75_18_high_sit", accept=True)
    assert long in row["tags"]
    lib.add_pose("cmu_75_18_high_sit", 40, "perch", tags=[long])
    with pytest.raises(TagError, match="at most 10 characters"):
        lib.add_pose("cmu_75_18_high_sit", 41, "perch2", tags=["z" * 11])
    with lib.edit() as ed:
        ed.tag("perch", remove=[long])
    assert lib.pose("perch").tags == ()
