"""Small answers of the pose library a user meets: an empty tag expression however written,
a rename to the name a pose or take already has."""

import pytest


def test_an_expression_of_spaces_alone_is_as_empty_every_pose_and_take(tmp_path):
    """`--tag ""` lists everything; `--tag "   "` (a script's empty variable, quoted with a
    space) was refused as a malformed expression. Both mean no filter."""
    from posedb.library import PoseLibrary
    from tests.conftest import recording

    lib = PoseLibrary(tmp_path / "l.h5", create=True)
    with lib.edit() as ed:
        take = ed.import_bvh(recording("cmu_75_18_high_sit.bvh"), subject="75", tags=["sit"])
        ed.add_pose(take, 39, "perch", tags=["sit"])
    assert [p.name for p in lib.find_poses("   ")] == ["perch"]
    assert lib.find_poses("   ") == lib.find_poses("") == lib.find_poses(None)
    assert len(lib.find_takes("  \t")) == 1
    assert lib.find_takes("  \t") == lib.find_takes("") == lib.find_takes(None)


def test_renaming_a_pose_or_take_to_its_own_name_changes_nothing(tmp_path):
    """`pose rename X X` (a script's rename that is already done) said a pose X already
    exists: it is its own name, so nothing changes and nothing clashes. Another's name still
    clashes."""
    from posedb.library import DuplicateNameError, PoseLibrary
    from tests.conftest import recording

    lib = PoseLibrary(tmp_path / "l.h5", create=True)
    with lib.edit() as ed:
        take = ed.import_bvh(recording("cmu_75_18_high_sit.bvh"), subject="75", tags=["sit"])
        ed.add_pose(take, 39, "perch")
    name = lib.takes()[0].name
    with lib.edit() as ed:
        ed.rename("perch", "perch")
        ed.rename_take(name, name)
    assert [p.name for p in lib.poses()] == ["perch"] and lib.takes()[0].name == name
    with pytest.raises(DuplicateNameError), lib.edit() as ed:
        ed.rename("perch", name)
